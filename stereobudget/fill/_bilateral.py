"""The filled sparse DSI (Eqs. 2-4): Eq. (2)'s cost of every left pixel against the right samples,
splatted into a bilateral grid (``_grid.py`` blurs and slices it) and normalised by the samples' mask.

The cost splatted at each sample is Eq. (2), evaluated by :func:`stereobudget.cost.sample_cost`
with its terms as one record (:class:`stereobudget.cost.SparseCostTerms`): the splat kernels
here only place it in the grid.  A full sample lattice (a regular grid) takes the lattice
splat, whose mask channels repeat with the stride; any other pattern the row splat, with a
weight grid per disparity.  Both are held bit for bit to the plain per-sample splat
(:func:`_splat_sparse_dsi_split`), which no decode runs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numba import get_num_threads, njit

from .._kernels._jit import NO_REFCOUNTS, RANGE_KERNEL
from .._kernels._parallel import run_parts
from .._kernels._scratch import empty_volume, zeroed_volume
from ..cost._sparse import LeftPixels, RightSamples, SparseCostTerms, left_terms, left_terms_at, sample_cost
from ._geometry import GridGeometry, grid_geometry
from ._grid import (SliceGrids, _blur_base_grid, _blur_grid, _corner_weights, _gaussian_kernel, _hat, _slice_grids,
                    release_grids, slice_volume)

@dataclass(frozen=True)
class FillScale:
    """Scales of Eq. (3)'s normalised joint bilateral fill and of the grid that computes it.

    Attributes
    ----------
    sigma_s : float
        Spatial standard deviation in pixels (the paper: ``3 * stride``).
    sigma_r : float
        Range standard deviation in guide units (the paper: 20).
    cells_per_sigma_s, cells_per_sigma_r : float
        Grid cells per sigma (2 keeps the grid's error near 1 %).
    """

    sigma_s: float
    sigma_r: float
    cells_per_sigma_s: float = 2.0
    cells_per_sigma_r: float = 2.0

    def geometry(self, height: int, width: int, guide_max: float) -> GridGeometry:
        """The :class:`GridGeometry` of a ``height`` x ``width`` guide whose largest value is ``guide_max``."""
        return grid_geometry(height, width, guide_max, sigma_s=self.sigma_s, sigma_r=self.sigma_r,
                             cells_per_sigma_s=self.cells_per_sigma_s, cells_per_sigma_r=self.cells_per_sigma_r)




# --------------------------------------------------------------------------------------
# Sparse DSI on a full sample lattice: the mask channels repeat with the stride.
#
# On a regular grid the samples of layer d sit at x = c + d for the lattice columns c, so
# the mask (weight) channel of layer d equals that of layer d + stride except for the
# lattice column that enters at the left border.  The weights are therefore kept as
# ``stride`` *base* channels (every lattice column of one residue class, the whole frame)
# plus, per layer, a *band* holding only the grid cells near the left border that the
# missing columns reach through the blur.  Every cell used from either is bit-for-bit
# the cell of the per-layer weight grid (same points, same summation order), so the
# result is unchanged; the weight grids shrink from D channels to ``stride`` channels
# plus a band of ~(max_disp + blur reach) / cell columns.


@njit(cache=True, inline="always")
def _corner_offsets(y0, x0, z0, gx_n, gz_n, band_n, num_disp, offsets, band_offsets):
    """Flat offsets of layer 0 of the 8 cells around a point, in the corner order of
    :func:`_corner_weights`: in the (GY, GX, GZ, K) value grid, and in the (GY, band, GZ, K)
    band grid (-1 where the cell is right of the band).  Unsigned, so the adds of
    :func:`_splat_cost` index without numba's negative-index checks."""
    c = 0
    for a in range(2):
        for b in range(2):
            for e in range(2):
                cell = ((y0 + a) * gx_n + (x0 + b)) * gz_n + (z0 + e)
                offsets[c] = np.uint64(cell * num_disp)
                if x0 + b < band_n:
                    band_offsets[c] = (((y0 + a) * band_n + (x0 + b)) * gz_n + (z0 + e)) * num_disp
                else:
                    band_offsets[c] = -1
                c += 1


@njit(cache=True, inline="always")
def _splat_cost(values_flat, band_flat, offsets, band_offsets, weights, layer, cost):
    """Add ``cost`` with its 8 corner ``weights`` (:func:`_corner_weights`) into layer ``layer``
    of the flat value grid, and the weights into the flat band grid where the cell lies in
    the band (offsets from :func:`_corner_offsets`)."""
    for c in range(8):
        values_flat[offsets[c] + np.uint64(layer)] += weights[c] * cost
        if band_offsets[c] >= 0:
            band_flat[np.uint64(band_offsets[c] + layer)] += weights[c]


class GridScales(NamedTuple):
    """The grid's scales, as the splat kernels take them beside Eq. (2)'s terms (:class:`stereobudget.cost.SparseTerms`:
    two flat records, not one nested in another)."""

    inv_cs: float       # grid cells per pixel
    inv_cr: float       # grid cells per gray level


class LatticeRows(NamedTuple):
    """Where the samples of a full lattice lie: sample ``r * n_cols + j`` is at
    ``(sample_rows[r], offset_x + j * stride)``."""

    sample_rows: np.ndarray  # int64 (rows,)
    offset_x: int
    stride: int
    n_cols: int


class LatticeGrids(NamedTuple):
    """The grids the lattice splat adds into (float32, uninitialised until zeroed by parts)."""

    values: np.ndarray              # (GY, GX, GZ, D): every layer's cost
    band_weights: np.ndarray        # (GY, B, GZ, D): the left-border band's weights
    base_weights: np.ndarray        # (GY, GX, GZ, n_base): mask weights per column residue
    channel_of_residue: np.ndarray  # int64 (stride,): base channel of x % stride (-1: none)


def _grid_scales(geom: GridGeometry) -> GridScales:
    return GridScales(1.0 / geom.cell_s, 1.0 / geom.cell_r)


@njit(cache=True)
def _splat_sparse_dsi_split(rows, cols, samples, pixels, min_disp, cost_terms, scales, grid_val, band_w):
    """Splat Eq. (2): right sample k at (row, col) meets left pixel (row, col + d) in layer d.

    The plain form of the row and lattice splats, which the tests hold them to.  The
    weights of layer i are written only into x-cells [0, B) of ``band_w`` (B = its second
    dimension); a full-width ``band_w`` gives every layer its own complete weight grid.

    Sample by sample, on one thread: every grid value receives its samples in their
    order, which the faster splats keep.  ``samples``: :class:`RightSamples`,
    ``pixels``: :class:`LeftPixels`, ``cost_terms``: :class:`stereobudget.cost.SparseTerms` (Eq. 2's, applied by
    :func:`stereobudget.cost.sample_cost`), ``scales``: :class:`GridScales`.
    """
    guide = pixels.guide
    inv_cs, inv_cr = scales
    gy_n, gx_n, gz_n, num_disp = grid_val.shape
    w = guide.shape[1]
    # Samples placed off the pixel grid (a grid rectified at the host) carry their offsets.
    subpixel = samples.offsets.shape[0] == rows.shape[0]
    band_n = band_w.shape[1]
    values_flat = grid_val.reshape(grid_val.size)
    band_flat = band_w.reshape(band_w.size)
    weights = np.empty(8, dtype=np.float64)
    offsets = np.empty(8, dtype=np.uint64)
    band_offsets = np.empty(8, dtype=np.int64)
    at = np.empty(pixels.image.shape[2], dtype=np.float32)
    for k in range(rows.shape[0]):
        y = rows[k]
        y0, ty = _hat(y * inv_cs, gy_n)
        fy = samples.offsets[k, 0] if subpixel else np.float32(0.0)
        fx = samples.offsets[k, 1] if subpixel else np.float32(0.0)
        for i in range(num_disp):
            x = cols[k] + min_disp + i
            if x < 0 or x >= w:
                continue
            if fy != 0 or fx != 0:
                at_left = left_terms_at(pixels, y, x, fy, fx, cost_terms, at)
            else:
                at_left = left_terms(pixels, y, x, cost_terms)
            cost = sample_cost(at_left, samples, k, cost_terms)
            x0, tx = _hat(x * inv_cs, gx_n)
            z0, tz = _hat(guide[y, x] * inv_cr, gz_n)
            _corner_weights(ty, tx, tz, weights)
            _corner_offsets(y0, x0, z0, gx_n, gz_n, band_n, num_disp, offsets, band_offsets)
            _splat_cost(values_flat, band_flat, offsets, band_offsets, weights, i, cost)


@njit(cache=True, inline="always")
def _corner_range(y0, cell_lo, cell_hi):
    """The corners ``[c_lo, c_hi)`` (of :func:`_corner_weights`' 8) of a point in cell row ``y0`` that lie
    in the cell rows ``[cell_lo, cell_hi]``: 4 per allowed row ``y0 + a``."""
    return 4 * max(0, cell_lo - y0), 4 * (min(1, cell_hi - y0) + 1)


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _splat_lattice_rows(r_lo, r_hi, cell_lo, cell_hi, lattice, samples, pixels, min_disp, cost_terms, scales,
                        grids, weights, offsets, band_offsets):
    """Splat sample rows ``[r_lo, r_hi)`` into the grids' cells whose y index lies in
    ``[cell_lo, cell_hi]``: every layer's cost into ``grid_val``, the band's weights into
    ``band_w`` and each left pixel's mask weight into its base channel of ``base_w``.

    Left pixel x of sample row ``r`` meets a sample in every layer ``i`` whose column
    ``x - min_disp - i`` is on the lattice: one layer in ``stride``.  Its hat weights are
    the same in all of them, so they are computed once per pixel, and the 8 cells it adds
    into stay in cache.  Base channel ``channel_of_residue[x % stride]`` holds the mask of
    the lattice columns congruent to x (-1: none).  Sample ``k = r * n_cols + j`` is at
    column ``offset_x + j * stride``; ``min_disp >= 0``.  ``lattice``: :class:`LatticeRows`,
    ``grids``: :class:`LatticeGrids`; ``samples``, ``pixels``, ``cost_terms``, ``scales`` as
    :func:`_splat_sparse_dsi_split`; ``weights`` (8,) float64, ``offsets`` (8,) uint64 and
    ``band_offsets`` (8,) int64 are the caller's scratch.

    A kernel of its own, not inlined: both passes of :func:`_splat_lattice` call it
    instead of compiling a copy of this loop each.
    """
    sample_rows, offset_x, stride, n_cols = lattice
    grid_val, band_w, base_w, channel_of_residue = grids
    guide = pixels.guide
    inv_cs, inv_cr = scales
    gy_n, gx_n, gz_n, num_disp = grid_val.shape
    w = guide.shape[1]
    band_n = band_w.shape[1]
    n_base = base_w.shape[3]
    values_flat = grid_val.reshape(grid_val.size)
    band_flat = band_w.reshape(band_w.size)
    base_flat = base_w.reshape(base_w.size)
    for r in range(r_lo, r_hi):
        y = sample_rows[r]
        y0, ty = _hat(y * inv_cs, gy_n)
        c_lo, c_hi = _corner_range(y0, cell_lo, cell_hi)
        if c_lo >= c_hi:
            continue
        all_corners = c_lo == 0 and c_hi == 8
        # (reach % stride), stepped along with x instead of divided per pixel.
        residue = (-min_disp - offset_x) % stride
        column_residue = 0  # x % stride
        for x in range(w):
            reach = x - min_disp - offset_x  # layer whose sample is the row's first column
            i_max = min(num_disp - 1, reach)
            i_first = residue
            residue += 1
            if residue == stride:
                residue = 0
            channel = channel_of_residue[column_residue]
            column_residue += 1
            if column_residue == stride:
                column_residue = 0
            if i_first > i_max and channel < 0:
                continue
            x0, tx = _hat(x * inv_cs, gx_n)
            z0, tz = _hat(guide[y, x] * inv_cr, gz_n)
            _corner_weights(ty, tx, tz, weights)
            _corner_offsets(y0, x0, z0, gx_n, gz_n, band_n, num_disp, offsets, band_offsets)
            if channel >= 0:
                c = 0
                for a in range(2):
                    for b in range(2):
                        for e in range(2):
                            if all_corners or c_lo <= c < c_hi:
                                cell = ((y0 + a) * gx_n + (x0 + b)) * gz_n + (z0 + e)
                                base_flat[np.uint64(cell * n_base + channel)] += weights[c]
                            c += 1
            if i_first > i_max:
                continue
            at_left = left_terms(pixels, y, x, cost_terms)
            # Sample of layer i: column (reach - i) / stride of the row, one less per step.
            k = r * n_cols + (reach - i_first) // stride
            for i in range(i_first, i_max + 1, stride):
                cost = sample_cost(at_left, samples, k, cost_terms)
                if all_corners:  # a fixed trip count: the 8 adds unrolled
                    _splat_cost(values_flat, band_flat, offsets, band_offsets, weights, i, cost)
                else:
                    for c in range(c_lo, c_hi):
                        values_flat[offsets[c] + np.uint64(i)] += weights[c] * cost
                        if band_offsets[c] >= 0:
                            band_flat[np.uint64(band_offsets[c] + i)] += weights[c]
                k -= 1


@njit(cache=True, **RANGE_KERNEL)
def _splat_lattice_pass(lattice, samples, pixels, min_disp, cost_terms, scales, grids, part_rows, shared_cells,
                        zero_cells, shared, weights, offsets, band_offsets, first, stop):
    """Parts ``[first, stop)`` of one pass of :func:`_splat_lattice`.  The first pass
    (``shared`` False): each part zeroes its rows of cells, then splats its sample rows into
    the cells below the reach of the part above.  The second: the cells each part shares
    with the part above."""
    grid_val, band_w, base_w, _ = grids
    gy_n = grid_val.shape[0]
    val_row = grid_val.size // gy_n
    band_row = band_w.size // gy_n
    base_row = base_w.size // gy_n
    values_flat = grid_val.reshape(grid_val.size)
    band_flat = band_w.reshape(band_w.size)
    base_flat = base_w.reshape(base_w.size)
    for p in range(first, stop):
        if shared:
            if shared_cells[p] >= 0:
                # np.int64(0), not 0: a literal would compile the rows' kernel a second time.
                _splat_lattice_rows(part_rows[p], part_rows[p + 1], np.int64(0), shared_cells[p], lattice, samples,
                                    pixels, min_disp, cost_terms, scales, grids, weights, offsets, band_offsets)
            continue
        lo, hi = zero_cells[p], zero_cells[p + 1]
        values_flat[lo * val_row:hi * val_row] = 0.0
        band_flat[lo * band_row:hi * band_row] = 0.0
        base_flat[lo * base_row:hi * base_row] = 0.0
        # Cells up to the last one the part above reaches (shared_cells[p]) wait for the second pass.
        _splat_lattice_rows(part_rows[p], part_rows[p + 1], shared_cells[p] + 1, gy_n, lattice, samples, pixels,
                            min_disp, cost_terms, scales, grids, weights, offsets, band_offsets)


def _splat_lattice(lattice, samples, pixels, min_disp, cost_terms, scales, grids, part_rows, shared_cells,
                   zero_cells):
    """All sample rows of a full lattice into the value, band and base-weight grids, the
    rows cut into parts ``[part_rows[p], part_rows[p + 1])``, one per thread; part ``p``
    shares the rows of cells up to ``shared_cells[p]`` with the part above (-1: none).

    Every sum of a cell must receive its terms in the order of a single row-major pass,
    so that the result is that of the per-sample kernel bit for bit.  A part writes
    only the cells below the reach of the parts above it; the cells it shares with the
    part above (the rows of cells where the parts meet) it adds after every part has
    finished its own, i.e. after the part above.  Parts must be tall enough that only
    neighbours share cells (``_lattice_parts``).

    The grids come uninitialised: part ``p`` first zeroes the rows of cells
    ``[zero_cells[p], zero_cells[p + 1])``, which hold every cell its first pass writes
    and none that another part's first pass writes (a separate pass of zeros over all
    three grids took 0.8 ms of a Teddy decode).
    """
    parts = part_rows.shape[0] - 1
    for shared in (False, True):
        run_parts(_splat_lattice_pass, parts, lattice, samples, pixels, min_disp, cost_terms, scales, grids,
                  part_rows, shared_cells, zero_cells, shared, parts=parts, scratch=_corner_scratch)


def _corner_scratch(channels=0):
    """Scratch of the splats: 8 corner weights (float64), offsets (uint64) and band offsets
    (int64), and with ``channels`` I1's terms at a sub-pixel position (float32)."""
    corners = np.empty(8, dtype=np.float64), np.empty(8, dtype=np.uint64), np.empty(8, dtype=np.int64)
    return corners + (np.empty(channels, np.float32),) if channels else corners


class SampleRows(NamedTuple):
    """Samples sorted by (row, col), grouped by row: the samples of ``rows[r]`` are
    ``[row_start[r], row_start[r + 1])``, their columns ``cols`` ascending."""

    rows: np.ndarray       # int64 (R,): the distinct sample rows, ascending
    row_start: np.ndarray  # int64 (R + 1,)
    cols: np.ndarray       # int64 (n,)


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _splat_sample_rows(r_lo, r_hi, cell_lo, cell_hi, sample_rows, samples, pixels, min_disp, cost_terms, scales,
                       grid_val, grid_w, weights, offsets, band_offsets, at):
    """:func:`_splat_sparse_dsi_split` pixel by pixel for sample rows ``[r_lo, r_hi)`` of any pattern
    (``sample_rows``: :class:`SampleRows`), into the cells whose y index lies in ``[cell_lo, cell_hi]``.

    Left pixel x of row y meets every sample of the row whose layer ``x - min_disp - col``
    is in range, so its hat weights and cell offsets are computed once for all of them.
    For one layer a cell still receives its samples in the order (row, col), the order of
    the per-sample kernel over sorted samples: the result is that kernel's bit for bit.
    ``grid_w`` holds every layer's weights (as the per-sample kernel's full-width band);
    ``weights`` (8,) float64, ``offsets`` (8,) uint64, ``band_offsets`` (8,) int64 and ``at``
    (C,) float32 are the caller's scratch.
    """
    rows, row_start, cols = sample_rows
    guide = pixels.guide
    inv_cs, inv_cr = scales
    gy_n, gx_n, gz_n, num_disp = grid_val.shape
    w = guide.shape[1]
    subpixel = samples.offsets.shape[0] == cols.shape[0]
    values_flat = grid_val.reshape(grid_val.size)
    weights_flat = grid_w.reshape(grid_w.size)
    for r in range(r_lo, r_hi):
        y = rows[r]
        y0, ty = _hat(y * inv_cs, gy_n)
        c_lo, c_hi = _corner_range(y0, cell_lo, cell_hi)
        first, last = row_start[r], row_start[r + 1]
        if c_lo >= c_hi or first == last:
            continue
        all_corners = c_lo == 0 and c_hi == 8
        lo = first   # first sample whose layer at x is below num_disp
        hi = first   # one past the last sample whose layer at x is >= 0
        for x in range(max(0, cols[first] + min_disp), min(w, cols[last - 1] + min_disp + num_disp)):
            while hi < last and cols[hi] + min_disp <= x:
                hi += 1
            while lo < hi and cols[lo] + min_disp + num_disp <= x:
                lo += 1
            if lo == hi:
                continue
            x0, tx = _hat(x * inv_cs, gx_n)
            z0, tz = _hat(guide[y, x] * inv_cr, gz_n)
            _corner_weights(ty, tx, tz, weights)
            _corner_offsets(y0, x0, z0, gx_n, gz_n, gx_n, num_disp, offsets, band_offsets)
            plain = left_terms(pixels, y, x, cost_terms)
            for k in range(lo, hi):
                i = x - min_disp - cols[k]
                fy = samples.offsets[k, 0] if subpixel else np.float32(0.0)
                fx = samples.offsets[k, 1] if subpixel else np.float32(0.0)
                if fy != 0 or fx != 0:
                    cost = sample_cost(left_terms_at(pixels, y, x, fy, fx, cost_terms, at), samples, k, cost_terms)
                else:
                    cost = sample_cost(plain, samples, k, cost_terms)
                if all_corners:
                    _splat_cost(values_flat, weights_flat, offsets, band_offsets, weights, i, cost)
                else:
                    for c in range(c_lo, c_hi):
                        values_flat[offsets[c] + np.uint64(i)] += weights[c] * cost
                        weights_flat[np.uint64(band_offsets[c] + i)] += weights[c]


@njit(cache=True, **RANGE_KERNEL)
def _splat_rows_pass(sample_rows, samples, pixels, min_disp, cost_terms, scales, grid_val, grid_w, part_rows,
                     shared_cells, shared, weights, offsets, band_offsets, at, first, stop):
    """Parts ``[first, stop)`` of one pass of :func:`_splat_rows`: the cells below the part
    above's reach (``shared`` False), then the cells shared with it."""
    for p in range(first, stop):
        if not shared:
            _splat_sample_rows(part_rows[p], part_rows[p + 1], shared_cells[p] + 1, grid_val.shape[0], sample_rows,
                               samples, pixels, min_disp, cost_terms, scales, grid_val, grid_w, weights, offsets,
                               band_offsets, at)
        elif shared_cells[p] >= 0:
            _splat_sample_rows(part_rows[p], part_rows[p + 1], np.int64(0), shared_cells[p], sample_rows, samples,
                               pixels, min_disp, cost_terms, scales, grid_val, grid_w, weights, offsets, band_offsets,
                               at)


def _splat_rows(sample_rows, samples, pixels, min_disp, cost_terms, scales, grid_val, grid_w, part_rows,
                shared_cells):
    """All samples (:class:`SampleRows`) into zeroed value and weight grids, the sample rows
    cut into parts as :func:`_splat_lattice` cuts them (and for the same reason: every sum
    keeps the order of one pass)."""
    parts = part_rows.shape[0] - 1
    channels = pixels.image.shape[2]
    for shared in (False, True):
        run_parts(_splat_rows_pass, parts, sample_rows, samples, pixels, min_disp, cost_terms, scales, grid_val,
                  grid_w, part_rows, shared_cells, shared, parts=parts, scratch=lambda: _corner_scratch(channels))


def _lattice_parts(sample_rows: np.ndarray, inv_cs: float, gy: int, parts: int) -> tuple:
    """Row bounds of ``parts`` contiguous parts of the sample rows for :func:`_splat_lattice`
    (fewer when parts would be too short for only neighbouring parts to share grid cells),
    the last row of cells each part shares with the part above (-1 for the first), and
    the bounds of the rows of cells each part zeroes (from its first row not shared with
    the part above to the last it shares with the part below; 0 and ``gy`` at the ends).

    A sample row at y splats into the cell rows ``c(y)`` and ``c(y) + 1``, ``c`` the
    clamped floor of :func:`_hat`.
    """
    count = len(sample_rows)
    first_cell = np.clip(np.floor(sample_rows * inv_cs), 0, gy - 2).astype(np.int64)
    while parts > 1:
        bounds = np.array([p * count // parts for p in range(parts + 1)], np.int64)
        # The part below starts sharing at most the cells reached by this part's last row,
        # and must not reach the cells of the part above this one.
        if all(bounds[p + 1] - bounds[p] >= 2 for p in range(parts)) and all(
                first_cell[bounds[p + 1]] > first_cell[bounds[p] - 1] + 1 for p in range(1, parts - 1)):
            shared = np.concatenate([[-1], first_cell[bounds[1:-1] - 1] + 1]).astype(np.int64)
            return bounds, shared, np.concatenate([[0], shared[1:] + 1, [gy]]).astype(np.int64)
        parts -= 1
    return np.array([0, count], np.int64), np.array([-1], np.int64), np.array([0, gy], np.int64)


def _lattice_stride(rows: np.ndarray, cols: np.ndarray, width: int) -> int:
    """Column stride when the samples are a full lattice in row-major order, else 0.

    Full lattice: every sample row holds the same columns ``ox, ox + s, ...`` up to the
    right edge (``ox < s``), and the samples come row by row, columns ascending.
    """
    # In row-major order each row's columns ascend, so the set is a full lattice exactly
    # when every row repeats the first row's columns and those are evenly spaced: a few
    # passes over the samples instead of numpy's sorts (np.unique: ~0.5 ms per Teddy decode).
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    n = len(rows)
    if n < 2:
        return 0
    other_row = rows != rows[0]
    n_cols = int(other_row.argmax()) if other_row.any() else n
    if n_cols < 2 or n % n_cols:
        return 0
    first = cols[:n_cols]
    stride = int(first[1] - first[0])
    if stride < 1 or first[0] >= stride or first[-1] + stride < width or np.any(np.diff(first) != stride):
        return 0
    by_row, cols_by_row = rows.reshape(-1, n_cols), cols.reshape(-1, n_cols)
    if np.any(cols_by_row != first) or np.any(by_row != by_row[:, :1]) or np.any(np.diff(by_row[:, 0]) <= 0):
        return 0
    return stride


def _lattice_sparse_dsi_grids(left, guide, rows, cols, samples, left_codes, *, stride, geom, min_disp, num_disp,
                              terms):
    h, w = guide.shape
    gy, gx, gz = geom.shape
    inv_cs = 1.0 / geom.cell_s
    reach = _gaussian_kernel(geom.blur_s).shape[0] // 2      # x-blur radius in cells
    offset_x = int(cols[0]) if len(cols) else 0
    layers = np.arange(num_disp, dtype=np.int64)
    # Last grid cell whose weight in layer i differs from its base channel: the missing
    # column ox + d_i - stride splats into its hat cell and the next, then the blur
    # spreads that by `reach` cells.
    missing = offset_x + min_disp + layers - stride
    hat_cell = np.minimum(np.floor(np.maximum(missing, 0) * inv_cs).astype(np.int64), gx - 2)
    last_changed = np.where(missing >= 0, hat_cell + 1 + reach, -1)
    band_n = int(min(max(int(last_changed.max()) + reach + 2, 1), gx))
    first_band_layer = np.searchsorted(last_changed, np.arange(gx), side="left").astype(np.int64)
    # Lowest x-cell where layer i's band weights can be non-zero: its leftmost sample
    # (left pixel ox + d_i) splats into its hat cell, which the blur spreads `reach` cells
    # further left; a layer without samples has none.  The cell count rises with i, so
    # each x-cell's first layer out of reach of both its corner cells is one search (one
    # cell of margin against rounding: a layer is skipped only where it is surely zero).
    leftmost = offset_x + min_disp + layers
    lowest_cell = np.where(leftmost < w, np.minimum(np.floor(np.maximum(leftmost, 0) * inv_cs), gx - 2) - reach,
                           gx + 2).astype(np.int64)
    first_missing_layer = np.maximum(
        first_band_layer, np.searchsorted(lowest_cell - 1, np.arange(gx) + 1, side="right")).astype(np.int64)

    # Uninitialised: _splat_lattice zeroes them part by part.
    grid_val = empty_volume(geom.shape + (num_disp,))
    band_w = empty_volume((gy, band_n, gz, num_disp))
    n_cols = (w - 1 - offset_x) // stride + 1  # a lattice row holds every column ox + m * stride < w
    sample_rows = np.ascontiguousarray(np.asarray(rows, np.int64)[::n_cols])
    base_w = empty_volume(geom.shape + (min(stride, num_disp),))
    # Base channel b holds the mask of lattice columns (offset_x + min_disp + b) % stride (mod stride).
    channel_of_residue = np.full(stride, -1, np.int64)
    channel_of_residue[(offset_x + min_disp + np.arange(base_w.shape[3], dtype=np.int64)) % stride] = \
        np.arange(base_w.shape[3])
    _splat_lattice(LatticeRows(sample_rows, offset_x, int(stride), n_cols), samples,
                   LeftPixels(left, guide, left_codes), int(min_disp), terms.kernel_terms(), _grid_scales(geom),
                   LatticeGrids(grid_val, band_w, base_w, channel_of_residue),
                   *_lattice_parts(sample_rows, inv_cs, gy, get_num_threads()))
    return _slice_grids(_blur_grid(grid_val, geom), _blur_base_grid(base_w, geom), _blur_grid(band_w, geom), geom,
                        density=len(rows) / float(h * w), missing_value=terms.truncation,
                        first_band_layer=first_band_layer, first_missing_layer=first_missing_layer)


def filled_sparse_dsi(left: np.ndarray, guide: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                      right_values: np.ndarray, *, min_disp: int, num_disp: int, scale: FillScale,
                      terms: SparseCostTerms, right_steps: np.ndarray | None = None,
                      pixel_of_row: np.ndarray | None = None, right_codes: np.ndarray | None = None,
                      right_offsets: np.ndarray | None = None) -> np.ndarray:
    """The paper's filled sparse DSI: Eq. (2) at the samples, spread by Eq. (3) to every pixel.

    Parameters
    ----------
    left : ndarray, float32 (H, W, C)
        I1 in 8-bit units.
    guide : ndarray, float32 (H, W)
        Guidance (gray I1).
    rows, cols : ndarray of int
        Positions of the right-image samples.
    right_values : ndarray, float32 (n, C)
        Sample values in 8-bit units.
    min_disp, num_disp : int
        Disparity range; layer ``i`` is ``min_disp + i``.
    scale : FillScale
        Eq. (3)'s sigmas and the grid's cells per sigma.
    terms : SparseCostTerms
        Eq. (2)'s cost terms.
    right_steps : ndarray, float32 (n,), optional
        Gray difference to the sample ``terms.step_spacing`` pixels to the right (NaN: none);
        without it the step term is off.
    pixel_of_row : ndarray of int (H * W,), optional
        Row ``k`` of an ``(H * W, num_disp)`` result holds pixel ``pixel_of_row[k]``
        (row-major), e.g. a tree's depth-first order (:class:`stereobudget.aggregate.TreeLayout`).
    right_codes : ndarray, int64 (n,), optional
        Lattice census code of each sample, for samples that came from a grid but no
        longer lie on one (a grid placed in a rectified frame); with
        ``terms.census_spacing`` they meet I1's census at that spacing.  Default: the
        codes of a regular grid sent row by row, or no census.
    right_offsets : ndarray, float32 (n, 2), optional
        ``(dy, dx)`` of each sample's true position from its pixel ``(row, col)`` (samples
        placed off the pixel grid): Eq. (2)'s colour term reads I1 there, bilinear.

    Returns
    -------
    ndarray, float32 (H, W, num_disp), or (H * W, num_disp) rows with ``pixel_of_row``
        Filled cost volume.

    Examples
    --------
    >>> import numpy as np
    >>> left = np.random.default_rng(0).uniform(0, 255, (20, 30, 1)).astype(np.float32)
    >>> rows, cols = (a.ravel() for a in np.mgrid[0:20:5, 0:30:5])
    >>> volume = filled_sparse_dsi(left, left[..., 0], rows, cols, left[rows, cols], min_disp=0, num_disp=4,
    ...                            scale=FillScale(sigma_s=7.5, sigma_r=20.0), terms=SparseCostTerms(truncation=15.0))
    >>> volume.shape, volume.dtype
    ((20, 30, 4), dtype('float32'))
    """
    grids = sparse_dsi_grids(left, guide, rows, cols, right_values, min_disp=min_disp, num_disp=num_disp,
                             scale=scale, terms=terms, right_steps=right_steps, right_codes=right_codes,
                             right_offsets=right_offsets)
    volume = slice_volume(guide, grids, pixel_of_row=pixel_of_row)
    release_grids(grids)
    return volume


def _census_codes(guide, rows, cols, right_values, terms, right_codes=None):
    """Lattice census codes of the samples and I1's codes at the same spacing, or (None, None).

    The samples must be a regular grid sent row by row (rows x cols in row-major order),
    unless their codes are given (``right_codes``).
    """
    from ..cost._census import lattice_census, spaced_census
    from ..cost._cost import to_gray
    if terms.census_spacing is None or terms.census_weight <= 0 or len(rows) < 4:
        return None, None
    if right_codes is not None:
        spacing_x, spacing_y = terms.census_spacing
        return (np.ascontiguousarray(right_codes, np.int64),
                spaced_census(guide, spacing_x=spacing_x, spacing_y=spacing_y))
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    n_cols = int(np.argmax(rows != rows[0])) if np.any(rows != rows[0]) else len(rows)
    if len(rows) % n_cols:
        return None, None
    values = np.ascontiguousarray(right_values, np.float32).reshape(len(rows) // n_cols, n_cols, -1)
    codes = lattice_census(to_gray(values))
    spacing_x, spacing_y = terms.census_spacing
    return codes, spaced_census(guide, spacing_x=spacing_x, spacing_y=spacing_y)


def _splat_any_pattern(rows, cols, samples, pixels, min_disp, cost_terms, geom, grid_val, grid_w):
    """Splat samples of any pattern into zeroed full per-layer grids: sorted by (row, col), then
    row by row (:func:`_splat_rows`; :func:`_splat_sparse_dsi_split` is its per-sample form)."""
    if len(rows) == 0:
        return
    order = np.lexsort((cols, rows))
    if np.any(order[1:] < order[:-1]):
        rows, cols = rows[order], cols[order]
        subpixel = len(samples.offsets) == len(order)
        samples = RightSamples(samples.values[order], samples.steps[order], samples.codes[order],
                               samples.offsets[order] if subpixel else samples.offsets)
    row_start = np.concatenate([[0], np.flatnonzero(np.diff(rows)) + 1, [len(rows)]]).astype(np.int64)
    sample_rows = SampleRows(np.ascontiguousarray(rows[row_start[:-1]]), row_start, np.ascontiguousarray(cols))
    part_rows, shared_cells, _ = _lattice_parts(sample_rows.rows, 1.0 / geom.cell_s, geom.shape[0],
                                                get_num_threads())
    _splat_rows(sample_rows, samples, pixels, min_disp, cost_terms, _grid_scales(geom), grid_val, grid_w, part_rows,
                shared_cells)


def sparse_dsi_grids(left: np.ndarray, guide: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                     right_values: np.ndarray, *, min_disp: int, num_disp: int, scale: FillScale,
                     terms: SparseCostTerms, right_steps: np.ndarray | None = None,
                     right_codes: np.ndarray | None = None, right_offsets: np.ndarray | None = None) -> SliceGrids:
    """The splatted and blurred grids of :func:`filled_sparse_dsi`, not yet sliced.

    For callers that slice pixel by pixel inside their own kernel (:func:`slice_pixel`),
    e.g. Hybrid, which mixes each sliced row with a dense cost before storing it.
    Parameters as for :func:`filled_sparse_dsi`.

    Returns
    -------
    SliceGrids
        ``K = num_disp`` layers.
    """
    h, w = guide.shape
    geom = scale.geometry(h, w, float(guide.max(initial=0.0)))
    if right_steps is None:
        right_steps = np.full(len(rows), np.nan, np.float32)
        terms = replace(terms, step_weight=0.0)
    right_codes, left_codes = _census_codes(guide, rows, cols, right_values, terms, right_codes)
    if right_codes is None:
        right_codes, left_codes = np.full(len(rows), -1, np.int64), np.zeros((h, w), np.uint8)
        terms = replace(terms, census_weight=0.0)
    offsets = (np.zeros((0, 2), np.float32) if right_offsets is None
               else np.ascontiguousarray(right_offsets, np.float32).reshape(-1, 2))
    samples = RightSamples(np.ascontiguousarray(right_values, np.float32),
                           np.ascontiguousarray(right_steps, np.float32), right_codes, offsets)
    stride = _lattice_stride(np.asarray(rows, np.int64), np.asarray(cols, np.int64), w) if min_disp >= 0 else 0
    if stride and num_disp > stride and right_offsets is None:
        return _lattice_sparse_dsi_grids(left, guide, rows, cols, samples, left_codes, stride=stride, geom=geom,
                                         min_disp=int(min_disp), num_disp=int(num_disp), terms=terms)
    grid_val = zeroed_volume(geom.shape + (num_disp,))
    grid_w = zeroed_volume(geom.shape + (num_disp,))
    _splat_any_pattern(np.asarray(rows, np.int64), np.asarray(cols, np.int64), samples,
                       LeftPixels(left, guide, left_codes), int(min_disp), terms.kernel_terms(), geom, grid_val, grid_w)
    return _slice_grids(_blur_grid(grid_val, geom), _blur_base_grid(grid_w, geom), None, geom,
                        density=len(rows) / float(h * w), missing_value=terms.truncation)


__all__ = ["FillScale", "filled_sparse_dsi", "sparse_dsi_grids"]
