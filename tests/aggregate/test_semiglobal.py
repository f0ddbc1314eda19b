"""Semi-global aggregation against its path-by-path reference, and the winners it gives."""

import numpy as np
import pytest

from stereobudget.aggregate import (fixed_point_scale, pixel_margins, semiglobal_aggregate,
                                    semiglobal_aggregate_reference, semiglobal_disparities, semiglobal_winners)


@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("layers", [6, 17, 18, 21, 34, 64])
@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
def test_matches_reference(paths, layers, dtype):
    """Bit for bit, on the same fixed point: below 18 layers element by element, from 18 on
    sixteen at a time with an overlapping last vector (34 = 2 + 2 * 16 does not overlap)."""
    rng = np.random.default_rng(5)
    shape = (9, 13, layers)
    if dtype == np.uint8:
        cost, p1, p2 = rng.integers(0, 25, shape).astype(np.uint8), 3.0, 20.0
    else:
        cost, p1, p2 = rng.uniform(0, 1.5, shape).astype(np.float32), 0.15, 1.1
    guide = rng.uniform(0, 255, shape[:2]).astype(np.float32)
    fast = semiglobal_aggregate(cost, guide, p1=p1, p2=p2, edge_scale=8.0, paths=paths)
    assert fast.dtype == np.float32
    reference = semiglobal_aggregate_reference(cost, guide, p1=p1, p2=p2, edge_scale=8.0, paths=paths)
    np.testing.assert_array_equal(fast, reference)


def test_fixed_point_keeps_integer_costs_and_fits_sixteen_bits():
    assert fixed_point_scale(255, 40) == 16            # 16 * 295 <= 8190 < 32 * 295
    assert fixed_point_scale(1.0, 7.0) == 512           # 512 * 8 <= 8190 < 1024 * 8
    assert fixed_point_scale(0, 0) == 1
    # The largest sum the scale admits: every cost at the bound, P2 at every step.
    rng = np.random.default_rng(2)
    cost = np.full((6, 40, 20), 1.0, np.float32)
    cost[:, :, ::3] = 0.0
    guide = rng.uniform(0, 255, (6, 40)).astype(np.float32)
    fast = semiglobal_aggregate(cost, guide, p1=0.5, p2=6.0, cost_max=1.0)
    np.testing.assert_array_equal(fast, semiglobal_aggregate_reference(cost, guide, p1=0.5, p2=6.0, cost_max=1.0))
    assert fast.max() <= 8 * (1.0 + 6.0)


def test_the_fixed_point_step_is_far_below_the_costs():
    """On float costs the fixed point moves a sum by well under a cost unit: the same winners
    as exact float64 path sums wherever those are not a near tie."""
    rng = np.random.default_rng(9)
    cost = rng.uniform(0, 1, (12, 30, 24)).astype(np.float32)
    guide = rng.uniform(0, 255, (12, 30)).astype(np.float32)
    fast = semiglobal_aggregate(cost, guide, p1=0.1, p2=1.5)
    exact = semiglobal_aggregate_reference(cost, guide, p1=0.1, p2=1.5, fixed_point=False)
    assert np.abs(fast - exact).max() < 8 * 30 / fixed_point_scale(1.0, 1.5)   # under a step per path and pixel
    ordered = np.sort(exact, axis=2)
    clear = ordered[:, :, 1] - ordered[:, :, 0] > 0.05
    np.testing.assert_array_equal(fast.argmin(axis=2)[clear], exact.argmin(axis=2)[clear])


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


@pytest.mark.parametrize("background", [False, True])
def test_fill_from_row_takes_the_nearest_or_the_farther_valid_pixel(background):
    from stereobudget.aggregate import fill_from_row
    rng = np.random.default_rng(1)
    disparity = rng.uniform(0, 30, (6, 17)).astype(np.float32)
    valid = rng.random((6, 17)) < 0.4
    valid[0] = False                                          # a row with nothing to copy
    out = fill_from_row(disparity, valid, background=background)
    for y in range(6):
        good = np.flatnonzero(valid[y])
        for x in range(17):
            left, right = good[good < x], good[good > x]
            if valid[y, x] or not len(good):
                assert out[y, x] == disparity[y, x]
            elif background and len(left) and len(right):
                # Beside an edge the rejected pixel belongs to the farther surface (smaller disparity).
                assert out[y, x] == min(disparity[y, left[-1]], disparity[y, right[0]])
            else:
                distance = np.abs(good - x)
                nearest = good[np.flatnonzero(distance == distance.min())[0]]   # the left one on a tie
                assert out[y, x] == disparity[y, nearest]


def test_the_background_fill_puts_an_occluded_strip_on_the_farther_surface():
    from stereobudget.aggregate import fill_from_row
    disparity = np.array([[10, 10, 10, 0, 0, 0, 4, 4]], np.float32)     # near 10, far 4, a strip rejected
    valid = disparity > 0
    np.testing.assert_array_equal(fill_from_row(disparity, valid, background=True)[0], [10, 10, 10, 4, 4, 4, 4, 4])
    np.testing.assert_array_equal(fill_from_row(disparity, valid)[0], [10, 10, 10, 10, 10, 4, 4, 4])


@pytest.mark.parametrize("paths", [4, 8])
@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
@pytest.mark.parametrize("min_disp, shape", [(2, (11, 23, 9)), (-3, (11, 23, 9)), (0, (5, 7, 12)), (-9, (4, 6, 5)),
                                             (1, (6, 40, 37))])
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


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
@pytest.mark.parametrize("shape, step", [((9, 13, 6), 1), ((37, 41, 24), 4), ((5, 3, 1), 4)])
def test_pixel_margins_are_mean_minus_min_of_the_subsampled_pixels(dtype, shape, step):
    rng = np.random.default_rng(11)
    cost = (rng.uniform(0, 1, shape) * (40 if dtype == np.uint8 else 1)).astype(dtype)
    sub = cost[::step, ::step].astype(np.float64)
    want = sub.mean(axis=2) - sub.min(axis=2)
    got = pixel_margins(cost, step=step)
    assert got.dtype == np.float32 and got.shape == want.shape
    np.testing.assert_array_equal(got, want.astype(np.float32))
