"""Sparse (paper Fig. 2(b)): Eq. (2) sparse DSI -> Eq. (3) normalised joint bilateral fill
guided by I1 -> Yang's non-local aggregation on I1's MST -> winner-take-all with parabolic
sub-pixel refinement -> 5x5 median, twice.  The fill's arguments are shared with Hybrid."""

from __future__ import annotations

import numpy as np

from ..aggregate import _mst, _tree
from ..aggregate._refine import median_filter_disparity
from ..cost._census import lattice_census
from ..cost._cost import sample_row_steps, to_gray
from ..cost._sparse import SparseCostTerms
from ..fill._bilateral import FillScale, filled_sparse_dsi
from ..fill._lowpass import _sample_values_f32
from ..cost._layers import volume_layers
from ..sampling._patterns import grid_shape
from .._kernels import _scratch as scratch
from ._params import sampling_stride


def sparse_fill_arguments(left_f, guide, samples, params):
    """Positional and keyword arguments of the Sparse fill (Eq. 2 + Eq. 3) for these samples."""
    rows, cols = samples.positions()
    values = _sample_values_f32(samples)
    steps = None
    codes = None
    # A grid placed off its lattice (rectified at the host) keeps its lattice neighbours:
    # its steps and census come from the lattice, I1's at the spacing the grid has where it landed.
    placed = getattr(samples, "lattice", None)
    if samples.pattern.is_regular_grid and params.step_weight > 0:
        # Row neighbours of a grid are stride_x pixels apart: their difference is exact data.
        lattice = to_gray(values.reshape(grid_shape(samples.pattern, samples.height, samples.width) + (-1,)))
        steps = sample_row_steps(lattice).ravel()
    elif placed is not None:
        lattice = to_gray(np.asarray(placed.values, np.float32).reshape(placed.shape + (-1,)))
        if params.step_weight > 0:
            steps = sample_row_steps(lattice).ravel()[placed.index]
        if params.sparse_census_weight > 0:
            codes = lattice_census(lattice)[placed.index]
    scale = FillScale(sigma_s=params.sigma_s_per_stride * sampling_stride(samples), sigma_r=params.sigma_r,
                      cells_per_sigma_s=params.grid_cells_per_sigma_s,
                      cells_per_sigma_r=params.grid_cells_per_sigma_r)
    grid = samples.pattern.is_regular_grid
    spacing = (samples.pattern.stride_x, samples.pattern.stride_y) if grid else (
        tuple(placed.spacing) if placed is not None else None)
    terms = SparseCostTerms(truncation=params.truncation, step_weight=params.step_weight,
                            step_truncation=params.step_truncation,
                            step_spacing=spacing[0] if spacing else samples.pattern.stride_x,
                            census_weight=params.sparse_census_weight, census_spacing=spacing)
    kwargs = dict(scale=scale, terms=terms, right_steps=steps)
    if codes is not None:
        kwargs["right_codes"] = codes
    offsets = getattr(samples, "offsets", None)
    if offsets is not None:
        kwargs["right_offsets"] = offsets
    return (left_f, guide, rows, cols, values), kwargs


def sparse_filled_cost(left_f, guide, samples, *, min_disp, num_disp, params, layout=None):
    """The Sparse fill's float32 volume (:func:`stereobudget.fill.filled_sparse_dsi`), its rows in
    ``layout``'s order when one is given."""
    args, kwargs = sparse_fill_arguments(left_f, guide, samples, params)
    return filled_sparse_dsi(*args, min_disp=min_disp, num_disp=num_disp, **kwargs,
                             pixel_of_row=None if layout is None else layout.pixel_of_row)


def decode_sparse(left_f, guide, samples, tree_guide, *, min_disp, num_disp, params, timer):
    """Left disparity by the Sparse decoder (module docstring).

    Parameters
    ----------
    left_f : ndarray, float32 (H, W, C)
        I1 in 8-bit units.
    guide : ndarray, float32 (H, W)
        Its gray image.
    samples : SampleSet
    tree_guide : ndarray, (H, W, C)
        The image I1's tree is built on (the 8-bit original when there is one).
    min_disp, num_disp : int
    params : DecoderParams
    timer : StageTimer

    Returns
    -------
    ndarray, float32 (H, W)
    """
    with timer("tree"):
        tree, = _mst.build_trees([tree_guide], sigma=params.tree_sigma, median_size=params.tree_median)
    with timer("jbf_fill"):
        # The fill writes its volume in the tree's depth-first row order, so the
        # aggregation walk streams through it (half the time of a pixel-order walk).
        layout = _mst.tree_layout(tree)
        cost = sparse_filled_cost(left_f, guide, samples, min_disp=min_disp, num_disp=volume_layers(num_disp),
                                  params=params, layout=layout)
    with timer("aggregate"):  # the winners are taken during the aggregation's walk
        disp = _tree.aggregate_rows_winners(cost, layout, min_disp=int(min_disp), num_disp=num_disp)
    scratch.recycle(cost)
    with timer("median"):
        return median_filter_disparity(disp, params.median_size, passes=params.median_passes)
