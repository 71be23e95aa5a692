"""urbansynth:tessellatestreets through real QGIS (processing.run and qgis_process.bin)."""

import numpy as np
import pytest
import shapely

from conftest import helsinki_layer, run_qgis_process
from helpers import layer_features, memory_layer
from urban_synthesis.plugin.network import street_surfaces as ss
from urban_synthesis.plugin.core.paths import RESOURCES

ALG = "urbansynth:tessellatestreets"
SURFACE_FIELDS = [name for name, _ in ss.SURFACE_FIELDS]
JUNCTION_FIELDS = [name for name, _ in ss.JUNCTION_FIELDS]
X0, Y0 = 385000.0, 6671000.0      # central Helsinki in ETRS-TM35FIN (EPSG:3067)
CRS = "EPSG:3067"
A, B = 0.03, 0.09                 # the test terrain: z = 20 + A x' + B y'


def _to_metric(layer, crs=CRS):
    """A layer's geometries transformed into ``crs`` by QGIS (as shapely, with Z)."""
    from qgis.core import QgsCoordinateReferenceSystem, QgsCoordinateTransform, QgsProject

    tr = QgsCoordinateTransform(layer.crs(), QgsCoordinateReferenceSystem(crs),
                                QgsProject.instance())
    out = []
    for f in layer.getFeatures():
        g = f.geometry()
        g.transform(tr)
        out.append(shapely.from_wkb(bytes(g.asWkb())))
    return np.array(out, dtype=object)


def _pairwise_overlap(polys, layers):
    tree = shapely.STRtree(polys)
    i, j = tree.query(polys, predicate="intersects")
    sel = (i < j) & (layers[i] == layers[j])
    return shapely.area(shapely.intersection(polys[i[sel]], polys[j[sel]]))


def _star_wkts(cx, cy, angles, length=70.0):
    return [f"LINESTRING({cx} {cy}, {cx + length * np.cos(np.radians(a))} "
            f"{cy + length * np.sin(np.radians(a))})" for a in angles]


STAR5 = [0, 70, 150, 215, 290]
STAR6 = [20, 75, 130, 200, 250, 320]


@pytest.fixture(scope="module")
def stars():
    wkts = _star_wkts(X0, Y0, STAR5) + _star_wkts(X0 + 300, Y0, STAR6)
    rows = [[w, "residential"] for w in (10.0, None, 7.0, 12.0, None, 9.0, 8.0, None, 6.0,
                                         11.0, 7.5)]
    return memory_layer("LineString", wkts, CRS, "&field=w:double&field=highway:string", rows,
                        name="stars")


def _write_plane(path, a=A, b=B, x0=X0 - 200, y0=Y0 + 200, cell=5.0, n=(140, 80)):
    from osgeo import gdal, osr

    cols, rows = n
    xs = x0 + cell * (np.arange(cols) + 0.5)
    ys = y0 - cell * (np.arange(rows) + 0.5)
    x, y = np.meshgrid(xs, ys)
    z = 20.0 + a * (x - X0) + b * (y - Y0)
    ds = gdal.GetDriverByName("GTiff").Create(str(path), cols, rows, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((x0, cell, 0.0, y0, 0.0, -cell))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(3067)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(z.astype(np.float32))
    ds.FlushCache()
    ds = None
    return str(path)


def test_a_dem_with_gaps_says_so_and_gives_no_false_heights(qgis_processing, stars, tmp_path):
    """The plane with a declared hole under the five-way star, and a second file whose hole
    is -9999 undeclared, in two bands: heights stay on the plane across the declared hole
    (they were 0 there), and each problem is warned of by name."""
    from osgeo import gdal

    from helpers import log_feedback

    plane = _write_plane(tmp_path / "plane.tif")
    z = gdal.Open(plane).ReadAsArray().astype(np.float32)
    hole = np.zeros(z.shape, bool)
    hole[30:50, 30:50] = True                         # 100 x 100 m around the star's centre
    for name, nodata, bands in (("holed", -9999.0, 1), ("undeclared", None, 2)):
        path = tmp_path / f"{name}.tif"
        ds = gdal.GetDriverByName("GTiff").CreateCopy(str(path), gdal.Open(plane))
        if bands == 2:
            ds = None
            ds = gdal.GetDriverByName("GTiff").Create(str(path), z.shape[1], z.shape[0], 2,
                                                      gdal.GDT_Float32)
            src = gdal.Open(plane)
            ds.SetGeoTransform(src.GetGeoTransform())
            ds.SetProjection(src.GetProjection())
            ds.GetRasterBand(2).WriteArray(z)
        ds.GetRasterBand(1).WriteArray(np.where(hole, -9999.0, z).astype(np.float32))
        if nodata is not None:
            ds.GetRasterBand(1).SetNoDataValue(nodata)
        ds = None
        log = log_feedback()
        out = qgis_processing.run(ALG, {"ROADS": stars, "WIDTH_FIELD": "w", "DEM": str(path),
                                        "OUTPUT_SURFACES": "memory:",
                                        "OUTPUT_JUNCTIONS": "memory:"}, feedback=log)
        xyz = shapely.get_coordinates(np.concatenate([
            layer_features(out[k])[1] for k in ("OUTPUT_SURFACES", "OUTPUT_JUNCTIONS")]),
            include_z=True)
        if name == "holed":
            np.testing.assert_allclose(
                xyz[:, 2], 20.0 + A * (xyz[:, 0] - X0) + B * (xyz[:, 1] - Y0), atol=0.1)
            assert any("% of the input's extent has no value" in w for w in log.warnings)
            assert any("streets run (partly) where the DEM has no value" in w
                       for w in log.warnings)
        else:
            assert any("has 2 bands: band 1" in w for w in log.warnings)
            assert any("cells of -9999 that are not declared" in w for w in log.warnings)


def test_helsinki_osm(qgis_processing):
    out = qgis_processing.run(ALG, {"ROADS": helsinki_layer(), "OUTPUT_SURFACES": "memory:",
                                    "OUTPUT_JUNCTIONS": "memory:"})
    surf, junc = out["OUTPUT_SURFACES"], out["OUTPUT_JUNCTIONS"]
    assert surf.crs().authid() == "EPSG:4326" and junc.crs().authid() == "EPSG:4326"
    assert [f.name() for f in surf.fields()] == SURFACE_FIELDS
    assert [f.name() for f in junc.fields()] == JUNCTION_FIELDS
    rows, _ = layer_features(surf)
    jrows, _ = layer_features(junc)
    assert 150 < len(rows) < 400 and 80 < len(jrows) < 250
    degrees = np.array([r["degree"] for r in jrows])
    # degree 2: joints where a bridge meets its approach (tests/test_street_surfaces.py)
    assert min(degrees) >= 2 and {3, 4} <= set(degrees) and (degrees == 2).mean() < 0.2
    # widths from the class table (halved for one-way carriageways) and OSM width tags
    widths = np.array([r["width_m"] for r in rows])
    table = np.array(list(ss.CLASS_WIDTHS.values()) + [ss.LINK_WIDTH])
    from_table = np.isin(widths, np.r_[table, np.maximum(table / 2, 3.5)])
    assert from_table.mean() > 0.97 and (widths == 4.0).any()     # one-way residential
    # no DEM: no slopes
    assert all(r["slope_long_pct"] is None and r["too_steep_lat"] is None for r in rows)
    # geometry checks in a metric CRS
    s = _to_metric(surf)
    j = _to_metric(junc)
    polys = np.concatenate([s, j])
    layers = np.r_[[r["z_layer"] for r in rows], [r["z_layer"] for r in jrows]]
    assert shapely.is_valid(polys).all()
    ov = _pairwise_overlap(polys, layers)
    assert ov.sum() < 0.01
    np.testing.assert_allclose([r["area_m2"] for r in rows], shapely.area(s), rtol=1e-3)
    # the streets between junctions join them: every from/to id is a junction or a dead end
    ids = {r["junction_id"] for r in jrows}
    ends = [r["from_junction"] for r in rows] + [r["to_junction"] for r in rows]
    assert np.mean([e in ids for e in ends]) > 0.6


def test_a_dem_in_feet_gives_heights_and_slopes_in_metres(qgis_processing, stars, tmp_path):
    """The plane's heights written in US survey feet, the unit declared by the band's unit
    type or by the file's compound CRS (ETRS-TM35FIN + a vertical CRS in feet): z and slopes
    are those of the plane in metres (they were 3.28 times too high and too steep), and the
    log says what was converted."""
    from osgeo import gdal, osr

    from helpers import log_feedback

    plane = _write_plane(tmp_path / "plane.tif")
    feet = 1200.0 / 3937.0
    z = gdal.Open(plane).ReadAsArray().astype(np.float64) / feet
    results = {}
    for how in ("unit type", "vertical CRS"):
        path = tmp_path / f"feet_{how.replace(' ', '_')}.tif"
        ds = gdal.GetDriverByName("GTiff").CreateCopy(str(path), gdal.Open(plane))
        ds.GetRasterBand(1).WriteArray(z.astype(np.float32))
        if how == "unit type":
            ds.GetRasterBand(1).SetUnitType("US survey foot")
        else:
            srs = osr.SpatialReference()
            srs.SetFromUserInput("EPSG:3067+6360")   # + NAVD88 height (ftUS)
            ds.SetSpatialRef(srs)
        ds = None
        log = log_feedback()
        out = qgis_processing.run(ALG, {"ROADS": stars, "WIDTH_FIELD": "w", "DEM": str(path),
                                        "OUTPUT_SURFACES": "memory:",
                                        "OUTPUT_JUNCTIONS": "memory:"}, feedback=log)
        rows, sg = layer_features(out["OUTPUT_SURFACES"])
        xyz = shapely.get_coordinates(sg, include_z=True)
        np.testing.assert_allclose(xyz[:, 2], 20 + A * (xyz[:, 0] - X0) + B * (xyz[:, 1] - Y0),
                                   atol=0.01)
        assert max(r["slope_long_pct"] for r in rows) < 100 * np.hypot(A, B) + 0.05
        assert any("converted to metres" in i for i in log.messages), how
        results[how] = sorted(r["slope_long_pct"] for r in rows)
    np.testing.assert_allclose(results["unit type"], results["vertical CRS"], atol=1e-6)


def test_degree_5_and_6_on_an_inclined_plane(qgis_processing, stars, tmp_path):
    dem = _write_plane(tmp_path / "plane.tif")
    out = qgis_processing.run(ALG, {"ROADS": stars, "WIDTH_FIELD": "w", "DEM": dem,
                                    "OUTPUT_SURFACES": "memory:", "OUTPUT_JUNCTIONS": "memory:"})
    from qgis.core import QgsWkbTypes

    surf, junc = out["OUTPUT_SURFACES"], out["OUTPUT_JUNCTIONS"]
    assert surf.wkbType() == QgsWkbTypes.Type.MultiPolygonZ
    assert junc.wkbType() == QgsWkbTypes.Type.MultiPolygonZ
    rows, sg = layer_features(surf)
    jrows, jg = layer_features(junc)
    assert sorted(r["degree"] for r in jrows) == [5, 6]
    assert len(rows) == 11
    # the width field where set, the residential class width (8 m) where it is NULL
    assert sorted(r["width_m"] for r in rows) == sorted(
        [10.0, 8.0, 7.0, 12.0, 8.0, 9.0, 8.0, 8.0, 6.0, 11.0, 7.5])
    polys = np.concatenate([sg, jg])
    assert shapely.is_valid(polys).all() and shapely.has_z(polys).all()
    assert _pairwise_overlap(shapely.force_2d(polys), np.zeros(len(polys), int)).sum() < 1e-3
    # coverage of the centre lines buffered by half their width
    lines = [shapely.from_wkt(w) for w in _star_wkts(X0, Y0, STAR5) +
             _star_wkts(X0 + 300, Y0, STAR6)]
    width = np.array([10.0, 8.0, 7.0, 12.0, 8.0, 9.0, 8.0, 8.0, 6.0, 11.0, 7.5])
    discs = [shapely.Point(X0, Y0).buffer(w / 2) for w in width[:5]] + \
        [shapely.Point(X0 + 300, Y0).buffer(w / 2) for w in width[5:]]
    ref = shapely.union_all(np.concatenate([shapely.buffer(lines, width / 2, cap_style="flat"),
                                            discs]))
    union = shapely.union_all(shapely.force_2d(polys))
    assert shapely.symmetric_difference(union, ref).area / ref.area < 0.01
    # every vertex on the plane, slopes as the plane's gradient along / across each street
    xyz = shapely.get_coordinates(polys, include_z=True)
    np.testing.assert_allclose(xyz[:, 2], 20 + A * (xyz[:, 0] - X0) + B * (xyz[:, 1] - Y0),
                               atol=1e-3)
    for r, g in zip(rows, sg):
        c = shapely.get_coordinates(shapely.centroid(g))[0]
        centre = np.array([X0, Y0]) if c[0] < X0 + 150 else np.array([X0 + 300, Y0])
        d = (c - centre) / np.linalg.norm(c - centre)
        along = 100 * abs(A * d[0] + B * d[1])
        across = 100 * abs(-A * d[1] + B * d[0])
        assert r["slope_long_pct"] == pytest.approx(along, abs=0.05)
        assert r["slope_lat_pct"] == pytest.approx(across, abs=0.05)
        assert r["too_steep_long"] == (r["slope_long_pct"] > 12.0)
        assert r["too_steep_lat"] == (r["slope_lat_pct"] > 8.0)
    assert any(r["too_steep_lat"] for r in rows) and not all(r["too_steep_lat"] for r in rows)
    for r in jrows:
        assert r["slope_pct"] == pytest.approx(100 * np.hypot(A, B), abs=0.01)
        assert r["z_centre"] == pytest.approx(20.0 + A * (300 if r["degree"] == 6 else 0),
                                              abs=0.01)


@pytest.mark.parametrize("case, match", [
    ("points", "lines are needed"),
    ("empty", "empty"),
    ("no_width_field", "no field 'nope'"),
    ("default_width", "DEFAULT_WIDTH"),
    ("far_dem", "no value over"),
])
def test_bad_input(qgis_processing, stars, tmp_path, case, match):
    from qgis.core import QgsProcessingException

    params = {"ROADS": stars, "OUTPUT_SURFACES": "memory:", "OUTPUT_JUNCTIONS": "memory:"}
    if case == "points":
        params["ROADS"] = memory_layer("Point", [f"POINT({X0} {Y0})"], CRS, name="pts")
    elif case == "empty":
        params["ROADS"] = memory_layer("LineString", [], CRS, name="nothing")
    elif case == "no_width_field":
        params["WIDTH_FIELD"] = "nope"
    elif case == "default_width":
        params["DEFAULT_WIDTH"] = 0.0
    elif case == "far_dem":
        params["DEM"] = _write_plane(tmp_path / "far.tif", x0=X0 + 50000, y0=Y0 + 50000)
    with pytest.raises(QgsProcessingException, match=match):
        qgis_processing.run(ALG, params)


def test_styles_load(qgis_app):
    from qgis.core import QgsRuleBasedRenderer, QgsVectorLayer

    styles = RESOURCES / "styles"
    for qml in ("street_surfaces.qml", "junctions.qml"):
        layer = QgsVectorLayer("Polygon?field=degree:integer&field=too_steep_long:boolean"
                               "&field=too_steep_lat:boolean", "x", "memory")
        message, ok = layer.loadNamedStyle(str(styles / qml))
        assert ok, message
        assert isinstance(layer.renderer(), QgsRuleBasedRenderer)
        assert len(layer.renderer().rootRule().children()) == 2


def test_qgis_process_helsinki(tmp_path):
    """The real qgis_process.bin on the OSM extract: exit 0, the outputs written, the 3D mesh
    as a Wavefront OBJ with Scharl's texture coordinates, its material and road texture."""
    surfaces, junctions = tmp_path / "surfaces.gpkg", tmp_path / "junctions.gpkg"
    obj = tmp_path / "helsinki.obj"
    code, out, err = run_qgis_process("tessellatestreets", {
        "ROADS": helsinki_layer(), "MERGE_DISTANCE": 6, "OUTPUT_SURFACES": str(surfaces),
        "OUTPUT_JUNCTIONS": str(junctions), "OUTPUT_OBJ": str(obj)})
    assert code == 0, err
    assert out is not None and surfaces.exists() and junctions.exists()
    assert out["results"]["OUTPUT_OBJ"] == str(obj)
    text = obj.read_text().splitlines()
    assert text[1].startswith("# x, y: EPSG:326") and "mtllib helsinki.mtl" in text
    faces = [ln for ln in text if ln.startswith("f ")]
    vt = np.array([[float(x) for x in ln.split()[1:]] for ln in text if ln.startswith("vt ")])
    assert len(faces) > 5000 and all(ln.count("/") == 3 for ln in faces)
    assert {"g streets", "g junctions"} <= set(text)
    # u from 0 to 1 across the streets, 0.5 on the junctions; one row each (flat: no sides)
    assert {0.0, 0.5, 1.0} <= set(vt[:, 0]) and len(set(vt[:, 1])) == 2
    assert (tmp_path / "helsinki_texture.png").stat().st_size > 0
    import pyogrio

    s = pyogrio.read_dataframe(surfaces)
    j = pyogrio.read_dataframe(junctions)
    assert list(s.columns[:len(SURFACE_FIELDS)]) == SURFACE_FIELDS
    assert 150 < len(s) < 400 and 60 < len(j) < 250
    assert (j.degree >= 2).all() and (j.degree == 2).mean() < 0.2  # 2: bridge joints
    assert j.merged_nodes.max() >= 2   # 6 m merges some centres
    assert s.geometry.is_valid.all() and j.geometry.is_valid.all()


def test_3d_mesh_on_an_inclined_plane(qgis_processing, stars, tmp_path):
    """Scharl ch. 5.2: the triangle mesh lies on the terrain (lifted by the z offset), its
    top faces tile the street and junction polygons, side faces reach into the terrain;
    the TIN Z GeoPackage holds the same triangles and QGIS reads it back."""
    from qgis.core import QgsVectorLayer, QgsWkbTypes

    dem = _write_plane(tmp_path / "plane.tif")
    tin = tmp_path / "mesh.gpkg"
    out = qgis_processing.run(ALG, {"ROADS": stars, "WIDTH_FIELD": "w", "DEM": dem,
                                    "Z_OFFSET": 0.2, "OUTPUT_SURFACES": "memory:",
                                    "OUTPUT_JUNCTIONS": "memory:",
                                    "OUTPUT_MESH": str(tmp_path / "mesh_layer.gpkg"),
                                    "OUTPUT_TIN": str(tin),
                                    "OUTPUT_OBJ": str(tmp_path / "mesh.obj")})
    mesh = QgsVectorLayer(out["OUTPUT_MESH"], "mesh", "ogr")   # opens with its saved style
    assert mesh.wkbType() == QgsWkbTypes.Type.MultiPolygonZ
    rows, geoms = layer_features(mesh)
    assert len(rows) == 11 + 2 and {r["kind"] for r in rows} == {"street", "junction"}
    # styled like the surfaces and junctions by its kind field, in the file (it had none)
    assert mesh.renderer().type() == "categorizedSymbol"
    assert {c.value() for c in mesh.renderer().categories()} == {"street", "junction"}
    tris = shapely.get_parts(geoms)
    xyz = shapely.get_coordinates(tris, include_z=True).reshape(-1, 4, 3)
    assert np.allclose(xyz[:, 0], xyz[:, 3])                 # closed triangles
    plane = 20 + A * (xyz[..., 0] - X0) + B * (xyz[..., 1] - Y0)
    a, b, c = xyz[:, 0, :2], xyz[:, 1, :2], xyz[:, 2, :2]
    flat_area = 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                             - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    vertical = flat_area < 1e-6                                # a wall seen from above
    side = np.zeros(len(tris), dtype=bool)
    n_side = sum(r["side_triangles"] for r in rows)
    # the top faces: 0.2 m above the plane, and their 2D union is the polygons' union
    up = np.abs(xyz[..., 2] - plane - 0.2).max(axis=1) < 1e-3   # the DEM is float32
    assert up.sum() + n_side == len(tris) and n_side > 0
    side[~up] = True
    top2d = shapely.union_all(shapely.force_2d(tris[up]))
    polys = shapely.union_all(shapely.force_2d(np.concatenate(
        [layer_features(out["OUTPUT_SURFACES"])[1], layer_features(out["OUTPUT_JUNCTIONS"])[1]])))
    assert shapely.symmetric_difference(top2d, polys).area < 1e-3 * polys.area
    assert abs(shapely.area(shapely.force_2d(tris[up])).sum() - top2d.area) < 1e-3 * top2d.area
    # side faces stand vertically along the street edges, from the top down below ground
    dz = xyz[side, :3, 2] - plane[side, :3]
    assert (np.isclose(dz, 0.2, atol=1e-3) | np.isclose(dz, -0.5, atol=1e-3)).all()
    assert (dz.min(axis=1) < -0.4).all() and (dz.max(axis=1) > 0.1).all()
    assert vertical[side].all() and not vertical[up].any()
    layer = QgsVectorLayer(f"{tin}|layername=street_mesh", "tin", "ogr")
    assert layer.isValid() and layer.featureCount() == len(rows)
    assert layer.wkbType() == QgsWkbTypes.Type.MultiPolygonZ      # how QGIS 3.22 reads a TIN
    from osgeo import ogr

    ds = ogr.Open(str(tin))
    lyr = ds.GetLayerByName("street_mesh")
    assert ogr.GeometryTypeToName(lyr.GetGeomType()) == "3D TIN"
    f = lyr.GetNextFeature()
    assert f.GetGeometryRef().GetGeometryName() == "TIN"
    assert f.GetGeometryRef().GetGeometryCount() == f.GetField("triangles")
    # the OBJ: every triangle, each corner with its texture coordinate, and its texture
    assert out["OUTPUT_OBJ"] == str(tmp_path / "mesh.obj")
    text = (tmp_path / "mesh.obj").read_text().splitlines()
    faces = [ln for ln in text if ln.startswith("f ")]
    assert len(faces) == len(tris) and all(ln.count("/") == 3 for ln in faces)
    assert text[1].startswith("# x, y: EPSG:") and "mtllib mesh.mtl" in text
    assert (tmp_path / "mesh_texture.png").stat().st_size > 0



def test_a_bridge_stays_a_bridge_through_the_hierarchy(qgis_processing, tmp_path):
    """hierarchy -> tessellate (or the hierarchy run again on its output), as a model chains
    them: the hierarchy writes a bridge's vertical layer as 'osm_layer', which no tool read
    back, so the bridge was noded with the street under it: a junction in mid-air and both
    cut in two (Liechtenstein's 8 bridges and tunnels: 4 such junctions). Now the bridge
    stays above the street: no junction where they cross, one surface each."""
    x, y = X0, Y0
    wkts = [f"LINESTRING({x - 100} {y}, {x + 100} {y})",
            f"LINESTRING({x} {y - 100}, {x} {y + 100})"]
    roads = memory_layer("LineString", wkts, CRS, "&field=highway:string&field=bridge:string",
                         [["primary", None], ["secondary", "yes"]], name="bridge")
    step = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": roads, "OUTPUT": str(tmp_path / "hierarchy.gpkg"),
        "OUTPUT_INTERSECTIONS": None})["OUTPUT"]
    again = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": step, "OUTPUT": "memory:", "OUTPUT_INTERSECTIONS": None})["OUTPUT"]
    rows, _ = layer_features(again)
    assert sorted(r["osm_layer"] for r in rows) == [0, 1]
    for source in (roads, step, again):
        out = qgis_processing.run(ALG, {"ROADS": source, "OUTPUT_SURFACES": "memory:",
                                        "OUTPUT_JUNCTIONS": "memory:"})
        rows, _ = layer_features(out["OUTPUT_SURFACES"])
        assert sorted(r["z_layer"] for r in rows) == [0, 1]
        assert out["OUTPUT_JUNCTIONS"].featureCount() == 0


def test_every_output_field_is_explained_in_the_help(qgis_processing):
    """edge_id, slope_pct, merged_nodes ... were named (or summed up as 'slopes') without
    a word on what they hold."""
    import re

    from qgis.core import QgsApplication

    alg = QgsApplication.processingRegistry().algorithmById(ALG)
    for output, fields in (("OUTPUT_SURFACES", SURFACE_FIELDS),
                           ("OUTPUT_JUNCTIONS", JUNCTION_FIELDS)):
        text = alg.parameterDefinition(output).help()
        named = set(re.findall(r"[a-z_0-9]+", text))
        assert not [f for f in fields if f not in named], output
    # the ones that need it are followed by what they hold
    for output, explained in (("OUTPUT_SURFACES", ("edge_id", "slope_long_pct", "slope_lat_pct")),
                              ("OUTPUT_JUNCTIONS", ("slope_pct", "z_centre", "merged_nodes",
                                                    "degree", "slope_lat_pct"))):
        text = alg.parameterDefinition(output).help()
        for f in explained:
            assert re.search(rf"\b{f} \(", text), (output, f)


def test_the_hierarchy_keeps_what_the_street_surfaces_need(qgis_processing, tmp_path):
    """hierarchy -> tessellate, as a model chains them: the hierarchy dropped OSM's 'oneway'
    and 'width', so each carriageway of a dual carriageway was paved at the full class
    width: Helsinki's paved area came out 38 % larger than from the same OSM lines
    directly (188,522 m² for 136,232), 106 polygons trimmed instead of 46 and 18 streets
    inside their junctions instead of 1. The hierarchy now writes width_m and oneway."""
    from qgis.core import QgsVectorLayer

    hierarchy = qgis_processing.run("urbansynth:extractroadhierarchy", {
        "INPUT": helsinki_layer("lines"), "OUTPUT": str(tmp_path / "roads.gpkg"),
        "OUTPUT_INTERSECTIONS": None})["OUTPUT"]
    areas = {}
    for name, source in (("direct", helsinki_layer("lines")), ("chained", hierarchy)):
        out = qgis_processing.run(ALG, {"ROADS": source, "OUTPUT_SURFACES": "memory:",
                                        "OUTPUT_JUNCTIONS": "memory:"})
        surfaces, _ = layer_features(out["OUTPUT_SURFACES"])
        areas[name] = sum(r["area_m2"] for r in surfaces)
    assert areas["chained"] == pytest.approx(areas["direct"], rel=0.01)
    rows, _ = layer_features(QgsVectorLayer(hierarchy, "roads", "ogr"))
    assert sum(r["oneway"] == "yes" for r in rows) > 100


def test_a_shapefile_output_styles_each_flag_by_its_own_field(qgis_processing, stars, tmp_path):
    """too_steep_long and too_steep_lat both cut to 'too_steep_' in a shapefile: GDAL numbers
    the second ('too_stee_1'), and the style saved beside the file names each flag as GDAL
    wrote it (cut alike, both rules read too_steep_long's values)."""
    from qgis.core import QgsVectorLayer

    dem = _write_plane(tmp_path / "plane.tif")
    paths = {"OUTPUT_SURFACES": tmp_path / "surfaces.shp",
             "OUTPUT_JUNCTIONS": tmp_path / "junctions.shp"}
    qgis_processing.run(ALG, {"ROADS": stars, "WIDTH_FIELD": "w", "DEM": dem,
                              **{k: str(v) for k, v in paths.items()}})
    for output, path in paths.items():
        layer = QgsVectorLayer(str(path), "out", "ogr")   # opens with the sidecar .qml
        declared = SURFACE_FIELDS if output == "OUTPUT_SURFACES" else JUNCTION_FIELDS
        written = dict(zip(declared, layer.fields().names()))
        assert written["too_steep_long"] != written["too_steep_lat"]
        filters = [r.filterExpression() for r in layer.renderer().rootRule().children()]
        assert f'"{written["too_steep_long"]}" OR "{written["too_steep_lat"]}"' in filters


def test_widths_out_of_range_are_counted_in_the_log(qgis_processing):
    """Widths the field gives that are no width (250 m, -3, 0) take the class width, as
    before, and the log now says how many and which (they were replaced silently)."""
    from helpers import log_feedback

    wkts = _star_wkts(X0, Y0, STAR5)
    rows = [[w, "residential"] for w in (250.0, -3.0, 0.0, 9.0, None)]
    roads = memory_layer("LineString", wkts, CRS, "&field=w:double&field=highway:string", rows,
                         name="odd widths")
    log = log_feedback()
    out = qgis_processing.run(ALG, {"ROADS": roads, "WIDTH_FIELD": "w",
                                    "OUTPUT_SURFACES": "memory:", "OUTPUT_JUNCTIONS": "memory:"},
                              feedback=log)
    widths = sorted(r["width_m"] for r in layer_features(out["OUTPUT_SURFACES"])[0])
    assert widths == [8.0, 8.0, 8.0, 8.0, 9.0]
    refused = [w for w in log.warnings if "not used" in w]
    assert len(refused) == 1 and refused[0].startswith("3 widths of 'odd widths'"), log.warnings
    assert "250" in refused[0] and "-3" in refused[0]
