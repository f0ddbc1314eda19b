"""The cost volumes of both views, each written in its tree's row layout, in one pass.

Yang's left-right check aggregates a cost volume for each view on that view's own tree.
The right view's costs are the left view's read along diagonals,
``C_R(x, d) = C_L(x + d, d)`` (left pixel ``x`` matches right pixel ``x - d``), so both
come from one computation of ``C_L``.  That computation runs one image row at a time
into a buffer of ``W x D`` float32 (and copies of the border column for the right view's
diagonals) that stays in cache; from it every left pixel's costs are copied to its row of
the left tree's layout, and every right pixel's costs are gathered to its row of the right
tree's layout (:class:`stereobudget.aggregate.TreeLayout`).

Compared with computing ``C_L`` as an (H, W, D) volume and deriving ``C_R`` from it,
this writes each volume once and reads neither back, and both aggregation walks then
stream through their volumes instead of fetching rows from data-dependent addresses
(scripts/bench.py, Teddy: Hybrid 320 -> 253 ms, full pair 225 -> 181 ms, Downsample 227 ->
170 ms when it replaced the volume and its shifted copy).  The values are the same, bit for bit.

Hybrid's cost is a weighted mean of the Sparse fill, sliced from its bilateral grids
(:func:`stereobudget.fill.slice_pixel`), and the dense DSI of the low-passed pair
(:func:`stereobudget.cost.dense_pixel_costs`); both are computed here per pixel, so the
mean needs no volume of its own.  Without grids the cost is the dense DSI alone (full
pair, Downsample).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .._kernels._prefetch import prefetch_row
from .._kernels._simd import LANES, skewed_block_copy
from ..fill._grid import SliceGrids, _slice_scratch, slice_pixel
from ..cost._cost import dense_pixel_costs, gradient_sources, reversed_right_row
from .._kernels._jit import NO_REFCOUNTS, RANGE_KERNEL
from .._kernels._parallel import run_parts
from .._kernels._scratch import empty_volume

#: Pixels ahead whose destination rows are prefetched before they are written.
_PREFETCH_AHEAD = 8


@njit(cache=True, inline="always")
def _gather_right_row(buffer, xr, min_disp, out):
    """``out[i] = buffer[x, i]`` with ``x = xr + min_disp + i`` clamped to the image (border replication)."""
    w, nd = buffer.shape
    base = xr + min_disp
    # Layers with x inside [0, w) form one run; clamp only outside it.
    lo = min(max(-base, 0), nd)
    hi = max(min(w - base, nd), lo)
    for i in range(lo):
        out[i] = buffer[0, i]
    # The run walks the buffer's diagonal: flat index (base + i) * nd + i, unsigned so
    # numba adds no negative-index check to each load (2x faster).
    flat = buffer.reshape(w * nd)
    step = np.uint64(nd + 1)
    first = np.uint64((base + lo) * nd + lo)
    run = out[lo:hi]
    for j in range(hi - lo):
        run[j] = flat[first + np.uint64(j) * step]
    for i in range(hi, nd):
        out[i] = buffer[w - 1, i]


@njit(cache=True, inline="always")
def _gather_right_rows(buffer, w, y, min_disp, right_rows, right_flat, right_row_of_pixel, starts):
    """The right view's rows of image row ``y`` from the left costs in ``buffer``.

    ``buffer`` (W + P, D) holds the row's W left pixels, then P copies of the last one:
    a diagonal that leaves the image on the right reads the border column, as the
    clamped gather does, so the blocks near that border need no clamping.  Blocks of 8
    right pixels x 8 layers whose diagonals stay inside the buffer are copied as vectors
    (:func:`stereobudget._kernels.skewed_block_copy`); the rest (the left border of a
    negative ``min_disp``, a last block of fewer than 8 pixels, layer counts that are not
    a multiple of 8), element by element with clamping (:func:`_gather_right_row`).
    """
    rows, num_disp = buffer.shape
    source = buffer.reshape(rows * num_disp)
    vector_layers = num_disp % LANES == 0
    for first in range(0, w, LANES):
        base = first + min_disp
        # The block reads buffer rows base .. base + num_disp + 6.
        if vector_layers and first + LANES <= w and base >= 0 and base + num_disp + LANES - 2 < rows:
            for r in range(LANES):
                starts[r] = right_row_of_pixel[y * w + first + r] * num_disp
            for layer in range(0, num_disp, LANES):
                skewed_block_copy(source, (base + layer) * num_disp + layer, num_disp, right_flat, starts)
                for r in range(LANES):
                    starts[r] += LANES
        else:
            for xr in range(first, min(first + LANES, w)):
                _gather_right_row(buffer[:w], xr, min_disp, right_rows[right_row_of_pixel[y * w + xr]])


class DensePair(NamedTuple):
    """The pair the dense cost compares, and the gray images of its gradient term."""

    left: np.ndarray         # float32 (H, W, C), 8-bit units
    right: np.ndarray        # float32 (H, W, C)
    left_gray: np.ndarray    # float32, (H, W) or (1, 1) without a gradient term
    right_gray: np.ndarray


class DenseTerms(NamedTuple):
    """Parameters of the dense cost (:func:`stereobudget.cost.dense_pixel_costs`)."""

    truncation: np.float32
    grad_truncation: np.float32
    grad_weight: np.float32


class FillMix(NamedTuple):
    """Hybrid's mean of the fill sliced from its grids and the dense cost.  The grids themselves
    travel as an argument of their own (None: the dense cost alone), not nested in this tuple."""

    guide: np.ndarray        # float32 (H, W), gray I1; (1, 1) without grids
    grid_weight: np.float32
    dense_weight: np.float32


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _pair_item(first_row, last_row, pair, min_disp, terms, grids, mix, left_row_of_pixel, right_row_of_pixel,
               left_rows, right_rows, buffer, rev, dense, den, corner_index, band_index, corner_weight, starts):
    """Image rows ``[first_row, last_row)`` of :func:`_pair_rows`, on one range's scratch.

    A kernel of its own without reference counts, called by the range kernel: the inlined
    fill and costs compile once, not again inside every caller.
    """
    left, right, left_gray, right_gray = pair
    truncation, grad_truncation, grad_weight = terms
    guide, grid_weight, dense_weight = mix
    h, w, channels = left.shape
    num_disp = left_rows.shape[1]
    use_grad = grad_weight > 0
    with_right = right_rows.shape[0] > 0
    left_flat = left_rows.reshape(left_rows.size)
    right_flat = right_rows.reshape(right_rows.size)
    border_rows = buffer.shape[0] - w
    first_column = -(min_disp + num_disp - 1)
    for y in range(first_row, last_row):
        reversed_right_row(right, right_gray, y, first_column, use_grad, rev)
        for x in range(w):
            if x + _PREFETCH_AHEAD < w:
                prefetch_row(left_flat, left_row_of_pixel[y * w + x + _PREFETCH_AHEAD], num_disp)
            if with_right:
                # The right view's rows are written after this image row's costs: asked
                # for now, their lines arrive during the row's work (asked for just
                # before the copy, in a burst, they cost the kernel ~15 %).
                prefetch_row(right_flat, right_row_of_pixel[y * w + x], num_disp)
            o = buffer[x]
            target = left_rows[left_row_of_pixel[y * w + x]]
            if grids is not None:  # decided when compiling: the dense-only kernel has no slice
                slice_pixel(grids, guide, y, x, o, den, corner_index, band_index, corner_weight)
                dense_pixel_costs(left, left_gray, y, x, rev, min_disp, first_column, truncation,
                                  grad_truncation, grad_weight, dense)
                for i in range(num_disp):  # the mix stored to the buffer and the volume in one loop
                    mixed = grid_weight * o[i] + dense_weight * dense[i]
                    o[i] = mixed
                    target[i] = mixed
            else:
                dense_pixel_costs(left, left_gray, y, x, rev, min_disp, first_column, truncation,
                                  grad_truncation, grad_weight, o)
                for i in range(num_disp):
                    target[i] = o[i]
        if with_right:
            last = buffer[w - 1]
            for k in range(w, w + border_rows):
                row = buffer[k]
                for i in range(num_disp):  # an array assignment would need numba's reference counts
                    row[i] = last[i]
            _gather_right_rows(buffer, w, y, min_disp, right_rows, right_flat, right_row_of_pixel, starts)


@njit(cache=True, **RANGE_KERNEL)
def _pair_rows(pair, min_disp, terms, grids, mix, left_row_of_pixel, right_row_of_pixel, left_rows, right_rows,
               buffer, rev, dense, den, corner_index, band_index, corner_weight, starts, first, stop):
    """Left costs of image rows ``[first, stop)`` into ``left_rows``, the right view's into
    ``right_rows``, on the range's scratch (:func:`_pair_scratch`).

    ``pair``: :class:`DensePair`, ``terms``: :class:`DenseTerms`, ``grids``: :class:`SliceGrids`
    or None, ``mix``: :class:`FillMix`.
    With grids the cost is ``grid_weight * slice + dense_weight * dense``, else the dense cost.
    ``right_rows`` with no rows skips the right view.
    """
    _pair_item(first, stop, pair, min_disp, terms, grids, mix, left_row_of_pixel, right_row_of_pixel, left_rows,
               right_rows, buffer, rev, dense, den, corner_index, band_index, corner_weight, starts)


def _pair_scratch(width, channels, min_disp, num_disp, right_view):
    """Scratch of one range of :func:`_pair_rows`: the row buffer, the reversed right row, the dense
    costs of a pixel, the slice's scratch and the right view's gather starts."""
    # Rows past the image that the right view's diagonals read (the clamped border column).
    border_rows = max(min_disp, 0) + num_disp + LANES if right_view else 0
    span = width + num_disp - 1  # columns -(min_disp + num_disp - 1) .. w - 1 - min_disp of the right image
    return (np.empty((width + border_rows, num_disp), dtype=np.float32),
            np.empty((channels + 1, span), dtype=np.float32), np.empty(num_disp, dtype=np.float32),
            *_slice_scratch(num_disp), np.empty(LANES, dtype=np.int64))


def pair_cost_rows(left: np.ndarray, right: np.ndarray, *, min_disp: int, num_disp: int, truncation: float,
                   grad_weight: float, grad_truncation: float, left_layout, right_layout=None,
                   grids: SliceGrids | None = None, guide: np.ndarray | None = None,
                   mix_weights: tuple[float, float] = (1.0, 1.0)):
    """Cost volumes of the left and right views, in the row layouts of their trees.

    Parameters
    ----------
    left, right : ndarray, float32 (H, W, C)
        The pair the dense cost compares (8-bit units): I1 and I2, or their low-passed /
        upsampled versions.
    min_disp, num_disp : int
        Layer ``i`` is disparity ``min_disp + i``.
    truncation, grad_weight, grad_truncation : float
        Parameters of the dense cost (:func:`stereobudget.cost.full_dsi`).
    left_layout : stereobudget.aggregate.TreeLayout
        Row layout of the left volume (the left image's tree).
    right_layout : stereobudget.aggregate.TreeLayout, optional
        Row layout of the right volume; ``None``: no right volume.
    grids : stereobudget.fill.SliceGrids, optional
        Grids of the Sparse fill (:func:`stereobudget.fill.sparse_dsi_grids`) with
        ``num_disp`` layers, sliced with ``guide`` (float32 (H, W), gray I1).
    mix_weights : (float, float)
        With ``grids``: the cost is ``mix_weights[0] * fill + mix_weights[1] * dense``
        (Hybrid's weighted mean): each product and the sum rounded to float32 once.

    Returns
    -------
    left_rows : ndarray, float32 (H * W, num_disp)
        Row ``k`` holds the costs of left pixel ``left_layout.pixel_of_row[k]``.
    right_rows : ndarray, float32 (H * W, num_disp), or None
        Row ``k`` holds the costs of right pixel ``right_layout.pixel_of_row[k]``:
        ``C_R(x, d) = C_L(x + d, d)``, the border column where ``x + d`` leaves the image.
    """
    h, w, _ = left.shape
    left = np.ascontiguousarray(left, np.float32)
    right = np.ascontiguousarray(right, np.float32)
    left_gray, right_gray = gradient_sources(left, right, grad_weight)
    use_grids = grids is not None
    if use_grids and (guide is None or grids.values.shape[1] != num_disp):
        raise ValueError("grids need a guide and num_disp layers")
    left_rows = empty_volume((h * w, int(num_disp)))
    right_rows = (empty_volume((h * w, int(num_disp))) if right_layout is not None
                  else np.empty((0, int(num_disp)), np.float32))
    empty_rows = np.zeros(0, np.int64)
    terms = DenseTerms(np.float32(truncation), np.float32(grad_truncation), np.float32(grad_weight))
    mix = FillMix(np.ascontiguousarray(guide, np.float32) if use_grids else np.zeros((1, 1), np.float32),
                  np.float32(mix_weights[0]), np.float32(mix_weights[1]))
    run_parts(_pair_rows, h, DensePair(left, right, left_gray, right_gray), int(min_disp),
              terms, grids, mix, left_layout.row_of_pixel,
              right_layout.row_of_pixel if right_layout is not None else empty_rows, left_rows, right_rows,
              scratch=lambda: _pair_scratch(w, left.shape[2], int(min_disp), int(num_disp), right_layout is not None))
    return left_rows, (right_rows if right_layout is not None else None)
