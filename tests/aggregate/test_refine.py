"""Yang's left-right check and non-local refinement against their plain reference."""

import numpy as np
import pytest

from stereobudget.aggregate import (build_tree, left_right_refinement_reference, left_right_stable,
                                    median_filter_disparity, nonlocal_refinement)
from stereobudget.scenes import make_scene


def _right_view(disparity):
    """The right view's disparity of an exact left one, by forward projection (0 where none lands)."""
    h, w = disparity.shape
    right = np.zeros((h, w), np.float32)
    for y in range(h):
        for x in range(w):
            xr = int(np.floor(x - disparity[y, x] + 0.5))
            if 0 <= xr < w:
                right[y, xr] = disparity[y, x]
    return right


@pytest.mark.parametrize("kind, min_disp, tolerance", [("planes", 0, 1.0), ("slanted", -2, 0.5)])
def test_check_and_refinement_equal_the_reference(kind, min_disp, tolerance):
    scene = make_scene(kind, height=48, width=72, max_disp=12, seed=3)
    rng = np.random.default_rng(4)
    left = scene.disparity.astype(np.float32) + rng.normal(0, 0.3, scene.disparity.shape).astype(np.float32)
    wrong = rng.random(left.shape) < 0.15                       # pixels the check must reject
    left[wrong] = rng.uniform(0, 12, wrong.sum())
    right = _right_view(scene.disparity)
    tree = build_tree(scene.left)
    stable = left_right_stable(left, right, tolerance)
    refined = nonlocal_refinement(left, stable, tree, min_disp=min_disp, num_disp=15)
    expected, expected_stable = left_right_refinement_reference(left, right, tree, min_disp=min_disp, num_disp=15,
                                                                tolerance=tolerance)
    np.testing.assert_array_equal(stable, expected_stable)
    assert 0.5 < stable.mean() < 0.95
    # float32 walk against the float64 reference: the winners agree, their parabola to rounding.
    np.testing.assert_allclose(refined, expected, atol=1e-3)


def _plain_median(disparity, size, passes):
    """A size x size median over windows clipped to the image by repeating its border, ``passes`` times."""
    out = disparity.astype(np.float64)
    r = size // 2
    for _ in range(passes):
        padded = np.pad(out, r, mode="edge")
        windows = np.lib.stride_tricks.sliding_window_view(padded, (size, size))
        out = np.median(windows.reshape(out.shape + (-1,)), axis=-1)
    return out


@pytest.mark.parametrize("size, passes", [(3, 1), (5, 1), (5, 2), (5, 3)])
def test_median_passes_equal_a_plain_median_repeated(size, passes):
    rng = np.random.default_rng(size * 10 + passes)
    disparity = np.repeat(rng.uniform(0, 30, (9, 1)), 23, axis=1).astype(np.float32)
    streaks = rng.random(disparity.shape) < 0.2                  # specks and broken row streaks
    disparity[streaks] = rng.uniform(0, 30, streaks.sum()).astype(np.float32)
    got = median_filter_disparity(disparity, size, passes=passes)
    assert got.dtype == np.float32 and got.shape == disparity.shape
    np.testing.assert_array_equal(got, _plain_median(disparity, size, passes).astype(np.float32))


def test_second_median_pass_removes_what_the_first_leaves():
    # A 3-pixel-wide diagonal band of wrong disparities on a flat field: one 5 x 5 window
    # holds up to 13 of its pixels, so one pass keeps its middle, and a second pass
    # finds fewer than half left and removes it.
    disparity = np.full((40, 40), 10.0, np.float32)
    for y in range(40):
        disparity[y, max(0, y - 1):y + 2] = 20.0
    once = median_filter_disparity(disparity, 5, passes=1)
    twice = median_filter_disparity(disparity, 5, passes=2)
    assert np.count_nonzero(once != 10.0) > 0
    assert np.count_nonzero(twice != 10.0) < np.count_nonzero(once != 10.0)
    np.testing.assert_array_equal(median_filter_disparity(disparity, 5, passes=0), disparity)
    np.testing.assert_array_equal(median_filter_disparity(disparity, 1, passes=2), disparity)
