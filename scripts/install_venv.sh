#!/usr/bin/env bash
# Creates .venv from Debian's python (so PyQGIS is importable) and installs requirements.
set -euo pipefail
VENV=${1:-.venv}
shift || true
REQS=("$@")
[ ${#REQS[@]} -eq 0 ] && REQS=(requirements.txt)
if [ ! -x "$VENV/bin/python" ]; then
  /usr/bin/python3 -m venv --system-site-packages "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade "pip<25" wheel
fi
# Source builds of shapely and pyogrio against Debian's GEOS/GDAL (see requirements.txt).
args=()
for r in "${REQS[@]}"; do args+=(-r "$r"); done
"$VENV/bin/python" -m pip install -q --no-binary shapely,pyogrio "${args[@]}"
# A pyproj wheel bundles its own PROJ and crashes QGIS: only Debian's may be importable.
if "$VENV/bin/python" -m pip show pyproj 2>/dev/null | grep -q "Location: .*$VENV"; then
  echo "error: a PyPI pyproj was installed into $VENV; remove it (Debian's python3-pyproj is required)" >&2
  exit 1
fi
