"""The sweep of bad inputs (issue 22, issue 14): inputs a hostile but realistic user gives,
generated here from the example data (no committed binaries), and the cases that run them.

Every case runs one algorithm (or the shipped model) and states what must happen: a clear
QgsProcessingException whose message matches ``expect`` (never a traceback), or a result
``check`` accepts. Whatever happens, the input files keep their checksums, a failed run
leaves no output and no staging folder behind, and nothing but a QgsProcessingException
escapes. ``tests/test_bad_inputs.py`` runs every case in ``make test`` and ``make sweep``,
the core cases when pytest runs it alone; ``python tests/bad_inputs.py`` prints the table
of the full sweep.

Generic cases are derived from each algorithm's declaration (every Number parameter out of
range and not whole, every vector input empty, null, of the wrong geometry type, without a
CRS, with an undefined CRS, geographic, with heights and measures (Z, M), multi-part; every
optional line or polygon input the same, and every optional raster without a CRS, elsewhere and flat,
where a result or any clear message will do; every file output onto an input and into a
read-only folder); specific cases are the findings of issue 22.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional

import numpy as np

from conftest import BUBENEC, HELSINKI

#: ``expect`` of a case that may succeed or stop with any clear message (invalid rings,
#: geographic input: repaired or projected, or refused for what they hold).
EITHER = "either a result or a clear message"
#: A message that is not clear: a Python traceback or an exception class in the text.
UNCLEAR = re.compile(r"Traceback \(most recent call last\)|\b(KeyError|AttributeError|"
                     r"TypeError|IndexError|ValueError|GEOSException|TopologyException|"
                     r"DataSourceError|OSError|ZeroDivisionError|RuntimeError)\b")


# --------------------------------------------------------------------------- inputs

def _translate(src: str, dst: Path, layer: Optional[str] = None, sql: Optional[str] = None,
               srs: Optional[str] = None, name: Optional[str] = None, fmt: str = "GPKG",
               dim: Optional[str] = None, geometry_type: Optional[str] = None):
    from osgeo import gdal

    options = gdal.VectorTranslateOptions(
        format=fmt, layers=[layer] if layer and not sql else None, SQLStatement=sql,
        dstSRS=srs, reproject=bool(srs), layerName=name or layer, accessMode=None, dim=dim,
        geometryType=geometry_type)
    ds = gdal.VectorTranslate(str(dst), src, options=options)
    assert ds is not None, (src, dst)
    ds = None


def _checksum(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _raster(path: Path, array: np.ndarray, epsg: Optional[int] = 32633,
            origin=(500000.0, 5500000.0), cell: float = 3.0):
    from osgeo import gdal, osr

    rows, cols = array.shape
    ds = gdal.GetDriverByName("GTiff").Create(str(path), cols, rows, 1, gdal.GDT_Byte)
    ds.SetGeoTransform((origin[0], cell, 0, origin[1] + rows * cell, 0, -cell))
    if epsg:
        srs = osr.SpatialReference()
        srs.ImportFromEPSG(epsg)
        ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(array.astype(np.uint8))
    ds = None


def make_inputs(folder: Path) -> Dict[str, str]:
    """Write every input of the sweep into ``folder``; returns name -> QGIS source."""
    from osgeo import gdal, ogr, osr

    folder.mkdir(parents=True, exist_ok=True)
    gdal.UseExceptions()
    out: Dict[str, str] = {}
    bub = str(BUBENEC)
    for layer in ("streets", "buildings", "plots"):
        _translate(bub, folder / f"{layer}.gpkg", layer)
        out[layer] = f"{folder / f'{layer}.gpkg'}|layername={layer}"
    # buildings with a text field of ids that look like heights, and a plausible number
    _translate(bub, folder / "buildings_ids.gpkg", sql="SELECT geom, CAST(fid + 30 AS TEXT) AS "
               "id_text, 12.5 AS height_num FROM buildings", name="buildings")
    out["buildings_ids"] = f"{folder / 'buildings_ids.gpkg'}|layername=buildings"
    # geographic (degrees) and a shapefile without .prj
    _translate(bub, folder / "streets_4326.gpkg", "streets", srs="EPSG:4326")
    out["streets_4326"] = f"{folder / 'streets_4326.gpkg'}|layername=streets"
    # heights and measures (a cadastre or a GPS survey exported in 3D)
    for layer in ("streets", "plots"):
        _translate(bub, folder / f"{layer}_zm.gpkg", layer, dim="XYZM")
        out[f"{layer}_zm"] = f"{folder / f'{layer}_zm.gpkg'}|layername={layer}"
    # every feature a multi-part one (as shapefiles and many tools' GeoJSON hold them)
    _translate(bub, folder / "streets_multi.gpkg", "streets", geometry_type="PROMOTE_TO_MULTI")
    out["streets_multi"] = f"{folder / 'streets_multi.gpkg'}|layername=streets"
    _translate(bub, folder / "plots_noprj.shp", "plots", fmt="ESRI Shapefile")
    (folder / "plots_noprj.prj").unlink()
    out["plots_noprj"] = str(folder / "plots_noprj.shp")
    _translate(bub, folder / "streets_noprj.shp", "streets", fmt="ESRI Shapefile")
    (folder / "streets_noprj.prj").unlink()
    out["streets_noprj"] = str(folder / "streets_noprj.shp")
    # a GeoPackage whose layer has the undefined CRS (srs_id 0), as some tools write it
    _translate(bub, folder / "streets_srs0.gpkg", "streets")
    ds = ogr.Open(str(folder / "streets_srs0.gpkg"), 1)
    ds.ExecuteSQL("UPDATE gpkg_geometry_columns SET srs_id = 0")
    ds.ExecuteSQL("UPDATE gpkg_contents SET srs_id = 0")
    ds = None
    out["streets_srs0"] = f"{folder / 'streets_srs0.gpkg'}|layername=streets"
    # empty layers, null geometries, invalid rings, points: in one GeoPackage
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(3857)
    path = folder / "odd.gpkg"
    ds = ogr.GetDriverByName("GPKG").CreateDataSource(str(path))
    for name, kind, wkts in (
            ("empty_lines", ogr.wkbLineString, []),
            ("empty_polygons", ogr.wkbPolygon, []),
            ("null_polygons", ogr.wkbPolygon, [None, None]),
            ("null_lines", ogr.wkbLineString, [None]),
            ("points", ogr.wkbPoint, ["POINT (1604000 6463000)", "POINT (1604100 6463100)"]),
            ("bowties", ogr.wkbPolygon, [
                "POLYGON ((1604000 6463000, 1604200 6463200, 1604200 6463000, 1604000 6463200, "
                "1604000 6463000))"]),
            ("tiny_lines", ogr.wkbLineString, ["LINESTRING (1604000 6463000, 1604000.01 "
                                               "6463000)"])):
        lyr = ds.CreateLayer(name, srs, kind)
        for wkt in wkts:
            feat = ogr.Feature(lyr.GetLayerDefn())
            if wkt:
                feat.SetGeometry(ogr.CreateGeometryFromWkt(wkt))
            lyr.CreateFeature(feat)
        out[name] = f"{path}|layername={name}"
    ds = None
    # a target of 400 x 400 km, and a study area far from Bubeneč
    srs33 = osr.SpatialReference()
    srs33.ImportFromEPSG(32633)
    path = folder / "areas.gpkg"
    ds = ogr.GetDriverByName("GPKG").CreateDataSource(str(path))
    for name, wkt in (("huge", "POLYGON ((300000 5300000, 700000 5300000, 700000 5700000, "
                                "300000 5700000, 300000 5300000))"),
                      ("far", "POLYGON ((300000 5300000, 301000 5300000, 301000 5301000, "
                               "300000 5301000, 300000 5300000))")):
        lyr = ds.CreateLayer(name, srs33, ogr.wkbPolygon)
        feat = ogr.Feature(lyr.GetLayerDefn())
        feat.SetGeometry(ogr.CreateGeometryFromWkt(wkt))
        lyr.CreateFeature(feat)
        out[name] = f"{path}|layername={name}"
    lyr = ds.CreateLayer("huge_lines", srs33, ogr.wkbLineString)
    for wkt in ("LINESTRING (300000 5300000, 700000 5300000, 700000 5700000, 300000 5700000, "
                "300000 5300000)", "LINESTRING (300000 5500000, 700000 5500000)",
                "LINESTRING (500000 5300000, 500000 5700000)"):
        feat = ogr.Feature(lyr.GetLayerDefn())
        feat.SetGeometry(ogr.CreateGeometryFromWkt(wkt))
        lyr.CreateFeature(feat)
    out["huge_lines"] = f"{path}|layername=huge_lines"
    ds = None
    # rasters: a road mask, all 255, without CRS
    roads = np.zeros((200, 200))
    roads[95:105, :] = 255
    roads[:, 95:105] = 255
    _raster(folder / "road_mask.tif", roads)
    _raster(folder / "all255.tif", np.full((100, 100), 255))
    _raster(folder / "mask_nocrs.tif", roads, epsg=None)
    out.update(road_mask=str(folder / "road_mask.tif"), all255=str(folder / "all255.tif"),
               mask_nocrs=str(folder / "mask_nocrs.tif"))
    # corrupt files where a database or a model is expected
    rng = np.random.default_rng(0)
    for name in ("corrupt.gpkg", "corrupt.onnx"):
        (folder / name).write_bytes(rng.bytes(4096))
        out[name.replace(".", "_")] = str(folder / name)
    (folder / "corrupt.json").write_text("{not json")
    shutil.copy(folder / "corrupt.onnx", folder / "nocard.onnx")
    out["nocard_onnx"] = str(folder / "nocard.onnx")
    ds = ogr.GetDriverByName("GPKG").CreateDataSource(str(folder / "not_a_db.gpkg"))
    lyr = ds.CreateLayer("something", srs, ogr.wkbPoint)
    ds = None
    out["not_a_db"] = str(folder / "not_a_db.gpkg")
    # a folder outputs cannot be written to: read-only (as root, whom permissions do not
    # stop, a "folder" that is a file)
    ro = folder / "read_only"
    if os.geteuid() == 0:
        ro.write_text("a file, not a folder")
    else:
        ro.mkdir(exist_ok=True)
        ro.chmod(stat.S_IRUSR | stat.S_IXUSR)
    out["read_only"] = str(ro)
    out["helsinki_lines"] = f"{HELSINKI}|layername=lines"
    # the example image of the aerial-image synthesis and polygons on it
    examples = Path(str(BUBENEC)).parent
    shutil.copy(examples / "atlanta_pan_0.5m.tif", folder / "atlanta.tif")
    _translate(str(examples / "atlanta_buildings.geojson"), folder / "atlanta.gpkg",
               name="lots")
    out["atlanta_image"] = str(folder / "atlanta.tif")
    out["atlanta_lots"] = f"{folder / 'atlanta.gpkg'}|layername=lots"
    return out


# --------------------------------------------------------------------------- cases

@dataclass
class Case:
    """One run: ``alg`` with ``params`` (``{name}`` placeholders are inputs of
    :func:`make_inputs`, ``{out}`` the case's output folder); ``expect`` a regex the error
    must match, or None when the run must succeed (then ``check(results)`` may look at the
    outputs); ``core`` runs in a plain pytest run too (every case runs in ``make test``)."""

    id: str
    alg: str
    params: dict
    expect: Optional[str] = None
    check: Optional[Callable] = None
    core: bool = False
    inputs: List[str] = field(default_factory=list)   # files whose checksums must not move


def _fill(value, inputs, out):
    if isinstance(value, str):
        for key, path in inputs.items():
            value = value.replace("{" + key + "}", path)
        return value.replace("{out}", str(out))
    return value


def input_files(params: dict) -> List[Path]:
    """The files a run reads (for the checksums)."""
    files = []
    for value in params.values():
        if isinstance(value, str) and not value.startswith(("ogr:", "memory:")):
            path = Path(value.split("|")[0])
            if path.is_file():
                files.append(path)
                if path.suffix == ".shp":
                    files += [p for p in path.parent.glob(path.stem + ".*") if p != path]
    return sorted(set(files))


def run_case(processing, case: Case, inputs: Dict[str, str], out: Path):
    """Run one case; returns (ok, what happened). Asserts nothing itself."""
    from qgis.core import QgsProcessingException

    out.mkdir(parents=True, exist_ok=True)
    params = {k: _fill(v, inputs, out) for k, v in case.params.items()}
    files = input_files(params)
    before = {p: _checksum(p) for p in files}
    problems = []
    try:
        results = processing.run(case.alg, params)
        error = None
    except QgsProcessingException as exc:
        results, error = None, str(exc)
    except Exception as exc:  # noqa: BLE001 - anything else is a finding
        results, error = None, None
        problems.append(f"{type(exc).__name__} escaped: {exc}")
    moved = [str(p) for p in files if _checksum(p) != before[p]]
    if moved:
        problems.append(f"input modified: {', '.join(moved)}")
    left = [str(p) for p in Path(out).rglob(".urbansynth-run-*")]
    if left:
        problems.append(f"staging left behind: {left}")
    if case.expect == EITHER:
        if error is not None and UNCLEAR.search(error):
            problems.append(f"unclear message: {error[:400]}")
    elif case.expect is None:
        if error is not None:
            problems.append(f"failed: {error[:300]}")
        elif case.check is not None and not problems:
            message = case.check(results)
            if message:
                problems.append(message)
    elif error is None:
        if not problems:
            problems.append(f"succeeded, expected an error matching {case.expect!r}")
    else:
        if UNCLEAR.search(error):
            problems.append(f"unclear message: {error[:400]}")
        if not re.search(case.expect, error, flags=re.S | re.I):
            problems.append(f"message {error[:300]!r} does not match {case.expect!r}")
        written = [str(p) for p in Path(out).rglob("*") if p.is_file()]
        if written:
            problems.append(f"failed run left outputs: {written}")
    return not problems, "; ".join(problems) or (error or "ok")


def derive_inputs(processing, inputs: Dict[str, str], folder: Path) -> Dict[str, str]:
    """Inputs made by the plugin itself: a road hierarchy, blocks, the two databases, and
    polygon variants of the odd layers."""
    from osgeo import gdal, ogr

    out = dict(inputs)
    run = processing.run
    out["hierarchy"] = run("urbansynth:extractroadhierarchy", {
        "INPUT": inputs["streets"], "OUTPUT": str(folder / "hierarchy.gpkg"),
        "OUTPUT_INTERSECTIONS": str(folder / "intersections.gpkg")})["OUTPUT"]
    out["intersections"] = str(folder / "intersections.gpkg")
    out["blocks"] = run("urbansynth:extractblocks", {
        "ROADS": inputs["streets"], "BUILDINGS": inputs["buildings"],
        "OUTPUT": str(folder / "blocks.gpkg"),
        "OUTPUT_BUILDINGS": str(folder / "blocks_buildings.gpkg")})["OUTPUT"]
    out["block_buildings"] = str(folder / "blocks_buildings.gpkg")
    out["blockdb"] = run("urbansynth:buildblockdatabase", {
        "BLOCKS": out["blocks"], "BUILDINGS": out["block_buildings"],
        "OUTPUT": str(folder / "blockdb.gpkg")})["OUTPUT"]
    out["fragdb"] = run("urbansynth:buildfragmentdatabase", {
        "ROADS": out["hierarchy"], "OUTPUT": str(folder / "fragdb.gpkg")})["OUTPUT"]
    gdal.UseExceptions()
    for name in ("plots",):
        _translate(str(folder / "plots.gpkg"), folder / "plots_4326.gpkg", "plots",
                   srs="EPSG:4326")
        out["plots_4326"] = f"{folder / 'plots_4326.gpkg'}|layername=plots"
        _translate(str(folder / "plots.gpkg"), folder / "plots_srs0.gpkg", "plots")
        ds = ogr.Open(str(folder / "plots_srs0.gpkg"), 1)
        ds.ExecuteSQL("UPDATE gpkg_geometry_columns SET srs_id = 0")
        ds.ExecuteSQL("UPDATE gpkg_contents SET srs_id = 0")
        ds = None
        out["plots_srs0"] = f"{folder / 'plots_srs0.gpkg'}|layername=plots"
        _translate(str(folder / "plots.gpkg"), folder / "plots_multi.gpkg", "plots",
                   geometry_type="PROMOTE_TO_MULTI")
        out["plots_multi"] = f"{folder / 'plots_multi.gpkg'}|layername=plots"
    # a 300 m square region (split domain, parts) and a 1 km² target, both UTM 33N
    from osgeo import osr

    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32633)
    path = folder / "small.gpkg"
    ds = ogr.GetDriverByName("GPKG").CreateDataSource(str(path))
    for name, wkt in (("square", "POLYGON ((500000 5500000, 500300 5500000, 500300 5500300, "
                                  "500000 5500300, 500000 5500000))"),
                      ("speck", "POLYGON ((500000 5500000, 500001 5500000, 500001 5500001, "
                                "500000 5500001, 500000 5500000))")):
        lyr = ds.CreateLayer(name, srs, ogr.wkbPolygon)
        feat = ogr.Feature(lyr.GetLayerDefn())
        feat.SetGeometry(ogr.CreateGeometryFromWkt(wkt))
        lyr.CreateFeature(feat)
        out[name] = f"{path}|layername={name}"
    ds = None
    return out


#: Per algorithm: a valid run (``{out}`` outputs) and its vector inputs with their kind.
BASE = {
    "extractroadhierarchy": ({"INPUT": "{streets}", "OUTPUT": "{out}/roads.gpkg",
                              "OUTPUT_INTERSECTIONS": "{out}/points.gpkg"},
                             {"INPUT": "lines"}),
    "extractblocks": ({"ROADS": "{streets}", "BUILDINGS": "{buildings}",
                       "OUTPUT": "{out}/blocks.gpkg", "OUTPUT_BUILDINGS": "{out}/b.gpkg"},
                      {"ROADS": "lines", "BUILDINGS": "polygons"}),
    "buildblockdatabase": ({"BLOCKS": "{blocks}", "BUILDINGS": "{block_buildings}",
                            "OUTPUT": "{out}/db.gpkg"},
                           {"BLOCKS": "polygons", "BUILDINGS": "polygons"}),
    "buildfragmentdatabase": ({"ROADS": "{hierarchy}", "OUTPUT": "{out}/db.gpkg"},
                              {"ROADS": "lines"}),
    "layoutmetrics": ({"ROADS": "{streets}", "OUTPUT": "{out}/m.gpkg",
                       "OUTPUT_HTML": "{out}/report.html"}, {"ROADS": "lines"}),
    "growroads": ({"BOUNDARY": "{square}", "OUTPUT": "{out}/roads.gpkg"},
                  {"BOUNDARY": "polygons"}),
    "subdivideparcels": ({"BLOCKS": "{blocks}", "OUTPUT": "{out}/parcels.gpkg"},
                         {"BLOCKS": "polygons"}),
    "synthesizeroadsfromfragments": ({"ARTERIALS": "{streets}", "FRAGMENT_DB": "{fragdb}",
                                      "OUTPUT": "{out}/roads.gpkg"}, {"ARTERIALS": "lines"}),
    "tessellatestreets": ({"ROADS": "{streets}", "OUTPUT_SURFACES": "{out}/s.gpkg",
                           "OUTPUT_JUNCTIONS": "{out}/j.gpkg"}, {"ROADS": "lines"}),
    "synthesizeroadsgan": ({"TARGET": "{square}", "OUTPUT": "{out}/roads.gpkg"},
                           {"TARGET": "polygons"}),
    "rasterroadstovector": ({"INPUT": "{road_mask}", "OUTPUT": "{out}/roads.gpkg"}, {}),
    "synthesizebuildingattributes": ({"FOOTPRINTS": "{buildings}",
                                      "EXAMPLE_BUILDINGS": "{block_buildings}",
                                      "OUTPUT": "{out}/b.gpkg"},
                                     {"FOOTPRINTS": "polygons", "EXAMPLE_BUILDINGS": "polygons"}),
    "placelibrarybuildings": ({"PARCELS": "{plots}", "ROADS": "{streets}",
                               "OUTPUT": "{out}/b.gpkg"},
                              {"PARCELS": "polygons", "ROADS": "lines"}),
    "synthesizepartbuildings": ({"SKELETON": "{square}", "PARTS_LIBRARY": 2,
                                 "OUTPUT": "{out}/parts.gpkg"}, {"SKELETON": "polygons"}),
    "synthesizeroadsrandomwalk": ({"EXAMPLE": "{streets}", "TARGET": "{square}",
                                   "OUTPUT": "{out}/roads.gpkg"},
                                  {"EXAMPLE": "lines", "TARGET": "polygons"}),
    "synthesizefootprints": ({"BLOCKS": "{blocks}", "BLOCK_DB": "{blockdb}",
                              "OUTPUT": "{out}/f.gpkg"}, {"BLOCKS": "polygons"}),
    "splitdomain": ({"REGION": "{square}", "OUTPUT_ROADS": "{out}/r.gpkg",
                     "OUTPUT_PARCELS": "{out}/p.gpkg"}, {"REGION": "polygons"}),
    "synthesizeroads": ({"METHOD": 1, "ARTERIALS": "{streets}", "OUTPUT": "{out}/roads.gpkg"},
                        {"ARTERIALS": "lines"}),
    "synthesizeaerialimage": ({"PARCELS": "{plots}", "EXAMPLE_IMAGE": "{atlanta_image}",
                               "EXAMPLE_PARCELS": "{atlanta_lots}",
                               "OUTPUT_IMAGE": "{out}/image.tif"},
                              {"PARCELS": "polygons", "EXAMPLE_PARCELS": "polygons"}),
}

#: Replacements of a vector input: (input name per kind, expected message, core).
VECTOR_MUTATIONS = {
    "empty": ({"lines": "empty_lines", "polygons": "empty_polygons"}, r"is empty"),
    "null": ({"lines": "null_lines", "polygons": "null_polygons"}, r"is empty.*null"),
    "points": ({"lines": "points", "polygons": "points"}, r"has points; \w+ are needed"),
    "no_prj": ({"lines": "streets_noprj", "polygons": "plots_noprj"},
               r"no coordinate reference system"),
    "srs_id_0": ({"lines": "streets_srs0", "polygons": "plots_srs0"},
                 r"no coordinate reference system"),
    "invalid_rings": ({"lines": "tiny_lines", "polygons": "bowties"}, EITHER),
    "geographic": ({"lines": "streets_4326", "polygons": "plots_4326"}, EITHER),
    "z_and_m": ({"lines": "streets_zm", "polygons": "plots_zm"}, EITHER),
    # a shapefile's lines are MultiLineStrings: synthesizeroads took StreetGAN's example
    # roads for points ("TypeError: ... incorrect geometry type", 2026-12-07)
    "multi_part": ({"lines": "streets_multi", "polygons": "plots_multi"}, EITHER),
}
#: Replacements of an optional raster input (each a result or a clear message).
RASTER_MUTATIONS = {"no_crs": "mask_nocrs", "elsewhere": "road_mask", "flat": "all255"}
#: Other clear messages a mutation may meet first: (algorithm, input) -> alternative.
ALTERNATIVES = {
    # a layer without the level field is refused before its CRS is looked at
    ("buildfragmentdatabase", "ROADS"): r"no field 'level'",
    # intersection points are welcome as the example; these lack the attributes
    ("synthesizeroadsrandomwalk", "EXAMPLE"): r"no field level_a",
}
#: Optional inputs of BASE whose layer given empty (or all null) is one not given
#: (qgis_io.read_source(optional=True): a model step before made nothing): a result or
#: a clear message. Other optional inputs given empty alone are still refused by name
#: (growroads' BOUNDARY, layoutmetrics' ROADS: nothing else to work on).
EMPTY_IS_NOT_GIVEN = {("extractblocks", "BUILDINGS")}
#: One mutation per algorithm runs in ``make test``: these (cycled over the algorithms).
CORE_ROTATION = ["empty", "points", "no_prj", "srs_id_0", "null"]


def _number_cases(alg_id, definition):
    """Out-of-range, fractional and non-numeric values of a Number parameter."""
    from qgis.core import QgsProcessingParameterNumber

    name, lo, hi = definition.name(), definition.minimum(), definition.maximum()
    integer = definition.dataType() == QgsProcessingParameterNumber.Type.Integer
    cases = []
    if hi < 1e300:
        cases.append(("above", hi + max(1.0, abs(hi)), r"out of range: allowed"))
    if lo > -1e300:
        cases.append(("below", lo - max(1.0, abs(lo)), r"out of range: allowed"))
    if integer:
        cases.append(("fraction", (lo if lo > -1e300 else 0) + 1.5, r"whole number"))
    cases.append(("text", "lots", r"must be a number"))
    return [(f"{alg_id}-{name}-{kind}", name, value, expect) for kind, value, expect in cases]


def generic_cases(registry) -> List[Case]:
    """Cases derived from the declarations of every algorithm of :data:`BASE`."""
    from qgis.core import (QgsProcessingParameterFeatureSink,
                           QgsProcessingParameterFileDestination, QgsProcessingParameterNumber,
                           QgsProcessingParameterRasterDestination)

    cases = []
    for k, (alg_id, (base, vectors)) in enumerate(BASE.items()):
        alg = registry.algorithmById(f"urbansynth:{alg_id}")
        full = f"urbansynth:{alg_id}"
        core_kind = CORE_ROTATION[k % len(CORE_ROTATION)]
        for m, (kind, (by_kind, expect)) in enumerate(VECTOR_MUTATIONS.items()):
            for p, (name, geometry) in enumerate(vectors.items()):
                alternative = ALTERNATIVES.get((alg_id, name)) if expect != EITHER else None
                expected = f"{expect}|{alternative}" if alternative else expect
                if kind in ("empty", "null") and (alg_id, name) in EMPTY_IS_NOT_GIVEN:
                    expected = EITHER
                cases.append(Case(f"{alg_id}-{name}-{kind}", full,
                                  dict(base, **{name: "{" + by_kind[geometry] + "}"}),
                                  expected,
                                  core=kind == core_kind and p == 0))
        # optional line and polygon inputs (key roads, given roads, key areas, ...): the
        # same mutations, each a result or a clear message (an empty layer may count as none
        # given; an input the run does not use, such as example roads for a method that
        # needs none, is not read; a missing field may be reported before the CRS)
        for name, geometry in _optional_vectors(alg, vectors).items():
            for kind, (by_kind, _) in VECTOR_MUTATIONS.items():
                cases.append(Case(f"{alg_id}-{name}-{kind}", full,
                                  dict(base, **{name: "{" + by_kind[geometry] + "}"}), EITHER))
        # optional rasters (terrain, example image, ...): one without a CRS, a road mask
        # (0 / 255) around the square, which lies elsewhere for the runs on the example data
        # and is a cliff-ridden terrain for those on the square, and a flat one
        for name in _optional_rasters(alg):
            for kind, source in RASTER_MUTATIONS.items():
                cases.append(Case(f"{alg_id}-{name}-{kind}", full,
                                  dict(base, **{name: "{" + source + "}"}), EITHER))
        numbers = [d for d in alg.parameterDefinitions()
                   if isinstance(d, QgsProcessingParameterNumber)]
        for n, definition in enumerate(numbers):
            for c, (case_id, name, value, expect) in enumerate(
                    _number_cases(alg_id, definition)):
                cases.append(Case(case_id, full, dict(base, **{name: value}), expect,
                                  core=n == 0 and c == 0))
        outputs = [d for d in alg.destinationParameterDefinitions()
                   if isinstance(d, (QgsProcessingParameterFeatureSink,
                                     QgsProcessingParameterFileDestination,
                                     QgsProcessingParameterRasterDestination))
                   and d.name() in base]
        main = next(iter(vectors), None)
        for o, definition in enumerate(outputs):
            name = definition.name()
            suffix = Path(str(base[name])).suffix or ".gpkg"
            cases.append(Case(f"{alg_id}-{name}-read-only", full,
                              dict(base, **{name: "{read_only}/x" + suffix}),
                              r"cannot be (written|created)", core=k % 4 == 0 and o == 0))
            if main is not None:
                source = base[main]
                cases.append(Case(f"{alg_id}-{name}-onto-{main}", full,
                                  dict(base, **{name: _file_of_source(source)}),
                                  r"would overwrite", core=k % 3 == 0 and o == 0))
    return cases


def _optional_vectors(alg, required) -> Dict[str, str]:
    """Name -> 'lines' or 'polygons' of the algorithm's optional vector inputs of one
    geometry type that are not among its ``required`` (BASE) inputs."""
    from qgis.core import (QgsProcessing, QgsProcessingParameterDefinition,
                           QgsProcessingParameterFeatureSource,
                           QgsProcessingParameterVectorLayer)

    kinds = {QgsProcessing.SourceType.TypeVectorLine: "lines",
             QgsProcessing.SourceType.TypeVectorPolygon: "polygons"}
    out = {}
    for d in alg.parameterDefinitions():
        if not isinstance(d, (QgsProcessingParameterFeatureSource,
                              QgsProcessingParameterVectorLayer)) or d.name() in required:
            continue
        if not d.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional:
            continue
        types = {kinds.get(t) for t in d.dataTypes()}
        if len(types) == 1 and None not in types:
            out[d.name()] = types.pop()
    return out


def _optional_rasters(alg) -> List[str]:
    """Names of the algorithm's optional raster inputs."""
    from qgis.core import QgsProcessingParameterDefinition, QgsProcessingParameterRasterLayer

    return [d.name() for d in alg.parameterDefinitions()
            if isinstance(d, QgsProcessingParameterRasterLayer)
            and d.flags() & QgsProcessingParameterDefinition.Flag.FlagOptional]


def _file_of_source(source: str) -> str:
    """The file of a '{input}' source: '{streets}' -> '{streets_file}'."""
    return source.replace("}", "_file}")


def _len_ok(min_features, layer_key="OUTPUT"):
    def check(results):
        from qgis.core import QgsVectorLayer

        layer = QgsVectorLayer(results[layer_key], "out", "ogr")
        n = layer.featureCount()
        return None if n >= min_features else f"only {n} features in {layer_key}"
    return check


def _arterials_kept(results):
    """StreetGAN through synthesizeroads keeps the arterials (the issue: 1.9 % survived)."""
    import geopandas as gpd
    import shapely

    roads = gpd.read_file(results["OUTPUT"]).to_crs(32633)
    streets = gpd.read_file(str(BUBENEC), layer="streets").to_crs(32633)
    kept = shapely.union_all(roads[roads["level"] == 0].geometry.values).buffer(0.5)
    share = shapely.length(shapely.intersection(streets.geometry.values, kept)).sum() / \
        streets.length.sum()
    return None if share > 0.95 else f"only {100 * share:.1f} % of the arterials kept"


def _heights_plausible(results):
    import geopandas as gpd

    heights = gpd.read_file(results["OUTPUT_BUILDINGS"])["height_m"].dropna()
    return None if heights.between(0, 1000).all() else "implausible heights written"


def specific_cases() -> List[Case]:
    """The findings of issue 22 (and the corrupt inputs of issue 14), one case each."""
    U = "urbansynth:"
    base = {k: v[0] for k, v in BASE.items()}
    return [
        # data loss: an output onto an input (file outputs of the databases and the DB)
        Case("footprints-OUTPUT-onto-BLOCK_DB", U + "synthesizefootprints",
             dict(base["synthesizefootprints"], OUTPUT="{blockdb}"), r"would overwrite",
             core=True),
        Case("blockdb-OUTPUT-onto-BLOCKS", U + "buildblockdatabase",
             dict(base["buildblockdatabase"], OUTPUT="{blocks}"), r"would overwrite",
             core=True),
        Case("hierarchy-OUTPUT-onto-INPUT-layer", U + "extractroadhierarchy",
             dict(base["extractroadhierarchy"],
                  OUTPUT="ogr:dbname='{streets_file}' table=\"streets\" (geom)"),
             r"would overwrite layer 'streets'", core=True),
        Case("hierarchy-OUTPUT-beside-INPUT-layer", U + "extractroadhierarchy",
             dict(base["extractroadhierarchy"], OUTPUT_INTERSECTIONS=None,
                  OUTPUT="ogr:dbname='{out}/both.gpkg' table=\"ranked\" (geom)"), None,
             check=_len_ok(10)),
        # data loss: partial outputs (StreetGAN wrote OUTPUT before failing on the raster)
        Case("gan-raster-read-only-no-partial", U + "synthesizeroadsgan",
             dict(base["synthesizeroadsgan"], OUTPUT_RASTER="{read_only}/image.tif"),
             r"Generator image.*cannot be (written|created)", core=True),
        Case("model-late-step-fails-no-partial", U + "synthesizedistrict", {
            "EXAMPLE_ROADS": "{streets}", "EXAMPLE_BUILDINGS": "{far}",
            "ARTERIALS": "{streets}", "ROAD_METHOD": 1, "FOOTPRINT_METHOD": 0, "SEED": 1,
            "roads:ROADS": "{out}/roads.gpkg", "blocks:BLOCKS": "{out}/blocks.gpkg",
            "parcels:PARCELS": "{out}/parcels.gpkg", "buildings:BUILDINGS": "{out}/b.gpkg",
            "streets:STREET_SURFACES": "{out}/s.gpkg", "streets:JUNCTIONS": "{out}/j.gpkg",
            "metrics:METRICS": "{out}/m.gpkg", "metrics:REPORT": "{out}/r.html"},
             r"Example block database: .*no building lies in one of the blocks"),
        # silent wrong results
        Case("blocks-HEIGHT_FIELD-text-ids", U + "extractblocks",
             dict(base["extractblocks"], BUILDINGS="{buildings_ids}", HEIGHT_FIELD="id_text"),
             r"HEIGHT_FIELD.*'id_text'.*numeric field is needed", core=True),
        Case("blocks-HEIGHT_FIELD-numeric", U + "extractblocks",
             dict(base["extractblocks"], BUILDINGS="{buildings_ids}", HEIGHT_FIELD="height_num"),
             None, check=_heights_plausible),
        Case("roads-gan-keeps-arterials", U + "synthesizeroads",
             {"METHOD": 2, "ARTERIALS": "{streets}", "SEED": 1, "OUTPUT": "{out}/roads.gpkg"},
             None, check=_arterials_kept, core=True),
        # StreetGAN measures the example roads it is held to: a shapefile's (multi-part)
        # lines were taken for points (TypeError, 2026-12-07)
        Case("roads-gan-multi-part-example", U + "synthesizeroads",
             {"METHOD": 2, "ARTERIALS": "{streets}", "EXAMPLE_ROADS": "{streets_multi}",
              "SEED": 1, "OUTPUT": "{out}/roads.gpkg"}, None, check=_len_ok(10), core=True),
        Case("roads-polygons-as-arterials", U + "synthesizeroads",
             {"METHOD": 2, "ARTERIALS": "{plots}", "OUTPUT": "{out}/roads.gpkg"},
             r"has polygons; lines are needed", core=True),
        Case("roads-fragments-without-example", U + "synthesizeroads",
             {"METHOD": 0, "ARTERIALS": "{streets}", "OUTPUT": "{out}/roads.gpkg"},
             r"needs a Fragment database"),
        Case("roads-empty-arterials-named", U + "synthesizeroads",
             {"METHOD": 1, "ARTERIALS": "{empty_lines}", "OUTPUT": "{out}/roads.gpkg"},
             r"empty_lines.*is empty"),
        Case("r2v-all-255", U + "rasterroadstovector",
             {"INPUT": "{all255}", "OUTPUT": "{out}/roads.gpkg"}, r"every pixel is above",
             core=True),
        Case("r2v-threshold-minus-1", U + "rasterroadstovector",
             {"INPUT": "{road_mask}", "THRESHOLD": -1, "OUTPUT": "{out}/roads.gpkg"},
             r"every pixel is above"),
        Case("r2v-no-crs", U + "rasterroadstovector",
             {"INPUT": "{mask_nocrs}", "OUTPUT": "{out}/roads.gpkg"},
             r"no coordinate reference system"),
        *[Case(f"grow-seed-{seed}", U + "growroads",
               dict(base["growroads"], SEED=seed), expect, core=seed == "2147483648")
          for seed, expect in (("2147483648", r"SEED.*out of range"),
                               ("9.3e18", r"SEED.*out of range"), ("1e30", r"out of range"),
                               ("1.5", r"SEED.*whole number"), ("-1", r"out of range"))],
        Case("metrics-study-area-elsewhere", U + "layoutmetrics",
             dict(base["layoutmetrics"], STUDY_AREA="{far}"), r"does not overlap", core=True),
        Case("parcels-noprj-shapefile", U + "subdivideparcels",
             {"BLOCKS": "{plots_noprj}", "OUTPUT": "{out}/p.gpkg"},
             r"no coordinate reference system"),
        # tracebacks and hangs
        Case("randomwalk-missing-BLEND_FIELD", U + "synthesizeroadsrandomwalk",
             dict(base["synthesizeroadsrandomwalk"], EXAMPLE_B="{streets}",
                  BLEND_FIELD="nope"), r"no field 'nope'", core=True),
        Case("splitdomain-400km", U + "splitdomain",
             dict(base["splitdomain"], REGION="{huge}"), r"more than", core=True),
        Case("randomwalk-400km", U + "synthesizeroadsrandomwalk",
             dict(base["synthesizeroadsrandomwalk"], TARGET="{huge}"), r"more than",
             core=True),
        Case("fragments-400km", U + "synthesizeroadsfromfragments",
             dict(base["synthesizeroadsfromfragments"], ARTERIALS="{huge_lines}"),
             r"more than"),
        Case("gan-400km", U + "synthesizeroadsgan",
             dict(base["synthesizeroadsgan"], TARGET="{huge}"), r"pixels"),
        Case("parcels-400km", U + "subdivideparcels",
             {"BLOCKS": "{huge}", "OUTPUT": "{out}/p.gpkg"}, r"more than"),
        Case("parts-400km", U + "synthesizepartbuildings",
             dict(base["synthesizepartbuildings"], SKELETON="{huge}", PARTS_LIBRARY=0),
             r"more than"),
        # unclear messages
        Case("splitdomain-speck-no-key-areas", U + "splitdomain",
             dict(base["splitdomain"], REGION="{speck}"), r"^(?!.*key area)"),
        # issue 14: corrupt databases and models, invalid rings, geographic input
        Case("footprints-corrupt-db", U + "synthesizefootprints",
             dict(base["synthesizefootprints"], BLOCK_DB="{corrupt_gpkg}"),
             r"Block database.*(not a|cannot|corrupt)", core=True),
        Case("footprints-not-a-db", U + "synthesizefootprints",
             dict(base["synthesizefootprints"], BLOCK_DB="{not_a_db}"),
             r"Block database.*not an Urban Synthesis example database"),
        Case("fragments-corrupt-db", U + "synthesizeroadsfromfragments",
             dict(base["synthesizeroadsfromfragments"], FRAGMENT_DB="{corrupt_gpkg}"),
             r"(not a|cannot|corrupt)"),
        Case("gan-corrupt-model", U + "synthesizeroadsgan",
             dict(base["synthesizeroadsgan"], MODEL_FILE="{corrupt_onnx}"),
             r"corrupt|cannot|card", core=True),
        Case("parcels-bowtie-blocks", U + "subdivideparcels",
             {"BLOCKS": "{bowties}", "OUTPUT": "{out}/p.gpkg"}, None, check=_len_ok(1)),
        Case("hierarchy-geographic", U + "extractroadhierarchy",
             dict(base["extractroadhierarchy"], INPUT="{streets_4326}"), None,
             check=_len_ok(20), core=True),
        Case("tessellate-tiny-lines", U + "tessellatestreets",
             dict(base["tessellatestreets"], ROADS="{tiny_lines}"),
             r"tiny_lines.*no road edges are left"),
    ]


def all_cases(registry) -> List[Case]:
    return specific_cases() + generic_cases(registry)


def with_file_keys(inputs: Dict[str, str]) -> Dict[str, str]:
    """'{name_file}': the file of every input (for outputs aimed at an input)."""
    out = dict(inputs)
    for key, value in inputs.items():
        out[f"{key}_file"] = value.split("|")[0]
    return out
