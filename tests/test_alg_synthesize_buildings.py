"""urbansynth:synthesizebuildingattributes and placelibrarybuildings (and the deprecated
synthesizebuildings that runs them) through real QGIS (processing.run and qgis_process.bin)."""
import numpy as np
import pytest
import shapely

from conftest import bubenec_layer, helsinki_layer, run_qgis_process
from helpers import layer_features, log_feedback, memory_layer
from urban_synthesis.plugin.buildings import attributes as building_attributes
from urban_synthesis.plugin.buildings import bestfit as building_bestfit
from urban_synthesis.plugin.measure import metrics

ATTRIBUTES = "urbansynth:synthesizebuildingattributes"
BESTFIT = "urbansynth:placelibrarybuildings"
DEPRECATED = "urbansynth:synthesizebuildings"
ATTRIBUTE_FIELDS = ["height_m", "levels", "building_type", "roof_shape", "source_id",
                    "similarity", "floor_area_m2", "height_given"]


@pytest.fixture(scope="module")
def helsinki_buildings(qgis_processing):
    """Helsinki buildings with normalised attributes (height_m, levels, building_type)."""
    out = qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": helsinki_layer("lines"), "BUILDINGS": helsinki_layer("multipolygons"),
        "OUTPUT": "memory:", "OUTPUT_BUILDINGS": "memory:"})
    return out["OUTPUT"], out["OUTPUT_BUILDINGS"]


def test_attributes_on_helsinki(qgis_processing, helsinki_buildings):
    blocks, buildings = helsinki_buildings
    out = qgis_processing.run(ATTRIBUTES, {
        "FOOTPRINTS": buildings, "EXAMPLE_BUILDINGS": helsinki_layer("multipolygons"),
        "ROADS": helsinki_layer("lines"), "EXAMPLE_ROADS": helsinki_layer("lines"),
        "MAX_HEIGHT": 40, "SEED": 2, "OUTPUT": "memory:"})
    layer = out["OUTPUT"]
    assert layer.crs().authid() == "EPSG:4326"  # back in the input CRS
    names = [f.name() for f in layer.fields()]
    assert names[-len(ATTRIBUTE_FIELDS):] == ATTRIBUTE_FIELDS
    assert "block_id" in names  # the footprints' own fields are kept
    rows, geoms = layer_features(layer)
    assert len(rows) == buildings.featureCount()
    h = np.array([r["height_m"] for r in rows], dtype=float)
    assert np.isfinite(h).all() and h.max() <= 40 and h.min() > 0
    assert all(r["levels"] >= 1 for r in rows)
    assert {r["building_type"] for r in rows} <= set(building_attributes.BUILDING_TYPES)
    # every source is an example building with a height (OSM feature ids)
    ex_rows, _ = layer_features(buildings)
    known = np.array([r["height_m"] for r in ex_rows], dtype=float)
    assert np.mean([r["similarity"] for r in rows]) > 0.3
    d = metrics.two_sample(h, np.minimum(known[np.isfinite(known)], 40))
    assert d["wasserstein_norm"] < 0.35


def test_examples_elsewhere_are_measured_in_their_own_crs(qgis_processing,
                                                          helsinki_buildings):
    """Prague footprints attributed from Helsinki's buildings: the same buildings, in the
    same metres, labelled with their own UTM zone (35N) or with zone 18N (northern
    Canada), give the same attributes: each example is measured in its own working CRS.
    Both were projected into the footprints' zone (33N), the Canadian ones across 90
    degrees of longitude, which tore their shapes and context apart."""
    from qgis.core import (QgsCoordinateReferenceSystem, QgsCoordinateTransform, QgsProject)

    _, buildings = helsinki_buildings
    tr = QgsCoordinateTransform(buildings.crs(), QgsCoordinateReferenceSystem("EPSG:32635"),
                                QgsProject.instance())
    wkts, rows = [], []
    for f in buildings.getFeatures():
        g = f.geometry()
        g.transform(tr)
        wkts.append(g.asWkt(3))
        rows.append([f["height_m"], f["levels"], f["building_type"]])
    fields = "&field=height_m:double&field=levels:integer&field=building_type:string"
    runs = {}
    for zone in ("EPSG:32635", "EPSG:32618"):
        examples = memory_layer("MultiPolygon", wkts, zone, fields, rows, name="helsinki")
        out = qgis_processing.run(ATTRIBUTES, {
            "FOOTPRINTS": bubenec_layer("buildings"), "EXAMPLE_BUILDINGS": examples,
            "SEED": 2, "OUTPUT": "memory:"})
        runs[zone] = [(r["source_id"], r["height_m"], round(r["similarity"], 9))
                      for r in layer_features(out["OUTPUT"])[0]]
    assert runs["EPSG:32635"] == runs["EPSG:32618"]


def test_example_without_heights_says_so(qgis_processing):
    """Bubeneč's buildings have no heights: types come across, heights stay empty, and
    the log says so instead of claiming heights were attributed."""
    log = log_feedback()
    out = qgis_processing.run(ATTRIBUTES, {
        "FOOTPRINTS": bubenec_layer("buildings"),
        "EXAMPLE_BUILDINGS": bubenec_layer("buildings"), "OUTPUT": "memory:"}, feedback=log)
    rows, _ = layer_features(out["OUTPUT"])
    assert all(r["height_m"] is None for r in rows)
    assert all(r["building_type"] for r in rows)
    # said once, naming the example layer (it was said twice, the second time without it)
    said = [w for w in log.warnings if "no example building has a height" in w.lower()]
    assert len(said) == 1 and "'bubenec (buildings)'" in said[0], log.warnings
    assert not any("with a height (features" in m for m in log.messages)
    assert any("144 footprints attributed with types and roofs" in m for m in log.messages)


def test_footprints_that_are_no_buildings_are_skipped_and_far_overshoot_warned(
        qgis_processing, helsinki_buildings):
    """OSM multipolygons as footprints: forests, water and boundaries got 15 m heights (one
    boundary 37 km² of floor area); they are skipped and counted. A target FAR the
    footprints exceed at one storey is warned of (it was an info line)."""
    from qgis.core import QgsVectorLayer

    blocks, buildings = helsinki_buildings
    log = log_feedback()
    out = qgis_processing.run(ATTRIBUTES, {
        "FOOTPRINTS": helsinki_layer("multipolygons"), "EXAMPLE_BUILDINGS": buildings,
        "TARGET_FAR": 0.01, "OUTPUT": "memory:"}, feedback=log)
    layer = out["OUTPUT"]
    source = QgsVectorLayer(helsinki_layer("multipolygons"), "mp", "ogr")
    n_in = sum(1 for f in source.getFeatures() if f.hasGeometry())
    assert 0 < layer.featureCount() < n_in
    assert all(r["building"] not in (None, "", "no") for r in layer_features(layer)[0])
    assert any("polygons without a 'building' value skipped" in m for m in log.messages)
    assert any("over the target floor-area ratio" in w for w in log.warnings), log.warnings
    # without blocks the target is met for the district: the warning says so ('1 blocks
    # (or the district) stay ...', '1 blocks stay ... under' of a run without blocks)
    assert any(w.startswith("The district stays more than 10 % over the target floor-area "
                            "ratio: its footprints cover more than it") for w in log.warnings)
    assert not any("1 blocks" in w for w in log.warnings)


def test_far_per_block(qgis_processing, helsinki_buildings):
    blocks, buildings = helsinki_buildings
    out = qgis_processing.run(ATTRIBUTES, {
        "FOOTPRINTS": buildings, "EXAMPLE_BUILDINGS": buildings, "BLOCKS": blocks,
        "TARGET_FAR": 2.0, "CHOICE": 1, "OUTPUT": "memory:"})
    rows, geoms = layer_features(out["OUTPUT"])
    # floor area = footprint area (metric) x levels, per block
    brows, bgeoms = layer_features(blocks)
    from pyproj import Transformer

    tr = Transformer.from_crs(4326, 32635, always_xy=True)
    to_m = lambda g: shapely.transform(g, lambda c: np.column_stack(tr.transform(c[:, 0], c[:, 1])))  # noqa: E731
    fa = np.array([r["floor_area_m2"] for r in rows])
    lv = np.array([r["levels"] for r in rows])
    area = shapely.area(to_m(geoms))
    assert np.allclose(fa, area * lv, rtol=1e-3)
    pts = shapely.point_on_surface(geoms)
    hit = 0
    for bg in bgeoms:
        inside = shapely.within(pts, bg)
        if inside.sum() >= 3:
            ground = shapely.area(to_m(bg))
            diff = 2.0 * ground - fa[inside].sum()
            # no single storey more or less on any footprint brings the FAR closer, unless
            # that footprint is at one storey already
            better = np.abs(diff - np.sign(diff) * area[inside]) < abs(diff) - 1e-6
            assert (lv[inside][better] == 1).all() and diff < 0 or not better.any()
            assert abs(diff) <= 0.5 * area[inside].max() + 1e-6
            hit += 1
    assert hit >= 10


def test_a_real_layer_keeps_the_heights_it_has(qgis_processing, helsinki_buildings):
    """A real layer with missing heights (Helsinki's buildings, some with height or
    building:levels): with KEEP_GIVEN every known height and its levels stay as they were,
    also under a target FAR per block (the other footprints make it up), and only the
    others are synthesised; they were all replaced by their donors' heights. Off (the
    default, for synthesised footprints), every footprint takes its donor's."""
    blocks, buildings = helsinki_buildings
    own, _ = layer_features(buildings)
    known = np.array([r["height_m"] for r in own], dtype=float)
    known_levels = np.array([r["levels"] if r["levels"] is not None else np.nan
                             for r in own], dtype=float)
    has = np.isfinite(known)
    assert 50 < has.sum() < len(own)
    log = log_feedback()
    params = {"FOOTPRINTS": buildings, "EXAMPLE_BUILDINGS": buildings, "BLOCKS": blocks,
              "TARGET_FAR": 2.0, "OUTPUT": "memory:"}
    kept = qgis_processing.run(ATTRIBUTES, {**params, "KEEP_GIVEN": True},
                               feedback=log)["OUTPUT"]
    rows, _ = layer_features(kept)
    h = np.array([r["height_m"] for r in rows], dtype=float)
    lv = np.array([r["levels"] for r in rows], dtype=float)
    assert np.allclose(h[has], known[has])
    with_levels = has & np.isfinite(known_levels)
    assert np.array_equal(lv[with_levels], np.round(known_levels[with_levels]))
    assert [r["height_given"] for r in rows] == list(has)
    assert np.isfinite(h[~has]).all() and (lv >= 1).all()
    assert any(f"{has.sum()} footprints keep their own height" in m for m in log.messages)
    replaced = qgis_processing.run(ATTRIBUTES, params)["OUTPUT"]
    h_off = np.array([r["height_m"] for r in layer_features(replaced)[0]], dtype=float)
    assert (h_off[has] != known[has]).mean() > 0.3     # about half changed (48 %)


def test_best_fit_on_bubenec(qgis_processing):
    out = qgis_processing.run(BESTFIT, {
        "PARCELS": bubenec_layer("plots"), "ROADS": bubenec_layer("streets"),
        "MIN_SETBACK": 1.0, "OUTPUT": "memory:"})
    layer = out["OUTPUT"]
    assert layer.crs().authid() == "EPSG:3857"
    names = [f.name() for f in layer.fields()]
    assert names[:len(building_bestfit.PLACEMENT_FIELDS)] == [
        n for n, _ in building_bestfit.PLACEMENT_FIELDS]
    assert {"height_m", "levels", "building_type", "street_access_sides"} <= set(names)
    rows, geoms = layer_features(layer)
    assert 150 < len(rows) < 407
    prow, pgeoms = layer_features(_ogr_layer(bubenec_layer("plots")))
    for r, g in zip(rows, geoms):
        # parcel ids are 1..n in layer order (the plots have no parcel_id)
        assert pgeoms[r["parcel_id"] - 1].buffer(1e-3).contains(g)


def test_best_fit_on_a_slope(qgis_processing, tmp_path):
    """Scharl ch. 6.2 through QGIS: a synthetic DEM (no real DEM ships with the plugin),
    the steep parcel stays empty, the building on the gentle one sits at the ground of
    its lowest corner."""
    from osgeo import gdal, osr
    from qgis.core import QgsWkbTypes

    crs = "EPSG:32633"
    x0, y0 = 500000.0, 5550000.0
    cell, cols, rows = 2.0, 150, 40
    x, y = np.meshgrid(x0 - 60 + cell * (np.arange(cols) + 0.5),
                       y0 + 20 - cell * (np.arange(rows) + 0.5))
    z = 300 + np.where(x - x0 < 100, -0.10, -0.40) * (y - y0)   # 10 % / 40 % up to the south
    path = tmp_path / "slope.tif"
    ds = gdal.GetDriverByName("GTiff").Create(str(path), cols, rows, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((x0 - 60, cell, 0.0, y0 + 20, 0.0, -cell))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32633)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(z.astype(np.float32))
    ds = None
    roads = memory_layer("LineString", [f"LINESTRING ({x0 - 50} {y0}, {x0 + 200} {y0})"], crs)
    plots = memory_layer("Polygon", [shapely.box(x0 + 20, y0 - 40, x0 + 70, y0 - 5).wkt,
                                     shapely.box(x0 + 120, y0 - 40, x0 + 170, y0 - 5).wkt], crs)
    out = qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads,
                                        "DEM": str(path), "MAX_PARCEL_SLOPE": 25,
                                        "OUTPUT": "memory:"})
    layer = out["OUTPUT"]
    assert layer.wkbType() == QgsWkbTypes.Type.PolygonZ
    rows_, geoms = layer_features(layer)
    assert len(rows_) == 1 and rows_[0]["parcel_id"] == 1
    r = rows_[0]
    assert r["parcel_slope_pct"] == pytest.approx(10.0, abs=0.2)
    xyz = shapely.get_coordinates(geoms[0], include_z=True)
    ground = 300 - 0.10 * (xyz[:, 1] - y0)
    assert np.allclose(xyz[:, 2], r["base_z"]) and r["base_z"] == pytest.approx(ground.min(),
                                                                                  abs=0.01)
    assert r["sunk_m"] == pytest.approx(np.ptp(ground), abs=0.01)
    # a DEM with no value under the gentle parcel (a hole, nodata 0): it stays empty with a
    # warning (a NaN base height crashed the run), the output is PolygonZ all the same
    z[(x - x0 > 10) & (x - x0 < 80)] = -9999
    holed = tmp_path / "holed.tif"
    ds = gdal.GetDriverByName("GTiff").Create(str(holed), cols, rows, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((x0 - 60, cell, 0.0, y0 + 20, 0.0, -cell))
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(z.astype(np.float32))
    ds.GetRasterBand(1).SetNoDataValue(-9999)
    ds = None
    log = log_feedback()
    out = qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads, "DEM": str(holed),
                                        "MAX_PARCEL_SLOPE": 25, "OUTPUT": "memory:"},
                              feedback=log)
    assert out["OUTPUT"].wkbType() == QgsWkbTypes.Type.PolygonZ
    assert out["OUTPUT"].featureCount() == 0
    assert any("1 parcel stays empty because the DEM has no value" in w for w in log.warnings)


def _ogr_layer(uri):
    from qgis.core import QgsVectorLayer

    return QgsVectorLayer(uri, "plots", "ogr")


def test_library_layer(qgis_processing):
    crs = "EPSG:32633"
    roads = memory_layer("LineString", ["LINESTRING (0 0, 300 0)"], crs)
    plots = memory_layer("Polygon", ["POLYGON ((10 -5, 40 -5, 40 -40, 10 -40, 10 -5))",
                                     "POLYGON ((50 -5, 56 -5, 56 -40, 50 -40, 50 -5))"], crs)
    # a 12 x 10 house drawn clockwise with its door on edge 1 (north), a blind wall on
    # edge 3 (south); the 6 m wide plot is too narrow for it
    lib = memory_layer("Polygon", ["POLYGON ((1000 1000, 1000 1010, 1012 1010, 1012 1000, "
                                   "1000 1000))"], crs,
                       fields="&field=street_access_sides:string&field=blind_sides:string"
                              "&field=height_m:double",
                       rows=[("1", "3", 8.5)])
    out = qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads,
                                    "BUILDING_LIBRARY": lib, "MIN_SETBACK": 3,
                                    "OUTPUT": "memory:"})
    rows, geoms = layer_features(out["OUTPUT"])
    assert len(rows) == 1 and rows[0]["parcel_id"] == 1 and rows[0]["height_m"] == 8.5
    # the door side (edge 1: (1000,1010)->(1012,1010), top) faces the street at y = 0
    assert shapely.bounds(geoms[0])[3] == pytest.approx(-8.0)
    assert rows[0]["rotation"] == pytest.approx(0.0)


def test_the_output_fields_do_not_depend_on_what_fitted(qgis_processing):
    """The library's fields and their types come from the whole library: one street house
    placed (access '0') gave street_access_sides a Real field and levels a Real one, a
    corner block placed gave it a String field, and a run where nothing fitted had no
    height_m, name or levels at all (a model writing into one table, the height style)."""
    from urban_synthesis.plugin.qgis_glue.qgis_io import field_kind

    crs = "EPSG:32633"
    roads = memory_layer("LineString", ["LINESTRING (0 0, 300 0)"], crs)
    fits = memory_layer("Polygon", [shapely.box(10, -40, 40, -5).wkt], crs)
    too_small = memory_layer("Polygon", [shapely.box(10, -9, 14, -5).wkt], crs)
    types = []
    for plots in (fits, too_small):
        out = qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads,
                                            "OUTPUT": "memory:"})
        layer = out["OUTPUT"]
        assert layer.featureCount() == (1 if plots is fits else 0)
        fields = layer.fields()
        types.append({f.name(): field_kind(f) for f in fields})
    assert types[0] == types[1]
    assert types[0]["street_access_sides"] == types[0]["blind_sides"] == "str"
    assert types[0]["levels"] == "int" and types[0]["height_m"] == "float"
    # a library whose sides are an integer field: text in the output as well
    lib = memory_layer("Polygon", ["POLYGON ((0 0, 12 0, 12 10, 0 10, 0 0))"], crs,
                       fields="&field=street_access_sides:integer&field=blind_sides:integer",
                       rows=[(0, None)])
    out = qgis_processing.run(BESTFIT, {"PARCELS": fits, "ROADS": roads,
                                        "BUILDING_LIBRARY": lib, "OUTPUT": "memory:"})
    rows, _ = layer_features(out["OUTPUT"])
    assert [(r["street_access_sides"], r["blind_sides"]) for r in rows] == [("0", "")]


def test_a_library_drawn_anywhere_keeps_its_size(qgis_processing):
    """The 12 x 10 m house of a library drawn in a metric CRS elsewhere (any position, the
    help says; here UTM zone 31N at the equator), placed on a plot in Prague: 120 m² (it
    was projected into the plot's UTM zone, 33N, 10.5 degrees of longitude east of it,
    and came out 8 % larger)."""
    crs = "EPSG:32633"
    x0, y0 = 458000.0, 5551000.0                  # Prague-Bubeneč in UTM 33N
    roads = memory_layer("LineString", [f"LINESTRING ({x0} {y0}, {x0 + 300} {y0})"], crs)
    plot = memory_layer("Polygon", [f"POLYGON (({x0 + 10} {y0 - 5}, {x0 + 40} {y0 - 5}, "
                                    f"{x0 + 40} {y0 - 40}, {x0 + 10} {y0 - 40}, "
                                    f"{x0 + 10} {y0 - 5}))"], crs)
    lib = memory_layer("Polygon", ["POLYGON ((0 0, 0 10, 12 10, 12 0, 0 0))"], "EPSG:32631",
                       fields="&field=street_access_sides:string&field=blind_sides:string",
                       rows=[("1", "3")])
    out = qgis_processing.run(BESTFIT, {"PARCELS": plot, "ROADS": roads,
                                        "BUILDING_LIBRARY": lib, "OUTPUT": "memory:"})
    rows, geoms = layer_features(out["OUTPUT"])
    assert len(rows) == 1
    assert shapely.area(geoms[0]) == pytest.approx(120.0, rel=1e-6)


def test_bad_input(qgis_processing):
    from qgis.core import QgsProcessingException

    def fails(params, match):
        """METHOD 0 / 1 say which tool: attributes / best fit (the deprecated tool with
        METHOD gives the same messages; test_deprecated_tool)."""
        alg = (ATTRIBUTES, BESTFIT)[params.pop("METHOD")]
        with pytest.raises(QgsProcessingException, match=match):
            qgis_processing.run(alg, dict(params, OUTPUT="memory:"))

    crs = "EPSG:32633"
    plots = memory_layer("Polygon", ["POLYGON ((0 -5, 30 -5, 30 -40, 0 -40, 0 -5))"], crs)
    roads = memory_layer("LineString", ["LINESTRING (0 0, 300 0)"], crs)
    fails({"METHOD": 0, "FOOTPRINTS": plots}, r"Example buildings \(EXAMPLE_BUILDINGS\) is needed")
    fails({"METHOD": 1, "PARCELS": plots}, r"Roads \(ROADS\) is needed")
    fails({"METHOD": 0, "FOOTPRINTS": memory_layer("Polygon", [], crs),
           "EXAMPLE_BUILDINGS": plots}, "empty")
    fails({"METHOD": 0, "FOOTPRINTS": plots, "EXAMPLE_BUILDINGS": plots, "TARGET_FAR": 2.0},
          "no example building has a height")
    fails({"METHOD": 0, "FOOTPRINTS": plots, "EXAMPLE_BUILDINGS": roads}, "lines; polygons")
    fails({"METHOD": 0, "FOOTPRINTS": plots, "EXAMPLE_BUILDINGS": bubenec_layer("buildings"),
           "MIN_HEIGHT": 50, "MAX_HEIGHT": 20}, "must be larger than the minimum height")
    no_fields = memory_layer("Polygon", ["POLYGON ((0 0, 5 0, 5 5, 0 0))"], crs)
    fails({"METHOD": 1, "PARCELS": plots, "ROADS": roads, "BUILDING_LIBRARY": no_fields},
          "no field 'street_access_sides'")
    bad = memory_layer("Polygon", ["POLYGON ((0 0, 5 0, 5 5, 0 5, 0 0))"], crs,
                       fields="&field=street_access_sides:string&field=blind_sides:string",
                       rows=[("7", "")])
    fails({"METHOD": 1, "PARCELS": plots, "ROADS": roads, "BUILDING_LIBRARY": bad},
          "edge 7 does not exist")


def test_qgis_process_run(tmp_path):
    """One real qgis_process.bin run on the example data: exit code 0."""
    target = tmp_path / "buildings.gpkg"
    code, out, err = run_qgis_process("placelibrarybuildings", {
        "PARCELS": bubenec_layer("plots"), "ROADS": bubenec_layer("streets"),
        "OUTPUT": str(target)})
    assert code == 0, err
    assert out is not None and target.exists()
    import pyogrio

    df = pyogrio.read_dataframe(target)
    assert 150 < len(df) < 407 and df.geometry.is_valid.all()
    assert (df.parcel_share > 0).all() and (df.parcel_share <= 1.0 + 1e-6).all()


def test_deprecated_tool(qgis_processing):
    """The old id still runs each method for existing models, flagged deprecated, with the
    focused tool's result; a method without its inputs says what it needs."""
    from qgis.core import QgsApplication, QgsProcessingAlgorithm, QgsProcessingException

    alg = QgsApplication.processingRegistry().algorithmById(DEPRECATED)
    assert alg.flags() & QgsProcessingAlgorithm.Flag.FlagDeprecated
    params = {"PARCELS": bubenec_layer("plots"), "ROADS": bubenec_layer("streets")}
    old = layer_features(qgis_processing.run(DEPRECATED, dict(params, METHOD=1,
                                                              OUTPUT="memory:"))["OUTPUT"])
    new = layer_features(qgis_processing.run(BESTFIT, dict(params, OUTPUT="memory:"))["OUTPUT"])
    assert old[0] == new[0] and shapely.equals_exact(old[1], new[1], 1e-9).all()
    for method, params, match in ((0, {}, "needs: Footprints, Example buildings"),
                                  (1, {"PARCELS": bubenec_layer("plots")}, "needs: Roads"),
                                  (2, {}, "needs: Skeletons")):
        with pytest.raises(QgsProcessingException, match=match):
            qgis_processing.run(DEPRECATED, dict(params, METHOD=method, OUTPUT="memory:"))


def test_the_output_help_names_every_output_field(qgis_processing):
    """Each field the two tools add is named in the OUTPUT help (the dialog, qgis_process
    help, the README's reference): the attributes' floor_area_m2 and the best fit's area_m2,
    parcel_share, base_z, parcel_slope_pct and sunk_m were not."""
    from qgis.core import QgsApplication

    crs = "EPSG:32633"
    roads = memory_layer("LineString", ["LINESTRING (0 0, 300 0)"], crs)
    plots = memory_layer("Polygon", [shapely.box(10, -40, 40, -5).wkt], crs)
    runs = {BESTFIT: {"PARCELS": plots, "ROADS": roads},
            ATTRIBUTES: {"FOOTPRINTS": plots, "EXAMPLE_BUILDINGS": bubenec_layer("buildings")}}
    for alg_id, params in runs.items():
        layer = qgis_processing.run(alg_id, dict(params, OUTPUT="memory:"))["OUTPUT"]
        help_text = QgsApplication.processingRegistry().algorithmById(
            alg_id).parameterDefinition("OUTPUT").help()
        added = [f.name() for f in layer.fields() if f.name() not in ("fid",)]
        assert [f for f in added if f not in help_text] == [], alg_id


def test_parcel_ids_that_cannot_be_kept_are_renumbered_with_a_note(qgis_processing):
    """Cadastre parcels with text ids ('A-1') or one id twice: the buildings' parcel_id was
    1..n without a word, so it silently named other parcels than the layer's own ids."""
    crs = "EPSG:32633"
    roads = memory_layer("LineString", ["LINESTRING (0 0, 300 0)"], crs)
    boxes = [shapely.box(10, -40, 40, -5).wkt, shapely.box(50, -40, 80, -5).wkt]
    for kind, ids in (("string", ("A-1", "A-2")), ("integer", (7, 7)), ("integer", (7, 9))):
        plots = memory_layer("Polygon", boxes, crs, fields=f"&field=parcel_id:{kind}",
                             rows=[(i,) for i in ids], name="cadastre")
        log = log_feedback()
        out = qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads,
                                            "OUTPUT": "memory:"}, feedback=log)
        got = sorted(r["parcel_id"] for r in layer_features(out["OUTPUT"])[0])
        note = any("parcel_id is not a unique whole number per parcel; parcels are numbered "
                   "1..n" in m for m in log.messages)
        if ids == (7, 9):
            assert got == [7, 9] and not note
        else:
            assert got == [1, 2] and note, ids


def test_parcels_no_building_fits_are_counted_and_named(qgis_processing):
    """A setback deeper than the parcels: every parcel faces the street and stays empty.
    The log said '0 of 2 parcels got a building; 100.0 % left empty (0 have no side facing
    a street)' and warned 'see the counts above', which named no reason."""
    crs = "EPSG:32633"
    roads = memory_layer("LineString", ["LINESTRING (0 0, 300 0)"], crs)
    plots = memory_layer("Polygon", [shapely.box(10, -40, 40, -5).wkt,
                                     shapely.box(50, -40, 80, -5).wkt], crs)
    log = log_feedback()
    out = qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads, "MIN_SETBACK": 40,
                                        "OUTPUT": "memory:"}, feedback=log)
    assert out["OUTPUT"].featureCount() == 0
    assert any("(0 have no side facing a street, 2 fit no library building with the minimum "
               "setback" in m for m in log.messages), log.messages
    assert any(w.startswith("No parcel got a building: no library building fits with the "
                            "minimum setback") for w in log.warnings), log.warnings


def test_footprints_from_a_shapefile_keep_their_full_names(qgis_processing, tmp_path):
    """Footprints saved as a shapefile (building_type cut to 'building_t', building_tag to
    'building_1') are read by the full names their sidecar style keeps as aliases, also
    where a tool reads every field: KEEP_GIVEN keeps their types, and the output has the
    fields of the run on the footprints from memory, not the cut name next to a new
    'building_type' (written 'building_1' beside the input's 'building_t')."""
    from qgis.core import QgsVectorLayer

    shp = tmp_path / "buildings.shp"
    made = {}
    for key, dest in (("memory", "memory:"), ("shapefile", str(shp))):
        made[key] = qgis_processing.run("urbansynth:extractblocks", {
            "ROADS": helsinki_layer("lines"), "BUILDINGS": helsinki_layer("multipolygons"),
            "OUTPUT": "memory:", "OUTPUT_BUILDINGS": dest})["OUTPUT_BUILDINGS"]
    assert "building_t" in QgsVectorLayer(str(shp), "b", "ogr").fields().names()
    outs = {}
    for key, footprints in made.items():
        out = qgis_processing.run(ATTRIBUTES, {
            "FOOTPRINTS": footprints, "EXAMPLE_BUILDINGS": made["memory"], "KEEP_GIVEN": True,
            "SEED": 2, "OUTPUT": "memory:"})["OUTPUT"]
        outs[key] = layer_features(out)[0]
    names = {key: list(rows[0].keys()) for key, rows in outs.items()}
    assert names["shapefile"] == names["memory"]
    assert "building_t" not in names["shapefile"]
    for field in ("building_type", "height_m", "levels", "height_given", "block_id"):
        assert [r[field] for r in outs["shapefile"]] == [r[field] for r in outs["memory"]], field


def test_a_library_from_a_shapefile(qgis_processing, tmp_path):
    """A building library saved as a shapefile cuts street_access_sides and blind_sides to
    'street_acc' and 'blind_side': the library written by 'Place library buildings' is
    read back by the full names its sidecar style keeps, not refused for missing them."""
    crs = "EPSG:32633"
    roads = memory_layer("LineString", ["LINESTRING (0 0, 300 0)"], crs)
    plots = memory_layer("Polygon", ["POLYGON ((10 -5, 40 -5, 40 -40, 10 -40, 10 -5))"], crs)
    lib = memory_layer("Polygon", ["POLYGON ((1000 1000, 1000 1010, 1012 1010, 1012 1000, "
                                   "1000 1000))"], crs,
                       fields="&field=street_access_sides:string&field=blind_sides:string"
                              "&field=height_m:double",
                       rows=[("1", "3", 8.5)])
    shp = tmp_path / "placed.shp"
    qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads, "BUILDING_LIBRARY": lib,
                                  "MIN_SETBACK": 3, "OUTPUT": str(shp)})
    out = qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads,
                                        "BUILDING_LIBRARY": str(shp), "MIN_SETBACK": 3,
                                        "OUTPUT": "memory:"})
    rows, geoms = layer_features(out["OUTPUT"])
    assert len(rows) == 1 and rows[0]["height_m"] == 8.5
    assert shapely.bounds(geoms[0])[3] == pytest.approx(-8.0)
    # a shapefile written by other software has no sidecar style: the names cut to ten
    # characters are read as the full ones (it was refused: "has no field
    # 'street_access_sides'")
    sidecar = tmp_path / "placed.qml"
    assert sidecar.exists()
    sidecar.unlink()
    log = log_feedback()
    out = qgis_processing.run(BESTFIT, {"PARCELS": plots, "ROADS": roads,
                                        "BUILDING_LIBRARY": str(shp), "MIN_SETBACK": 3,
                                        "OUTPUT": "memory:"}, feedback=log)
    assert [r["height_m"] for r in layer_features(out["OUTPUT"])[0]] == [8.5]
    assert any("'street_access_sides' read from 'street_acc'" in m and "cut to 10" in m
               for m in log.messages), log.messages


def test_a_given_height_that_is_no_height_is_said_so(qgis_processing):
    """KEEP_GIVEN with a given height over 1,000 m (a typo: the rule of every height read)
    synthesises that footprint's height as for a missing one, and now says so; it was
    dropped silently."""
    crs = "EPSG:32633"
    squares = [f"POLYGON (({x} {y}, {x + 12} {y}, {x + 12} {y + 10}, {x} {y + 10}, {x} {y}))"
               for x in range(0, 200, 40) for y in range(0, 160, 40)]
    examples = memory_layer("Polygon", squares, crs, "&field=height_m:double",
                            [(10.0 + k,) for k in range(len(squares))], name="examples")
    footprints = memory_layer("Polygon", squares[:3], crs, "&field=height_m:double",
                              [(12.0,), (1200.0,), (None,)], name="given")
    log = log_feedback()
    out = qgis_processing.run(ATTRIBUTES, {"FOOTPRINTS": footprints, "EXAMPLE_BUILDINGS":
                                           examples, "KEEP_GIVEN": True, "OUTPUT": "memory:"},
                              feedback=log)
    rows, _ = layer_features(out["OUTPUT"])
    assert [r["height_given"] for r in rows] == [True, False, False]
    assert rows[0]["height_m"] == 12.0 and 10 <= rows[1]["height_m"] <= 29
    warned = [w for w in log.warnings if "not kept" in w]
    assert len(warned) == 1 and warned[0].startswith("1 height of 'given'") and \
        "1200" in warned[0], log.warnings
