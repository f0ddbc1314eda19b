"""Hybrid (paper Fig. 2(c)): a weighted mean of the Sparse filled DSI and a full DSI between
the low-passed interpolation of the samples and an equally low-passed I1.

By default the full DSI is a census at the grid's spacing, summed along semi-global paths
with a diagonal left-right check and a row fill (robust to the exposure differences and
slanted surfaces of real pairs); ``hybrid_aggregation="tree"`` is the paper's: absolute
differences, Yang's tree, left-right check against the interpolated right image, non-local
refinement; ``"semiglobal"`` puts the paper's mixed cost on the semi-global paths.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ..aggregate._pair_volumes import pair_cost_rows
from ..aggregate._refine import left_right_refined_rows, pair_trees
from ..cost._census import mix_spaced_census, spaced_census
from ..cost._cost import to_gray
from ..fill._bilateral import sparse_dsi_grids
from ..fill._grid import release_grids
from ..fill._lowpass import gaussian_lowpass, lowpass_interpolation
from ..cost._layers import volume_layers
from .._kernels import _scratch as scratch
from ._full import semiglobal_disparity, typical_margin
from ._params import sampling_stride
from ._sparse import sparse_fill_arguments, sparse_filled_cost


def hybrid_weight(stride: float) -> float:
    """Weight of the Sparse DSI in Hybrid's mean, from the sampling stride.

    The sweep in docs/results.md (strides 3 and 5, weights 0.3-0.9) has its optimum at
    0.7 for both: the interpolated DSI is blurred in proportion to the stride, but so is
    the Sparse fill (sigma_s = 1.5 stride), so their relative reliability does not move
    with the sampling rate and one weight serves all strides.
    """
    return 0.7


def decode_hybrid(left_f, guide, samples, tree_guide, *, min_disp, num_disp, params, timer):
    """Left disparity by the Hybrid decoder, on the route ``params.hybrid_aggregation`` names.

    Parameters are those of :func:`stereobudget.decoding._sparse.decode_sparse`.
    """
    layers = volume_layers(num_disp)
    stride = sampling_stride(samples)
    weight = params.hybrid_sparse_weight if params.hybrid_sparse_weight is not None else hybrid_weight(stride)
    if params.hybrid_aggregation == "semiglobal_census":
        with timer("interpolate"):
            sigma = params.lowpass_per_stride * stride
            right_lp = lowpass_interpolation(samples, sigma=sigma)
            left_lp = gaussian_lowpass(left_f, sigma=sigma)
        return _hybrid_census_semiglobal(left_f, guide, samples, left_lp, right_lp, min_disp=min_disp,
                                         num_disp=num_disp, params=params, timer=timer, weight=weight)
    with timer("jbf_fill"):
        # Splat and blur only: the grids are sliced pixel by pixel in the cost kernel below.
        args, kwargs = sparse_fill_arguments(left_f, guide, samples, params)
        grids = sparse_dsi_grids(*args, min_disp=min_disp, num_disp=layers, **kwargs)
    with timer("interpolate"):
        sigma = params.lowpass_per_stride * stride
        right_lp = lowpass_interpolation(samples, sigma=sigma)
        left_lp = gaussian_lowpass(left_f, sigma=sigma)
    if params.hybrid_aggregation == "semiglobal":
        return _hybrid_semiglobal(left_lp, right_lp, grids, guide, min_disp=min_disp, num_disp=num_disp,
                                  params=params, timer=timer, mix_weights=_hybrid_mix(params, weight), image=left_f)
    with timer("tree"):
        tree, left_layout, right_layout = pair_trees(tree_guide, right_lp, params=params)
    with timer("cost"):
        # The fill and the dense DSI of the low-passed pair, both brought to [0, 1] by their
        # largest possible value and mixed per pixel; the right view's volume is gathered
        # from the same rows (volumes.pair_cost_rows).
        left_rows, right_rows = pair_cost_rows(
            left_lp, right_lp, min_disp=min_disp, num_disp=layers, truncation=params.full_truncation,
            grad_weight=params.grad_weight, grad_truncation=params.grad_truncation, left_layout=left_layout,
            right_layout=right_layout, grids=grids, guide=guide, mix_weights=_hybrid_mix(params, weight))
    release_grids(grids)
    del grids
    disp, _ = left_right_refined_rows(left_rows, right_rows, left_layout=left_layout, right_layout=right_layout,
                                      left_tree=tree, min_disp=min_disp, params=params, timer=timer,
                                      num_disp=num_disp)
    scratch.recycle(left_rows, right_rows)
    return disp


def _hybrid_mix(params, weight):
    """Weights of the fill and of the dense DSI in Hybrid's mean, each brought to [0, 1]
    by its largest possible value."""
    dense_max = (1 - params.grad_weight) * params.full_truncation + params.grad_weight * params.grad_truncation
    return weight / params.truncation, (1.0 - weight) / dense_max


def _hybrid_semiglobal(left_lp, right_lp, grids, guide, *, min_disp, num_disp, params, timer, mix_weights, image):
    """Hybrid's mixed DSI aggregated along semi-global paths, LR-checked on the diagonal,
    rejected pixels filled from their row (as the full pair, :mod:`stereobudget.decoding._full`)."""
    h, w = guide.shape
    layers = volume_layers(num_disp)
    with timer("cost"):
        pixel_order = SimpleNamespace(row_of_pixel=np.arange(h * w, dtype=np.int32))
        rows, _ = pair_cost_rows(left_lp, right_lp, min_disp=min_disp, num_disp=layers,
                                 truncation=params.full_truncation, grad_weight=params.grad_weight,
                                 grad_truncation=params.grad_truncation, left_layout=pixel_order, grids=grids,
                                 guide=guide, mix_weights=mix_weights)
        release_grids(grids)
        cost = np.ascontiguousarray(rows.reshape(h, w, layers)[:, :, :num_disp])  # float32
        scratch.recycle(rows)
        margin = typical_margin(cost, floor=0.0)
    return semiglobal_disparity(cost, guide, min_disp=min_disp, p1=params.sgm_p1 * margin,
                                p2=params.hybrid_sgm_p2 * margin, params=params, timer=timer,
                                paths=params.hybrid_sgm_paths, row_fill=params.hybrid_row_fill, image=image)


def _hybrid_census_semiglobal(left_f, guide, samples, left_lp, right_lp, *, min_disp, num_disp, params, timer,
                              weight):
    """Hybrid with a radiometrically robust dense term: the Sparse fill mixed with the census
    of the low-passed pair at the grid's spacing, aggregated on semi-global paths."""
    with timer("jbf_fill"):
        cost = sparse_filled_cost(left_f, guide, samples, min_disp=min_disp, num_disp=num_disp, params=params)
    return census_semiglobal_tail(cost, guide, samples, left_lp, right_lp, min_disp=min_disp, params=params,
                                  timer=timer, weight=weight, image=left_f)


def census_semiglobal_tail(cost, guide, samples, left_lp, right_lp, *, min_disp, params, timer, weight, image):
    """What the default Hybrid runs after the Sparse fill ``cost`` (H, W, D): the census of the
    low-passed pair mixed in, the semi-global paths, the checks, the row fill and the weighted
    median (weighed by the colours of I1, ``image``).  Its own function so that ``python -m
    stereobudget.warm`` can compile it apart from the fill."""
    p = samples.pattern
    with timer("cost"):
        cost = np.ascontiguousarray(cost, np.float32)
        left_codes = spaced_census(to_gray(left_lp), spacing_x=p.stride_x, spacing_y=p.stride_y)
        right_codes = spaced_census(to_gray(right_lp), spacing_x=p.stride_x, spacing_y=p.stride_y)
        mix_spaced_census(cost, left_codes, right_codes, min_disp=int(min_disp),
                          volume_scale=weight / params.truncation, census_weight=(1.0 - weight) / 8.0)
        margin = typical_margin(cost, floor=0.0)
    # The fill is a weighted mean of sample costs in [0, truncation] (truncation where it has
    # none), and the census has 8 bits: the mix is at most |weight| + |1 - weight|.
    return semiglobal_disparity(cost, guide, min_disp=min_disp, p1=params.sgm_p1 * margin,
                                p2=params.hybrid_sgm_p2 * margin, params=params, timer=timer,
                                samples=samples, paths=params.hybrid_sgm_paths, row_fill=params.hybrid_row_fill,
                                cost_max=abs(weight) + abs(1.0 - weight), image=image)
