"""Run seeded syntheses and save every output coordinate: the cross-kernel probe.

``python tests/kernel_probe.py OUT.npz`` in a process whose BLAS kernel is chosen by
``OPENBLAS_CORETYPE`` (read when numpy loads, so one process per kernel);
test_reproducible.py compares two such files. Footprints by transfer and by re-synthesis
(Helsinki database onto Bubeneč: rigid alignment, warps, relaxation), fragment synthesis
(Helsinki fragments into a sketch: mean value coordinates) and random walks (Vaduz from the
other Liechtenstein towns: points placed by the quadtree in its rotated frame, then walked).
"""
import sys
import tempfile
from pathlib import Path

import numpy as np
import shapely

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import PLUGINS  # noqa: E402,F401  (puts the plugin package on sys.path)
from helpers import bubenec, helsinki_roads  # noqa: E402
from test_footprints import helsinki_example_db  # noqa: E402
from test_random_walk import _left_out as left_out  # noqa: E402
from towns import LI_PBF  # noqa: E402
from urban_synthesis.plugin.network import blocks  # noqa: E402
from urban_synthesis.plugin.retrieval import database
from urban_synthesis.plugin.buildings import footprints
from urban_synthesis.plugin.network import fragments
from urban_synthesis.plugin.network import hierarchy
from urban_synthesis.plugin.network import street_graph as roads
from urban_synthesis.plugin.roads import from_fragments as synthesis_fragments
from urban_synthesis.plugin.roads import random_walk


def main(out: str) -> None:
    arrays = {}
    with tempfile.TemporaryDirectory() as tmp:
        db = footprints.prepare_examples(helsinki_example_db(Path(tmp) / "b.gpkg"), "helsinki")
        streets = bubenec("streets").geometry.values
        target = blocks.extract_blocks(streets).geometry
        for method in footprints.METHODS:
            r = footprints.synthesize_footprints(target, [db], method, street_width=6.0,
                                                 seed=3, roads=streets)
            assert shapely.is_valid(r.geometry).all()
            arrays[f"footprints_{method}"] = shapely.get_coordinates(r.geometry)
        df = helsinki_roads()
        graph = roads.clean_network(df.geometry.values, df.highway.values, z_layer=df.z.values)
        h = hierarchy.road_hierarchy(graph, "both", roads.ARTERIAL_CLASSES, 0.1, 45.0)
        frag = fragments.extract_fragments(graph.geometry, h.street_level[h.streets.street_id])
        path = Path(tmp) / "f.gpkg"
        database.write_fragment_database(str(path), frag, "EPSG:32635")
        fdb = database.load_fragment_database(path)
        sketch = [shapely.LineString([(x, -40), (x + 30, 1040)]) for x in (0, 500, 1000)] + \
            [shapely.LineString([(-40, y), (1040, y + 20)]) for y in (0, 500, 1000)]
        res = synthesis_fragments.synthesize(sketch, [fdb], seed=1)
        arrays["fragments"] = shapely.get_coordinates(res.geometry)
    if LI_PBF.exists():
        # Vaduz from the other Liechtenstein towns, as the fidelity benchmark runs it: the
        # quadtree's frame was a BLAS product, and the generic kernel placed other points
        target, _, points, _ = left_out("Vaduz")
        walk = random_walk.synthesize(points, target.area, existing_lines=target.given, seed=0,
                                      in_place=False)
        arrays["random_walk"] = shapely.get_coordinates(walk.geometry)
    np.savez(out, **arrays)


if __name__ == "__main__":
    main(sys.argv[1])
