"""Winner-take-all: each pixel's disparity from its (aggregated) cost layers.

The smallest cost wins, and a parabola through it and its two neighbours gives the
sub-pixel offset (clamped to +-0.5).  :func:`subpixel_winner` is the one definition used
by the stand-alone :func:`winner_take_all`, by the aggregation that takes winners as it
walks the tree (:func:`stereobudget.aggregate.aggregate_winners`) and by the diagonal
right-view search (:func:`stereobudget.aggregate.right_disparity_from_left`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL
from .._kernels._parallel import run_parts
from .._kernels._simd import first_min


@njit(cache=True, inline="always")
def subpixel_winner(costs, min_disp):
    """Disparity of the smallest of ``costs`` (one pixel's layers), refined by a parabola
    through the minimum and its two neighbours (offset clamped to +-0.5)."""
    return refined_winner(costs, first_min(costs), min_disp)


@njit(cache=True, inline="always")
def refined_winner(costs, best, min_disp):
    """:func:`subpixel_winner` for a known index ``best`` of the first smallest of ``costs``."""
    nd = costs.shape[0]
    bv = costs[best]
    sub = np.float32(0.0)
    if 0 < best < nd - 1:
        cm = costs[best - 1]
        cp = costs[best + 1]
        denom = cm - 2 * bv + cp
        if denom > 1e-12:
            sub = np.float32(0.5) * (cm - cp) / denom
            if sub > 0.5:
                sub = np.float32(0.5)
            elif sub < -0.5:
                sub = np.float32(-0.5)
    return min_disp + best + sub


def winner_take_all(cost, min_disp):
    """Per-pixel argmin over disparity with a parabola fit through the minimum and its neighbours.

    Parameters
    ----------
    cost : ndarray, float32 (H, W, D)
    min_disp : int

    Returns
    -------
    ndarray, float32 (H, W)
    """
    h, w = cost.shape[:2]
    out = np.empty((h, w), dtype=np.float32)
    run_parts(_winner_rows, h, cost, min_disp, out)
    return out


@njit(cache=True, **RANGE_KERNEL)
def _winner_rows(cost, min_disp, out, first, stop):
    """Rows ``[first, stop)`` of :func:`winner_take_all`."""
    for y in range(first, stop):
        for x in range(cost.shape[1]):
            out[y, x] = subpixel_winner(cost[y, x], min_disp)
