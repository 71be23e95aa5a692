"""Many part-based buildings at once: one per skeleton, with its site, its FAR bounds and
the count constraints of a whole layer.

:mod:`parts` builds one building (the k best part sequences of one skeleton, Hartmann
thesis ch. 6); a layer of skeletons needs the rest, which lives here so that the
Processing algorithm stays a thin adapter:

- :func:`parse_counts`: the count constraints of the dialog, ``'corner=4; doors=2..6'``;
- :func:`far_bounds`: an exact target FAR, or an interval, never both;
- :func:`site_areas`: the site of each building, the block holding most of its skeleton
  (thesis ch. 6: the FAR refers to the plot the building stands on);
- :func:`build_buildings`: every skeleton's building, infeasible ones reported, not fatal.

Nothing here imports QGIS.

Examples
--------
>>> library = parts.terrace_library(infill=False)
>>> parse_counts("corner=4; doors=2..6", library)
{'corner': (4.0, 4.0), 'doors': (2.0, 6.0)}
>>> far_bounds(0.0, 1.0, 0.0)
(1.0, inf)
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import pandas as pd
import shapely

from ..core.progress import InputError, Progress, ensure
from . import parts

__all__ = ["OUTPUT_FIELDS", "parse_counts", "far_bounds", "site_areas", "BuildingsResult",
           "build_buildings"]

#: The output table: :attr:`parts.PartsResult.table` with the building each part belongs to.
OUTPUT_FIELDS = [("building_id", "int"), ("solution", "int"), ("cost", "float"),
                 ("seq_index", "int"), ("part_id", "str"), ("kind", "str"),
                 ("start_m", "float"), ("length_m", "float"), ("base_m", "float"),
                 ("top_m", "float"), ("height_m", "float"), ("levels", "int"),
                 ("floor_area_m2", "float"), ("building_floor_area_m2", "float"),
                 ("building_far", "float")]

_COUNT = re.compile(r"([^=\s]+)\s*=\s*(\d+(?:\.\d*)?)\s*(?:\.\.\s*(\d+(?:\.\d*)?))?")


def parse_counts(text: Optional[str], library: parts.PartsLibrary,
                 label: str = "the parts") -> Dict[str, Tuple[float, float]]:
    """Count constraints per building from ``'name=n'`` or ``'name=lo..hi'`` items
    separated by ';' or ','; a name is a part kind or a numeric field of the library.

    Raises
    ------
    InputError
        For an item that is not of that form, lo > hi, or an unknown name.
    """
    counts = {}
    for item in filter(None, (s.strip() for s in re.split(r"[;,]", text or ""))):
        m = _COUNT.fullmatch(item)
        if not m:
            raise InputError(f"count constraint '{item}' is not 'name=n' or 'name=lo..hi'")
        name, lo = m.group(1), float(m.group(2))
        hi = float(m.group(3)) if m.group(3) else lo
        if hi < lo:
            raise InputError(f"count constraint '{item}': {hi:g} < {lo:g}")
        if name not in parts.PART_KINDS and name not in library.table:
            raise InputError(f"count constraint on '{name}': neither a part kind "
                             f"({', '.join(parts.PART_KINDS)}) nor a field of {label}")
        counts[name] = (lo, hi)
    return counts


def far_bounds(target: float, lo: float, hi: float):
    """The FAR constraint of every building: ``target`` (exact, > 0), or the interval
    [lo, hi] (0 = unbounded), or None without any; giving both is an error."""
    if target > 0 and (lo > 0 or hi > 0):
        raise InputError("give either a Target FAR (exact) or a minimum / maximum FAR, "
                         "not both")
    if hi > 0 and hi < lo:
        raise InputError(f"the maximum FAR ({hi:g}) is below the minimum ({lo:g})")
    if target > 0:
        return target
    if lo > 0 or hi > 0:
        return lo, hi if hi > 0 else np.inf
    return None


def site_areas(skeletons: Sequence, blocks: Optional[Sequence] = None) -> np.ndarray:
    """The site area of each skeleton: the block holding most of it (1 m around it), else
    the skeleton's own polygon area (NaN for a line outside every block).

    >>> site_areas([shapely.box(0, 0, 10, 10), shapely.LineString([(0, 0), (5, 0)])]).tolist()
    [100.0, nan]
    >>> site_areas([shapely.LineString([(1, 1), (5, 1)])], [shapely.box(0, 0, 20, 20)]).tolist()
    [400.0]
    """
    skeletons = np.asarray(skeletons, dtype=object)
    area = np.where(shapely.get_type_id(skeletons) == 3, shapely.area(skeletons), np.nan)
    if blocks is None or len(blocks) == 0:
        return area
    blocks = np.asarray(blocks, dtype=object)
    probe = shapely.buffer(skeletons, 1.0)
    i, j = shapely.STRtree(blocks).query(probe, predicate="intersects")
    if len(i):
        share = shapely.area(shapely.intersection(probe[i], blocks[j]))
        best = pd.DataFrame({"i": i, "j": j, "s": share}).sort_values("s").groupby("i").last()
        area[best.index.to_numpy()] = shapely.area(blocks[best["j"].to_numpy()])
    return area


@dataclass
class BuildingsResult:
    """Parts of every building made: ``geometry`` (PolygonZ at each part's base) and
    ``table`` (:data:`OUTPUT_FIELDS`); ``failed``: (building id, reason) of the
    skeletons no part sequence fits."""

    geometry: np.ndarray
    table: pd.DataFrame
    failed: List[Tuple[int, str]] = field(default_factory=list)


def build_buildings(skeletons: Sequence, building_ids: Sequence[int], fronts: Sequence[str],
                    library: parts.PartsLibrary, *, tower_height: Optional[float] = None,
                    site_area: Optional[np.ndarray] = None, far=None, floor_area=None,
                    counts=None, k: int = 1, corner_tolerance: float = parts.CORNER_TOLERANCE,
                    area_resolution: float = parts.AREA_QUANTUM,
                    progress: Optional[Progress] = None) -> BuildingsResult:
    """One building of parts per skeleton (:func:`parts.build_along_skeleton`, or
    :func:`parts.stack_floors` on the skeleton polygon as site when ``tower_height`` is
    given).

    A skeleton without a feasible sequence is reported in ``failed`` and the others are
    built; when none is feasible, the first reason is raised. Cancellation (progress)
    stops between and inside buildings.
    """
    progress = ensure(progress)
    skeletons = np.asarray(skeletons, dtype=object)
    n = len(skeletons)
    site_area = np.full(n, np.nan) if site_area is None else np.asarray(site_area, float)
    if far is not None and not np.isfinite(site_area).all():
        raise InputError("a FAR needs a site for every building: give blocks (the block "
                         "holding each skeleton line is its site) or polygon skeletons")
    options = dict(far=far, floor_area=floor_area, counts=counts or {}, k=k,
                   area_resolution=area_resolution)
    geoms, tables, failed = [], [], []
    for i, (skeleton, bid, front) in enumerate(zip(skeletons, building_ids, fronts)):
        sub = progress.sub(i / n, (i + 1) / n)
        sub.step(0.0)
        site = float(site_area[i]) if np.isfinite(site_area[i]) else None
        try:
            if tower_height is not None:
                result = parts.stack_floors(library, tower_height, site=skeleton,
                                            site_area=site, progress=sub, **options)
            else:
                result = parts.build_along_skeleton(
                    skeleton, library, front=front, site_area=site,
                    corner_tolerance=corner_tolerance, progress=sub, **options)
        except InputError as err:      # infeasible: the others are still built
            failed.append((int(bid), str(err)))
            continue
        table = result.table.copy()
        summary = result.summary.set_index("solution").loc[table["solution"]]
        table.insert(0, "building_id", int(bid))
        table["building_floor_area_m2"] = summary["floor_area_m2"].to_numpy()
        table["building_far"] = summary["far"].to_numpy()
        geoms.append(np.array([shapely.force_3d(g, z) for g, z in
                               zip(result.geometry, table["base_m"].to_numpy(float))],
                              dtype=object))
        tables.append(table)
    if not tables:
        bid, reason = failed[0] if failed else (None, "no skeleton")
        raise InputError(f"no building could be made (building {bid}: {reason})")
    table = pd.concat(tables, ignore_index=True)[[name for name, _ in OUTPUT_FIELDS]]
    return BuildingsResult(np.concatenate(geoms), table, failed)
