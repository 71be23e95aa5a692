"""Runs that take several seconds, one per algorithm, and a feedback that cancels after
0.5 s: how long each algorithm takes to stop (issue 22: within 1 s everywhere).

Used by tests/test_cancel.py (which asserts on the processor time spent after the cancel,
not on wall-clock time, so that a loaded machine does not fail it) and by
tests/benchmarks/bench_cancel.py (which prints wall and processor times).
"""
from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Dict

import numpy as np

from conftest import BUBENEC, HELSINKI

CANCEL_AFTER_S = 0.5


#: Progress (%) at which the run is canceled if the timer has not fired yet: a fast machine
#: cannot finish a run before the cancel.
CANCEL_AT_PROGRESS = 40.0


def canceling_feedback(after: float = CANCEL_AFTER_S, at_progress: float = CANCEL_AT_PROGRESS):
    """A QgsProcessingFeedback that cancels itself ``after`` seconds once started or when the
    run reports ``at_progress`` %, whichever comes first, and records the wall and processor
    clocks at that moment."""
    from qgis.core import QgsProcessingFeedback

    class Canceling(QgsProcessingFeedback):
        def __init__(self):
            super().__init__()
            self.cpu_at_cancel = self.wall_at_cancel = None
            self.timer = threading.Timer(after, self._cancel)
            self._lock = threading.Lock()

        def setProgress(self, progress):  # noqa: N802 (QGIS API)
            super().setProgress(progress)
            if progress >= at_progress:
                self._cancel()

        def _cancel(self):
            with self._lock:
                if self.cpu_at_cancel is not None:
                    return
                self.cpu_at_cancel = time.process_time()
                self.wall_at_cancel = time.monotonic()
            self.cancel()

    return Canceling()


def heavy_inputs(processing, folder: Path) -> Dict[str, str]:
    """Inputs that keep each algorithm busy for seconds (Helsinki, a 5 km² target ...)."""
    from osgeo import gdal, ogr, osr

    folder.mkdir(parents=True, exist_ok=True)
    lines = f"{HELSINKI}|layername=lines"
    out = {"lines": lines, "multipolygons": f"{HELSINKI}|layername=multipolygons",
           "plots": f"{BUBENEC}|layername=plots", "streets": f"{BUBENEC}|layername=streets"}
    run = processing.run
    out["hierarchy"] = run("urbansynth:extractroadhierarchy", {
        "INPUT": lines, "OUTPUT": str(folder / "hierarchy.gpkg"),
        "OUTPUT_INTERSECTIONS": str(folder / "points.gpkg")})["OUTPUT"]
    out["intersections"] = str(folder / "points.gpkg")
    res = run("urbansynth:extractblocks", {
        "ROADS": lines, "BUILDINGS": out["multipolygons"], "OUTPUT": str(folder / "blocks.gpkg"),
        "OUTPUT_BUILDINGS": str(folder / "buildings.gpkg")})
    out["blocks"], out["buildings"] = res["OUTPUT"], res["OUTPUT_BUILDINGS"]
    out["blockdb"] = run("urbansynth:buildblockdatabase", {
        "BLOCKS": out["blocks"], "BUILDINGS": out["buildings"],
        "OUTPUT": str(folder / "blockdb.gpkg")})["OUTPUT"]
    out["fragdb"] = run("urbansynth:buildfragmentdatabase", {
        "ROADS": out["hierarchy"], "OUTPUT": str(folder / "fragdb.gpkg")})["OUTPUT"]
    out["arterials"] = run("native:extractbyattribute", {
        "INPUT": out["hierarchy"], "FIELD": "level", "OPERATOR": 0, "VALUE": "0",
        "OUTPUT": str(folder / "arterials.gpkg")})["OUTPUT"]
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32635)
    path = folder / "areas.gpkg"
    ds = ogr.GetDriverByName("GPKG").CreateDataSource(str(path))
    x0, y0 = 385000.0, 6671000.0
    for name, side in (("district", 1200.0), ("town", 2500.0), ("city", 6000.0)):
        lyr = ds.CreateLayer(name, srs, ogr.wkbPolygon)
        feat = ogr.Feature(lyr.GetLayerDefn())
        feat.SetGeometry(ogr.CreateGeometryFromWkt(
            f"POLYGON (({x0} {y0}, {x0 + side} {y0}, {x0 + side} {y0 + side}, "
            f"{x0} {y0 + side}, {x0} {y0}))"))
        lyr.CreateFeature(feat)
        out[name] = f"{path}|layername={name}"
    lyr = ds.CreateLayer("skeletons", srs, ogr.wkbPolygon)
    for k in range(12):
        feat = ogr.Feature(lyr.GetLayerDefn())
        x = x0 + 100 * k
        feat.SetGeometry(ogr.CreateGeometryFromWkt(
            f"POLYGON (({x} {y0}, {x + 62} {y0}, {x + 62} {y0 + 48}, {x} {y0 + 48}, "
            f"{x} {y0}))"))
        lyr.CreateFeature(feat)
    out["skeletons"] = f"{path}|layername=skeletons"
    ds = None
    # a 4000 x 4000 px road grid raster
    grid = np.zeros((4000, 4000), dtype=np.uint8)
    for k in range(20, 4000, 40):
        grid[k:k + 4, :] = 255
        grid[:, k:k + 4] = 255
    drv = gdal.GetDriverByName("GTiff")
    ds = drv.Create(str(folder / "grid.tif"), 4000, 4000, 1, gdal.GDT_Byte)
    ds.SetGeoTransform((x0, 3.0, 0, y0 + 12000, 0, -3.0))
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(grid)
    ds = None
    out["grid"] = str(folder / "grid.tif")
    return out


#: Per algorithm (or the model): parameters of a run that takes seconds; '{out}' outputs.
RUNS = {
    "extractroadhierarchy": {"INPUT": "{lines}", "OUTPUT": "{out}/r.gpkg"},
    "extractblocks": {"ROADS": "{lines}", "BUILDINGS": "{multipolygons}",
                      "OUTPUT": "{out}/b.gpkg", "OUTPUT_BUILDINGS": "{out}/bb.gpkg"},
    "buildblockdatabase": {"BLOCKS": "{blocks}", "BUILDINGS": "{buildings}",
                           "OUTPUT": "{out}/db.gpkg"},
    "buildfragmentdatabase": {"ROADS": "{hierarchy}", "OUTPUT": "{out}/db.gpkg"},
    "layoutmetrics": {"ROADS": "{hierarchy}", "BUILDINGS": "{buildings}",
                      "EXAMPLE_ROADS": "{lines}", "OUTPUT": "{out}/m.gpkg",
                      "OUTPUT_HTML": "{out}/m.html"},
    "growroads": {"BOUNDARY": "{city}", "OUTPUT": "{out}/g.gpkg"},
    "subdivideparcels": {"BLOCKS": "{blocks}", "MAX_AREA": 300, "OUTPUT": "{out}/p.gpkg"},
    "synthesizeroadsfromfragments": {"ARTERIALS": "{arterials}", "FRAGMENT_DB": "{fragdb}",
                                     "N_BEST": 3, "OUTPUT": "{out}/f.gpkg"},
    "tessellatestreets": {"ROADS": "{lines}", "OUTPUT_SURFACES": "{out}/s.gpkg",
                          "OUTPUT_JUNCTIONS": "{out}/j.gpkg"},
    "synthesizeroadsgan": {"TARGET": "{city}", "OUTPUT": "{out}/gan.gpkg"},
    "rasterroadstovector": {"INPUT": "{grid}", "OUTPUT": "{out}/r2v.gpkg"},
    "synthesizebuildingattributes": {"FOOTPRINTS": "{buildings}",
                                     "EXAMPLE_BUILDINGS": "{multipolygons}",
                                     "ROADS": "{lines}", "EXAMPLE_ROADS": "{lines}",
                                     "OUTPUT": "{out}/a.gpkg"},
    "placelibrarybuildings": {"PARCELS": "{plots}", "ROADS": "{streets}",
                              "OUTPUT": "{out}/lib.gpkg"},
    "synthesizepartbuildings": {"SKELETON": "{skeletons}", "PARTS_FAR_MIN": 1.0,
                                "PARTS_FAR_MAX": 3.0, "K_SOLUTIONS": 5,
                                "OUTPUT": "{out}/parts.gpkg"},
    "synthesizeroadsrandomwalk": {"EXAMPLE": "{intersections}", "TARGET": "{city}",
                                  "OUTPUT": "{out}/rw.gpkg"},
    "synthesizefootprints": {"BLOCKS": "{blocks}", "BLOCK_DB": "{blockdb}", "METHOD": 1,
                             "OUTPUT": "{out}/fp.gpkg"},
    "splitdomain": {"REGION": "{town}", "OUTPUT_ROADS": "{out}/sr.gpkg",
                    "OUTPUT_PARCELS": "{out}/sp.gpkg"},
    "synthesizeroads": {"METHOD": 1, "ARTERIALS": "{arterials}", "BOUNDARY": "{city}",
                        "OUTPUT": "{out}/sr.gpkg"},
    "synthesizeaerialimage": {"PARCELS": "{plots}",
                              "EXAMPLE_IMAGE": str(Path(str(BUBENEC)).parent
                                                   / "atlanta_pan_0.5m.tif"),
                              "EXAMPLE_PARCELS": str(Path(str(BUBENEC)).parent
                                                     / "atlanta_buildings.geojson"),
                              "PIXEL_SIZE": 0.25, "OUTPUT_IMAGE": "{out}/image.tif"},
    "synthesizedistrict": {"EXAMPLE_ROADS": "{streets}",
                           "EXAMPLE_BUILDINGS": f"{BUBENEC}|layername=buildings",
                           "ARTERIALS": "{streets}", "ROAD_METHOD": 0, "FOOTPRINT_METHOD": 1,
                           "roads:ROADS": "{out}/d.gpkg", "blocks:BLOCKS": "{out}/db.gpkg",
                           "parcels:PARCELS": "{out}/dp.gpkg",
                           "buildings:BUILDINGS": "{out}/dbb.gpkg",
                           "streets:STREET_SURFACES": "{out}/ds.gpkg",
                           "streets:JUNCTIONS": "{out}/dj.gpkg",
                           "metrics:METRICS": "{out}/dm.gpkg", "metrics:REPORT": "{out}/d.html"},
}


def cancel_run(processing, alg_id: str, inputs: Dict[str, str], out: Path,
               after: float = CANCEL_AFTER_S):
    """Run one algorithm with a feedback that cancels after ``after`` s. Returns a dict: finished
    (it ended before the cancel), message, cpu_s / wall_s spent after the cancel, written
    (files left in ``out``)."""
    from qgis.core import QgsProcessingException

    out.mkdir(parents=True, exist_ok=True)
    params = {}
    for key, value in RUNS[alg_id].items():
        if isinstance(value, str):
            for name, path in inputs.items():
                value = value.replace("{" + name + "}", path)
            value = value.replace("{out}", str(out))
        params[key] = value
    feedback = canceling_feedback(after)
    message = None
    feedback.timer.start()
    try:
        processing.run(f"urbansynth:{alg_id}", params, feedback=feedback)
    except QgsProcessingException as exc:
        message = str(exc)
    cpu, wall = time.process_time(), time.monotonic()
    feedback.timer.cancel()
    finished = feedback.cpu_at_cancel is None
    return {"finished": finished, "message": message,
            "cpu_s": None if finished else cpu - feedback.cpu_at_cancel,
            "wall_s": None if finished else wall - feedback.wall_at_cancel,
            "written": sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())}
