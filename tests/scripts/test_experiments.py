"""Evaluation-only baselines: lower bound, JBU and "upsample without smoothing" on synthetic scenes."""

from __future__ import annotations

import numpy as np
import pytest

import experiments
from stereobudget.errors import OptionError
from stereobudget.metrics import bad_pixel_rate
from stereobudget.scenes import make_scene


@pytest.fixture(scope="module")
def scene():
    return make_scene("planes", height=96, width=128, max_disp=16, seed=1)


def _good_fraction(disp, scene):
    assert disp.shape == scene.disparity.shape and disp.dtype == np.float32
    return 100.0 - bad_pixel_rate(disp, scene.disparity, scene.nonocc, threshold=1.0)


def test_full_pair_reference_is_accurate(scene):
    disp = experiments.full_pair_disparity(scene.left, scene.right, max_disp=scene.max_disp)
    assert _good_fraction(disp, scene) >= 95.0


def test_lower_bound_is_accurate_and_improves_with_the_budget(scene):
    bad = {f: bad_pixel_rate(experiments.lower_bound_disparity(scene.left, scene.right, fraction=f,
                                                               max_disp=scene.max_disp),
                             scene.disparity, scene.nonocc)
           for f in (0.002, 0.005, 0.04, 1.0)}
    assert bad[0.04] <= 2.0 and bad[1.0] <= 2.0
    # A DSI squeezed to 0.2 % of its entries per layer loses the small structures.
    assert bad[0.002] > bad[0.005] > bad[0.04] + 0.3
    assert bad[0.002] > 3.0


def test_lower_bound_rejects_a_bad_fraction(scene):
    for fraction in (0.0, 1.5):
        with pytest.raises(OptionError, match="fraction"):
            experiments.lower_bound_disparity(scene.left, scene.right, fraction=fraction, max_disp=16)


def test_jbu_gives_a_sensible_disparity(scene):
    disp = experiments.jbu_disparity(scene.left, scene.right, scale=2, max_disp=scene.max_disp)
    assert np.isfinite(disp).all()
    assert _good_fraction(disp, scene) >= 85.0


def test_upsample_without_smoothing_gives_a_sensible_disparity(scene):
    disp = experiments.upsample_no_smoothing_disparity(scene.left, scene.right, scale=2,
                                                       max_disp=scene.max_disp)
    assert _good_fraction(disp, scene) >= 90.0


def test_baselines_reject_a_bad_scale(scene):
    for fn in (experiments.jbu_disparity, experiments.upsample_no_smoothing_disparity):
        with pytest.raises(OptionError, match="scale"):
            fn(scene.left, scene.right, scale=0, max_disp=16)


@pytest.mark.parametrize("stride", [3, 5])
def test_upsample_block_means_reproduces_a_linear_ramp(stride):
    """Block means of a ramp sit on the ramp at odd-sized block centres; bilinear recovers it between them."""
    h, w = 4 * stride + 2, 6 * stride + 1
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    ramp = 2.0 * x + 3.0 * y + 10.0
    rows, cols = -(-h // stride), -(-w // stride)
    low = np.empty((rows, cols), np.float64)
    for i in range(rows):
        for j in range(cols):
            low[i, j] = ramp[i * stride:(i + 1) * stride, j * stride:(j + 1) * stride].mean()
    up = experiments.upsample_block_means(low, stride_x=stride, stride_y=stride, height=h, width=w)
    assert up.shape == (h, w, 1) and up.dtype == np.float32
    # Between the first and last block centres the ramp is exact; outside, clamped to the edge value.
    first = (stride - 1) // 2
    last_row = (rows - 1) * stride + (min(stride, h - (rows - 1) * stride) - 1) / 2
    last_col = (cols - 1) * stride + (min(stride, w - (cols - 1) * stride) - 1) / 2
    inside = (y >= first) & (y <= last_row) & (x >= first) & (x <= last_col)
    np.testing.assert_allclose(up[:, :, 0][inside], ramp[inside], atol=1e-3)
    np.testing.assert_allclose(up[0, 0, 0], low[0, 0], atol=1e-3)
