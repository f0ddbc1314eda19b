"""Both views' cost volumes in their trees' row layouts (stereobudget.aggregate._pair_volumes)."""

import numpy as np
import pytest

from stereobudget.cost import SparseCostTerms
from stereobudget.fill import FillScale, filled_sparse_dsi, sparse_dsi_grids
from stereobudget.cost import full_dsi, to_gray
from stereobudget.aggregate import build_tree, tree_layout
from stereobudget.aggregate import pair_cost_rows

DENSE = dict(truncation=7.0, grad_weight=0.89, grad_truncation=2.0)


def _pair(seed=0, h=23, w=57):
    rng = np.random.default_rng(seed)
    left = rng.uniform(0, 255, (h, w, 3)).astype(np.float32)
    right = np.roll(left, -4, axis=1) + rng.normal(0, 3, (h, w, 3)).astype(np.float32)
    return left, np.clip(right, 0, 255).astype(np.float32)


def _layouts(left, right):
    return (tree_layout(build_tree(left, median_size=0)), tree_layout(build_tree(right, median_size=0)))


@pytest.mark.parametrize("min_disp, num_disp", [(0, 12), (-3, 9), (5, 7), (0, 70),
                                                (0, 16), (-5, 8), (3, 24), (0, 32), (-9, 16)])
def test_dense_rows_are_the_full_dsi_and_its_diagonals(min_disp, num_disp, right_view_reference):
    # num_disp 70 > width: every right pixel's diagonal leaves the image on both sides.
    # Multiples of 8 layers: blocks of 8 x 8 inside the image are copied as vectors, the
    # blocks near the borders element by element; both must give the diagonals.
    left, right = _pair()
    left_layout, right_layout = _layouts(left, right)
    expected = full_dsi(left, right, min_disp=min_disp, num_disp=num_disp, **DENSE)
    left_rows, right_rows = pair_cost_rows(left, right, min_disp=min_disp, num_disp=num_disp, **DENSE,
                                           left_layout=left_layout, right_layout=right_layout)
    np.testing.assert_array_equal(left_rows, expected.reshape(-1, num_disp)[left_layout.pixel_of_row])
    right_expected = right_view_reference(expected, min_disp).reshape(-1, num_disp)
    np.testing.assert_array_equal(right_rows, right_expected[right_layout.pixel_of_row])


def test_without_a_right_layout_only_the_left_view_is_made():
    left, right = _pair(1)
    left_layout, _ = _layouts(left, right)
    left_rows, right_rows = pair_cost_rows(left, right, min_disp=0, num_disp=6, **DENSE, left_layout=left_layout)
    assert right_rows is None and left_rows.shape == (left.shape[0] * left.shape[1], 6)


@pytest.mark.parametrize("stride, min_disp", [(3, 0), (4, 2), (3, -2)])
def test_hybrid_rows_are_the_weighted_mean_of_fill_and_dense(stride, min_disp, right_view_reference):
    # A lattice (split grids) with min_disp >= 0, the per-layer grids with a negative one.
    left, right = _pair(2, h=30, w=48)
    guide = to_gray(left)
    rows, cols = np.meshgrid(np.arange(1, 30, stride), np.arange(0, 48, stride), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    values = right[rows, cols]
    num_disp = 11
    fill_args = dict(min_disp=min_disp, num_disp=num_disp, terms=SparseCostTerms(truncation=15.0),
                     scale=FillScale(sigma_s=2.0 * stride, sigma_r=15.0, cells_per_sigma_s=1.0, cells_per_sigma_r=1.0))
    fill = filled_sparse_dsi(left, guide, rows, cols, values, **fill_args)
    grids = sparse_dsi_grids(left, guide, rows, cols, values, **fill_args)
    weights = (0.7 / 15.0, 0.3 / 2.55)
    left_layout, right_layout = _layouts(left, right)
    left_rows, right_rows = pair_cost_rows(left, right, min_disp=min_disp, num_disp=num_disp, **DENSE,
                                           left_layout=left_layout, right_layout=right_layout, grids=grids,
                                           guide=guide, mix_weights=weights)
    dense = full_dsi(left, right, min_disp=min_disp, num_disp=num_disp, **DENSE)
    # float32 products and sum, each rounded once: the kernel's arithmetic.
    expected = np.float32(weights[0]) * fill + np.float32(weights[1]) * dense
    np.testing.assert_array_equal(left_rows, expected.reshape(-1, num_disp)[left_layout.pixel_of_row])
    right_expected = right_view_reference(expected, min_disp).reshape(-1, num_disp)
    np.testing.assert_array_equal(right_rows, right_expected[right_layout.pixel_of_row])


def test_grids_need_their_guide_and_layer_count():
    left, right = _pair(3)
    guide = to_gray(left)
    rows, cols = np.meshgrid(np.arange(0, 23, 3), np.arange(0, 57, 3), indexing="ij")
    grids = sparse_dsi_grids(left, guide, rows.ravel(), cols.ravel(), right[rows.ravel(), cols.ravel()],
                             min_disp=0, num_disp=5, scale=FillScale(sigma_s=6.0, sigma_r=15.0),
                             terms=SparseCostTerms(truncation=15.0))
    left_layout, _ = _layouts(left, right)
    with pytest.raises(ValueError, match="layers"):
        pair_cost_rows(left, right, min_disp=0, num_disp=6, **DENSE, left_layout=left_layout, grids=grids,
                       guide=guide)


@pytest.mark.parametrize("shape", [(1, 1), (4, 2), (5, 3), (23, 57)])
def test_gradient_taken_in_the_kernels_is_the_gradient_image(shape):
    # The cost kernels take I1's and I2's x-gradients pixel by pixel (cost.gradient_at);
    # they must be horizontal_gradient's values, bit for bit.
    from numba import njit

    from stereobudget.cost import gradient_at, horizontal_gradient

    @njit
    def every_pixel(gray):
        out = np.empty(gray.shape, np.float32)
        for y in range(gray.shape[0]):
            for x in range(gray.shape[1]):
                out[y, x] = gradient_at(gray, y, x)
        return out

    gray = np.random.default_rng(5).uniform(0, 255, shape).astype(np.float32)
    np.testing.assert_array_equal(every_pixel(gray), horizontal_gradient(gray))
