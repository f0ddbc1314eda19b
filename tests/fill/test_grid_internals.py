"""White-box tests of stereobudget.fill._grid: the grid blur, held to three plain passes bit for bit.

test_bilateral.py holds the fills to brute-force references; this pins the blur kernel the
grid is made of and goes with ``_grid.py`` when it is rewritten.
"""

from __future__ import annotations

import numpy as np
import pytest

from stereobudget.fill import grid_geometry
import stereobudget.fill._grid as grid_module


def _blur_axis_in_tap_order(grid, kernel, axis):
    """One zero-boundary pass: every output starts from its first tap inside the grid and
    adds the others in kernel order (float32 products and sums, as the kernel does)."""
    r = kernel.shape[0] // 2
    n = grid.shape[axis]
    moved = np.moveaxis(grid, axis, 0)
    out = np.empty_like(moved)
    for i in range(n):
        taps = [t for t in range(-r, r + 1) if 0 <= i + t < n]
        acc = kernel[taps[0] + r] * moved[i + taps[0]]
        for t in taps[1:]:
            acc = acc + kernel[t + r] * moved[i + t]
        out[i] = acc
    return np.moveaxis(out, 0, axis)


@pytest.mark.parametrize("channels", [1, 5, 64])
@pytest.mark.parametrize("guide_max", [255.0, 20.0])  # 20: fewer intensity cells than z-taps
@pytest.mark.parametrize("cells_per_sigma", [1.0, 2.0])  # seven taps (summed in one pass) and more
def test_grid_blur_is_three_passes_bit_for_bit(channels, guide_max, cells_per_sigma):
    geom = grid_geometry(70, 95, guide_max, sigma_s=10.0, sigma_r=15.0, cells_per_sigma_s=cells_per_sigma,
                         cells_per_sigma_r=cells_per_sigma)
    rng = np.random.default_rng(3)
    grid = rng.uniform(0, 50, geom.shape + (channels,)).astype(np.float32)
    grid[rng.random(geom.shape) < 0.6] = 0.0  # splats leave most cells empty
    expected = grid
    for axis, std in ((0, geom.blur_s), (1, geom.blur_s), (2, geom.blur_r)):
        radius = max(1, int(np.ceil(3.0 * std)))
        t = np.arange(-radius, radius + 1, dtype=np.float64)
        kernel = np.exp(-0.5 * (t / std) ** 2)
        expected = _blur_axis_in_tap_order(expected, (kernel / kernel.sum()).astype(np.float32), axis)
    blurred, spatial = grid_module._blur_grid(grid.copy(), geom)
    assert blurred.dtype == np.float32 and blurred.shape == grid.shape
    np.testing.assert_array_equal(blurred, expected)
    # The spatial-only fallback: the blurred cells added in intensity order from the first.
    summed = expected[:, :, 0].copy()
    for z in range(1, grid.shape[2]):
        summed += expected[:, :, z]
    assert spatial.dtype == np.float32
    np.testing.assert_array_equal(spatial, summed)
