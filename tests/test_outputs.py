"""Outputs are written under a temporary name and moved into place only when the run
succeeded (plugin/qgis_glue/outputs.py): file, shapefile and GeoPackage-layer outputs, the
results QGIS loads, an existing destination after a failed run, and the command line."""
import hashlib

import pytest

from conftest import bubenec_layer, helsinki_layer, run_qgis_process
from helpers import memory_layer

ALG = "urbansynth:extractroadhierarchy"


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_failed_run_leaves_an_existing_output_untouched(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingException

    out = tmp_path / "roads.gpkg"
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT": str(out)})
    before = _sha(out)
    empty = memory_layer("LineString", [], "EPSG:3857", name="no roads")
    with pytest.raises(QgsProcessingException, match="'no roads' is empty"):
        qgis_processing.run(ALG, {"INPUT": empty, "OUTPUT": str(out)})
    assert _sha(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["roads.gpkg"]   # no staging left


def test_shapefile_and_layer_outputs_land_in_place(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingContext, QgsVectorLayer

    shp = tmp_path / "roads.shp"
    gpkg = tmp_path / "both.gpkg"
    context = QgsProcessingContext()
    results = qgis_processing.run(ALG, {
        "INPUT": bubenec_layer("streets"), "OUTPUT": str(shp),
        "OUTPUT_INTERSECTIONS": f"ogr:dbname='{gpkg}' table=\"points\" (geom)"},
        context=context)
    assert results["OUTPUT"] == str(shp)
    assert {p.suffix for p in tmp_path.glob("roads.*")} >= {".shp", ".shx", ".dbf", ".prj"}
    assert results["OUTPUT_INTERSECTIONS"] == f"{gpkg}|layername=points"
    assert QgsVectorLayer(results["OUTPUT_INTERSECTIONS"], "p", "ogr").featureCount() > 10
    # a second layer into the same GeoPackage keeps the first
    qgis_processing.run(ALG, {
        "INPUT": bubenec_layer("streets"), "OUTPUT_INTERSECTIONS": None,
        "OUTPUT": f"ogr:dbname='{gpkg}' table=\"ranked\" (geom)"})
    for layer in ("points", "ranked"):
        assert QgsVectorLayer(f"{gpkg}|layername={layer}", layer, "ogr").featureCount() > 10
    assert not list(tmp_path.glob(".urbansynth-run-*"))


def test_layers_to_load_name_the_final_files(qgis_processing, tmp_path):
    from qgis.core import QgsProcessingContext, QgsProcessingOutputLayerDefinition, QgsProject

    context = QgsProcessingContext()
    context.setProject(QgsProject.instance())
    out = tmp_path / "roads.gpkg"
    definition = QgsProcessingOutputLayerDefinition(str(out), QgsProject.instance())
    definition.destinationName = "My roads"
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT": definition,
                              "OUTPUT_INTERSECTIONS": None}, context=context)
    loads = context.layersToLoadOnCompletion()
    assert str(out) in loads and loads[str(out)].name == "My roads"
    assert not any(".urbansynth-run-" in key for key in loads)


def test_command_line_refuses_output_onto_input(tmp_path):
    import shutil

    src = tmp_path / "streets.gpkg"
    shutil.copy(bubenec_layer("streets").split("|")[0], src)
    before = _sha(src)
    code, _, err = run_qgis_process("extractroadhierarchy", {
        "INPUT": f"{src}|layername=streets", "OUTPUT": str(src)})
    assert code != 0 and "would overwrite" in err and "Traceback" not in err, err
    assert _sha(src) == before


def test_outputs_open_styled_in_a_new_project(qgis_processing, tmp_path):
    """The shipped style travels with the file: a GeoPackage layer's default style in
    layer_styles, a shapefile's sidecar .qml; a fresh layer of the file is styled."""
    from qgis.core import QgsVectorLayer

    gpkg, shp = tmp_path / "roads.gpkg", tmp_path / "points.shp"
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT": str(gpkg),
                              "OUTPUT_INTERSECTIONS": str(shp)})
    roads = QgsVectorLayer(str(gpkg), "roads", "ogr")
    assert roads.renderer().type() == "categorizedSymbol"
    assert roads.renderer().classAttribute() == "level"
    assert shp.with_suffix(".qml").exists()
    points = QgsVectorLayer(str(shp), "points", "ogr")
    plain = QgsVectorLayer(str(shp), "plain", "ogr",
                           QgsVectorLayer.LayerOptions(loadDefaultStyle=False))
    styled_colour = points.renderer().symbol().color().name()
    assert styled_colour != plain.renderer().symbol().color().name() or \
        points.renderer().symbol().size() != plain.renderer().symbol().size()
    # the run's style requests are consumed
    from urban_synthesis.plugin.qgis_glue import styles

    assert not [k for k in styles.STYLE_REQUESTS if str(tmp_path) in k]


def test_a_nested_runs_layer_in_an_existing_geopackage_opens_styled(qgis_processing,
                                                                      tmp_path):
    """synthesizeroads runs its method as a child, whose own staging stores the style in
    the parent's staging GeoPackage; the parent copied only the layer into an existing
    GeoPackage, not its layer_styles row: the output opened unstyled."""
    from osgeo import gdal
    from qgis.core import QgsVectorLayer

    gpkg = tmp_path / "district.gpkg"
    gdal.VectorTranslate(str(gpkg), bubenec_layer("streets").split("|")[0],
                         options=gdal.VectorTranslateOptions(format="GPKG",
                                                             layers=["streets"]))
    qgis_processing.run("urbansynth:synthesizeroads", {
        "METHOD": 1, "ARTERIALS": f"{gpkg}|layername=streets", "SEED": 1,
        "OUTPUT": f"ogr:dbname='{gpkg}' table=\"grown\" (geom)"})
    grown = QgsVectorLayer(f"{gpkg}|layername=grown", "grown", "ogr")
    assert grown.featureCount() > 10
    assert grown.renderer().type() == "categorizedSymbol"
    assert grown.renderer().classAttribute() == "level"
    assert not list(tmp_path.glob(".urbansynth-run-*"))


def test_loaded_outputs_stack_buildings_above_parcels(qgis_processing, tmp_path):
    """Outputs loaded on completion are placed by kind, whatever their file names: roads
    over buildings over blocks over parcels."""
    from qgis.core import QgsProject

    project = QgsProject.instance()
    project.removeAllMapLayers()
    blocks = tmp_path / "z_blocks.gpkg"
    qgis_processing.runAndLoadResults("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "BUILDINGS": bubenec_layer("buildings"),
        "OUTPUT": str(blocks), "OUTPUT_BUILDINGS": str(tmp_path / "a_buildings.gpkg")})
    qgis_processing.runAndLoadResults(ALG, {"INPUT": bubenec_layer("streets"),
                                            "OUTPUT": str(tmp_path / "m_roads.gpkg")})
    order = [node.layer().source().split("|")[0].rsplit("/", 1)[-1]
             for node in project.layerTreeRoot().findLayers()]
    project.removeAllMapLayers()
    assert order.index("m_roads.gpkg") < order.index("a_buildings.gpkg") \
        < order.index("z_blocks.gpkg"), order


def test_two_outputs_into_one_file_and_a_layerless_uri_are_refused(qgis_processing, tmp_path):
    """Two outputs of one run into the same file (the random walk waited forever on the
    GeoPackage, StreetGAN left a GeoTIFF where the roads should be) and an ogr: URI that
    names a GeoPackage but no layer (QGIS 3.22 appends the output to its first layer: an
    input's, once) are refused before anything is written; two layers of one GeoPackage
    are fine."""
    import shutil

    from qgis.core import QgsProcessingException

    same = tmp_path / "same.gpkg"
    with pytest.raises(QgsProcessingException, match="OUTPUT.*OUTPUT_INTERSECTIONS.*would "
                                                     "both be written to"):
        qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT": str(same),
                                  "OUTPUT_INTERSECTIONS": str(same)})
    assert not list(tmp_path.iterdir())
    src = tmp_path / "streets.gpkg"
    shutil.copy(bubenec_layer("streets").split("|")[0], src)
    before = _sha(src)
    with pytest.raises(QgsProcessingException, match="names the file .* but no layer"):
        qgis_processing.run(ALG, {"INPUT": f"{src}|layername=streets",
                                  "OUTPUT": f"ogr:dbname='{src}'",
                                  "OUTPUT_INTERSECTIONS": None})
    assert _sha(src) == before
    both = tmp_path / "both.gpkg"
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"),
                              "OUTPUT": f"ogr:dbname='{both}' table=\"roads\" (geom)",
                              "OUTPUT_INTERSECTIONS": f"ogr:dbname='{both}' table=\"points\" "
                                                      "(geom)"})
    code, _, err = run_qgis_process("extractroadhierarchy", {
        "INPUT": bubenec_layer("streets"), "OUTPUT": str(same),
        "OUTPUT_INTERSECTIONS": str(same)})
    assert code != 0 and "would both be written to" in err and "Traceback" not in err, err


def test_a_new_layer_beside_a_bare_path_input_is_written(qgis_processing, tmp_path):
    """An input given as a bare GeoPackage path reads the file's first layer: a new layer
    of another name in that file is no overwrite (it was refused as 'would overwrite layer
    roads of the input'); the first layer's own name still is, and the input is kept."""
    from qgis.core import QgsProcessingException, QgsVectorLayer

    roads = tmp_path / "roads.gpkg"
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"),
                              "OUTPUT": f"ogr:dbname='{roads}' table=\"hierarchy\" (geom)"})
    before = QgsVectorLayer(str(roads), "in", "ogr").featureCount()
    qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": str(roads), "OUTPUT": f"ogr:dbname='{roads}' table=\"blocks\" (geom)"})
    assert QgsVectorLayer(f"{roads}|layername=blocks", "b", "ogr").featureCount() > 5
    assert QgsVectorLayer(f"{roads}|layername=hierarchy", "h", "ogr").featureCount() == before
    with pytest.raises(QgsProcessingException, match="would overwrite layer 'hierarchy'"):
        qgis_processing.run("urbansynth:extractblocks", {
            "ROADS": str(roads), "OUTPUT": f"ogr:dbname='{roads}' table=\"hierarchy\" (geom)"})


def test_a_raster_output_named_for_another_type_is_refused(qgis_processing, tmp_path):
    """Every raster output is written as a GeoTIFF (qgis_io.write_geotiff / write_image),
    whatever its name: the generator image or the fragments' relief named .asc or .gpkg
    was a GeoTIFF under that name, which other programs misread. Refused before anything
    is written, as a file output of another type is; .tif and .TIFF pass."""
    from qgis.core import QgsApplication, QgsProcessingContext, QgsProcessingException

    from urban_synthesis.plugin.qgis_glue import outputs

    params = {"TARGET": bubenec_layer("plots"), "OUTPUT": "memory:"}
    for name in ("generator.asc", "generator.gpkg"):
        with pytest.raises(QgsProcessingException,
                           match=r"Generator image \(OUTPUT_RASTER\) is written as GeoTIFF.*"
                                 rf"{name} does not end in \.tif or \.tiff"):
            qgis_processing.run("urbansynth:synthesizeroadsgan",
                                {**params, "OUTPUT_RASTER": str(tmp_path / name)})
        assert not (tmp_path / name).exists()
    alg = QgsApplication.processingRegistry().createAlgorithmById(
        "urbansynth:synthesizeroadsgan")
    for name in ("generator.tif", "generator.TIFF"):
        assert outputs.destination_error(
            alg, {**params, "OUTPUT_RASTER": str(tmp_path / name)},
            QgsProcessingContext()) is None


def test_a_file_output_named_for_another_type_is_refused(qgis_processing, tmp_path):
    """A file output is written in its declared format whatever its name: a fragment
    database named .txt was a GeoPackage that a text editor or QGIS's 'Add layer' then
    misread. Such a name is refused before anything is written; the declared extension
    (any case) is written."""
    from qgis.core import QgsProcessingException

    roads = tmp_path / "roads.gpkg"
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT": str(roads),
                              "OUTPUT_INTERSECTIONS": None})
    with pytest.raises(QgsProcessingException,
                       match=r"Fragment database \(OUTPUT\) is written as GeoPackage.*db\.txt "
                             r"does not end in \.gpkg"):
        qgis_processing.run("urbansynth:buildfragmentdatabase",
                            {"ROADS": str(roads), "OUTPUT": str(tmp_path / "db.txt")})
    assert not (tmp_path / "db.txt").exists()
    code, _, err = run_qgis_process("buildfragmentdatabase", {
        "ROADS": str(roads), "OUTPUT": str(tmp_path / "db")})
    assert code != 0 and "does not end in .gpkg" in err and "Traceback" not in err, err
    qgis_processing.run("urbansynth:buildfragmentdatabase",
                        {"ROADS": str(roads), "OUTPUT": str(tmp_path / "db.GPKG")})
    assert (tmp_path / "db.GPKG").stat().st_size > 0


def test_a_new_layer_in_an_input_database_is_refused_by_what_it_would_do(qgis_processing,
                                                                        tmp_path):
    """A fragment database is an input file read whole: an output layer of a new name in it
    would modify it and is refused, with a message that says so (it said 'would overwrite
    layer roads of the input' of a layer that did not exist)."""
    from qgis.core import QgsProcessingException

    roads = tmp_path / "roads.gpkg"
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT": str(roads),
                              "OUTPUT_INTERSECTIONS": None})
    db = tmp_path / "db.gpkg"
    qgis_processing.run("urbansynth:buildfragmentdatabase", {"ROADS": str(roads),
                                                           "OUTPUT": str(db)})
    before = _sha(db)
    arterials = memory_layer("LineString", ["LINESTRING(1605000 6460000, 1606000 6460000)"],
                             "EPSG:3857", name="arterials")
    with pytest.raises(QgsProcessingException,
                       match=r"would write layer 'new_roads' into the input .*db\.gpkg\), a "
                             r"file read whole"):
        qgis_processing.run("urbansynth:synthesizeroadsfromfragments", {
            "ARTERIALS": arterials, "FRAGMENT_DB": str(db),
            "OUTPUT": f"ogr:dbname='{db}' table=\"new_roads\" (geom)"})
    assert _sha(db) == before


def test_a_second_run_into_the_same_geopackage_layer_does_not_wait_for_a_dialog(tmp_path):
    """Batch mode: the same tool run twice into one GeoPackage layer. QGIS 3.22 asks 'A
    matching style already exists ... overwrite it?' in a modal message box before it
    stores a style over the first run's: the second run waited for an answer forever
    (qgis_process, a script) and would open a dialog from Processing's worker thread in
    the desktop. The old style is replaced: one default style per layer."""
    import sqlite3

    gpkg = tmp_path / "runs.gpkg"
    out = f"ogr:dbname='{gpkg}' table=\"hierarchy\" (geom)"
    for run in range(2):
        # a guard, not a timing: the run takes seconds, the old code never ended
        code, _, err = run_qgis_process("extractroadhierarchy", {
            "INPUT": bubenec_layer("streets"), "OUTPUT": out}, timeout=240)
        assert code == 0, err
    with sqlite3.connect(gpkg) as db:
        styles = db.execute("SELECT f_table_name, useAsDefault FROM layer_styles").fetchall()
        n = db.execute("SELECT COUNT(*) FROM hierarchy").fetchone()[0]
    assert styles == [("hierarchy", 1)]
    assert n > 5


def test_a_geopackage_holding_other_layers_is_not_replaced_whole(qgis_processing, tmp_path):
    """An output named by a GeoPackage file alone (no layer) replaces the file whole in
    QGIS: a project GeoPackage given as the output lost every other layer in it (its wells
    and its pumps, for a layer of hierarchy). It is refused, naming the layers, and the file
    is left as it was; a second run into a file that holds only the first run's output, or
    a database written again over an earlier database, still replaces it."""
    import sqlite3

    from qgis.core import QgsProcessingException

    project = tmp_path / "project.gpkg"
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT_INTERSECTIONS": None,
                              "OUTPUT": f"ogr:dbname='{project}' table=\"wells\" (geom)"})
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT_INTERSECTIONS": None,
                              "OUTPUT": f"ogr:dbname='{project}' table=\"pumps\" (geom)"})
    before = _sha(project)
    for alg, params in ((ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT": str(project),
                               "OUTPUT_INTERSECTIONS": None}),
                        ("urbansynth:buildfragmentdatabase", {
                            "ROADS": bubenec_layer("streets"), "OUTPUT": str(project)})):
        with pytest.raises(QgsProcessingException,
                           match=r"would replace the GeoPackage .*project\.gpkg whole, and "
                                 r"with it its layers 'pumps', 'wells': nothing is written"):
            qgis_processing.run(alg, params)
        assert _sha(project) == before
    # again into an earlier run's own file: replaced, as before
    roads = tmp_path / "roads.gpkg"
    db = tmp_path / "db.gpkg"
    for _ in range(2):
        qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"), "OUTPUT": str(roads),
                                  "OUTPUT_INTERSECTIONS": None})
        qgis_processing.run("urbansynth:buildfragmentdatabase", {"ROADS": str(roads),
                                                               "OUTPUT": str(db)})
    with sqlite3.connect(roads) as con:
        assert [r[0] for r in con.execute("SELECT table_name FROM gpkg_contents "
                                          "WHERE data_type = 'features'")] == ["roads"]


def test_an_input_field_named_geom_is_kept_in_a_geopackage(qgis_processing, tmp_path):
    """A field named 'geom' (a PostGIS export's) carried to a GeoPackage output clashed
    with the geometry column GDAL names 'geom': 'duplicate column name: geom', nothing
    written. It is written as 'geom_1' with its values, and the log says so; a shapefile,
    which has no geometry column, keeps 'geom'."""
    from qgis.core import QgsVectorLayer

    from helpers import layer_rows, log_feedback

    source = QgsVectorLayer(bubenec_layer("buildings"), "b", "ogr")
    wkts = [f.geometry().asWkt() for f in source.getFeatures()]
    export = memory_layer("Polygon", wkts, "EPSG:3857", "&field=geom:string&field=name:string",
                          [[f"g{i}", f"n{i}"] for i in range(len(wkts))], name="pg export")
    feedback = log_feedback()
    gpkg = tmp_path / "buildings.gpkg"
    qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "BUILDINGS": export, "OUTPUT": "TEMPORARY_OUTPUT",
        "OUTPUT_BUILDINGS": f"ogr:dbname='{gpkg}' table=\"buildings\" (geom)"},
        feedback=feedback)
    rows = layer_rows(QgsVectorLayer(f"{gpkg}|layername=buildings", "b", "ogr"))
    assert len(rows) == len(wkts)
    assert [r["geom_1"] for r in rows[:3]] == ["g0", "g1", "g2"]
    assert rows[0]["name"] == "n0" and "geom" not in rows[0]
    assert any("field 'geom' as 'geom_1': 'geom' is the name of the geometry column" in w
               for w in feedback.warnings), feedback.warnings
    shp = tmp_path / "buildings.shp"
    qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "BUILDINGS": export, "OUTPUT": "TEMPORARY_OUTPUT",
        "OUTPUT_BUILDINGS": str(shp)})
    assert layer_rows(QgsVectorLayer(str(shp), "b", "ogr"))[0]["geom"] == "g0"


def test_shapefile_outputs_keep_integers_and_list_the_cut_field_names(qgis_processing,
                                                                      tmp_path):
    """A shapefile output had every integer field as Real (QGIS writes a 64-bit integer
    without a length 20 digits wide, which GDAL reads back as Real), and GDAL cut the long
    field names silently (tortuosity_a, tortuosity_b -> tortuosity, tortuosi_1). Integers
    now read back as integers, and the log lists each renamed field; a GeoPackage output
    keeps its full names, without that warning."""
    from osgeo import ogr

    from helpers import log_feedback

    feedback = log_feedback()
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"),
                              "OUTPUT": str(tmp_path / "roads.gpkg"),
                              "OUTPUT_INTERSECTIONS": str(tmp_path / "points.shp")},
                        feedback=feedback)
    for path in (tmp_path / "points.shp", tmp_path / "roads.gpkg"):
        ds = ogr.Open(str(path))
        defn = ds.GetLayer(0).GetLayerDefn()
        types = {defn.GetFieldDefn(i).GetName(): defn.GetFieldDefn(i).GetTypeName()
                 for i in range(defn.GetFieldCount())}
        ds = None
        for name in ("node_id", "degree", "level_a") if path.suffix == ".shp" else \
                ("edge_id", "level", "street_id"):
            assert types[name] == "Integer64", (path.name, types)
    assert {"tortuosity", "tortuosi_1"} <= set(types) or path.suffix == ".gpkg"
    cut = [w for w in feedback.warnings if "is a shapefile" in w]
    assert len(cut) == 1 and cut[0].startswith("Output OUTPUT_INTERSECTIONS"), feedback.warnings
    assert "tortuosity_a -> tortuosity, tortuosity_b -> tortuosi_1" in cut[0]
    assert "parcel_area -> parcel_are" in cut[0]


def test_a_loaded_shapefile_output_shows_the_full_field_names(qgis_processing, tmp_path):
    """The shapefile's sidecar style holds the full names as aliases, but Processing loads
    an output without its default style: the attribute table showed 'tortuosi_1'. The
    loaded layer gets them as aliases (with its style, or alone where it has none)."""
    from qgis.core import (QgsProcessingContext, QgsProcessingFeedback,
                           QgsProcessingOutputLayerDefinition, QgsProcessingUtils, QgsProject)

    context = QgsProcessingContext()
    context.setProject(QgsProject.instance())
    points = QgsProcessingOutputLayerDefinition(str(tmp_path / "points.shp"),
                                                QgsProject.instance())
    qgis_processing.run(ALG, {"INPUT": bubenec_layer("streets"),
                              "OUTPUT": str(tmp_path / "roads.gpkg"),
                              "OUTPUT_INTERSECTIONS": points}, context=context)
    details = context.layerToLoadOnCompletionDetails(str(tmp_path / "points.shp"))
    layer = QgsProcessingUtils.mapLayerFromString(str(tmp_path / "points.shp"), context)
    assert layer.attributeAlias(layer.fields().indexOf("tortuosi_1")) == ""
    details.postProcessor().postProcessLayer(layer, context, QgsProcessingFeedback())
    assert layer.attributeAlias(layer.fields().indexOf("tortuosi_1")) == "tortuosity_b"
    assert layer.attributeAlias(layer.fields().indexOf("parcel_are")) == "parcel_area"
    # an output with no style of its own gets its aliases alone
    from urban_synthesis.plugin.qgis_glue import styles

    plain = QgsProcessingUtils.mapLayerFromString(str(tmp_path / "points.shp"), context)
    styles.attach_style(context, str(tmp_path / "points.shp"), None)
    details = context.layerToLoadOnCompletionDetails(str(tmp_path / "points.shp"))
    details.postProcessor().postProcessLayer(plain, context, QgsProcessingFeedback())
    assert plain.attributeAlias(plain.fields().indexOf("tortuosi_1")) == "tortuosity_b"


def test_a_shapefile_output_keeps_its_text_in_utf8(qgis_processing, tmp_path):
    """A shapefile output was written in Processing's 'System' encoding (its .cpg said so):
    the machine's code page, which on a Western Windows has no 'č' (Bubeneč) and on others
    no 'ä' (Helsinki's street names). It is UTF-8 now; its text fields are 254 wide,
    dBase's most (GDAL warned 'Field name of width 255 truncated to 254' for every one)."""
    from osgeo import ogr
    from qgis.core import QgsVectorLayer

    qgis_processing.run(ALG, {"INPUT": helsinki_layer(), "OUTPUT": str(tmp_path / "roads.shp"),
                              "OUTPUT_INTERSECTIONS": None})
    assert (tmp_path / "roads.cpg").read_text().strip() == "UTF-8"
    ds = ogr.Open(str(tmp_path / "roads.shp"))
    layer = ds.GetLayer(0)
    defn = layer.GetLayerDefn()
    text = [defn.GetFieldDefn(i) for i in range(defn.GetFieldCount())
            if defn.GetFieldDefn(i).GetType() == ogr.OFTString]
    assert text and {f.GetWidth() for f in text} == {254}
    names = {f.GetField("name") for f in layer} - {None}
    ds = None
    lines = QgsVectorLayer(helsinki_layer(), "lines", "ogr")
    source = {f["name"] for f in lines.getFeatures()} - {None}
    assert any(not n.isascii() for n in names) and names <= source


def test_outputs_named_with_dots_load_under_their_full_name(qgis_processing, tmp_path,
                                                           monkeypatch):
    """'my.town.v2.shp' loaded as 'my', and 'my.town.v2.gpkg' held a layer 'my': QGIS
    3.22 takes the name up to the file name's first dot (QFileInfo::baseName). The loaded
    layer and the GeoPackage layer are 'my.town.v2'; each output is loaded once. (QGIS names
    outputs in the system temporary folder after the output instead, so TMPDIR is moved.)"""
    from qgis.core import (QgsProcessingContext, QgsProcessingOutputLayerDefinition,
                           QgsProcessingUtils, QgsProject)

    from urban_synthesis.plugin.core.destinations import geopackage_layers

    (tmp_path / "elsewhere").mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp_path / "elsewhere"))
    from osgeo import ogr

    ds = ogr.GetDriverByName("GPKG").CreateDataSource(str(tmp_path / "my.town.gpkg"))
    ds.CreateLayer("wells", geom_type=ogr.wkbPoint)
    ds = None
    for destination, name in (("my.town.v2.shp", "my.town.v2"),
                              ("my.town.v2.gpkg", "my.town.v2"), ("plain.gpkg", "plain"),
                              ("ogr:dbname='{}/both.gpkg' table=\"roads\" (geom)", "roads"),
                              # QGIS 3.22 read this URI's format after the first dot ('town.
                              # gpkg') and failed once the run was done
                              ("ogr:dbname='{}/my.town.gpkg' table=\"roads\" (geom)", "roads")):
        context = QgsProcessingContext()
        context.setProject(QgsProject.instance())
        out = destination.format(tmp_path) if destination.startswith("ogr:") else \
            str(tmp_path / destination)
        qgis_processing.run(ALG, {
            "INPUT": bubenec_layer("streets"), "OUTPUT_INTERSECTIONS": None,
            "OUTPUT": QgsProcessingOutputLayerDefinition(out, QgsProject.instance())},
            context=context)
        # once: not also under the destination as given (an ogr: URI, which QGIS fails to
        # load, or the bare path of a GeoPackage whose layer is named)
        loads = context.layersToLoadOnCompletion()
        assert len(loads) == 1, loads
        (key, details), = loads.items()
        layer = QgsProcessingUtils.mapLayerFromString(key, context)
        details.setOutputLayerName(layer)       # what Processing does when it loads it
        assert layer.name() == name, (key, layer.name())
    assert "my.town.v2" in geopackage_layers(tmp_path / "my.town.v2.gpkg")
    assert "my" not in geopackage_layers(tmp_path / "my.town.v2.gpkg")
    assert {"wells", "roads"} <= set(geopackage_layers(tmp_path / "my.town.gpkg"))


def test_a_table_output_to_a_shapefile_or_csv_says_what_was_written(qgis_processing, tmp_path):
    """A table (layoutmetrics' metrics, no geometry) written to a .shp: GDAL writes its .dbf
    alone, so the .shp named never exists; the log said nothing of it, read the renamed
    fields from the missing .shp (no warning) and could not open it to store the style.
    A polygon output written to a CSV (a table: no symbology) warned that its style could
    not be applied."""
    from helpers import log_feedback

    log = log_feedback()
    qgis_processing.run("urbansynth:layoutmetrics", {
        "ROADS": bubenec_layer("streets"), "OUTPUT": str(tmp_path / "metrics.shp")},
        feedback=log)
    assert (tmp_path / "metrics.dbf").exists() and not (tmp_path / "metrics.shp").exists()
    assert any("has no geometry" in w and "metrics.dbf" in w for w in log.warnings), log.warnings
    renamed = [w for w in log.warnings if "is a shapefile" in w]
    assert len(renamed) == 1 and "n_candidate -> n_candidat" in renamed[0], log.warnings
    assert not any("style" in w for w in log.warnings), log.warnings
    log = log_feedback()
    qgis_processing.run("urbansynth:extractblocks", {
        "ROADS": bubenec_layer("streets"), "OUTPUT": str(tmp_path / "blocks.csv")},
        feedback=log)
    assert (tmp_path / "blocks.csv").exists()
    assert not any("style" in w for w in log.warnings), log.warnings
