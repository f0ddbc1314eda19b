"""The bilateral-grid filter against a brute-force normalised joint bilateral filter."""

import numpy as np
import pytest

from stereobudget.cost import SparseCostTerms
from stereobudget.fill import (FillScale, filled_sparse_dsi, filled_sparse_dsi_reference, sparse_joint_bilateral,
                               sparse_joint_bilateral_reference)


def _textured(h, w, seed=0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = 128 + 60 * np.sin(xx / 7.0 + rng.uniform(0, 6)) * np.cos(yy / 11.0)
    img[:, w // 2:] += 40  # an edge the range kernel must respect
    return np.clip(img + rng.normal(0, 3, (h, w)), 0, 255).astype(np.float32)


# (cells per sigma, sigma_s per stride, sigma_r, bounds on mean / 99th percentile / max |error|).
# Measured on the scene below, values spanning 0..127 and 0..50:
# - 2 cells per sigma (the module default), the paper's sigmas: mean ~0.04, p99 ~0.18;
# - 1 cell per sigma with the decoders' sigmas (2 * stride, 15): mean 0.14-0.33,
#   p99 0.49-1.22, max 0.85-2.26, about 5x the errors of the finer grid.
GRID_CASES = [(2.0, 3.0, 20.0, (0.1, 0.4, 0.6)), (1.0, 2.0, 15.0, (0.5, 2.0, 3.5))]


@pytest.mark.parametrize("cells, sigma_s_per_stride, sigma_r, bounds", GRID_CASES)
@pytest.mark.parametrize("stride", [3, 5])
def test_grid_filter_matches_brute_force(stride, cells, sigma_s_per_stride, sigma_r, bounds):
    h, w = 60, 80
    guide = _textured(h, w)
    rng = np.random.default_rng(1)
    rr, cc = np.mgrid[0:h:stride, 1:w:stride]
    rows, cols = rr.ravel(), cc.ravel()
    values = np.stack([guide[rows, cols] * 0.5, rng.uniform(0, 50, rows.size)], axis=1).astype(np.float32)
    sigma_s = sigma_s_per_stride * stride
    fast = sparse_joint_bilateral(guide, rows, cols, values, sigma_s=sigma_s, sigma_r=sigma_r,
                                  cells_per_sigma_s=cells, cells_per_sigma_r=cells)
    ref = sparse_joint_bilateral_reference(guide, rows, cols, values, sigma_s=sigma_s, sigma_r=sigma_r)
    mean_bound, p99_bound, max_bound = bounds
    for ch in range(2):
        err = np.abs(fast[..., ch] - ref[..., ch])
        assert np.mean(err) < mean_bound
        assert np.percentile(err, 99) < p99_bound
        assert err.max() < max_bound


def test_filled_dsi_matches_per_layer_brute_force():
    h, w, stride, min_disp, num_disp = 40, 64, 4, 0, 6
    rng = np.random.default_rng(3)
    left = np.repeat(_textured(h, w, seed=2)[:, :, None], 3, axis=2)
    right = np.roll(left, -2, axis=1) + rng.normal(0, 2, left.shape).astype(np.float32)
    guide = left[:, :, 0].copy()
    rr, cc = np.mgrid[0:h:stride, 0:w:stride]
    rows, cols = rr.ravel(), cc.ravel()
    args = (left, guide, rows, cols, right[rows, cols])
    options = dict(min_disp=min_disp, num_disp=num_disp, scale=FillScale(sigma_s=3.0 * stride, sigma_r=20.0),
                   terms=SparseCostTerms(truncation=40.0))
    err = np.abs(filled_sparse_dsi(*args, **options) - filled_sparse_dsi_reference(*args, **options))
    assert np.all(np.mean(err, axis=(0, 1)) < 1.0), np.mean(err, axis=(0, 1))
    assert np.all(np.percentile(err, 99, axis=(0, 1)) < 4.0), np.percentile(err, 99, axis=(0, 1))


def test_reference_fill_has_the_colour_term_only():
    with pytest.raises(ValueError, match="colour term only"):
        filled_sparse_dsi_reference(np.zeros((4, 4, 1)), np.zeros((4, 4)), [0], [0], np.zeros((1, 1)), min_disp=0,
                                    num_disp=2, scale=FillScale(sigma_s=2.0, sigma_r=10.0),
                                    terms=SparseCostTerms(truncation=15.0, census_weight=0.5))


def test_no_samples_nearby_falls_back_to_missing_value():
    guide = np.zeros((30, 30), np.float32)
    out = sparse_joint_bilateral(guide, np.array([0]), np.array([0]), np.array([[7.0]], np.float32),
                                 sigma_s=1.0, sigma_r=5.0, missing_value=-1.0)
    assert out[0, 0, 0] == pytest.approx(7.0, abs=1e-4)
    assert out[29, 29, 0] == -1.0
