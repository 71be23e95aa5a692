"""Engine tests of the conflict relaxation of the block transfer (thesis ch. 5.1):
position-based dynamics (footprint_transfer.relax_pbd) against the rigid shape matching.

- A footprint a little wider than the gap between two fixed buildings: PBD fits it by
  giving its walls a little (within the strain bound), rigid matching cannot.
- The end of a dead-end road reaching into a footprint's wall between two corners (no
  corner on the road): PBD sees the road through the sampled street-offset outline and
  moves the footprint off it; rigid matching, projecting corners only, does not.
- On a seeded family of random conflicts: every relaxed footprint is valid, inside the
  buildable area and free of the others, walls within the strain bound; rigid+PBD frees
  at least what rigid frees, and more in total.
"""
import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.buildings import footprint_transfer as ft
from urban_synthesis.plugin.buildings import footprints


def walls(poly):
    xy = np.asarray(poly.exterior.coords)
    return np.hypot(*np.diff(xy, axis=0).T)


def freed(moved, original, conflicted, buildable):
    out = []
    for i in np.flatnonzero(conflicted):
        others = np.delete(moved, i)
        ok = (not moved[i].equals(original[i]) and shapely.is_valid(moved[i])
              and shapely.within(moved[i], buildable)
              and shapely.area(shapely.intersection(moved[i], shapely.union_all(others)))
              <= ft.SLIVER)
        out.append(ok)
    return np.array(out, dtype=bool)


def test_pbd_fits_a_footprint_into_a_slightly_narrower_gap():
    block = shapely.box(0, 0, 100, 60)
    buildable = footprints.street_offset(block, 10.0)
    f1, f2 = shapely.box(10, 10, 30, 30), shapely.box(49.5, 10, 69.5, 30)
    house = shapely.box(29, 12, 49, 28)                   # 20 m into a 19.5 m gap
    fp = np.array([f1, f2, house], dtype=object)
    conf = np.array([False, False, True])
    rigid, _ = ft.relax_rigid(fp, conf, buildable)
    assert rigid[2].equals(house)                          # rigid matching gives up
    moved, steps = ft.relax_pbd(fp, conf, buildable)
    assert moved[0].equals(f1) and moved[1].equals(f2)    # fixed footprints never move
    assert freed(moved, fp, conf, buildable).all()
    strain = np.abs(walls(moved[2]) / walls(house) - 1)
    assert strain.max() <= ft.PBD_MAX_STRAIN
    assert 0.02 < strain.max()                             # it did give a little
    assert shapely.area(moved[2]) == pytest.approx(house.area, rel=ft.PBD_MAX_STRAIN)
    combined, _ = ft.relax(fp, conf, buildable)
    assert freed(combined, fp, conf, buildable).all()


def test_pbd_moves_a_footprint_off_a_road_between_its_corners():
    block = shapely.box(0, 0, 120, 80)
    road = shapely.LineString([(60, 0), (60, 40)])        # a dead end into the block
    buildable = footprints.street_offset(block, 6.0, roads=[block.exterior, road])
    house = shapely.box(54, 41, 66, 55)                    # the road's end 2 m into its wall
    assert shapely.contains_xy(buildable, *np.asarray(house.exterior.coords)[:-1].T).all()
    fp = np.array([house], dtype=object)
    keep, conf = ft.classify(fp, block, buildable)
    assert conf.all()
    rigid, _ = ft.relax_rigid(fp, conf, buildable)
    assert rigid[0].equals(house)
    moved, _ = ft.relax_pbd(fp, conf, buildable)
    assert freed(moved, fp, conf, buildable).all()
    assert np.abs(walls(moved[0]) / walls(house) - 1).max() <= ft.PBD_MAX_STRAIN


def random_conflicts(seed):
    rng = np.random.default_rng(seed)
    block = shapely.box(0, 0, 90, 70)
    buildable = footprints.street_offset(block, 8.0)
    polys = []
    while len(polys) < 9:
        w, h = rng.uniform(8, 18, 2)
        x, y = rng.uniform(0, 90 - w), rng.uniform(0, 70 - h)
        p = shapely.box(x, y, x + w, y + h)
        if polys and shapely.area(shapely.intersection(p, shapely.union_all(polys))) > 0.3 * p.area:
            continue
        polys.append(p)
    fp = np.array(polys, dtype=object)
    keep, conf = ft.classify(fp, block, buildable)
    # overlapping pairs: the later one conflicts too
    for i in range(len(fp)):
        if shapely.area(shapely.intersection(fp[i], shapely.union_all(np.delete(fp, i)))) > 1:
            conf[i] |= i % 2 == 1
    return fp[keep], conf[keep], buildable


def test_rigid_plus_pbd_frees_more_on_random_conflicts():
    n_rigid = n_both = n_conf = 0
    for seed in range(12):
        fp, conf, buildable = random_conflicts(seed)
        if not conf.any():
            continue
        rigid, _ = ft.relax_rigid(fp, conf, buildable)
        both, _ = ft.relax(fp, conf, buildable)
        fr, fb = freed(rigid, fp, conf, buildable), freed(both, fp, conf, buildable)
        # what rigid frees, the combination keeps (it only adds PBD for the rest)
        assert (fb | ~fr).all()
        for i in np.flatnonzero(conf):
            g = both[i]
            assert shapely.is_valid(g) and g.exterior.is_closed
            if not g.equals(fp[i]):
                assert np.abs(walls(g) / walls(fp[i]) - 1).max() <= ft.PBD_MAX_STRAIN + 1e-9
        n_rigid += fr.sum()
        n_both += fb.sum()
        n_conf += conf.sum()
    assert n_conf >= 15
    assert n_both > n_rigid


def test_unknown_relaxation_is_rejected():
    from urban_synthesis.plugin.core.progress import InputError
    with pytest.raises(InputError, match="relaxation"):
        ft.relax([shapely.box(0, 0, 1, 1)], np.array([True]), shapely.box(0, 0, 9, 9), "x")
