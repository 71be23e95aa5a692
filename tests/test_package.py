"""`make package`: the plugin zip holds what the plugin needs (and nothing of the dev tree),
installs into a clean QGIS profile and runs there through qgis_process.bin."""
import configparser
import os
import subprocess
import zipfile
from pathlib import PurePosixPath
from urllib.parse import urlparse
from xml.etree import ElementTree

import pyogrio
import pytest
from conftest import HELSINKI, ROOT

ZIP = ROOT / "build" / "dist" / "urban_synthesis.zip"
TOP = "urban_synthesis"
SITE_PACKAGES = ROOT / ".venv" / "lib" / "python3.11" / "site-packages"
# dev-only parts of the repository that must stay out of the zip
EXCLUDED = ("tests", "data", "build", "out", ".venv", "scripts", "docs", "tools", ".ci",
            ".git", ".gitignore", "Makefile", "pytest.ini")


def _git_files(*paths):
    out = subprocess.run(["git", "ls-tree", "-r", "--name-only", "HEAD", "--", *paths],
                         cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return set(out.split())


@pytest.fixture(scope="module")
def package():
    proc = subprocess.run(["make", "--no-print-directory", "package"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert ZIP.exists()
    with zipfile.ZipFile(ZIP) as z:
        assert z.testzip() is None  # no corrupt member
        names = [n for n in z.namelist() if not n.endswith("/")]
        metadata = z.read(f"{TOP}/metadata.txt").decode("utf-8")
    return names, metadata


def test_zip_holds_the_plugin_and_nothing_else(package):
    names, _ = package
    assert all(n.startswith(f"{TOP}/") for n in names)
    inner = {n[len(TOP) + 1:] for n in names}
    for required in ("__init__.py", "metadata.txt", "README.md", "plugin/__init__.py",
                     "plugin/qgis_glue/plugin.py", "plugin/qgis_glue/provider.py", "plugin/qgis_glue/qgis_io.py",
                     "processing_algorithms/__init__.py", "processing_algorithms/common.py",
                     "resources/icons/urbansynth.svg", "resources/styles/roads_by_level.qml",
                     "resources/styles/buildings_by_height.qml",
                     "resources/styles/parcels_by_quality.qml", "resources/styles/blocks.qml"):
        assert required in inner, required
    # every committed file of the runtime folders is there, and only committed files
    assert _git_files("plugin", "processing_algorithms", "resources") <= inner
    assert inner <= _git_files(".")
    tops = {PurePosixPath(n).parts[0] for n in inner}
    assert not tops & set(EXCLUDED), tops & set(EXCLUDED)
    # plugins.qgis.org refuses .pyc files, __pycache__/.git/__MACOSX folders and zips over 25 MB
    assert not [n for n in inner if n.endswith((".pyc", ".pbf"))
                or {"__pycache__", ".git", "__MACOSX"} & set(PurePosixPath(n).parts)]
    assert ZIP.stat().st_size < 25_000_000


@pytest.mark.parametrize("where", ["zip", "checkout"])
def test_metadata_is_complete_for_the_plugin_repository(package, where):
    """What plugins.qgis.org's validator requires, and the fields the plugin manager shows."""
    names, metadata = package
    if where == "checkout":  # the zip holds the committed one; this one is committed next
        metadata = (ROOT / "metadata.txt").read_text(encoding="utf-8")
    meta = configparser.ConfigParser()
    meta.optionxform = str  # case-sensitive keys, as the validator reads them
    meta.read_string(metadata)
    general = meta["general"]
    for key in ("name", "qgisMinimumVersion", "description", "about", "version", "author",
                "email", "repository", "tracker", "homepage", "tags", "category", "icon",
                "experimental", "hasProcessingProvider", "changelog"):
        assert general.get(key, "").strip(), key
    assert general["qgisMinimumVersion"] == "3.22"
    assert general["hasProcessingProvider"] == "yes"
    assert general["category"] == "Analysis"
    assert "/" not in general["author"]
    for key in ("repository", "tracker", "homepage"):
        url = urlparse(general[key])
        assert url.scheme == "https" and url.netloc, (key, general[key])
    assert general["tracker"].startswith(general["repository"])
    assert (ROOT / general["icon"]).exists()
    assert f"{TOP}/{general['icon']}" in names or where == "checkout"
    assert general["version"] in general["changelog"]  # the changelog covers this version
    assert len(general["about"]) > 300 and len(general["tags"].split(",")) >= 5


def _qgis_env(xdg):
    env = {k: v for k, v in os.environ.items() if k not in ("QGIS_PLUGINPATH", "PYTHONHOME")}
    env.update(XDG_DATA_HOME=str(xdg), QT_QPA_PLATFORM="offscreen",
               PATH=os.pathsep.join(["/usr/bin", "/bin", env.get("PATH", "")]),
               PYTHONPATH=os.pathsep.join(filter(None, [str(SITE_PACKAGES),
                                                        env.get("PYTHONPATH")])))
    return env


def _qgis_process(env, *args, timeout=300):
    return subprocess.run(["/usr/bin/qgis_process.bin", *args], env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_zip_installs_into_a_clean_profile(package, tmp_path):
    """Unzipped where QGIS's 'Install from ZIP' puts it, in a profile that has seen nothing."""
    names, _ = package
    xdg = tmp_path / "xdg"
    plugins = xdg / "QGIS" / "QGIS3" / "profiles" / "default" / "python" / "plugins"
    plugins.mkdir(parents=True)
    with zipfile.ZipFile(ZIP) as z:
        z.extractall(plugins)
    env = _qgis_env(xdg)  # no QGIS_PLUGINPATH: the checkout is not visible

    enable = _qgis_process(env, "plugins", "enable", TOP)
    assert enable.returncode == 0, enable.stdout + enable.stderr
    assert f"Enabled {TOP}" in enable.stdout

    listing = _qgis_process(env, "list")
    assert listing.returncode == 0, listing.stderr
    listed = {line.split()[0] for line in listing.stdout.splitlines()
              if line.strip().startswith("urbansynth:")}
    # one algorithm per module of processing_algorithms/ (docs/ARCHITECTURE.md's toolbox contract)
    modules = {PurePosixPath(n).stem for n in names
               if n.startswith(f"{TOP}/processing_algorithms/") and n.endswith(".py")}
    # deprecated algorithms (flagged so) run but are not listed: 'synthesizebuildings'
    deprecated = {"synthesize_buildings"}
    expected = {f"urbansynth:{m.replace('_', '')}"
                for m in modules - {"__init__", "common"} - deprecated}
    # and the shipped Processing models (resources/models/*.model3), by their model_name
    with zipfile.ZipFile(ZIP) as z:
        for n in names:
            if n.startswith(f"{TOP}/resources/models/") and n.endswith(".model3"):
                # the model's own name, whatever order Qt wrote the attributes in
                root = ElementTree.fromstring(z.read(n))
                found = [o.get("value") for o in root.iter("Option")
                         if o.get("name") == "model_name"]
                assert found, n
                expected.add(f"urbansynth:{found[0]}")
    assert listed == expected
    for module in deprecated:
        shown = _qgis_process(env, "help", f"urbansynth:{module.replace('_', '')}")
        assert shown.returncode == 0 and "deprecated" in shown.stdout.lower(), shown.stderr

    # the installed copy runs on the real data (styles and resources are all in the zip)
    out = tmp_path / "roads.gpkg"
    run = _qgis_process(env, "--json", "run", "urbansynth:extractroadhierarchy", "--",
                        f"INPUT={HELSINKI}|layername=lines", f"OUTPUT={out}")
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    roads = pyogrio.read_dataframe(out)
    assert len(roads) > 150 and roads["level"].min() == 0


def test_stock_qgis_gets_the_packages_from_the_installer(package, tmp_path):
    """A QGIS whose Python lacks the engine's packages (no project venv on PYTHONPATH): every
    algorithm stays listed, a tool says which package to install, the installer puts them
    into the profile, and then a synthesis runs."""
    xdg = tmp_path / "xdg"
    profile = xdg / "QGIS" / "QGIS3" / "profiles" / "default"
    plugins = profile / "python" / "plugins"
    plugins.mkdir(parents=True)
    with zipfile.ZipFile(ZIP) as z:
        z.extractall(plugins)
    env = _qgis_env(xdg)
    env.pop("PYTHONPATH")  # QGIS's own Python only: no shapely, pandas, cv2, onnxruntime
    stock = subprocess.run(["/usr/bin/python3", "-c", "import shapely"], env=env,
                           capture_output=True)
    if stock.returncode == 0:
        pytest.skip("this machine's system Python already has shapely")
    assert _qgis_process(env, "plugins", "enable", TOP).returncode == 0

    listing = _qgis_process(env, "list")
    listed = {line.split()[0] for line in listing.stdout.splitlines()
              if line.strip().startswith("urbansynth:")}
    assert {"urbansynth:extractroadhierarchy", "urbansynth:synthesizefootprints",
            "urbansynth:installdependencies"} <= listed

    out = tmp_path / "roads.gpkg"
    args = ("--json", "run", "urbansynth:extractroadhierarchy", "--",
            f"INPUT={HELSINKI}|layername=lines", f"OUTPUT={out}")
    before = _qgis_process(env, *args)
    assert before.returncode != 0 and not out.exists()
    assert "shapely" in before.stdout + before.stderr
    assert "Install Python dependencies" in before.stdout + before.stderr

    install = _qgis_process(env, "run", "urbansynth:installdependencies", timeout=1200)
    assert install.returncode == 0, install.stdout[-3000:] + install.stderr[-3000:]
    site = profile / "python" / "dependencies" / "urban_synthesis" / "python3.11"
    assert (site / "shapely").is_dir() and (site / "pandas").is_dir()
    assert not (site / "numpy").exists() or "numpy" in install.stdout  # QGIS's numpy kept

    after = _qgis_process(env, *args)
    assert after.returncode == 0, after.stdout[-2000:] + after.stderr[-2000:]
    roads = pyogrio.read_dataframe(out)
    assert len(roads) > 150 and roads["level"].min() == 0
