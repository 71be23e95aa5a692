"""Small blocks merged to the example's block sizes (plugin/network/small_blocks.py)."""
import numpy as np
import pytest
import shapely

from urban_synthesis.plugin.network import invariants


def test_small_blocks_merge_down_to_the_examples_share():
    """A 400 m square of given roads cut by a synthesised 50 m grid (64 blocks of 2,500 m²),
    merged with the example's 10th-percentile block of 10,000 m²: at most a tenth of the
    blocks stay smaller, no dead end is made, the network stays one piece and the given
    roads stay whole."""
    from urban_synthesis.plugin.network.small_blocks import merge_small_blocks

    frame = [shapely.LineString([(0, 0), (400, 0), (400, 400), (0, 400), (0, 0)])]
    grid = [shapely.LineString([(x, 0), (x, 400)]) for x in range(50, 400, 50)] + \
        [shapely.LineString([(0, y), (400, y)]) for y in range(50, 400, 50)]
    lines = np.array(frame + grid, dtype=object)
    out, new, removed = merge_small_blocks(lines, np.r_[False, np.ones(len(grid), bool)],
                                           10_000.0)
    faces = shapely.get_parts(shapely.polygonize(out))
    area = shapely.area(faces)
    assert removed > 0 and (area < 10_000).sum() <= 0.1 * len(faces)
    assert area.sum() == pytest.approx(400 * 400)
    assert shapely.union_all(out[~new]).length == pytest.approx(1600)
    ends = shapely.get_coordinates(np.r_[shapely.get_point(out, 0), shapely.get_point(out, -1)])
    _, counts = np.unique(np.round(ends, 3), axis=0, return_counts=True)
    assert (counts != 1).all()                        # no dead end
    assert invariants.check_network(out[new], out[~new]).floating_pieces == 0
