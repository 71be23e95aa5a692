"""urbansynth:splitdomain through real QGIS (processing.run and qgis_process.bin)."""
import numpy as np
import pytest
import shapely
import shapely.affinity

from conftest import BUBENEC, run_qgis_process
from helpers import (bubenec, drawn_court_template, drawn_pentagon_template, layer_features,
                     memory_layer)
from urban_synthesis.plugin.planned import domain_split

ALG = "urbansynth:splitdomain"


@pytest.fixture(scope="module")
def full_hull():
    """Convex hull of Bubeneč's cadastre plots (UTM 33N)."""
    return shapely.convex_hull(shapely.union_all(bubenec("plots").geometry.to_numpy()))


@pytest.fixture(scope="module")
def hull(full_hull):
    """The hull cut to 400 m x 400 m around its centre (fast tests)."""
    c = full_hull.centroid
    return full_hull.intersection(shapely.box(c.x - 200, c.y - 200, c.x + 200, c.y + 200))


@pytest.fixture(scope="module")
def region_layer(qgis_processing, hull):
    return memory_layer("Polygon", [hull.wkt], crs="EPSG:32633", name="bubenec hull")


def test_two_variations(qgis_processing, region_layer, hull):
    out = qgis_processing.run(ALG, {
        "REGION": region_layer, "VARIATIONS": 2, "SEED": 3, "OUTPUT_ROADS": "memory:",
        "OUTPUT_PARCELS": "memory:", "OUTPUT_METRICS": "memory:"})
    roads, parcels, table = out["OUTPUT_ROADS"], out["OUTPUT_PARCELS"], out["OUTPUT_METRICS"]
    assert parcels.crs().authid() == "EPSG:32633" and roads.crs().authid() == "EPSG:32633"
    assert [f.name() for f in parcels.fields()] == [n for n, _ in domain_split.PARCEL_FIELDS]
    assert [f.name() for f in table.fields()] == [n for n, _ in domain_split.METRIC_FIELDS]
    rows, geoms = layer_features(parcels)
    road_rows, road_geoms = layer_features(roads)
    metric_rows = layer_features(table)[0]
    assert [r["variation"] for r in metric_rows] == [1, 2]
    assert shapely.is_valid(geoms).all()
    for v in (1, 2):
        sel = np.array([r["variation"] == v for r in rows])
        res = sel & np.array([r["land_use"] == "residential" for r in rows])
        assert res.sum() > 60
        assert all(rows[i]["has_street_access"] for i in np.flatnonzero(res))
        # no overlap within a variation; everything inside the region
        assert abs(shapely.union_all(geoms[sel]).area - shapely.area(geoms[sel]).sum()) < 1.0
        m = metric_rows[v - 1]
        assert m["p_count"] == res.sum() and m["no_access"] == 0
        assert m["p_angle"] < 4.0 and m["p_area"] < 1.07
        for r in (r for r in rows if r["variation"] == v):
            assert r["undesirable"] == (r["p_angle"] > 15 or r["p_area"] > 1.2)
    assert shapely.within(geoms, hull.buffer(1e-3)).all()
    # variations differ: different streets
    streets = {v: {g.wkb for g, r in zip(road_geoms, road_rows)
                   if r["variation"] == v and r["level"] == 2} for v in (1, 2)}
    assert streets[1] and streets[1] != streets[2]
    assert {r["level"] for r in road_rows} >= {1, 2}


def test_key_roads_areas_and_land_use(qgis_processing, region_layer, hull):
    c = hull.centroid
    minx, _, maxx, _ = hull.bounds
    road = memory_layer("LineString", [f"LINESTRING ({minx - 5} {c.y}, {maxx + 5} {c.y})"],
                        crs="EPSG:32633", name="main road")
    park = memory_layer("Polygon", [c.buffer(35).wkt], crs="EPSG:32633",
                        fields="&field=use:string", rows=[("school",)], name="school")
    out = qgis_processing.run(ALG, {
        "REGION": region_layer, "KEY_ROADS": road, "KEY_AREAS": park,
        "KEY_AREA_USE_FIELD": "use", "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})
    rows, geoms = layer_features(out["OUTPUT_PARCELS"])
    assert sum(r["land_use"] == "school" for r in rows) == 1
    road_rows = layer_features(out["OUTPUT_ROADS"])[0]
    assert any(r["level"] == 0 and r["kind"] == "key" for r in road_rows)
    key_line = shapely.LineString([(minx - 5, c.y), (maxx + 5, c.y)])
    res = np.array([r["land_use"] == "residential" for r in rows])
    assert not shapely.intersects(geoms[res], key_line).any()


def test_drawn_templates(qgis_processing, region_layer):
    cells = [shapely.box(i * 18, j * 30, (i + 1) * 18, (j + 1) * 30)
             for i in range(3) for j in range(2)]
    tmpl = memory_layer("Polygon", [g.wkt for g in cells], crs="EPSG:32633",
                        fields="&field=template:string&field=label:string",
                        rows=[("double", "R")] * 6, name="my templates")
    out = qgis_processing.run(ALG, {"REGION": region_layer, "TEMPLATE_LAYER": tmpl,
                                    "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})
    rows = layer_features(out["OUTPUT_PARCELS"])[0]
    used = {r["template"] for r in rows if r["land_use"] == "residential"}
    assert "double" in used and used <= {"double", "recursive"}


def test_a_template_drawn_in_a_crs_far_away_is_used_as_drawn(qgis_processing):
    """Templates are drawn anywhere: five lots round a park drawn at (0, 0) of UTM zone
    18N (off Ecuador) fill a region in Prague exactly as when drawn in the region's own
    zone (the template was projected into zone 33N, 94 degrees of longitude away, which
    PROJ refused: the run failed)."""
    outline, pentagon, labels = drawn_pentagon_template()
    poly = shapely.affinity.translate(shapely.affinity.scale(outline, 1.1, 1.1), 500000,
                                      5550000)
    runs = {}
    for crs in ("EPSG:32633", "EPSG:32618"):
        out = qgis_processing.run(ALG, {
            "REGION": memory_layer("Polygon", [poly.wkt], crs="EPSG:32633", name="region"),
            "TEMPLATE_LAYER": memory_layer(
                "Polygon", [g.wkt for g in pentagon], crs=crs,
                fields="&field=template:string&field=label:string",
                rows=[("court", lab) for lab in labels], name="my templates"),
            "SEED": 1, "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})
        rows, geoms = layer_features(out["OUTPUT_PARCELS"])
        runs[crs] = sorted((r["template"], r["land_use"], round(float(a), 3))
                           for r, a in zip(rows, shapely.area(geoms)))
    assert sum(t == "court" for t, _, _ in runs["EPSG:32633"]) == 6
    assert runs["EPSG:32618"] == runs["EPSG:32633"]


def test_a_drawn_template_warped_as_drawn(qgis_processing):
    """Through Processing: a template drawn as five lots round a private park (no strip)
    fills a pentagonal region as drawn, the park kept; a court drawn with its own bent
    cul-de-sac (label S) gets that street; a template whose parcels leave a gap is refused
    by name."""
    from qgis.core import QgsProcessingException

    def template_layer(geoms, labels, name, title):
        return memory_layer("Polygon", [g.wkt for g in geoms], crs="EPSG:32633",
                            fields="&field=template:string&field=label:string",
                            rows=[(name, lab) for lab in labels], name=title)

    def region_layer_of(poly, title):
        poly = shapely.affinity.translate(poly, 500000, 5550000)
        return memory_layer("Polygon", [poly.wkt], crs="EPSG:32633", name=title)

    outline, pentagon, labels = drawn_pentagon_template()
    layer = region_layer_of(shapely.affinity.scale(outline, 1.1, 1.1), "court region")
    out = qgis_processing.run(ALG, {
        "REGION": layer, "TEMPLATE_LAYER": template_layer(pentagon, labels, "court",
                                                          "my templates"),
        "SEED": 1, "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})
    rows, geoms_out = layer_features(out["OUTPUT_PARCELS"])
    court = [r for r in rows if r["template"] == "court"]
    assert len(court) == 6 and sum(r["land_use"] == "park" for r in court) == 1
    assert all(r["has_street_access"] for r in court if r["land_use"] == "residential")
    block, geoms, labels = drawn_court_template()
    out = qgis_processing.run(ALG, {
        "REGION": region_layer_of(shapely.affinity.scale(block, 1.12, 1.15), "cul-de-sac region"),
        "TEMPLATE_LAYER": template_layer(geoms, labels, "cds", "my cul-de-sac"),
        "SEED": 1, "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})
    roads = layer_features(out["OUTPUT_ROADS"])[0]
    assert sum(r["kind"] == "cul_de_sac" for r in roads) == 1
    gap = template_layer([pentagon[0], pentagon[2]], ["R", "P"], "broken", "gappy templates")
    with pytest.raises(QgsProcessingException, match="gappy templates.*broken.*one polygon"):
        qgis_processing.run(ALG, {"REGION": layer, "TEMPLATE_LAYER": gap,
                                  "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})


def test_drawn_template_counts_from_fields(qgis_processing):
    """A template layer's optional fields max_count / min_count (Yang's k1, k2) and
    probability: with max_count 0 the pentagon that filled its region is never used; a
    minimum above the maximum is refused naming the layer and the template."""
    from qgis.core import QgsProcessingException

    outline, pentagon, labels = drawn_pentagon_template()
    region = memory_layer("Polygon", [shapely.affinity.translate(
        shapely.affinity.scale(outline, 1.1, 1.1), 500000, 5550000).wkt], crs="EPSG:32633",
        name="court region")

    def counted(min_count, max_count, title):
        return memory_layer("Polygon", [g.wkt for g in pentagon], crs="EPSG:32633",
                            fields="&field=template:string&field=label:string"
                                   "&field=min_count:integer&field=max_count:integer",
                            rows=[("court", lab, min_count, max_count) for lab in labels],
                            name=title)

    out = qgis_processing.run(ALG, {"REGION": region, "TEMPLATE_LAYER": counted(0, 0, "none"),
                                    "SEED": 1, "OUTPUT_ROADS": "memory:",
                                    "OUTPUT_PARCELS": "memory:"})
    rows = layer_features(out["OUTPUT_PARCELS"])[0]
    assert rows and not any(r["template"] == "court" for r in rows)
    with pytest.raises(QgsProcessingException,
                       match="counted templates.*'court'.*min_count 3 is above max_count 1"):
        qgis_processing.run(ALG, {"REGION": region,
                                  "TEMPLATE_LAYER": counted(3, 1, "counted templates"),
                                  "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})


def test_key_areas_covering_the_region_leave_no_parcels_and_say_so(qgis_processing,
                                                                    region_layer, hull):
    """Key areas that cover all but a 2 m rim of the region (the region, reprojected,
    given again as a lake; covering it exactly is refused as an empty region): no lot is
    made, and the log says why instead of printing p_angle nan."""
    from helpers import log_feedback

    lake = memory_layer("Polygon", [hull.buffer(-2.0).wkt], crs="EPSG:32633", name="lake")
    log = log_feedback()
    out = qgis_processing.run(ALG, {
        "REGION": region_layer, "KEY_AREAS": lake, "SEED": 1,
        "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"}, feedback=log)
    rows, _ = layer_features(out["OUTPUT_PARCELS"])
    assert not [r for r in rows if r["land_use"] == "residential"]
    assert any("no parcels: the key areas cover the region" in w for w in log.warnings)


def test_a_region_too_small_for_a_lot_says_so(qgis_processing):
    """A 2 m square region: no parcel, and the log says the region is too small for a lot
    (it said 'the parcels layer has no geometries', an output the user never gave)."""
    from helpers import log_feedback

    tiny = memory_layer("Polygon", ["POLYGON ((0 0, 2 0, 2 2, 0 2, 0 0))"], crs="EPSG:32633",
                        name="tiny region")
    log = log_feedback()
    out = qgis_processing.run(ALG, {"REGION": tiny, "SEED": 1, "OUTPUT_ROADS": "memory:",
                                    "OUTPUT_PARCELS": "memory:"}, feedback=log)
    assert not layer_features(out["OUTPUT_PARCELS"])[0]
    assert any("no parcels: the region is too small for a lot" in w for w in log.warnings)
    assert not any("key areas" in w for w in log.warnings)      # none was given


def test_key_roads_away_from_the_region_are_named(qgis_processing):
    """A key road 1 km from a 200 m region played no part without a word."""
    from helpers import log_feedback

    region = memory_layer("Polygon", ["POLYGON ((0 0, 200 0, 200 200, 0 200, 0 0))"],
                          crs="EPSG:32633", name="square")
    roads = memory_layer("LineString", ["LINESTRING (-50 100, 250 100)",
                                        "LINESTRING (1000 1000, 1300 1000)"],
                         crs="EPSG:32633", name="key roads")
    log = log_feedback()
    qgis_processing.run(ALG, {"REGION": region, "KEY_ROADS": roads, "SEED": 1,
                              "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"},
                        feedback=log)
    assert any("1 of 2 key roads of 'key roads' do not reach the region" in w
               for w in log.warnings), log.warnings


def test_bad_input(qgis_processing, region_layer):
    from qgis.core import QgsProcessingException

    lines = memory_layer("LineString", ["LINESTRING (0 0, 100 0)"], crs="EPSG:32633",
                         name="not a region")
    with pytest.raises(QgsProcessingException, match="not a region"):
        qgis_processing.run(ALG, {"REGION": lines, "OUTPUT_ROADS": "memory:",
                                  "OUTPUT_PARCELS": "memory:"})
    empty = memory_layer("Polygon", [], crs="EPSG:32633", name="empty region")
    with pytest.raises(QgsProcessingException, match="empty region"):
        qgis_processing.run(ALG, {"REGION": empty, "OUTPUT_ROADS": "memory:",
                                  "OUTPUT_PARCELS": "memory:"})
    with pytest.raises(QgsProcessingException, match="absurd"):
        qgis_processing.run(ALG, {"REGION": region_layer, "STREET_WIDTH": 199,
                                  "PARCEL_LENGTH": 5, "OUTPUT_ROADS": "memory:",
                                  "OUTPUT_PARCELS": "memory:"})
    tmpl = memory_layer("Polygon", [shapely.box(0, 0, 10, 10).wkt], crs="EPSG:32633",
                        name="no fields")
    with pytest.raises(QgsProcessingException, match="template"):
        qgis_processing.run(ALG, {"REGION": region_layer, "TEMPLATE_LAYER": tmpl,
                                  "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})


def test_qgis_process_drawn_template_on_bubenec(tmp_path, hull):
    """The real qgis_process.bin on the Bubeneč cadastre's hull with a template drawn in a
    GeoPackage: three rows of parcels (no strip, so warped as drawn) take part in the real
    layout beside a drawn strip; every residential lot keeps street access (the middle
    row's lots, with no frontage, join their neighbours). Before, three rows were refused."""
    import geopandas as gpd
    import pyogrio

    region, templates_file, parcels_out = (tmp_path / n for n in (
        "region.gpkg", "templates.gpkg", "parcels.gpkg"))
    pyogrio.write_dataframe(gpd.GeoDataFrame({"name": ["bubenec"]}, geometry=[hull],
                                             crs=32633), region)
    cells = [shapely.box(i * 18, j * 30, (i + 1) * 18, (j + 1) * 30)
             for i in range(5) for j in range(3)]
    pyogrio.write_dataframe(gpd.GeoDataFrame(
        {"template": ["three_rows"] * 15 + ["strip"] * 3, "label": ["R"] * 18},
        geometry=cells + [shapely.box(i * 18, 200, (i + 1) * 18, 230) for i in range(3)],
        crs=32633), templates_file)
    code, out, err = run_qgis_process("splitdomain", {
        "REGION": str(region), "TEMPLATE_LAYER": str(templates_file), "SEED": 2,
        "OUTPUT_ROADS": "TEMPORARY_OUTPUT", "OUTPUT_PARCELS": str(parcels_out)})
    assert code == 0, err
    df = pyogrio.read_dataframe(parcels_out)
    assert (df.template == "three_rows").sum() > 10
    res = df[df.land_use == "residential"]
    assert res.has_street_access.all() and shapely.is_valid(df.geometry.to_numpy()).all()


def test_qgis_process_on_bubenec(tmp_path, full_hull):
    """The real qgis_process.bin on a region file made from the Bubeneč cadastre, with the
    whole shipped library: the drawn spike and loop take part beside the strips."""
    import pyogrio
    import geopandas as gpd

    region = tmp_path / "region.gpkg"
    pyogrio.write_dataframe(gpd.GeoDataFrame({"name": ["bubenec"]}, geometry=[full_hull],
                                             crs=32633).to_crs(3857), region)
    roads, parcels_out, table = (tmp_path / n for n in ("roads.gpkg", "parcels.gpkg",
                                                        "metrics.csv"))
    code, out, err = run_qgis_process("splitdomain", {
        "REGION": str(region), "KEY_ROADS": f"{BUBENEC}|layername=streets", "SEED": 2,
        "TEMPLATES": 1, "OUTPUT_ROADS": str(roads), "OUTPUT_PARCELS": str(parcels_out),
        "OUTPUT_METRICS": str(table)})
    assert code == 0, err
    assert out is not None and set(out["results"]) >= {"OUTPUT_ROADS", "OUTPUT_PARCELS"}
    df = pyogrio.read_dataframe(parcels_out)
    assert df.crs.to_epsg() == 3857  # back in the region's CRS
    res = df[df.land_use == "residential"]
    assert len(res) > 100 and res.has_street_access.all()
    assert shapely.is_valid(df.geometry.to_numpy()).all()
    rd = pyogrio.read_dataframe(roads)
    assert (rd.level == 0).sum() >= 10  # Bubeneč's real streets are kept
    assert {"spike", "loop"} & set(df.template) and {"cul_de_sac", "loop"} & set(rd.kind)


@pytest.mark.parametrize("choice", [0, 1])
def test_rule_based_parcels_follow_the_choice(qgis_processing, choice):
    """FALLBACK_PARCELS picks the method of the rule-based parcels (a region no template
    fits: a twelve-sided 280 m disc) by its place in ``domain_split.FALLBACK_PARCELS``: the
    lots carry that method's name, never the other's, and tile without overlaps."""
    disc = shapely.Point(460_000, 5_550_000).buffer(140, quad_segs=3)
    region = memory_layer("Polygon", [disc.wkt], crs="EPSG:32633", name="disc")
    out = qgis_processing.run(ALG, {"REGION": region, "FALLBACK_PARCELS": choice, "SEED": 1,
                                    "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})
    rows, geoms = layer_features(out["OUTPUT_PARCELS"])
    used = {r["template"] for r in rows if r["land_use"] == "residential"}
    assert used == {domain_split.FALLBACK_PARCELS[choice]}
    assert shapely.is_valid(geoms).all()
    assert abs(shapely.union_all(geoms).area - shapely.area(geoms).sum()) < 1.0


def test_selected_features_only_name_the_layer_and_its_selection(qgis_processing):
    """With "Selected features only" (a QgsProcessingFeatureSourceDefinition) the messages
    named the parameter, not the layer: an empty selection said "Layer 'Region' is empty"
    of a layer that was neither called so nor empty."""
    from qgis.core import (QgsProcessingException, QgsProcessingFeatureSourceDefinition,
                           QgsProject)

    region = memory_layer("Polygon", ["POLYGON ((0 0, 200 0, 200 200, 0 200, 0 0))"],
                          crs="EPSG:32633", name="my districts")
    QgsProject.instance().addMapLayer(region)
    try:
        region.removeSelection()
        with pytest.raises(QgsProcessingException,
                           match=r"Layer 'my districts' \(selected features\) is empty"):
            qgis_processing.run(ALG, {
                "REGION": QgsProcessingFeatureSourceDefinition(region.id(), True),
                "OUTPUT_ROADS": "memory:", "OUTPUT_PARCELS": "memory:"})
    finally:
        QgsProject.instance().removeMapLayer(region.id())


def test_settle_joints_reaches_the_layout_and_the_log(qgis_processing):
    """SETTLE_JOINTS on (the default) moves joints of the parallelogram's slanted row ends
    and lowers p_area; off keeps the warp's joints; the log says how many moved."""
    from helpers import log_feedback

    region = memory_layer("Polygon", ["POLYGON((0 0,300 0,380 200,80 200,0 0))"],
                          crs="EPSG:32633", name="parallelogram")
    p_area, settled = {}, {}
    for on in (False, True):
        log = log_feedback()
        out = qgis_processing.run(ALG, {"REGION": region, "SEED": 1, "OPTIMISE": False,
                                        "SETTLE_JOINTS": on, "OUTPUT_ROADS": "memory:",
                                        "OUTPUT_PARCELS": "memory:",
                                        "OUTPUT_METRICS": "memory:"}, feedback=log)
        p_area[on] = layer_features(out["OUTPUT_METRICS"])[0][0]["p_area"]
        settled[on] = [int(m.split(" joints settled")[0].rsplit(" ", 1)[1])
                       for m in log.messages if " joints settled" in m]
    assert settled[False] == [0] and settled[True][0] > 0
    assert p_area[True] < p_area[False] - 0.001
