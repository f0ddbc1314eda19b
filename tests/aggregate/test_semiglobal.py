"""Semi-global aggregation against its path-by-path reference, and the winners it gives."""

import numpy as np
import pytest

from stereobudget.aggregate import (semiglobal_aggregate, semiglobal_aggregate_reference, semiglobal_disparities,
                                    semiglobal_winners)


@pytest.mark.parametrize("paths", [4, 8])
def test_matches_reference(paths):
    rng = np.random.default_rng(5)
    cost = rng.integers(0, 25, (9, 13, 6)).astype(np.uint8)
    guide = rng.uniform(0, 255, (9, 13)).astype(np.float32)
    fast = semiglobal_aggregate(cost, guide, p1=3.0, p2=20.0, edge_scale=8.0, paths=paths)
    assert fast.dtype == np.float32
    reference = semiglobal_aggregate_reference(cost, guide, p1=3.0, p2=20.0, edge_scale=8.0, paths=paths)
    np.testing.assert_allclose(fast, reference, rtol=1e-5, atol=1e-3)


def test_smoothness_overrules_a_lone_wrong_pixel():
    cost = np.full((15, 15, 5), 10, np.uint8)
    cost[:, :, 2] = 2                                        # the surface is at disparity 2
    cost[7, 7, 2], cost[7, 7, 4] = 10, 0                     # one pixel's data says 4
    total = semiglobal_aggregate(cost, np.zeros((15, 15), np.float32), p1=2.0, p2=16.0)
    assert total[7, 7].argmin() == 2


def test_winners_left_and_right_views():
    h, w, nd = 4, 20, 6
    total = np.full((h, w, nd), 50, np.float32)
    total[:, :, 3] = 1                                       # every left pixel at disparity 3
    left, right = semiglobal_winners(total, 1)
    np.testing.assert_allclose(left, 4.0)                    # min_disp + 3
    # Right pixel xr matches left xr + 4; the last 4 right columns see no left pixel at 3.
    np.testing.assert_allclose(right[:, :w - 4], 4.0)
    with pytest.raises(ValueError):
        semiglobal_aggregate(np.zeros((2, 2, 2), np.uint8), np.zeros((2, 2), np.float32), p1=1, p2=2, paths=6)


def test_fill_from_row_takes_the_nearest_valid_pixel():
    from stereobudget.aggregate import fill_from_row
    rng = np.random.default_rng(1)
    disparity = rng.uniform(0, 30, (6, 17)).astype(np.float32)
    valid = rng.random((6, 17)) < 0.4
    valid[0] = False                                          # a row with nothing to copy
    out = fill_from_row(disparity, valid)
    for y in range(6):
        good = np.flatnonzero(valid[y])
        for x in range(17):
            if valid[y, x] or not len(good):
                assert out[y, x] == disparity[y, x]
            else:
                distance = np.abs(good - x)
                nearest = good[np.flatnonzero(distance == distance.min())[0]]   # the left one on a tie
                assert out[y, x] == disparity[y, nearest]


@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
@pytest.mark.parametrize("min_disp, shape", [(2, (11, 23, 9)), (-3, (11, 23, 9)), (0, (5, 7, 12)), (-9, (4, 6, 5))])
def test_fused_winners_match_the_two_steps(paths, dtype, min_disp, shape):
    """The fused route's right winners (a transposed row, every layer at once) against the
    diagonal walk, with negative ranges and more layers than columns; ties are frequent in
    integer costs, so the first smallest must win in both."""
    rng = np.random.default_rng(7)
    cost = rng.integers(0, 40, shape).astype(dtype)
    guide = rng.uniform(0, 255, shape[:2]).astype(np.float32)
    kwargs = dict(p1=2.5, p2=17.0, edge_scale=8.0, paths=paths)
    left, right = semiglobal_disparities(cost, guide, min_disp=min_disp, **kwargs)
    want_left, want_right = semiglobal_winners(semiglobal_aggregate(cost, guide, **kwargs), min_disp)
    np.testing.assert_array_equal(left, want_left)
    np.testing.assert_array_equal(right, want_right)


def test_a_single_disparity_layer():
    cost = np.arange(12, dtype=np.uint8).reshape(3, 4, 1)
    guide = np.zeros((3, 4), np.float32)
    fast = semiglobal_aggregate(cost, guide, p1=1.0, p2=4.0)
    np.testing.assert_allclose(fast, semiglobal_aggregate_reference(cost, guide, p1=1.0, p2=4.0))
