"""Yang's left-right check and non-local refinement against their plain reference."""

import numpy as np
import pytest

from stereobudget.aggregate import (build_tree, left_right_refinement_reference, left_right_stable,
                                    nonlocal_refinement)
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
