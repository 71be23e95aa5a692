"""Building attributes by example: height, levels, type and roof from similar buildings.

Hartmann's thesis (ch. 4.1.2, 5.1, 6) attaches semantics to example footprints (building
heights, density, style) and carries them over to synthesised layouts; its block
database stores them with each footprint. This module assigns ``height_m``, ``levels``,
``building_type`` and ``roof_shape`` to any footprint (synthesised or real) by copying
them from the most similar example building:

1. **Features** (:func:`footprint_features`) describe a footprint by its shape (log area,
   compactness 4πA/P², elongation of the minimum rotated rectangle) and its context:
   the coverage of footprints within 50 m and 150 m (a block-density proxy that needs
   no blocks), the mean log area of the neighbours within 100 m (the grain of the
   district), when roads are given on both sides the distance to the nearest road and to
   the nearest arterial, and, where example buildings with heights lie around a footprint
   (real footprints with gaps), the mean log height of the 6 nearest within 150 m
   (:func:`neighbour_height`, the context a block median uses, without blocks).
2. **Matching** (:func:`transfer_attributes`): features are standardised by the
   donors' spread and weighted (:data:`FEATURE_WEIGHTS`), the ``k`` nearest examples
   with a known height are found with a ``scipy.spatial.cKDTree`` and one of them is the
   donor: ``medoid`` (default) takes the candidate with the similarity-weighted median
   height, a real example's value with the error of a median; ``random`` draws one with
   weights ``exp(-d² / 2h²)`` (``h`` the median distance of the k), so that height and
   type histograms keep the example's spread. The donor's id is ``source_id``,
   ``similarity = 1 / (1 + d)`` (d the weighted feature distance). Every attribute comes
   from the one donor, so height, type and roof stay consistent.
3. **Constraints**: heights are clipped to ``[min_height, max_height]`` (levels follow
   at the donor's storey height) and an optional target floor-area ratio (FAR = Σ
   footprint area x levels / ground area) per block or for the whole district is met by
   scaling levels and then adding or removing single storeys on the largest footprints
   (:func:`meet_far`).

Nothing here imports QGIS; geometry is in a metric CRS.

References
----------
Hartmann, S. (2017). Example-based urban modeling (thesis), ch. 4.1.2 (block database with
    building semantics), ch. 6 (building synthesis; FAR = floor area / ground area).
docs/ARCHITECTURE.md, "Real example data": OSM heights are sparse (165 of ~490 Helsinki buildings).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence

import numpy as np
import pandas as pd
import shapely
from scipy import sparse
from scipy.spatial import cKDTree

from ..core.geometry import minimum_rectangles
from ..core.progress import InputError, Progress, ensure
from .attributes import STOREY_HEIGHT

__all__ = ["FEATURE_NAMES", "OUTPUT_FIELDS", "AttributeTransfer", "footprint_features",
           "transfer_attributes", "meet_far", "neighbour_height", "block_median_baseline",
           "CONTEXT_RADIUS", "DonorModel", "donor_model", "target_features", "match_attributes"]

#: Radii (m) of the context features.
COVERAGE_RADII = (50.0, 150.0)
GRAIN_RADIUS = 100.0
#: Feature names in the order of :func:`footprint_features` columns.
FEATURE_NAMES = ("log_area", "compactness", "elongation", "coverage_50", "coverage_150",
                 "grain_100", "road_distance", "arterial_distance")
#: Relative weights of the features after standardisation (area and density first).
FEATURE_WEIGHTS = {"log_area": 1.5, "compactness": 0.5, "elongation": 0.5, "coverage_50": 1.0,
                   "coverage_150": 1.0, "grain_100": 1.0, "road_distance": 0.5,
                   "arterial_distance": 1.0, "neighbour_height": 3.0}
#: Neighbour heights: the ``NEIGHBOURS`` nearest example buildings with a height within
#: ``NEIGHBOUR_RADIUS`` m (the context a block median uses, without needing blocks).
NEIGHBOURS = 6
NEIGHBOUR_RADIUS = 150.0
#: Output columns with their types.
OUTPUT_FIELDS = [("height_m", "float"), ("levels", "int"), ("building_type", "str"),
                 ("roof_shape", "str"), ("source_id", "int"), ("similarity", "float"),
                 ("floor_area_m2", "float"), ("height_given", "bool")]


@dataclass
class AttributeTransfer:
    """Result of :func:`transfer_attributes`.

    table : DataFrame with :data:`OUTPUT_FIELDS`, one row per target footprint
    stats : dict of counts and achieved FARs
    """

    table: pd.DataFrame
    stats: Dict[str, float] = field(default_factory=dict)


def _polygons(geoms, what: str) -> np.ndarray:
    geoms = np.asarray(geoms, dtype=object)
    if len(geoms) == 0:
        raise InputError(f"no {what}")
    ok = np.isin(shapely.get_type_id(geoms), (3, 6)) & ~shapely.is_empty(geoms)
    if not ok.all():
        raise InputError(f"{int((~ok).sum())} of the {what} are not polygons")
    return geoms


def _coverage(centres: np.ndarray, tree_pts: np.ndarray, weights: np.ndarray, radius: float,
              tree: cKDTree, query_tree: cKDTree) -> np.ndarray:
    """Sum of ``weights`` of the points within ``radius`` of each centre (sparse matrix)."""
    m = query_tree.sparse_distance_matrix(tree, radius, output_type="ndarray")
    # pairs at distance 0 (a footprint with itself) are listed too: count pairs, not values
    near = sparse.csr_matrix((np.ones(len(m)), (m["i"], m["j"])),
                             shape=(len(centres), len(tree_pts)))
    out = near @ weights
    return out


def footprint_features(footprints, context=None, roads=None, arterials=None) -> pd.DataFrame:
    """Shape and context features of footprints (one row each, :data:`FEATURE_NAMES`).

    Parameters
    ----------
    footprints : array of Polygon / MultiPolygon (metric CRS)
    context : array of polygons, optional
        All buildings around them (default: the footprints themselves); coverage and
        grain are measured on these.
    roads, arterials : arrays of lines, optional
        Without them ``road_distance`` / ``arterial_distance`` are NaN.

    Returns
    -------
    DataFrame
        ``log_area`` (ln m²), ``compactness`` (4πA/P², 1 for a disc), ``elongation``
        (short / long side of the minimum rotated rectangle), ``coverage_50`` and
        ``coverage_150`` (footprint area with its centroid within the radius / disc
        area), ``grain_100`` (mean log area of those within 100 m), ``road_distance``
        and ``arterial_distance`` (ln(1 + m)).
    """
    fp = np.asarray(footprints, dtype=object)
    ctx = fp if context is None else np.asarray(context, dtype=object)
    area = shapely.area(fp)
    perim = shapely.length(fp)
    # vectorised rotating calipers (shapely's oriented_envelope is a Python loop on GEOS 3.11)
    length, width, _ = minimum_rectangles(fp)
    side = np.column_stack([length, width])
    with np.errstate(divide="ignore", invalid="ignore"):
        elong = np.where(side.max(1) > 0, side.min(1) / side.max(1), 1.0)
        compact = np.where(perim > 0, 4 * math.pi * area / perim ** 2, 0.0)
    c_fp = shapely.get_coordinates(shapely.centroid(fp))
    c_ctx = shapely.get_coordinates(shapely.centroid(ctx))
    a_ctx = shapely.area(ctx)
    t_ctx, t_fp = cKDTree(c_ctx), cKDTree(c_fp)
    out = {"log_area": np.log(np.maximum(area, 1.0)), "compactness": compact,
           "elongation": elong}
    for r in COVERAGE_RADII:
        out[f"coverage_{int(r)}"] = _coverage(c_fp, c_ctx, a_ctx, r, t_ctx, t_fp) / (math.pi * r * r)
    la = np.log(np.maximum(a_ctx, 1.0))
    s = _coverage(c_fp, c_ctx, la, GRAIN_RADIUS, t_ctx, t_fp)
    n = _coverage(c_fp, c_ctx, np.ones(len(ctx)), GRAIN_RADIUS, t_ctx, t_fp)
    out["grain_100"] = np.where(n > 0, s / np.maximum(n, 1), out["log_area"])
    for name, lines in (("road_distance", roads), ("arterial_distance", arterials)):
        if lines is None or len(lines) == 0:
            out[name] = np.full(len(fp), np.nan)
        else:
            lines = np.asarray(lines, dtype=object)
            _, d = shapely.STRtree(lines).query_nearest(fp, return_distance=True,
                                                        all_matches=False)
            out[name] = np.log1p(d)
    return pd.DataFrame(out, columns=list(FEATURE_NAMES))


def neighbour_height(centres: np.ndarray, heights: np.ndarray,
                     donor_centres: np.ndarray) -> np.ndarray:
    """Mean log height of the :data:`NEIGHBOURS` nearest example buildings with a height
    within :data:`NEIGHBOUR_RADIUS` of each centre; NaN where there is none. A building at
    the centre itself (the same footprint) is left out, so that an example and a target
    in the same place see the same context."""
    if len(donor_centres) == 0:
        return np.full(len(centres), np.nan)
    kq = min(NEIGHBOURS + 1, len(donor_centres))
    d, i = cKDTree(donor_centres).query(centres, k=kq, distance_upper_bound=NEIGHBOUR_RADIUS)
    d, i = d.reshape(len(centres), kq), i.reshape(len(centres), kq)
    ok = np.isfinite(d) & (d > 1e-3)
    ok &= np.cumsum(ok, axis=1) <= NEIGHBOURS
    logs = np.log(np.append(heights, 1.0))[np.where(ok, i, len(heights))]
    n = ok.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (logs * ok).sum(axis=1) / n, np.nan)


def _storey(height: np.ndarray, levels: np.ndarray, storey_height: float) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where((levels > 0) & np.isfinite(height), height / levels, storey_height)
    # heights like 2 m for 3 levels are typos: keep storeys plausible
    return np.clip(np.nan_to_num(s, nan=storey_height), 2.2, 6.0)


#: A block whose FAR stays this share or more under the target is reported as short of it.
FAR_SHORT = 0.1


def meet_far(footprint_area: np.ndarray, levels: np.ndarray, group: np.ndarray,
             ground_area: Dict, target_far: float, min_levels: np.ndarray,
             max_levels: np.ndarray) -> np.ndarray:
    """Integer levels per footprint so that each group's FAR comes close to ``target_far``.

    FAR of a group = Σ area x levels / ground area. Levels are first scaled by the ratio
    of the target to the current floor area and rounded, then single storeys are added to
    (or removed from) the largest footprints while that brings the FAR closer; levels
    stay within ``[min_levels, max_levels]`` per footprint.
    """
    levels = np.asarray(levels, dtype=float).copy()
    for g, ground in ground_area.items():
        sel = np.flatnonzero(group == g)
        if len(sel) == 0 or not ground > 0:
            continue
        a = footprint_area[sel]
        target = target_far * ground
        cur = float((a * levels[sel]).sum())
        lv = levels[sel] * (target / cur) if cur > 0 else np.full(len(sel), target / a.sum())
        lv = np.clip(np.round(lv), min_levels[sel], max_levels[sel])
        order = np.argsort(-a, kind="stable")
        for _ in range(50):  # sweeps until no single storey brings the FAR closer
            changed = False
            for i in order:
                diff = target - float((a * lv).sum())
                step = 1.0 if diff > 0 else -1.0
                new = lv[i] + step
                if min_levels[sel][i] <= new <= max_levels[sel][i] and abs(diff - step * a[i]) < abs(diff):
                    lv[i] = new
                    changed = True
            if not changed:
                break
        levels[sel] = lv
    return levels


def transfer_attributes(footprints, examples, example_attributes: pd.DataFrame,
                        example_ids: Optional[Sequence[int]] = None,
                        roads=None, arterials=None, example_roads=None,
                        example_arterials=None, footprint_context=None, k: int = 9,
                        seed: int = 0, min_height: float = 0.0, max_height: float = 1000.0,
                        target_far: Optional[float] = None, blocks=None,
                        storey_height: float = STOREY_HEIGHT, choice_mode: str = "medoid",
                        given: Optional[pd.DataFrame] = None,
                        progress: Optional[Progress] = None) -> AttributeTransfer:
    """Assign height, levels, type and roof to footprints from the most similar examples.

    Parameters
    ----------
    footprints : array of polygons (metric CRS)
        The buildings to attribute.
    examples : array of polygons (same CRS)
        Example buildings: all of them give the context features; those with a known
        ``height_m`` (or ``levels``) are the donors.
    example_attributes : DataFrame
        ``height_m``, ``levels``, ``building_type``, ``roof_shape`` per example (as from
        :func:`building_attributes.building_attributes`); missing columns are empty.
    example_ids : int sequence, optional
        ``source_id`` of each example (default 1..n).
    roads, arterials / example_roads, example_arterials : arrays of lines, optional
        Streets around the footprints / the examples. The distance features are used only
        when both sides have them.
    footprint_context : array of polygons, optional
        Buildings around the footprints for the context features (default: the
        footprints).
    k : int >= 1
        Candidates per footprint; 1 copies the nearest example.
    seed : int
        Seed of the random choice among the k candidates.
    min_height, max_height : float
        Height range (m); heights are clipped into it.
    target_far : float, optional
        Target floor-area ratio, per block of ``blocks`` or, without blocks, for the
        district (ground area: the convex hull of the footprints).
    blocks : array of polygons, optional
        Blocks for the per-block FAR; a footprint belongs to the block containing its
        representative point (footprints outside every block keep their levels).
    storey_height : float
        Storey height (m) for donors without levels or heights.
    choice_mode : {'medoid', 'random'}
        How the donor is chosen among the k candidates (see the module docstring).
    given : DataFrame, optional
        What the footprints know of themselves (``height_m``, ``levels``,
        ``building_type``, ``roof_shape`` per footprint, as from
        :func:`building_attributes.building_attributes`; NaN / None / 'unknown' where
        nothing is known): a footprint with a height keeps it and its levels (not clipped
        to the height range, not changed by the target FAR: ``height_given``), and a known
        type or roof is kept; only what is missing is copied from the donor.

    Returns
    -------
    AttributeTransfer

    Raises
    ------
    InputError
        No footprints, no example with a height, absurd parameters.
    """
    progress = ensure(progress)
    fp = _polygons(footprints, "footprints")
    if not (k >= 1):
        raise InputError("k must be at least 1")
    if not (0 <= min_height < max_height):
        raise InputError(f"the height range {min_height:g}..{max_height:g} m is empty")
    if target_far is not None and not (target_far > 0 and math.isfinite(target_far)):
        raise InputError("the target floor-area ratio must be a positive number")
    if choice_mode not in ("medoid", "random"):
        raise InputError(f"unknown choice mode '{choice_mode}' (medoid, random)")
    use_roads = bool(roads is not None and example_roads is not None and len(roads)
                     and len(example_roads))
    use_art = bool(arterials is not None and example_arterials is not None and len(arterials)
                   and len(example_arterials))
    # examples without any height (e.g. a cadastre of outlines only) still give types and
    # roofs; heights and levels stay empty
    model = donor_model(examples, example_attributes, example_ids, example_roads,
                        example_arterials, use_roads, use_art, storey_height)
    if model.no_heights and target_far is not None:
        raise InputError("no example building has a height or a number of levels, so a "
                         "target floor-area ratio cannot be met")
    progress.step(0.05)
    f_t = target_features(fp, footprint_context, roads, arterials, model)
    progress.step(0.55)
    model = model.standardise({c: bool(np.isfinite(f_t[c]).any())
                               for c in FEATURE_NAMES + ("neighbour_height",)})
    uniforms = np.random.default_rng(seed).random((len(fp), 1)) \
        if choice_mode == "random" else None
    table, pick = _match(f_t, shapely.area(fp), model, k, choice_mode, uniforms,
                         min_height, max_height)
    progress.step(0.8)
    ex_h = model.ex_h
    kept = _keep_given(table, given, shapely.area(fp))
    stats: Dict[str, float] = {
        "n_footprints": len(fp), "n_examples": len(model.ex_h),
        "n_donors": int(model.donor.sum()), "features": ",".join(model.cols),
        "no_heights": bool(model.no_heights), "n_height_given": int(kept.sum()),
        "n_clipped": 0 if model.no_heights else
        int(((np.clip(ex_h[pick], min_height, max_height) != ex_h[pick]) & ~kept).sum())}
    if target_far is not None:
        area = shapely.area(fp)
        storey = _storey(ex_h, model.ex_l, storey_height)[pick]
        min_lv = np.maximum(np.ceil(min_height / storey - 1e-9), 1.0)
        max_lv = np.maximum(np.floor(max_height / storey + 1e-9), min_lv)
        # a footprint's own levels are fixed: the others make up the target around them
        given_levels = table["levels"].to_numpy(dtype=float)
        min_lv = np.where(kept, given_levels, min_lv)
        max_lv = np.where(kept, given_levels, max_lv)
        if blocks is not None and len(blocks):
            blocks = np.asarray(blocks, dtype=object)
            pts = shapely.point_on_surface(fp)
            pi, bi = shapely.STRtree(blocks).query(pts, predicate="within")
            group = np.full(len(fp), -1)
            group[pi] = bi
            ground = {int(b): float(shapely.area(blocks[b])) for b in np.unique(bi)}
            stats["n_outside_blocks"] = int((group < 0).sum())
        else:
            group = np.zeros(len(fp), dtype=int)
            ground = {0: float(shapely.area(shapely.convex_hull(shapely.union_all(fp))))}
        levels = meet_far(area, table["levels"].to_numpy(dtype=float), group, ground,
                          target_far, min_lv, max_lv)
        table["height_m"] = np.where(kept, table["height_m"].to_numpy(dtype=float),
                                     np.round(levels * storey, 2))
        table["levels"] = levels.astype(np.int64)
        table["floor_area_m2"] = area * levels
        far = [float((area[group == g] * levels[group == g]).sum() / a)
               for g, a in ground.items() if a > 0]
        stats["far_min"], stats["far_max"] = (min(far), max(far)) if far else (np.nan, np.nan)
        # a block whose footprints cannot hold the target under the height limit: its
        # footprints go to that limit (a shed of 15 m² in a 1.5 ha block to 100 storeys) and
        # it stays short of the target; the log says how many, so that the analyst can raise
        # the limit or lower the target; one whose footprints exceed the target at their
        # lowest storeys stays over it
        placed = group >= 0
        stats["n_blocks_short_of_far"] = int(sum(f < (1 - FAR_SHORT) * target_far for f in far))
        stats["n_blocks_over_far"] = int(sum(f > (1 + FAR_SHORT) * target_far for f in far))
        stats["n_at_max_height"] = int((placed & ~kept & (levels >= max_lv)
                                        & (max_lv > min_lv)).sum())
        stats["far_mean"] = float(np.mean(far)) if far else np.nan
    stats["n_with_height"] = int(pd.notna(table["height_m"]).sum())
    progress.step(1.0)
    return AttributeTransfer(table, stats)


def _keep_given(table: pd.DataFrame, given: Optional[pd.DataFrame],
                area: np.ndarray) -> np.ndarray:
    """Put what the footprints know of themselves (:func:`transfer_attributes`' ``given``)
    into the matched ``table`` in place; True per footprint that kept its own height."""
    n = len(area)
    if given is None:
        return np.zeros(n, dtype=bool)
    if len(given) != n:
        raise InputError(f"{len(given)} rows of given attributes for {n} footprints")
    height = pd.to_numeric(given.get("height_m", pd.Series([np.nan] * n)),
                           errors="coerce").to_numpy(dtype=float)
    levels = pd.to_numeric(given.get("levels", pd.Series([np.nan] * n)),
                           errors="coerce").to_numpy(dtype=float)
    kept = np.isfinite(height) & (height > 0)
    if kept.any():
        storey = table["height_m"].to_numpy(dtype=float) / \
            np.maximum(table["levels"].to_numpy(dtype=float), 1.0)
        storey = np.where(np.isfinite(storey) & (storey > 0), storey, STOREY_HEIGHT)
        own_levels = np.where(np.isfinite(levels) & (levels >= 1), np.round(levels),
                              np.maximum(np.round(height / storey), 1.0))
        table["height_m"] = np.where(kept, height, table["height_m"].to_numpy(dtype=float))
        lv = np.where(kept, own_levels, table["levels"].to_numpy(dtype=float))
        table["levels"] = lv if not np.isfinite(lv).all() else lv.astype(np.int64)
        table["floor_area_m2"] = np.asarray(area, dtype=float) * lv
        table["height_given"] = kept
    for column, unknown in (("building_type", "unknown"), ("roof_shape", None)):
        if column in given:
            own = given[column].to_numpy(dtype=object)
            has = np.array([isinstance(v, str) and bool(v) and v != unknown for v in own])
            table[column] = np.where(has, own, table[column].to_numpy(dtype=object))
    return kept


def block_median_baseline(footprints, known_height: np.ndarray, blocks) -> np.ndarray:
    """The block-median baseline of the evidence: each footprint gets the median known
    height of the other footprints in its block, else the median of all known heights."""
    fp = np.asarray(footprints, dtype=object)
    known_height = np.asarray(known_height, dtype=float)
    pts = shapely.point_on_surface(fp)
    pi, bi = shapely.STRtree(np.asarray(blocks, dtype=object)).query(pts, predicate="within")
    group = np.full(len(fp), -1)
    group[pi] = bi
    overall = float(np.nanmedian(known_height))
    out = np.full(len(fp), overall)
    frame = pd.DataFrame({"g": group, "h": known_height})
    med = frame[frame.g >= 0].groupby("g")["h"].median()
    has = (group >= 0) & np.isin(group, med.index.to_numpy())
    out[has] = med.reindex(group[has]).to_numpy()
    return np.where(np.isfinite(out), out, overall)



# --------------------------------------------------------------------------- partitioned runs
# The steps of transfer_attributes, also run separately for targets in partitions
# (plugin.scale.distributed): the example side once (donor_model), the target features per
# partition with a halo of CONTEXT_RADIUS around it (target_features), the feature columns
# and their standardisation once from all targets (DonorModel.standardise), matching per
# partition (match_attributes). A target FAR is a district-wide step of transfer_attributes.

#: How far (m) the context features of a footprint reach (coverage and grain radii; the
#: neighbour heights come from the examples, which every partition has).
CONTEXT_RADIUS = max(max(COVERAGE_RADII), GRAIN_RADIUS)


@dataclass
class DonorModel:
    """The example side of :func:`transfer_attributes`, computed once."""

    features: pd.DataFrame        # example features incl. neighbour_height
    donor: np.ndarray             # examples with a height (all when none has one)
    donor_centres: np.ndarray
    ex_h: np.ndarray
    ex_l: np.ndarray
    ids: np.ndarray
    btype: np.ndarray
    roof: np.ndarray
    no_heights: bool
    use_roads: bool
    use_art: bool
    storey_height: float
    cols: Optional[list] = None   # set by standardise
    mu: Optional[np.ndarray] = None
    sd: Optional[np.ndarray] = None
    w: Optional[np.ndarray] = None

    def standardise(self, target_finite: Dict[str, bool]) -> "DonorModel":
        """Choose the feature columns (``target_finite[c]``: some target has a finite
        value of c) and the donors' mean and spread, as :func:`transfer_attributes`."""
        f_e, donor = self.features, self.donor
        cols = [c for c in FEATURE_NAMES + ("neighbour_height",)
                if np.isfinite(f_e.loc[donor, c]).mean() > 0.5 and target_finite[c]]
        mu = f_e.loc[donor, cols].mean().to_numpy()
        sd = f_e.loc[donor, cols].std().to_numpy()
        sd = np.where(np.isfinite(sd) & (sd > 1e-9), sd, 1.0)
        w = np.array([FEATURE_WEIGHTS[c] for c in cols])
        return DonorModel(**{**self.__dict__, "cols": cols, "mu": mu, "sd": sd, "w": w})


def donor_model(examples, example_attributes: pd.DataFrame,
                example_ids: Optional[Sequence[int]] = None, example_roads=None,
                example_arterials=None, use_roads: bool = False, use_art: bool = False,
                storey_height: float = STOREY_HEIGHT) -> DonorModel:
    """Example features, donors and their heights (the first half of
    :func:`transfer_attributes`); ``use_roads`` / ``use_art``: both sides have roads /
    arterials."""
    ex = _polygons(examples, "example buildings")
    if len(example_attributes) != len(ex):
        raise InputError("example attributes and geometries differ in length")
    if not (storey_height > 0):
        raise InputError("the storey height must be positive")

    def col(name, default):
        if name in example_attributes:
            return example_attributes[name].to_numpy()
        return np.full(len(ex), default, dtype=object)

    ex_h = pd.to_numeric(pd.Series(col("height_m", np.nan)), errors="coerce").to_numpy(float)
    ex_l = pd.to_numeric(pd.Series(col("levels", np.nan)), errors="coerce").to_numpy(float)
    ex_h = np.where(np.isfinite(ex_h), ex_h, ex_l * storey_height)
    donor = np.isfinite(ex_h) & (ex_h > 0)
    no_heights = not donor.any()
    if no_heights:
        donor = np.ones(len(ex), dtype=bool)
    ids = np.arange(1, len(ex) + 1) if example_ids is None else np.asarray(example_ids)
    f_e = footprint_features(ex, None, example_roads if use_roads else None,
                             example_arterials if use_art else None)
    c_ex = shapely.get_coordinates(shapely.centroid(ex[donor]))
    f_e.loc[donor, "neighbour_height"] = neighbour_height(c_ex, ex_h[donor], c_ex)
    return DonorModel(f_e, donor, c_ex, ex_h, ex_l, ids,
                      np.asarray(col("building_type", None), dtype=object),
                      np.asarray(col("roof_shape", None), dtype=object), bool(no_heights),
                      bool(use_roads), bool(use_art), float(storey_height))


def target_features(footprints, context, roads, arterials, model: DonorModel) -> pd.DataFrame:
    """Features of target footprints (``context``: all buildings within
    :data:`CONTEXT_RADIUS` of them, in one fixed order), with their neighbour heights."""
    fp = np.asarray(footprints, dtype=object)
    f_t = footprint_features(fp, context, roads if model.use_roads else None,
                             arterials if model.use_art else None)
    f_t["neighbour_height"] = neighbour_height(
        shapely.get_coordinates(shapely.centroid(fp)), model.ex_h[model.donor],
        model.donor_centres)
    return f_t


def match_attributes(f_t: pd.DataFrame, area: np.ndarray, model: DonorModel, k: int = 9,
                     choice_mode: str = "medoid", uniforms: Optional[np.ndarray] = None,
                     min_height: float = 0.0, max_height: float = 1000.0) -> pd.DataFrame:
    """Donor and attributes of each target (rows of :func:`transfer_attributes` without a
    target FAR) from its features and a standardised model. ``uniforms``: for 'random',
    each target's draw, shape (n, 1) (transfer_attributes draws them from one stream)."""
    return _match(f_t, area, model, k, choice_mode, uniforms, min_height, max_height)[0]


def _match(f_t, area, model: DonorModel, k, choice_mode, uniforms, min_height, max_height):
    """:func:`match_attributes` and the index of each target's donor among the examples."""
    if model.cols is None:
        raise InputError("the donor model is not standardised")
    n = len(f_t)
    if n == 0:
        return pd.DataFrame({f: [] for f, _ in OUTPUT_FIELDS}), np.zeros(0, dtype=np.int64)
    donor, ex_h, ex_l = model.donor, model.ex_h, model.ex_l
    cols, mu, sd, w = model.cols, model.mu, model.sd, model.w
    xe = np.nan_to_num((model.features.loc[donor, cols].to_numpy() - mu) / sd * w, nan=0.0)
    xt = np.nan_to_num((f_t[cols].to_numpy() - mu) / sd * w, nan=0.0)
    donors = np.flatnonzero(donor)
    kk = int(min(k, len(donors)))
    dist, idx = cKDTree(xe).query(xt, k=kk)
    dist, idx = dist.reshape(n, kk), idx.reshape(n, kk)
    if model.no_heights:
        choice = np.zeros(n, dtype=int)
    elif kk > 1 and choice_mode == "medoid":
        hk = np.log(ex_h[donors[idx]])
        wk = 1.0 / (dist + 1e-6)
        order = np.argsort(hk, axis=1)
        cw = np.cumsum(np.take_along_axis(wk, order, 1), axis=1)
        mid = (cw < 0.5 * cw[:, -1:]).sum(axis=1)
        choice = order[np.arange(n), np.minimum(mid, kk - 1)]
    elif kk > 1:
        if uniforms is None or len(uniforms) != n:
            raise InputError("the random choice needs one uniform draw per footprint")
        h = np.maximum(np.median(dist, axis=1, keepdims=True), 1e-6)
        p = np.exp(-0.5 * (dist / h) ** 2)
        p /= p.sum(axis=1, keepdims=True)
        choice = (np.asarray(uniforms).reshape(n, 1) > np.cumsum(p, axis=1)).sum(axis=1)
        choice = np.minimum(choice, kk - 1)
    else:
        choice = np.zeros(n, dtype=int)
    pick = donors[idx[np.arange(n), choice]]
    d = dist[np.arange(n), choice]
    storey = _storey(ex_h, ex_l, model.storey_height)[pick]
    height = np.clip(ex_h[pick], min_height, max_height)
    levels = np.where(np.isfinite(ex_l[pick]) & (ex_h[pick] == height), ex_l[pick],
                      np.round(height / storey))
    min_lv = np.maximum(np.ceil(min_height / storey - 1e-9), 1.0)
    max_lv = np.maximum(np.floor(max_height / storey + 1e-9), min_lv)
    levels = np.clip(np.maximum(np.floor(levels + 0.5), 1.0), min_lv, max_lv)
    if model.no_heights:
        height = np.full(n, np.nan)
        levels = np.full(n, np.nan)
    return pd.DataFrame({
        "height_m": height, "levels": levels if model.no_heights else levels.astype(np.int64),
        "building_type": [t if isinstance(t, str) and t else "unknown"
                          for t in model.btype[pick]],
        "roof_shape": [r if isinstance(r, str) and r else None for r in model.roof[pick]],
        "source_id": model.ids[pick], "similarity": 1.0 / (1.0 + d),
        "floor_area_m2": np.asarray(area) * levels,
        "height_given": np.zeros(n, dtype=bool)}), pick
