"""urbansynth:layoutmetrics through real QGIS (processing.run and qgis_process.bin)."""
import math

import pytest

from conftest import bubenec_layer, helsinki_layer, run_qgis_process
from helpers import layer_rows

ALG = "urbansynth:layoutmetrics"


def _row(rows, kind, metric):
    return next(r for r in rows if r["kind"] == kind and r["metric"] == metric)


def test_helsinki_against_bubenec(qgis_processing, tmp_path):
    from qgis.core import QgsWkbTypes

    html = tmp_path / "report.html"
    out = qgis_processing.run(ALG, {
        "ROADS": helsinki_layer("lines"),
        "EXAMPLE_ROADS": bubenec_layer("streets"), "EXAMPLE_PARCELS": bubenec_layer("plots"),
        "EXAMPLE_BUILDINGS": bubenec_layer("buildings"),
        "OUTPUT": "memory:", "OUTPUT_HTML": str(html)})
    table = out["OUTPUT"]
    assert table.wkbType() == QgsWkbTypes.Type.NoGeometry
    rows = layer_rows(table)
    assert {r["kind"] for r in rows} == {"layout", "invariants", "roads", "blocks", "parcels",
                                        "buildings"}
    for metric in ("segment_length", "node_degree", "intersection_angle", "street_bearing"):
        r = _row(rows, "roads", metric)
        assert r["statistic"] in ("mean", "axial_mean")
        assert r["n_candidate"] > 1000 and r["n_example"] > 20
        assert r["wasserstein"] > 0 and 0 < r["ks_stat"] <= 1 and 0 <= r["ks_pvalue"] <= 1
        assert r["wasserstein_norm"] == pytest.approx(r["wasserstein_norm"])  # not NULL
    # Helsinki lines include footways: a dense network, tens of km per km², metric units
    s_l = _row(rows, "roads", "street_length_km_per_km2")
    assert 20 < s_l["candidate"] < 300 and 1 < s_l["example"] < 50
    entropy = _row(rows, "roads", "orientation_entropy")
    assert math.log(4) < entropy["candidate"] < math.log(36)
    assert entropy["rel_diff"] == pytest.approx((entropy["candidate"] - entropy["example"])
                                                / entropy["example"])
    # blocks come from the road faces on both sides
    assert _row(rows, "blocks", "count")["candidate"] > 50
    assert _row(rows, "blocks", "count")["example"] == 7
    # parcels and footprints exist only in the example
    p_area = _row(rows, "parcels", "p_area")
    assert p_area["candidate"] is None and p_area["example"] >= 1
    assert _row(rows, "buildings", "overlap_area")["example"] == 0
    text = html.read_text(encoding="utf-8")
    assert text.count("<img") >= 10 and "data:image/png;base64," in text
    for name in ("segment_length", "intersection_angle", "orientation_entropy", "p_angle",
                 "Wasserstein", "Kolmogorov"):
        assert name in text
    assert out["OUTPUT_HTML"] == str(html)


def test_osm_multipolygons_count_their_buildings_only(qgis_processing):
    """Helsinki's OSM multipolygons as BUILDINGS: the 480 polygons with a building value
    are measured, not the parks, land use and water with them (1,065 'buildings' covering
    110 % of the blocks, 1.2 km² of overlap)."""
    from helpers import log_feedback

    log = log_feedback()
    out = qgis_processing.run(ALG, {"BUILDINGS": helsinki_layer("multipolygons"),
                                    "OUTPUT": "memory:"}, feedback=log)
    rows = layer_rows(out["OUTPUT"])
    assert _row(rows, "buildings", "count")["candidate"] == 480
    assert _row(rows, "buildings", "overlap_area")["candidate"] < 1e4
    assert any("without a 'building' value skipped" in m for m in log.messages)


def test_identical_layouts_have_zero_distance(qgis_processing, tmp_path):
    out = qgis_processing.run(ALG, {
        "ROADS": bubenec_layer("streets"), "PARCELS": bubenec_layer("plots"),
        "BUILDINGS": bubenec_layer("buildings"),
        "EXAMPLE_ROADS": bubenec_layer("streets"), "EXAMPLE_PARCELS": bubenec_layer("plots"),
        "EXAMPLE_BUILDINGS": bubenec_layer("buildings"), "OUTPUT": "memory:"})
    assert "OUTPUT_HTML" not in out  # the report is optional
    rows = layer_rows(out["OUTPUT"])
    dists = [r for r in rows if r["statistic"] != "value"]
    assert len(dists) >= 12
    assert all(r["wasserstein"] == pytest.approx(0, abs=1e-9) for r in dists)
    assert all(r["ks_stat"] == pytest.approx(0) for r in dists)
    scalars = [r for r in rows if r["statistic"] == "value"]
    assert all(r["rel_diff"] in (None, pytest.approx(0, abs=1e-9)) for r in scalars)
    # Bubeneč, measured in UTM 33N: 407 parcels, Yang's measures within their ranges
    assert _row(rows, "parcels", "count")["candidate"] == 407
    assert 0 <= _row(rows, "parcels", "p_angle")["candidate"] <= 90
    assert _row(rows, "parcels", "p_area")["candidate"] >= 1
    assert _row(rows, "buildings", "count")["candidate"] == 144


def test_parcels_alone_with_land_use_and_study_area(qgis_processing, tmp_path):
    out = qgis_processing.run(ALG, {
        "PARCELS": bubenec_layer("plots"), "LANDUSE_FIELD": "TYPPPD_KOD",
        "STUDY_AREA": bubenec_layer("tessellation"),
        "OUTPUT": "memory:", "OUTPUT_HTML": str(tmp_path / "parcels.html")})
    rows = layer_rows(out["OUTPUT"])
    assert {r["kind"] for r in rows} == {"layout", "parcels"}
    assert all(r["example"] is None for r in rows)
    # the cadastre code is no residential / park label: all parcel land is 'other'
    shares = {m: _row(rows, "parcels", m)["candidate"] for m in ("l_s", "l_r", "l_p", "l_o")}
    assert shares["l_r"] == 0 and shares["l_p"] == 0 and shares["l_o"] > 0
    assert sum(shares.values()) == pytest.approx(100.0)
    # densities count the parcels inside the study area (the building plots' tessellation)
    area = _row(rows, "layout", "area_km2")["candidate"]
    assert 0.05 < area < 1.0
    inside = _row(rows, "parcels", "p_n_per_km2")["candidate"] * area
    assert inside == pytest.approx(round(inside)) and 100 < inside < 407


def test_no_input_is_rejected(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="No layer to measure"):
        qgis_processing.run(ALG, {"EXAMPLE_ROADS": bubenec_layer("streets"),
                                  "OUTPUT": "memory:", "OUTPUT_HTML": str(tmp_path / "x.html")})


def test_wrong_geometry_and_empty_layers_are_rejected(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingException, QgsVectorLayer

    with pytest.raises(QgsProcessingException, match="points; lines are needed"):
        qgis_processing.run(ALG, {"ROADS": helsinki_layer("points"), "OUTPUT": "memory:",
                                  "OUTPUT_HTML": str(tmp_path / "x.html")})
    with pytest.raises(QgsProcessingException, match="lines; polygons are needed"):
        qgis_processing.run(ALG, {"BUILDINGS": bubenec_layer("streets"), "OUTPUT": "memory:",
                                  "OUTPUT_HTML": str(tmp_path / "x.html")})
    empty = QgsVectorLayer("LineString?crs=EPSG:3857", "no roads", "memory")
    # the warning said the run goes on without it; the refusal says why it cannot
    with pytest.raises(QgsProcessingException, match="Nothing to measure, no layer holds a "
                                                     "feature: Layer 'no roads' is empty"):
        qgis_processing.run(ALG, {"ROADS": empty, "OUTPUT": "memory:",
                                  "OUTPUT_HTML": str(tmp_path / "x.html")})


def test_cancel(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingException, QgsProcessingFeedback

    feedback = QgsProcessingFeedback()
    feedback.cancel()
    with pytest.raises(QgsProcessingException, match="Canceled"):
        qgis_processing.run(ALG, {"ROADS": bubenec_layer("streets"), "OUTPUT": "memory:",
                                  "OUTPUT_HTML": str(tmp_path / "x.html")}, feedback=feedback)
    assert not (tmp_path / "x.html").exists()


def test_qgis_process_exit_code(tmp_path):
    html = tmp_path / "report.html"
    table = tmp_path / "metrics.gpkg"
    code, out, err = run_qgis_process("layoutmetrics", {
        "ROADS": bubenec_layer("streets"), "PARCELS": bubenec_layer("plots"),
        "BUILDINGS": bubenec_layer("buildings"), "EXAMPLE_ROADS": helsinki_layer("lines"),
        "OUTPUT": table, "OUTPUT_HTML": html})
    assert code == 0, err
    assert html.exists() and "<img" in html.read_text(encoding="utf-8")
    assert out is not None and out["results"]["OUTPUT_HTML"] == str(html)
    import sqlite3

    with sqlite3.connect(table) as db:
        n, = db.execute("SELECT count(*) FROM metrics").fetchone()
    assert n > 30


def test_counting_choices_and_invariants(qgis_processing, tmp_path):
    """Plain counts with the choices off; footways dropped on request; the invariants of a
    street drawn over an arterial reported in the table and flagged in the report."""
    from helpers import memory_layer

    plain = layer_rows(qgis_processing.run(ALG, {
        "ROADS": helsinki_layer("lines"), "MIN_BLOCK_AREA": 0, "MIN_BLOCK_WIDTH": 0,
        "OUTPUT": "memory:"})["OUTPUT"])
    default = layer_rows(qgis_processing.run(ALG, {
        "ROADS": helsinki_layer("lines"), "OUTPUT": "memory:"})["OUTPUT"])
    cars = layer_rows(qgis_processing.run(ALG, {
        "ROADS": helsinki_layer("lines"), "DRIVABLE_ONLY": True, "OUTPUT": "memory:"})["OUTPUT"])
    n_faces = _row(plain, "blocks", "count")["candidate"]
    assert n_faces > 1.4 * _row(default, "blocks", "count")["candidate"]
    s_l = {name: _row(rows, "roads", "street_length_km_per_km2")["candidate"]
           for name, rows in (("all", default), ("cars", cars))}
    assert s_l["cars"] < 0.5 * s_l["all"]
    arterials = memory_layer("LineString", ["LINESTRING(0 0, 300 0)", "LINESTRING(300 0, 300 300)",
                                            "LINESTRING(300 300, 0 300)", "LINESTRING(0 300, 0 0)"],
                             crs="EPSG:32633", fields="&field=highway:string",
                             rows=[["trunk"], ["primary"], ["primary"], ["primary"]],
                             name="arterials")
    synthesis = memory_layer("LineString", ["LINESTRING(0 0, 300 0)", "LINESTRING(150 -20, 150 320)",
                                            "LINESTRING(0 100, 300 100)"], crs="EPSG:32633",
                             name="synthesis")
    html = tmp_path / "inv.html"
    rows = layer_rows(qgis_processing.run(ALG, {
        "ROADS": synthesis, "GIVEN_ROADS": arterials, "OUTPUT": "memory:",
        "OUTPUT_HTML": str(html)})["OUTPUT"])
    assert _row(rows, "invariants", "crossings_given")["candidate"] == 2
    assert _row(rows, "invariants", "crossings_synthesised")["candidate"] == 1
    assert _row(rows, "invariants", "controlled_access")["candidate"] == 1   # on the trunk
    assert _row(rows, "invariants", "violations")["candidate"] >= 4
    text = html.read_text(encoding="utf-8")
    assert "Network invariants" in text and "class='warn'" in text
    from qgis.core import QgsProcessingException
    with pytest.raises(QgsProcessingException, match="needs a 'highway' or 'road_class'"):
        qgis_processing.run(ALG, {"ROADS": synthesis, "DRIVABLE_ONLY": True, "OUTPUT": "memory:"})


def test_a_dead_end_share_beyond_the_example_band_is_logged(qgis_processing):
    """A sound network whose dead-end share is a third under the example's: the log warns
    (it said 'no violation', the violation count leaving the share out)."""
    from helpers import log_feedback, memory_layer

    given = memory_layer("LineString", ["LINESTRING(0 0, 400 0)"], crs="EPSG:32633",
                         name="given")
    layout = memory_layer("LineString", [
        "LINESTRING(0 0, 400 0)", "LINESTRING(100 0, 100 150)", "LINESTRING(300 0, 300 150)",
        "LINESTRING(100 150, 300 150)"], crs="EPSG:32633", name="layout")
    tee = memory_layer("LineString", ["LINESTRING(0 0, 200 0)", "LINESTRING(100 0, 100 100)"],
                       crs="EPSG:32633", name="a T")
    log = log_feedback()
    qgis_processing.run(ALG, {"ROADS": layout, "GIVEN_ROADS": given, "EXAMPLE_ROADS": tee,
                              "OUTPUT": "memory:"}, feedback=log)
    assert any("dead-end share 0.50 is 33 % below the example's 0.75" in w
               for w in log.warnings), log.warnings


def test_a_layer_of_several_variations_is_warned_of(qgis_processing):
    """splitdomain's VARIATIONS > 1 writes every layout into one layer (field 'variation'):
    measured as one network over itself, silently; the log now says so and how to pick
    one."""
    from helpers import log_feedback, memory_layer

    wkts = ["LINESTRING(0 0, 400 0)", "LINESTRING(100 0, 100 150)",
            "LINESTRING(0 0, 400 0)", "LINESTRING(200 0, 200 150)"]
    layout = memory_layer("LineString", wkts, crs="EPSG:32633", name="layouts",
                          fields="&field=variation:integer", rows=[(1,), (1,), (2,), (2,)])
    log = log_feedback()
    qgis_processing.run(ALG, {"ROADS": layout, "OUTPUT": "memory:"}, feedback=log)
    assert any("'layouts' holds 2 variations (field 'variation')" in w for w in log.warnings), \
        log.warnings
    one = memory_layer("LineString", wkts[:2], crs="EPSG:32633", name="one",
                       fields="&field=variation:integer", rows=[(1,), (1,)])
    log = log_feedback()
    qgis_processing.run(ALG, {"ROADS": one, "OUTPUT": "memory:"}, feedback=log)
    assert not any("variations" in w for w in log.warnings), log.warnings
