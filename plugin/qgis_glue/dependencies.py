"""The Python packages the engine needs, checked and installed for QGIS's own Python.

A stock QGIS has numpy and GDAL (often scipy and matplotlib too); the engine also needs
shapely 2, pandas, OpenCV and onnxruntime. They are installed with QGIS's own Python and pip
into a folder private to this plugin inside the QGIS profile
(``<profile>/python/dependencies/urban_synthesis/python3.X``), never into the user's site,
and that folder goes to the *end* of ``sys.path``: whatever QGIS ships (numpy, GDAL) keeps
precedence, and the packages QGIS already has are pinned to their installed versions so pip
does not pull a second copy that would not match QGIS's binaries.

On Linux shapely is built from source against the system GEOS (the wheel bundles its own
GEOS, and QGIS and shapely geometry operations in one process then crash: see
docs/ARCHITECTURE.md); that needs the GEOS headers (Debian/Ubuntu: ``libgeos-dev``, plus
``python3-dev`` and a compiler).

This module imports nothing but the standard library and qgis, so that it works when the
engine's packages are missing.
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

from ..core.paths import PLUGIN_ROOT

#: import name -> distribution name, for the packages the toolbox needs at run time
RUNTIME_PACKAGES: Dict[str, str] = {
    "numpy": "numpy", "scipy": "scipy", "shapely": "shapely", "pandas": "pandas",
    "matplotlib": "matplotlib", "cv2": "opencv-contrib-python-headless",
    "onnxruntime": "onnxruntime",
}
#: packages QGIS itself loads binaries of: never replaced, only pinned
QGIS_OWNED = ("numpy",)
REQUIREMENTS = PLUGIN_ROOT / "requirements.txt"
HELP = ("Install {} with Plugins > Urban Synthesis > Install Python dependencies (or run "
        "'urbansynth:installdependencies'); see the README, section 'Install'.")


def private_site(profile_dir: Optional[str] = None) -> Path:
    """The plugin's own package folder in the QGIS profile, per Python minor version."""
    if profile_dir is None:
        from qgis.core import QgsApplication

        profile_dir = QgsApplication.qgisSettingsDirPath()
    minor = f"python{sys.version_info.major}.{sys.version_info.minor}"
    return Path(profile_dir) / "python" / "dependencies" / "urban_synthesis" / minor


def activate(site: Optional[Path] = None) -> Path:
    """Append the private folder to ``sys.path`` (after QGIS's own packages)."""
    site = private_site() if site is None else Path(site)
    if site.is_dir() and str(site) not in sys.path:
        sys.path.append(str(site))
        importlib.invalidate_caches()
    return site


def missing_packages() -> List[str]:
    """Distribution names of the runtime packages that cannot be imported."""
    missing = []
    for module, dist in RUNTIME_PACKAGES.items():
        if importlib.util.find_spec(module) is None:
            missing.append(dist)
        elif module == "shapely" and not _shapely_2():
            missing.append(dist)
    return missing


def _shapely_2() -> bool:
    try:
        import shapely
    except Exception:  # noqa: BLE001 - a broken install counts as missing
        return False
    return int(shapely.__version__.split(".")[0]) >= 2


def missing_message(missing: Sequence[str]) -> str:
    return (f"Urban Synthesis needs the Python package{'s' if len(missing) > 1 else ''} "
            f"{', '.join(missing)}, which QGIS's Python does not have. "
            + HELP.format("them" if len(missing) > 1 else "it"))


def pinned_versions(path: Path = REQUIREMENTS) -> Dict[str, str]:
    """``name -> version`` of the ``name==version`` lines of requirements.txt."""
    pins = {}
    if path.exists():
        for line in path.read_text().splitlines():
            m = re.match(r"^\s*([A-Za-z0-9_.\-\[\]]+)==([^\s;#]+)", line)
            if m:
                pins[m.group(1).split("[")[0].lower()] = m.group(2)
    return pins


def python_executable() -> str:
    """QGIS's own Python interpreter (inside QGIS, ``sys.executable`` is often QGIS)."""
    exe = Path(sys.executable)
    if exe.name.lower().startswith("python"):
        return str(exe)
    minor = f"{sys.version_info.major}.{sys.version_info.minor}"
    candidates = [Path(sys.exec_prefix) / "python.exe", Path(sys.exec_prefix) / "python3.exe",
                  Path(sys.exec_prefix) / "bin" / f"python{minor}",
                  Path(sys.exec_prefix) / "bin" / "python3"]
    for c in candidates:
        if c.exists():
            return str(c)
    found = shutil.which(f"python{minor}") or shutil.which("python3")
    if found:
        return found
    raise RuntimeError("QGIS's Python interpreter was not found; install the packages of "
                       "requirements.txt with it by hand (README, section 'Install').")


def pip_command(packages: Sequence[str], site: Path, constraints: Path) -> List[str]:
    """The pip call that installs ``packages`` into ``site`` (see the module docstring)."""
    cmd = [python_executable(), "-m", "pip", "install", "--target", str(site),
           "--disable-pip-version-check", "--no-warn-script-location", "--upgrade",
           "-c", str(constraints)]
    if sys.platform.startswith("linux") and "shapely" in packages:
        cmd += ["--no-binary", "shapely"]
    return cmd + list(packages)


def write_constraints(path: Path, pins: Dict[str, str]) -> Path:
    """Pins of requirements.txt, except that packages QGIS already has stay as they are."""
    lines = []
    for name, version in pins.items():
        module = next((m for m, d in RUNTIME_PACKAGES.items() if d == name), name)
        spec = importlib.util.find_spec(module) if module in QGIS_OWNED else None
        if spec is not None:
            installed = importlib.import_module(module).__version__
            lines.append(f"{name}=={installed}")
        else:
            lines.append(f"{name}=={version}")
    path.write_text("\n".join(lines) + "\n")
    return path


def install(packages: Sequence[str], site: Path, log: Callable[[str], None],
            is_canceled: Callable[[], bool] = lambda: False,
            progress: Callable[[float], None] = lambda p: None) -> None:
    """Run pip for ``packages`` (distribution names, pinned by requirements.txt).

    Raises RuntimeError with pip's last lines when pip fails, or when the GEOS headers that a
    Linux build of shapely needs are missing.
    """
    if sys.platform.startswith("linux") and "shapely" in packages and \
            shutil.which("geos-config") is None:
        raise RuntimeError(
            "shapely must be built against the system GEOS on Linux, and its headers are "
            "missing: install them (Debian/Ubuntu: sudo apt install libgeos-dev python3-dev "
            "build-essential; Fedora: sudo dnf install geos-devel python3-devel gcc-c++), "
            "then run this installer again.")
    site.mkdir(parents=True, exist_ok=True)
    pins = pinned_versions()
    constraints = write_constraints(site.parent / "constraints.txt", pins)
    cmd = pip_command([p if p not in pins else f"{p}=={pins[p]}" for p in packages], site,
                      constraints)
    log(" ".join(cmd))
    env = dict(os.environ, PIP_NO_INPUT="1")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=env, bufsize=1)
    tail: List[str] = []
    done = 0
    try:
        for line in proc.stdout:
            line = line.rstrip()
            if line:
                log(line)
                tail = (tail + [line])[-15:]
            if line.startswith(("Collecting", "Building wheel", "Installing collected")):
                done += 1
                progress(min(95.0, 5.0 + 4.0 * done))
            if is_canceled():
                proc.kill()
                raise RuntimeError("Canceled: the packages were not installed.")
    finally:
        proc.wait()
    if proc.returncode != 0:
        raise RuntimeError("pip failed:\n" + "\n".join(tail))
    activate(site)
    progress(100.0)
