"""Block extraction against momepy's block generation, on the same roads.

``bench_block_extraction(lines)`` times, on the same street centrelines (a metric CRS):

- ours: :func:`blocks.extract_blocks` on the street graph that ``extractblocks`` hands it
  (the lines as a :class:`roads.RoadGraph`): faces, sliver filter, shape measures, dead
  ends. This is the block step of the algorithm;
- ours from lines: the same from the bare lines, noding included (the same input momepy
  gets: nothing known about the lines);
- ours with cleaning: :func:`roads.clean_network` + the block step, i.e. everything the
  ``extractblocks`` algorithm does between reading and writing its layers;
- momepy's ``enclosures``: the momepy function that does the same thing (polygonize the
  union of the barrier lines: the faces of the street network, no sliver filter, no
  measures);
- optionally (``buildings`` given) momepy's ``generate_blocks`` and the morphological
  tessellation it needs: momepy's "blocks" are tessellation cells of buildings dissolved
  within the street faces, a different and much heavier product.

Each time is the best of several runs after one warm-up run (small inputs are repeated
for about a second: single runs of a few milliseconds are noisy on a shared machine).
Run this file to print the Helsinki and the 10 x 10 tiled Helsinki numbers.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT / "build" / "plugins") not in sys.path:
    sys.path.insert(0, str(ROOT / "build" / "plugins"))

from urban_synthesis.plugin.network import blocks  # noqa: E402
from urban_synthesis.plugin.network import street_graph as roads  # noqa: E402

__all__ = ["bench_block_extraction", "tile_lines", "helsinki_drivable_lines"]


def _best(fn, repeat, budget_s: float = 1.0):
    """Best time of at least ``repeat`` runs after a warm-up run.

    Runs of a few milliseconds are repeated until ``budget_s`` is spent (at most 200
    times): on a shared 2-core machine single runs of small inputs vary by 2x.
    """
    fn()  # warm-up (imports, caches)
    times = []
    spent = 0.0
    while len(times) < repeat or (spent < budget_s and len(times) < 200):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
        spent += times[-1]
    return min(times), out


def tile_lines(lines, nx: int = 10, ny: int = 10) -> np.ndarray:
    """Copies of ``lines`` translated by the size of their bounding box, nx x ny times."""
    lines = np.asarray(lines, dtype=object)
    x0, y0, x1, y1 = shapely.total_bounds(lines)
    w, h = x1 - x0, y1 - y0
    return np.concatenate([shapely.transform(lines, lambda c, i=i, j=j: c + [i * w, j * h])
                           for i in range(nx) for j in range(ny)])


def helsinki_drivable_lines(crs: int = 32635, clean: bool = False) -> np.ndarray:
    """The drivable Helsinki road lines (raw OSM ways, or the cleaned graph's edges)."""
    import pyogrio

    df = pyogrio.read_dataframe(ROOT / "data" / "examples" / "Helsinki.osm.pbf", layer="lines")
    df = df[df.highway.isin(roads.DRIVABLE_CLASSES)].to_crs(crs)
    if not clean:
        return df.geometry.values
    return roads.clean_network(df.geometry.values, df.highway.values,
                               merge_degree2=False).geometry


def bench_block_extraction(lines, buildings=None, repeat: int = 3, crs=None) -> dict:
    """Time our block extraction and momepy's block generation on the same roads.

    Parameters
    ----------
    lines : array of LineString, GeoSeries or GeoDataFrame
        Road centrelines in a metric CRS: raw drivable OSM lines, the cleaned Helsinki
        edges, or a tiling of them (:func:`tile_lines`). They are cleaned once with
        :func:`roads.clean_network` (as ``extractblocks`` does); both sides then get the
        cleaned edges: ours as the street graph, momepy as a GeoDataFrame.
    buildings : array of Polygon, optional
        When given, momepy's ``generate_blocks`` (with the morphological tessellation it
        needs) is timed too, once (it takes seconds).
    repeat : int
        Best of at least this many runs (more for runs of a few milliseconds).
    crs : optional
        CRS for the GeoDataFrame handed to momepy (taken from ``lines`` when it has one).

    Returns
    -------
    dict
        ``n_lines`` (input), ``n_edges`` (cleaned), ``n_blocks``, ``n_faces``, ``ours_s``
        (graph -> blocks), ``ours_from_lines_s`` (cleaned edges as bare lines -> blocks,
        noding included), ``ours_with_cleaning_s`` (input lines -> clean_network -> blocks),
        ``momepy_enclosures_s``, ``momepy_n_enclosures``, ``ratio`` (momepy enclosures /
        ours), ``ratio_from_lines``, ``ratio_with_cleaning``, ``momepy_version``; with
        buildings also ``momepy_tessellation_s``, ``momepy_generate_blocks_s``,
        ``momepy_n_blocks``. Without momepy, ``momepy_version`` is None and its entries are
        absent.
    """
    if hasattr(lines, "geometry"):
        crs = crs if crs is not None else getattr(lines, "crs", None)
        lines = lines.geometry.values
    lines = np.asarray(lines, dtype=object)
    # the graph extractblocks hands to the block step
    graph = roads.clean_network(lines, merge_degree2=False)
    edges = graph.geometry
    out = {"n_lines": len(lines), "n_edges": len(edges)}
    out["ours_s"], result = _best(lambda: blocks.extract_blocks(graph), repeat)
    out["n_blocks"], out["n_faces"] = len(result.geometry), result.stats["n_faces"]
    out["ours_from_lines_s"], _ = _best(lambda: blocks.extract_blocks(edges), repeat)
    out["ours_with_cleaning_s"], _ = _best(
        lambda: blocks.extract_blocks(roads.clean_network(lines, merge_degree2=False)), repeat)
    try:
        import geopandas as gpd
        import momepy
    except ImportError:
        out["momepy_version"] = None
        return out
    out["momepy_version"] = momepy.__version__
    streets = gpd.GeoDataFrame(geometry=edges, crs=crs)
    out["momepy_enclosures_s"], enc = _best(lambda: momepy.enclosures(streets), repeat)
    out["momepy_n_enclosures"] = len(enc)
    out["ratio"] = out["momepy_enclosures_s"] / out["ours_s"]
    out["ratio_from_lines"] = out["momepy_enclosures_s"] / out["ours_from_lines_s"]
    out["ratio_with_cleaning"] = out["momepy_enclosures_s"] / out["ours_with_cleaning_s"]
    if buildings is not None:
        b = gpd.GeoDataFrame(geometry=np.asarray(buildings, dtype=object), crs=crs)
        b = b.explode(ignore_index=True)
        b = b[b.geom_type == "Polygon"].reset_index(drop=True)
        t0 = time.perf_counter()
        tessellation = momepy.morphological_tessellation(b)
        t1 = time.perf_counter()
        generated, _ = momepy.generate_blocks(tessellation, streets, b)
        t2 = time.perf_counter()
        out["momepy_tessellation_s"] = t1 - t0
        out["momepy_generate_blocks_s"] = t2 - t1
        out["momepy_n_blocks"] = len(generated)
    return out


def _print(label, r):
    print(f"{label}: {r['n_lines']} lines, {r['n_edges']} cleaned edges -> {r['n_blocks']} "
          f"blocks ({r['n_faces']} faces)")
    print(f"  ours (graph -> blocks)          {r['ours_s'] * 1000:9.1f} ms")
    print(f"  ours from bare lines (noding)   {r['ours_from_lines_s'] * 1000:9.1f} ms")
    print(f"  ours incl. clean_network        {r['ours_with_cleaning_s'] * 1000:9.1f} ms")
    if r.get("momepy_version"):
        print(f"  momepy {r['momepy_version']} enclosures         "
              f"{r['momepy_enclosures_s'] * 1000:9.1f} ms ({r['momepy_n_enclosures']} faces)")
        print(f"  ratio momepy / ours: {r['ratio']:.1f}x (from lines {r['ratio_from_lines']:.1f}x, "
              f"incl. cleaning {r['ratio_with_cleaning']:.1f}x)")
        if "momepy_generate_blocks_s" in r:
            print(f"  momepy tessellation + generate_blocks "
                  f"{r['momepy_tessellation_s']:.2f} s + {r['momepy_generate_blocks_s']:.2f} s "
                  f"({r['momepy_n_blocks']} blocks)")


if __name__ == "__main__":
    import warnings

    warnings.filterwarnings("ignore")
    import pyogrio

    lines = helsinki_drivable_lines()
    mp = pyogrio.read_dataframe(ROOT / "data" / "examples" / "Helsinki.osm.pbf",
                                layer="multipolygons", on_invalid="ignore")
    mp = mp[mp.building.notna() & mp.geometry.notna()].to_crs(32635)
    helsinki = bench_block_extraction(lines, shapely.make_valid(mp.geometry.values), repeat=5,
                                      crs=32635)
    _print("Helsinki", helsinki)
    tiled = bench_block_extraction(tile_lines(helsinki_drivable_lines(clean=True)), repeat=2,
                                   crs=32635)
    _print("Helsinki tiled 10 x 10", tiled)
    growth = tiled["ours_s"] / helsinki["ours_s"]
    print(f"  growth for {tiled['n_edges'] / helsinki['n_edges']:.0f}x the edges: "
          f"{growth:.0f}x ({growth / 100:.2f}x linear)")
