#!/usr/bin/env bash
# Installs QGIS 3.22 LTR and the native libraries the venv builds against, from Debian's
# packages. Does nothing when everything is already there (make setup is idempotent).
set -euo pipefail
PACKAGES=(qgis python3-qgis qgis-providers python3-pyproj libgdal-dev libgeos-dev
          python3-venv python3-dev build-essential xvfb)
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
echo "installing Debian packages: ${missing[*]}"
$SUDO apt-get update -q
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q "${missing[@]}"
