#!/usr/bin/env python3
"""Start QGIS desktop headless (Xvfb) with the plugin enabled in a fresh profile and run
scripts/desktop_check.py inside it; print its findings.

    python3 scripts/run_desktop_check.py [--out out] [--plugins DIR] [--timeout 120]

--plugins is a folder holding ``urban_synthesis/`` (e.g. an unzipped package); by default
the checkout itself is linked in. Writes <out>/desktop.png and <out>/desktop_check.json.
Needs no QGIS import itself (tests/test_desktop.py uses :func:`run`).
"""
import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHECK = ROOT / "scripts" / "desktop_check.py"
PLUGIN = "urban_synthesis"
SITE_PACKAGES = ROOT / ".venv" / "lib" / "python3.11" / "site-packages"
HELSINKI = ROOT / "data" / "examples" / "Helsinki.osm.pbf"

# Fresh profile: the plugin enabled, no plugin-repository check at start (no network here).
PROFILE_INI = f"""[PythonPlugins]
{PLUGIN}=true

[app]
plugin_installer\\checkOnStart=false
plugin_installer\\checkOnStartLastDate=2099-01-01T00:00:00

[qgis]
checkVersion=false
"""


def run(out_dir, plugins_dir=None, timeout=120.0, work=None):
    """Run the desktop check; returns (result dict or None, exit code, combined stderr/stdout).

    ``work`` is a scratch folder (profile, XDG dirs, outputs); a temporary one by default.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scratch = Path(work) if work else Path(tempfile.mkdtemp(prefix="urbansynth-desktop-"))
    profiles = scratch / "profiles-root"
    ini = profiles / "profiles" / "default" / "QGIS" / "QGIS3.ini"
    ini.parent.mkdir(parents=True, exist_ok=True)
    ini.write_text(PROFILE_INI)
    if plugins_dir is None:
        plugins_dir = scratch / "plugins"
        plugins_dir.mkdir(exist_ok=True)
        link = plugins_dir / PLUGIN
        if not link.exists():
            link.symlink_to(ROOT, target_is_directory=True)
    outputs = scratch / "outputs"
    outputs.mkdir(exist_ok=True)
    result_path = out_dir / "desktop_check.json"
    screenshot = out_dir / "desktop.png"
    for stale in (result_path, screenshot):
        stale.unlink(missing_ok=True)

    env = {k: v for k, v in os.environ.items()
           if k not in ("QT_QPA_PLATFORM", "QGIS_PLUGINPATH", "PYQGIS_STARTUP", "DISPLAY",
                        "PYTHONHOME")}
    env.update({
        # QGIS embeds Debian's Python 3.11, which finds its standard library through the first
        # python3 on PATH: a pyenv or venv interpreter first on PATH would hijack it
        "PATH": os.pathsep.join(["/usr/bin", "/bin", env.get("PATH", "")]),
        "QGIS_PLUGINPATH": str(plugins_dir),
        "PYTHONPATH": os.pathsep.join(filter(None, [str(SITE_PACKAGES), env.get("PYTHONPATH")])),
        "PYQGIS_STARTUP": str(CHECK),
        "XDG_DATA_HOME": str(scratch / "xdg-data"),
        "XDG_CONFIG_HOME": str(scratch / "xdg-config"),
        "XDG_CACHE_HOME": str(scratch / "xdg-cache"),
        "XDG_RUNTIME_DIR": str(scratch / "xdg-runtime"),
        "US_DESKTOP_RESULT": str(result_path),
        "US_DESKTOP_SCREENSHOT": str(screenshot),
        "US_DESKTOP_WORK": str(outputs),
        "US_DESKTOP_HELSINKI": str(HELSINKI),
        # the script's own watchdog fires before ours, so partial findings are still written
        "US_DESKTOP_TIMEOUT": str(max(10.0, timeout - 20)),
    })
    (scratch / "xdg-runtime").mkdir(mode=0o700, exist_ok=True)
    cmd = ["xvfb-run", "-a", "-s", "-screen 0 1600x1000x24",
           "/usr/bin/qgis", "--nologo", "--noversioncheck", "--profiles-path", str(profiles),
           "--code", str(CHECK)]
    # own process group: on a timeout, Xvfb and QGIS are killed together
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    try:
        output, _ = proc.communicate(timeout=timeout)
        code = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        output, _ = proc.communicate()
        code = None
        output += f"\n[run_desktop_check] QGIS did not exit within {timeout:.0f} s; killed."
    result = None
    if result_path.exists():
        result = json.loads(result_path.read_text())
    if not work:
        shutil.rmtree(scratch, ignore_errors=True)
    return result, code, output


def summary(result):
    """Problems found, as sentences (empty when the desktop check passed)."""
    if result is None:
        return ["no result was written (QGIS did not reach the check)"]
    problems = list(result.get("errors", []))
    if not result.get("provider"):
        problems.append("provider 'urbansynth' is not registered")
    for alg, issues in (result.get("algorithm_problems") or {}).items():
        problems.append(f"{alg}: {', '.join(issues)}")
    if result.get("toolbox_algorithms") != result.get("algorithms"):
        problems.append("the Processing toolbox does not list every algorithm")
    for alg, error in (result.get("dialog_errors") or {}).items():
        problems.append(f"dialog of {alg} fails: {error}")
    for entry in python_errors(result):
        problems.append(f"log [{entry['tag']}]: ...{entry['message'][-400:]}")  # tail: the error
    return problems


def python_errors(result):
    """Message-log entries that are Python errors/tracebacks or critical messages about us."""
    bad = []
    for entry in result.get("log", []):
        text = entry["message"]
        ours = any(name in text for name in (PLUGIN, "urbansynth", "Urban Synthesis"))
        error = (entry["tag"] == "Python error" or "Traceback" in text
                 or entry["level"] >= 2)  # Qgis.Critical
        if ours and error:
            bad.append(entry)
    return bad


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(ROOT / "out"))
    parser.add_argument("--plugins", default=None, help="folder holding urban_synthesis/")
    parser.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args()
    result, code, output = run(args.out, args.plugins, args.timeout)
    problems = summary(result)
    if result:
        print(f"QGIS {result.get('qgis_version')}: {len(result.get('algorithms', []))} "
              f"urbansynth algorithms, layers {sorted(result.get('layers', {}))}, "
              f"{len(result.get('log', []))} log messages, {result.get('elapsed_s')} s")
        print(f"screenshot: {result.get('screenshot')}")
    for p in problems:
        print("PROBLEM:", p)
    if code != 0 or problems:
        print(output[-3000:], file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
