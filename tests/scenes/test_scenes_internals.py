"""White-box tests of stereobudget.scenes._scenes: the tabulated renderer against evaluating each surface directly."""

import numpy as np
import pytest

import stereobudget.scenes._scenes as sc
from stereobudget.scenes import make_scene


@pytest.mark.parametrize("kind", ["slanted", "fine_texture"])
def test_rendered_views_equal_direct_texture_evaluation(kind):
    # The renderer tabulates row/column phases; check it against evaluating every sinusoid
    # at the ray-cast texture coordinates directly (this is what warp_error_bound assumes).
    h, w, max_disp = 60, 90, 16
    rng = np.random.default_rng([5, sc.SCENE_KINDS.index(kind)])
    surfaces = sc._layout(kind, rng, h, w, float(max_disp))
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    left_labels, _ = sc._front_surface_left(surfaces, x, y)
    right_labels, right_x, _ = sc._front_surface_right(surfaces, x, y)
    for labels, tex_x, right_view in ((left_labels, x, False), (right_labels, right_x, True)):
        fast = sc._shade(surfaces, labels, right_view=right_view)
        direct = np.zeros_like(fast)
        for index, surface in enumerate(surfaces):
            sel = labels == index
            direct[sel] = surface.texture.evaluate(tex_x[sel], y[sel])
        np.testing.assert_allclose(fast, direct, atol=1e-9)
    rendered = make_scene(kind, height=h, width=w, max_disp=max_disp, seed=5)
    np.testing.assert_array_equal(rendered.surface_left, left_labels)
    np.testing.assert_array_equal(rendered.surface_right, right_labels)
