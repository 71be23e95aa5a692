"""urbansynth:synthesizepartbuildings (Hartmann thesis ch. 6) through real QGIS.

The thesis's skyscraper case (120 m, FAR 10 / 15 / 20 from 18 floor parts) is met exactly;
k-best solutions are distinct and ordered by cost; terraces along a line and around a block
polygon have valid parts that do not overlap within a solution, end parts at the ends and
corner parts at the vertices; bad input gives messages naming the layer; one real
qgis_process.bin run builds block-filling buildings on Bubeneč's blocks.
"""
import numpy as np
import pytest
import shapely
import shapely.affinity

from conftest import run_qgis_process
from helpers import bubenec, layer_features, memory_layer
from urban_synthesis.plugin.network import blocks

ALG = "urbansynth:synthesizepartbuildings"
TERRACE, TERRACE_2M, SKYSCRAPER = 0, 1, 2
CRS = "EPSG:32633"
SITE = "POLYGON ((500000 5500000, 500040 5500000, 500040 5500040, 500000 5500040, " \
       "500000 5500000))"     # a 40 m x 40 m plot, 1,600 m²
X0, Y0 = 500000.0, 5500000.0
L_LINE = shapely.LineString([(0, 0), (50, 0), (50, 40), (90, 40)])
BLOCK = shapely.box(0, 0, 80, 60)


def _at(geom):
    return shapely.affinity.translate(geom, X0, Y0)


def _run(qgis_processing, **params):
    out = qgis_processing.run(ALG, dict({"OUTPUT": "memory:"}, **params))
    rows, geoms = layer_features(out["OUTPUT"])
    return out["OUTPUT"], rows, geoms


def _by_solution(rows, geoms, building_id=None):
    """{solution: (rows sorted by seq_index, their geometries)}"""
    out = {}
    for r, g in zip(rows, geoms):
        if building_id is None or r["building_id"] == building_id:
            out.setdefault(r["solution"], []).append((r, g))
    return {s: ([r for r, _ in sorted(v, key=lambda x: x[0]["seq_index"])],
                np.array([g for _, g in sorted(v, key=lambda x: x[0]["seq_index"])], object))
            for s, v in sorted(out.items())}


def _assert_no_overlaps(geoms, tol=1e-6):
    geoms = np.asarray(geoms, dtype=object)
    assert shapely.is_valid(geoms).all()
    i, j = shapely.STRtree(geoms).query(geoms, predicate="intersects")
    pairs = i < j
    if pairs.any():
        assert shapely.area(shapely.intersection(geoms[i[pairs]], geoms[j[pairs]])).max() < tol


def _assert_k_best(solutions):
    """Distinct part sequences in non-decreasing cost, ranks 1..k."""
    assert list(solutions) == list(range(1, len(solutions) + 1))
    costs = [rows[0]["cost"] for rows, _ in solutions.values()]
    assert all(len({r["cost"] for r in rows}) == 1 for rows, _ in solutions.values())
    assert (np.diff(costs) >= -1e-9).all()
    seqs = {tuple(r["part_id"] for r in rows) for rows, _ in solutions.values()}
    assert len(seqs) == len(solutions)


@pytest.mark.parametrize("far", [10.0, 15.0, 20.0])
def test_skyscrapers_of_the_thesis(qgis_processing, far):
    site = memory_layer("Polygon", [SITE], CRS, name="plot")
    layer, rows, geoms = _run(qgis_processing, SKELETON=site, PARTS_LIBRARY=SKYSCRAPER,
                              PARTS_HEIGHT=120, TARGET_FAR=far, K_SOLUTIONS=3)
    assert layer.crs().authid() == CRS
    assert layer.wkbType() in (3006, 1006)          # MultiPolygonZ (25D or Z)
    solutions = _by_solution(rows, geoms)
    assert len(solutions) == 3
    _assert_k_best(solutions)
    plot = shapely.from_wkt(SITE)
    for rows_s, geoms_s in solutions.values():
        assert {r["building_id"] for r in rows_s} == {1}
        assert {r["kind"] for r in rows_s} == {"floor"}
        # exact: sum of the parts' floor areas / site area, summed here independently
        assert sum(r["floor_area_m2"] for r in rows_s) / plot.area == far
        assert sum(r["height_m"] for r in rows_s) == 120.0
        assert sum(r["levels"] for r in rows_s) == 30
        assert all(r["building_far"] == far for r in rows_s)
        base = np.array([r["base_m"] for r in rows_s])
        top = np.array([r["top_m"] for r in rows_s])
        np.testing.assert_allclose(base[1:], top[:-1])
        assert base[0] == 0 and top[-1] == 120.0
        # PolygonZ at the floor's base, inside the plot; each floor on the one below it
        z = [np.unique(shapely.get_coordinates(g, include_z=True)[:, 2]) for g in geoms_s]
        assert all(len(zz) == 1 for zz in z)
        np.testing.assert_allclose([zz[0] for zz in z], base)
        flat = shapely.force_2d(geoms_s)
        assert shapely.within(flat, plot.buffer(1e-6)).all()
        for below, above in zip(flat[:-1], flat[1:]):
            assert above.buffer(-1e-6).within(below)


def test_terrace_along_a_line(qgis_processing):
    wkts = [_at(L_LINE).wkt, _at(shapely.affinity.translate(L_LINE, 0, 200)).wkt]
    skel = memory_layer("LineString", wkts, CRS, fields="&field=front:string",
                        rows=[("right",), ("LEFT",)], name="facades")
    site = memory_layer("Polygon", [_at(shapely.box(-20, -60, 120, 300)).wkt], CRS)
    layer, rows, geoms = _run(qgis_processing, SKELETON=skel, PARTS_LIBRARY=TERRACE,
                              K_SOLUTIONS=4, BLOCKS=site, PARTS_COUNTS="end_left=1; corner=2")
    assert {r["building_id"] for r in rows} == {1, 2}
    for fid, side in ((1, 1), (2, -1)):
        solutions = _by_solution(rows, geoms, fid)
        assert 2 <= len(solutions) <= 4
        _assert_k_best(solutions)
        line = shapely.affinity.translate(_at(L_LINE), 0, 200 * (fid - 1))
        for rows_s, geoms_s in solutions.values():
            flat = shapely.force_2d(geoms_s)
            _assert_no_overlaps(flat)
            assert sum(r["length_m"] for r in rows_s) == pytest.approx(L_LINE.length)
            assert rows_s[0]["kind"] == "end_left" and rows_s[-1]["kind"] == "end_right"
            kinds = [r["kind"] for r in rows_s]
            assert kinds.count("corner") == 2 and kinds.count("end_left") == 1
            # corner parts wrap the two skeleton vertices
            vertices = shapely.points(shapely.get_coordinates(line)[1:3])
            corners = flat[np.array(kinds) == "corner"]
            assert (shapely.distance(corners[:, None], vertices[None, :]).min(axis=0)
                    < 1e-6).all()
            # the building lies away from the street: left of the line for a street on
            # the right, mirrored for front = left
            y = Y0 + 200 * (fid - 1)
            first_leg = flat[shapely.intersects(flat, shapely.box(X0, y - 30, X0 + 30, y + 30))]
            dy = shapely.get_coordinates(shapely.centroid(first_leg))[:, 1] - line.coords[0][1]
            assert (np.sign(dy) == side).all()
            # building_far on the block from BLOCKS (the site holding the line)
            far = rows_s[0]["building_far"]
            assert far == pytest.approx(sum(r["floor_area_m2"] for r in rows_s) / (140 * 360))


def test_terrace_around_a_block_with_far_interval(qgis_processing):
    block = memory_layer("Polygon", [_at(BLOCK).wkt], CRS, name="block")
    _, rows, geoms = _run(qgis_processing, SKELETON=block, PARTS_LIBRARY=TERRACE, K_SOLUTIONS=3)
    strip = _at(BLOCK).difference(_at(shapely.box(12, 12, 68, 48)))
    solutions = _by_solution(rows, geoms)
    assert len(solutions) == 3
    _assert_k_best(solutions)
    for rows_s, geoms_s in solutions.values():
        flat = shapely.force_2d(geoms_s)
        _assert_no_overlaps(flat)
        union = shapely.union_all(flat)
        assert union.within(_at(BLOCK).buffer(1e-6))
        assert union.area == pytest.approx(strip.area, rel=1e-6)
        assert [r["kind"] for r in rows_s].count("corner") == 4
        assert sum(r["length_m"] for r in rows_s) == pytest.approx(BLOCK.length)
    # a FAR interval (2 m library: few floor-area sums), site = the block polygon itself
    _, rows, geoms = _run(qgis_processing, SKELETON=block, PARTS_LIBRARY=TERRACE_2M,
                          PARTS_FAR_MIN=2.0, PARTS_FAR_MAX=2.2, K_SOLUTIONS=2)
    for rows_s, _ in _by_solution(rows, geoms).values():
        area = sum(r["floor_area_m2"] for r in rows_s)
        assert 2.0 * BLOCK.area <= area <= 2.2 * BLOCK.area
        assert rows_s[0]["building_far"] == pytest.approx(area / BLOCK.area)


@pytest.mark.parametrize("parts_crs", [CRS, "EPSG:32618"])
def test_parts_layer(qgis_processing, parts_crs):
    """A user's parts database as a polygon layer with only the required fields; drawn at
    (0, 0) of UTM zone 18N too (any position, here off Ecuador): its parts keep their
    sizes (they were projected into the skeleton's zone, 33N, 94 degrees of longitude
    away, where PROJ cannot take them: the run failed)."""
    boxes = [shapely.box(0, 0, 6, 10), shapely.box(0, 0, 8, 10), shapely.box(0, 0, 4, 10),
             shapely.box(0, 0, 4, 10), shapely.box(0, 0, 20, 10)]
    fields = "&field=kind:string&field=length_m:double&field=height_m:double"
    values = [("straight", 6, 9), ("Straight", 8, 12), ("end_left", 4, 9), ("end_right", 4, 9),
              ("corner", 20, 12)]
    parts = memory_layer("Polygon", [b.wkt for b in boxes], parts_crs, fields=fields,
                         rows=values, name="my parts")
    skel = memory_layer("LineString", [_at(shapely.LineString([(0, 0), (40, 0), (40, 30)])).wkt],
                        CRS)
    _, rows, geoms = _run(qgis_processing, SKELETON=skel, BUILDING_PARTS=parts, K_SOLUTIONS=2)
    solutions = _by_solution(rows, geoms)
    assert len(solutions) == 2
    _assert_k_best(solutions)
    for rows_s, geoms_s in solutions.values():
        _assert_no_overlaps(shapely.force_2d(geoms_s))
        assert sum(r["length_m"] for r in rows_s) == pytest.approx(70.0)
        # levels derived from the height (3 m storeys), floor area = footprint x levels
        for r in rows_s:
            assert r["levels"] == round(r["height_m"] / 3)
            if r["kind"] == "straight":
                assert r["floor_area_m2"] == r["length_m"] * 10 * r["levels"]


def test_bad_input(qgis_processing):
    from qgis.core import QgsProcessingException

    def fails(params, match):
        with pytest.raises(QgsProcessingException, match=match):
            qgis_processing.run(ALG, dict({"OUTPUT": "memory:"}, **params))

    site = memory_layer("Polygon", [SITE], CRS, name="tower plot")
    line = memory_layer("LineString", [_at(L_LINE).wkt], CRS, name="facade line")
    fails({}, r"Skeletons \(SKELETON\) is needed")
    no_kind = memory_layer("Polygon", [shapely.box(0, 0, 6, 10).wkt], CRS,
                           fields="&field=length_m:double&field=height_m:double",
                           rows=[(6, 9)], name="broken parts")
    fails({"SKELETON": line, "BUILDING_PARTS": no_kind},
          r"Layer 'broken parts': missing field\(s\) kind")
    # 30.5 x 1,600 m² is more than 30 levels of the widest floor can give
    fails({"SKELETON": site, "PARTS_LIBRARY": SKYSCRAPER, "TARGET_FAR": 30.5},
          r"Layer 'tower plot': no building could be made .* no tower of 120 m")
    fails({"SKELETON": line, "PARTS_LIBRARY": SKYSCRAPER}, "'facade line' has lines: floor parts")
    fails({"SKELETON": line, "TARGET_FAR": 2.0}, "'facade line': a FAR needs a site")
    fails({"SKELETON": line, "PARTS_COUNTS": "chimneys=1..2"}, "neither a part kind")
    fails({"SKELETON": line, "PARTS_COUNTS": "doors>2"}, "is not 'name=n'")
    fails({"SKELETON": site, "TARGET_FAR": 2.0, "PARTS_FAR_MAX": 3.0}, "either a Target FAR")
    sharp = memory_layer("LineString", [_at(shapely.LineString([(0, 0), (50, 0), (0, 10)])).wkt],
                         CRS, name="sharp line")
    fails({"SKELETON": sharp}, "'sharp line': no building could be made .* no corner part fits")
    bad_front = memory_layer("LineString", [_at(L_LINE).wkt], CRS, fields="&field=front:string",
                             rows=[("up",)], name="fronts")
    fails({"SKELETON": bad_front}, "'fronts', feature 1: front must be 'left' or 'right'")


def test_qgis_process_on_bubenec_blocks(tmp_path):
    """Block-filling buildings on Bubeneč's real blocks (from its streets, buffered inward
    by a 6 m half street) through qgis_process.bin: exit 0, valid parts inside their blocks
    that do not overlap, each building as long as its block's skeleton, its FAR taken on
    its block; blocks the library cannot fill are skipped with a warning."""
    import geopandas as gpd

    extraction = blocks.extract_blocks(bubenec("streets").geometry.values)
    rings = shapely.buffer(np.asarray(extraction.geometry, object), -6.0, join_style="mitre")
    skel = gpd.GeoDataFrame({"block": np.arange(len(rings))}, geometry=rings, crs=32633)
    path = tmp_path / "bubenec_blocks.gpkg"
    skel.to_file(path, layer="skeletons", driver="GPKG")
    gpd.GeoDataFrame(geometry=list(extraction.geometry), crs=32633).to_file(
        path, layer="blocks", driver="GPKG")
    target = tmp_path / "parts.gpkg"
    code, out, err = run_qgis_process("synthesizepartbuildings", {
        "SKELETON": f"{path}|layername=skeletons", "K_SOLUTIONS": 2,
        "BLOCKS": f"{path}|layername=blocks", "OUTPUT": str(target)})
    assert code == 0, err
    assert out is not None and target.exists()
    import pyogrio

    df = pyogrio.read_dataframe(target)
    assert df.crs.to_epsg() == 32633 and df.geometry.is_valid.all()
    made = sorted(df.building_id.unique())
    assert len(made) >= 4                     # the engine fills at least 4 of the 7 blocks
    simplified = shapely.simplify(rings, 0.5, preserve_topology=True)
    for fid in made:
        block = extraction.geometry[fid - 1]          # GPKG feature ids are 1..n
        for _, parts in df[df.building_id == fid].groupby("solution"):
            geoms = shapely.force_2d(parts.geometry.values)
            _assert_no_overlaps(geoms)
            assert shapely.union_all(geoms).within(block.buffer(1e-6))
            assert parts.length_m.sum() == pytest.approx(simplified[fid - 1].length, abs=0.3)
            assert (parts.kind == "corner").sum() >= 4
            # the FAR is taken on the block holding the skeleton (Blocks), not on the ring
            assert parts.building_far.iloc[0] == pytest.approx(
                parts.floor_area_m2.sum() / block.area, rel=1e-9)


COURTYARD = [shapely.LineString([(0, 0), (24, 0), (48, 0), (48, 18), (48, 36), (24, 36),
                                 (0, 36), (0, 0)]),
             shapely.LineString([(24, 0), (24, -18), (24, -30)]),
             shapely.LineString([(24, -18), (44, -18)]),
             shapely.LineString([(24, 36), (24, 60)]),
             shapely.LineString([(48, 18), (72, 18)])]


def test_wing_network_with_local_counts(qgis_processing):
    """SKELETON_NETWORK: touching wing lines form one building with T-parts (thesis Fig.
    6.6); a wing's 'counts' field is a local constraint; a separate T is its own building;
    a malformed 'counts' names its feature."""
    from qgis.core import QgsProcessingException
    from urban_synthesis.plugin.buildings import parts as bp

    tee = [shapely.LineString([(200, 0), (260, 0)]), shapely.LineString([(230, 0), (230, 24)])]
    wkts = [_at(g).wkt for g in COURTYARD + tee]
    counts = [None, None, None, None, "doors=3"] + [None, None]
    skel = memory_layer("LineString", wkts, CRS, fields="&field=counts:string",
                        rows=[(c,) for c in counts], name="wings")
    _, rows, geoms = _run(qgis_processing, SKELETON=skel, SKELETON_NETWORK=True,
                          K_SOLUTIONS=2)
    assert {r["building_id"] for r in rows} == {1, 6}
    doors = bp.terrace_library().table.set_index("part_id")["doors"]
    target = shapely.union_all([shapely.buffer(_at(g), 6.0, cap_style="flat",
                                               join_style="mitre") for g in COURTYARD])
    solutions = _by_solution(rows, geoms, 1)
    assert len(solutions) == 2
    _assert_k_best(solutions)
    for rows_s, geoms_s in solutions.values():
        flat = shapely.force_2d(geoms_s)
        _assert_no_overlaps(flat)
        assert shapely.symmetric_difference(shapely.union_all(flat), target).area < 1e-3
        kinds = [r["kind"] for r in rows_s]
        assert kinds.count("corner") == 4 and kinds.count("tee") == 4
        assert kinds.count("end_left") + kinds.count("end_right") == 4
        east = shapely.get_coordinates(shapely.centroid(flat))[:, 0] > X0 + 55
        assert sum(doors[r["part_id"]] for r, e in zip(rows_s, east) if e) == 3
    tee_rows = _by_solution(rows, geoms, 6)[1][0]
    assert [r["kind"] for r in tee_rows].count("tee") == 1
    bad = memory_layer("LineString", [_at(g).wkt for g in tee], CRS,
                       fields="&field=counts:string", rows=[("doors>2",), (None,)],
                       name="bad wings")
    with pytest.raises(QgsProcessingException, match="'bad wings': feature 1: .*not 'name=n'"):
        qgis_processing.run(ALG, {"OUTPUT": "memory:", "SKELETON": bad,
                                  "SKELETON_NETWORK": True})


def test_qgis_process_wing_network(tmp_path):
    """The courtyard building through qgis_process.bin: exit 0, T-parts written."""
    import geopandas as gpd
    import pyogrio

    path = tmp_path / "wings.gpkg"
    gpd.GeoDataFrame({"counts": [None] * len(COURTYARD)},
                     geometry=[_at(g) for g in COURTYARD], crs=32633).to_file(
        path, layer="wings", driver="GPKG")
    target = tmp_path / "building.gpkg"
    code, out, err = run_qgis_process("synthesizepartbuildings", {
        "SKELETON": f"{path}|layername=wings", "SKELETON_NETWORK": "true",
        "OUTPUT": str(target)})
    assert code == 0, err
    df = pyogrio.read_dataframe(target)
    assert df.geometry.is_valid.all() and (df.kind == "tee").sum() == 4
    assert df.building_id.nunique() == 1
