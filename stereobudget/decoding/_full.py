"""The full-pair decoder (``--stride 1``): census cost, semi-global aggregation, LR check.

Real pairs differ in exposure and noise between the cameras and hold slanted surfaces
(roads, table tops) over wide ranges.  The census cost (:mod:`stereobudget.cost`) is blind
to a monotonic change of brightness, and semi-global aggregation charges a slanted
surface one small penalty per disparity step instead of the tree filter's fronto-parallel
pull.  Pixels the left-right check rejects (occlusions, mismatches) take the disparity of
the nearest stable pixel of their row, or for Hybrid the smaller of the stable ones on
either side (:func:`stereobudget.aggregate.fill_from_row`); each of them then takes the
weighted median of its neighbourhood (:func:`stereobudget.aggregate.weighted_median_fill`),
and the map a 5x5 median twice.

The penalties scale with the cost volume itself: P1 and P2 are multiples of the *typical
margin*, the median over pixels of (mean cost over disparities - smallest cost).  That
margin is what a pixel's data term says for its winner; measured as 7.5-9 bits on every
Middlebury and KITTI scene of the development set, so fixed multiples of it carry over
between scenes and image sizes.
"""

from __future__ import annotations

import numpy as np

from ..aggregate._refine import fill_from_row, full_pair_disparity, left_right_stable, median_filter_disparity
from ..aggregate._planes import plane_refinement
from ..aggregate._weighted_median import weighted_median_fill
from ..aggregate._semiglobal import pixel_margins, semiglobal_disparities
from ..cost._census import census_cost_volume
from ..cost._cost import to_gray
from ..fill._lowpass import _sample_values_f32
from .._kernels import _scratch as scratch


def decode_full(left_f, guide, samples, tree_guide, *, min_disp, num_disp, params, timer):
    """Left disparity of a full pair (a stride-1 sample set holds all of I2): census and
    semi-global paths, or with ``params.full_cost="ad"`` the paper's Eq. (1) cost on Yang's tree.

    Arguments as :func:`stereobudget.decoding._sparse.decode_sparse` (``guide`` unused: the
    census route takes the gray images of both views itself).
    """
    with timer("prepare"):
        right_f = _sample_values_f32(samples).reshape(samples.height, samples.width, samples.channels)
    route = census_semiglobal_disparity if params.full_cost == "census" else full_pair_disparity
    return route(left_f, right_f, tree_guide=tree_guide, min_disp=min_disp, num_disp=num_disp,
                 params=params, timer=timer)


def typical_margin(cost: np.ndarray, *, step: int = 4, floor: float = 1.0) -> float:
    """Median over pixels of (mean over disparities - minimum) of a cost volume.

    Parameters
    ----------
    cost : ndarray, (H, W, D)
    step : int
        Every ``step``-th row and column is looked at (the median settles long before).

    Returns
    -------
    float
        In the cost's units; at least ``floor``.
    """
    return max(float(np.median(pixel_margins(cost, step=step))), floor)


def census_semiglobal_disparity(left_f, right_f, *, tree_guide, min_disp, num_disp, params, timer):
    """Left disparity of a full pair by census + semi-global aggregation (module docstring).

    Parameters
    ----------
    left_f, right_f : ndarray, float32 (H, W, C)
        The pair in 8-bit units.
    tree_guide : ndarray, (H, W, C)
        Unused (the tree routes take it); kept so every full-pair route has one signature.
    min_disp, num_disp : int
    params : stereobudget.decoding.DecoderParams
        ``sgm_p1``, ``sgm_p2`` (multiples of the typical margin), ``sgm_edge_scale``,
        ``sgm_paths``, ``median_size``, ``median_passes``.
    timer : callable
        ``timer(stage)`` context manager.

    Returns
    -------
    ndarray, float32 (H, W)
    """
    with timer("cost"):
        left_gray, right_gray = to_gray(left_f), to_gray(right_f)
        cost = census_cost_volume(left_gray, right_gray, min_disp=min_disp, num_disp=num_disp)  # uint8
        margin = typical_margin(cost)
    return semiglobal_disparity(cost, left_gray, min_disp=min_disp, p1=params.sgm_p1 * margin,
                                p2=params.sgm_p2 * margin, params=params, timer=timer, image=left_f)


def semiglobal_disparity(cost, guide, *, min_disp, p1, p2, params, timer, samples=None, paths=None,
                         cost_max=None, row_fill=None, image=None):
    """Semi-global paths, diagonal left-right check, row fill of rejected pixels and their
    weighted median (``params.rejected_median``), the plane refinement
    (``params.plane_refinement``), median.

    The tail that every semi-global route shares (the full pair, both of Hybrid's).

    Parameters
    ----------
    cost : ndarray, uint8 or float32 (H, W, D)
        Left-view cost; consumed.
    guide : ndarray, float32 (H, W)
        I1's gray image (lowers P2 at its edges).
    min_disp : int
    p1, p2 : float
        Path penalties in the cost's units.
    params : stereobudget.decoding.DecoderParams
        ``sgm_edge_scale``, ``sgm_paths`` (unless ``paths``), ``rejected_median``, ``median_size``,
        ``median_passes``, ``plane_refinement``, ``plane_segment_size``.
    timer : callable
    samples : SampleSet, optional
        The samples the plane refinement checks its planes against.
    paths : {4, 8}, optional
        Semi-global paths (default: ``params.sgm_paths``).
    cost_max : float, optional
        A bound on the costs (:func:`stereobudget.aggregate.semiglobal_aggregate`).
    row_fill : {"nearest", "background"}, optional
        What the rejected pixels take (default: ``params.row_fill``).
    image : ndarray, float32 (H, W, C), optional
        I1, whose colours weigh the rejected pixels' weighted median (default: ``guide``).

    Returns
    -------
    ndarray, float32 (H, W)
    """
    max_disp = min_disp + cost.shape[2] - 1
    with timer("aggregate"):
        # The winners are taken row by row as the last pass completes each row's sum.
        disp_left, disp_right = semiglobal_disparities(cost, guide, min_disp=int(min_disp), p1=p1, p2=p2,
                                                       edge_scale=params.sgm_edge_scale,
                                                       paths=params.sgm_paths if paths is None else paths,
                                                       cost_max=cost_max)
        # Consumed: its memory serves the next decode's volume of this size, which would
        # otherwise page-fault on fresh memory (~55 ms for Teddy's 39 MiB on a VM).
        scratch.recycle(cost)
        del cost
    with timer("refine"):
        stable = left_right_stable(disp_left, disp_right, np.float32(1.0))
        filled = fill_from_row(disp_left, stable,
                               background=(params.row_fill if row_fill is None else row_fill) == "background")
        if params.rejected_median:
            filled = weighted_median_fill(filled, stable, guide if image is None else image)
    if params.plane_refinement:
        with timer("planes"):
            filled = plane_refinement(filled, stable, guide, samples=samples, min_disp=min_disp,
                                      max_disp=max_disp, size=params.plane_segment_size)
    with timer("refine"):
        return median_filter_disparity(filled, params.median_size, passes=params.median_passes)
