"""Normalised joint bilateral filtering of sparse data on a bilateral grid.

This module implements the paper's Eq. (3): a sparse signal known only at sample points
is spread to every pixel by a joint bilateral filter guided by a dense image, and
normalised by the same filter applied to the sample mask::

    out(p) = sum_q F(p, q) s(q) m(q) / sum_q F(p, q) m(q)
    F(p, q) = exp(-|p - q|^2 / (2 sigma_s^2)) * exp(-(g(p) - g(q))^2 / (2 sigma_r^2))

A brute-force evaluation costs O(N * sigma_s^2) per layer.  A bilateral grid (Paris &
Durand; Chen et al.) makes it O(N): splat only the sample points into a coarse
(y, x, intensity) grid with trilinear weights, blur the grid with a separable Gaussian,
and slice it trilinearly at every pixel.  The signal and the mask share one grid layout,
so the normalisation costs one extra channel per distinct mask.

Grid volumes are float32 with shape (GY, GX, GZ, K): K channels (disparity layers)
contiguous so slicing reads one vector per corner.

Accuracy: splatting and slicing with hat functions each add 1/6 cell^2 of variance per
axis; the blur is narrowed by exactly that amount so the effective kernel has the
requested sigma.  ``tests/test_bilateral.py`` states the agreement with a brute-force
filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numba import get_num_threads, njit, prange

from .._kernels._jit import NO_REFCOUNTS
from .._kernels._simd import MAX_PERIOD_LANES, PERIOD_READ_PAST, periodic_corner_sum
from ..cost._cost import sparse_pair_cost
from .._kernels._scratch import empty_volume, recycle, zeroed_volume

#: Rows per parallel work item of the slice kernels.
_CHUNK = 512


@dataclass(frozen=True)
class GridGeometry:
    """Sampling of the bilateral grid.

    Attributes
    ----------
    cell_s : float
        Spatial cell size in pixels.
    cell_r : float
        Range cell size in guide intensity units.
    shape : tuple of int
        (GY, GX, GZ) grid cells.
    blur_s, blur_r : float
        Standard deviations of the grid blur, in cells.
    """

    cell_s: float
    cell_r: float
    shape: tuple
    blur_s: float
    blur_r: float


def grid_geometry(height: int, width: int, guide_max: float, *, sigma_s: float, sigma_r: float,
                  cells_per_sigma_s: float = 2.0, cells_per_sigma_r: float = 2.0) -> GridGeometry:
    """Choose grid cells so each sigma spans ``cells_per_sigma`` cells (2 keeps errors near 1 %)."""
    cell_s = max(sigma_s / cells_per_sigma_s, 1.0)
    cell_r = max(sigma_r / cells_per_sigma_r, 1e-3)
    # Hat-function splat + slice add 2 * (1/6) cell^2 of variance per axis.
    blur_s = math.sqrt(max((sigma_s / cell_s) ** 2 - 1.0 / 3.0, 1e-6))
    blur_r = math.sqrt(max((sigma_r / cell_r) ** 2 - 1.0 / 3.0, 1e-6))
    gy = int(math.floor((height - 1) / cell_s)) + 2
    gx = int(math.floor((width - 1) / cell_s)) + 2
    gz = int(math.floor(max(guide_max, 0.0) / cell_r)) + 2
    return GridGeometry(cell_s, cell_r, (gy, gx, gz), blur_s, blur_r)


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


@dataclass(frozen=True)
class SparseCostTerms:
    """The terms of Eq. (2)'s cost at a sample (:func:`stereobudget.cost.sparse_pair_cost`).

    Attributes
    ----------
    truncation : float
        Truncation of the colour term (:func:`stereobudget.cost.pixel_cost`); every term is
        brought to ``[0, truncation]``.
    step_weight, step_truncation : float
        Weight (0: off) and truncation (gray levels) of the step term, the gray difference
        to the sample ``step_spacing`` pixels to the right.
    step_spacing : int
        Column spacing of the steps (the grid stride).
    census_weight : float
        Weight of the lattice census (0: off).
    census_spacing : (int, int), optional
        ``(stride_x, stride_y)`` of a regular sample grid whose samples arrive row by row;
        ``None`` (not a regular grid) turns the lattice census off.
    """

    truncation: float
    step_weight: float = 0.0
    step_truncation: float = 5.0
    step_spacing: int = 1
    census_weight: float = 0.0
    census_spacing: tuple[int, int] | None = None


def _gaussian_kernel(std: float) -> np.ndarray:
    radius = max(1, int(math.ceil(3.0 * std)))
    t = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (t / std) ** 2)
    return (k / k.sum()).astype(np.float32)


@njit(cache=True, inline="always")
def _hat(f, n):
    i0 = int(math.floor(f))
    if i0 < 0:
        i0 = 0
    if i0 > n - 2:
        i0 = n - 2
    t = f - i0
    if t < 0.0:
        t = 0.0
    if t > 1.0:
        t = 1.0
    return i0, np.float32(t)


@njit(cache=True)
def _splat_points(rows, cols, values, guide, inv_cs, inv_cr, grid_val, grid_w):
    """Splat points carrying all K channels at shared positions (one mask channel)."""
    gy_n, gx_n, gz_n, k_n = grid_val.shape
    weights = np.empty(8, dtype=np.float64)
    for k in range(rows.shape[0]):
        y = rows[k]
        x = cols[k]
        y0, ty = _hat(y * inv_cs, gy_n)
        x0, tx = _hat(x * inv_cs, gx_n)
        z0, tz = _hat(guide[y, x] * inv_cr, gz_n)
        _corner_weights(ty, tx, tz, weights)
        c = 0
        for a in range(2):
            for b in range(2):
                for e in range(2):
                    wgt = weights[c]
                    for ch in range(k_n):
                        grid_val[y0 + a, x0 + b, z0 + e, ch] += wgt * values[k, ch]
                    grid_w[y0 + a, x0 + b, z0 + e, 0] += wgt
                    c += 1


@njit(cache=True, inline="always")
def _add_tap(out, row, kw, started):
    """``out = kw * row`` for a sum's first tap, ``out += kw * row`` after it (the same
    roundings as a zero-started sum: the first product is stored exactly)."""
    if started:
        for ch in range(out.shape[0]):
            out[ch] += kw * row[ch]
    else:
        for ch in range(out.shape[0]):
            out[ch] = kw * row[ch]


@njit(cache=True, inline="always")
def _seven_taps(out, rows, first, step, kernel):
    """``out = sum over t < 7 of kernel[t] * rows[first + t * step:][:len(out)]``, the taps
    added in order from a stored first product: :func:`_add_tap` seven times, bit for
    bit, in one pass (one store per element instead of seven read-modify-writes)."""
    k0, k1, k2, k3, k4, k5, k6 = kernel[0], kernel[1], kernel[2], kernel[3], kernel[4], kernel[5], kernel[6]
    n = out.shape[0]
    r0 = rows[first:first + n]
    r1 = rows[first + step:first + step + n]
    r2 = rows[first + 2 * step:first + 2 * step + n]
    r3 = rows[first + 3 * step:first + 3 * step + n]
    r4 = rows[first + 4 * step:first + 4 * step + n]
    r5 = rows[first + 5 * step:first + 5 * step + n]
    r6 = rows[first + 6 * step:first + 6 * step + n]
    for i in range(n):
        out[i] = (((((k0 * r0[i] + k1 * r1[i]) + k2 * r2[i]) + k3 * r3[i]) + k4 * r4[i]) + k5 * r5[i]) + k6 * r6[i]


@njit(cache=True, parallel=True)
def _blur_grid_rows(src, dst, spatial, kernel_s, kernel_r, blocks):
    """``dst`` = ``src`` (GY, GX, GZ, K) blurred along y and x by ``kernel_s``, then along z
    by ``kernel_r``, with zero boundaries (taps outside the grid are left out; each sum
    starts from its first tap inside); ``spatial`` (GY, GX, K) = ``dst`` summed over
    intensity, the cells added in intensity order from the first (the slice's
    spatial-only fallback), while each column is in cache.

    The three passes run per grid row: row y's y-blurred slab and one x-blurred column
    of cells at a time stay in cache, so the grid is read once and written once instead
    of three times each, and every pass loops over whole contiguous runs (a grid row of
    GX * GZ * K floats, a column of GZ * K) rather than one cell's K channels at a time.
    Empty cells are blurred like the others: skipping them (the splat's occupancy flags)
    saved nothing at one cell per sigma, where ~40 % of the cells are occupied.
    """
    gy, gx, gz, k = src.shape
    run = gz * k
    blocks = max(1, min(blocks, gy))
    for block in prange(blocks):
        slab = np.empty(gx * run, dtype=np.float32)
        column = np.empty(run, dtype=np.float32)
        _blur_grid_band(src, dst, spatial, kernel_s, kernel_r, block * gy // blocks, (block + 1) * gy // blocks,
                        slab, column)


@njit(cache=True, **NO_REFCOUNTS)
def _blur_grid_band(src, dst, spatial, kernel_s, kernel_r, y_start, y_stop, slab, column):
    """Grid rows ``[y_start, y_stop)`` of :func:`_blur_grid_rows`, with its scratch given
    (compiled without reference counting: its many views are free).  Windows of seven
    taps (a blur sigma under one cell: the default grids) are summed in one pass each."""
    gy, gx, gz, k = src.shape
    rs = kernel_s.shape[0] // 2
    rr = kernel_r.shape[0] // 2
    run = gz * k
    slab_size = gx * run
    src_flat = src.reshape(src.size)
    # Along z, the cells with every tap inside the grid form one run; the border cells go apart.
    inner_lo, inner_hi = min(rr, gz), max(gz - rr, min(rr, gz))
    for y in range(y_start, y_stop):
        if rs == 3 and 3 <= y < gy - 3:  # along y, the whole row at once
            _seven_taps(slab, src_flat, (y - 3) * slab_size, slab_size, kernel_s)
        else:
            started = False
            for t in range(max(-rs, -y), min(rs, gy - 1 - y) + 1):
                _add_tap(slab, src[y + t].reshape(slab_size), kernel_s[t + rs], started)
                started = True
        target = dst[y].reshape(slab_size)
        for x in range(gx):
            if rs == 3 and 3 <= x < gx - 3:  # along x, one column of cells
                _seven_taps(column, slab, (x - 3) * run, run, kernel_s)
            else:
                started = False
                for t in range(max(-rs, -x), min(rs, gx - 1 - x) + 1):
                    _add_tap(column, slab[(x + t) * run:(x + t + 1) * run], kernel_s[t + rs], started)
                    started = True
            out = target[x * run:(x + 1) * run]
            if inner_hi > inner_lo:  # along z
                inner = out[inner_lo * k:inner_hi * k]
                if rr == 3:
                    _seven_taps(inner, column, (inner_lo - 3) * k, k, kernel_r)
                else:
                    for t in range(-rr, rr + 1):
                        _add_tap(inner, column[(inner_lo + t) * k:(inner_hi + t) * k], kernel_r[t + rr], t > -rr)
            for z in range(gz):
                if inner_lo <= z < inner_hi:
                    continue
                started = False
                for t in range(max(-rr, -z), min(rr, gz - 1 - z) + 1):
                    _add_tap(out[z * k:(z + 1) * k], column[(z + t) * k:(z + t + 1) * k], kernel_r[t + rr],
                             started)
                    started = True
            total = spatial[y, x]
            for z in range(gz):
                _add_tap(total, out[z * k:(z + 1) * k], np.float32(1.0), z > 0)


def _blur_grid(grid: np.ndarray, geom: GridGeometry, *, extra_cells: int = 0) -> tuple:
    """Separable Gaussian blur of a C-contiguous float32 (GY, GX, GZ, K) grid, and the
    blurred grid summed over intensity, float32 (GY, GX, K).  ``grid`` is consumed (its
    memory is handed to :mod:`stereobudget._kernels._scratch`).  With ``extra_cells`` the blurred
    grid comes as (GY * GX * GZ + extra_cells, K) rows of cells, the extra ones zero."""
    gy, gx, gz, k = grid.shape
    cells = gy * gx * gz
    rows = empty_volume((cells + extra_cells, k))
    rows[cells:] = 0.0
    out = rows[:cells].reshape(grid.shape)
    spatial = np.zeros((gy, gx, k), np.float32)  # zeros: a grid without intensity cells sums to 0
    _blur_grid_rows(grid, out, spatial, _gaussian_kernel(geom.blur_s), _gaussian_kernel(geom.blur_r),
                    get_num_threads())
    recycle(grid)
    return (rows if extra_cells else out), spatial


def _blur_base_grid(grid: np.ndarray, geom: GridGeometry) -> tuple:
    """:func:`_blur_grid` of a weight grid as :class:`SliceGrids` keeps it: cell rows
    followed by zero cells of at least :data:`~stereobudget._kernels.PERIOD_READ_PAST`
    floats, which the slice's vector loads read past the last cell."""
    return _blur_grid(grid, geom, extra_cells=-(-PERIOD_READ_PAST // grid.shape[3]))


@njit(cache=True, inline="always")
def _bilinear(grid2d, y0, ty, x0, tx, channel):
    """Bilinear value of channel ``channel`` of a (GY, GX, K) grid (the spatial-only fallback).

    In float64: ``1 - ty`` promotes the weights, and with them the sum (the vectorised
    fallback in :func:`_divide_or_fall_back` repeats this arithmetic term by term).
    """
    acc = np.float32(0.0)
    for a in range(2):
        wy = ty if a else 1 - ty
        for b in range(2):
            wx = tx if b else 1 - tx
            acc += wy * wx * grid2d[y0 + a, x0 + b, channel]
    return acc


@njit(cache=True, inline="always")
def _trilinear_corners(y0, ty, x0, tx, z0, tz, nx, nz, corner_weight, corner_index):
    """Weights and flat (y, x, z) row indices of the 8 grid corners around a pixel, in a fixed order.

    ``nx``/``nz`` are the grid's x and z extents, so the same corners index grids of other widths.
    """
    # float32 hat weights: a float64 weight would turn every multiply-add of the slice into float64.
    one = np.float32(1.0)
    c = 0
    for a in range(2):
        wy = ty if a else one - ty
        for b in range(2):
            wx = tx if b else one - tx
            for e in range(2):
                wz = tz if e else one - tz
                corner_weight[c] = wy * wx * wz
                corner_index[c] = ((y0 + a) * nx + (x0 + b)) * nz + (z0 + e)
                c += 1


@njit(cache=True, inline="always")
def _add_corners_from(rows, corner_index, corner_weight, lo, n, acc):
    """acc[lo:n] = sum over the 8 corners of weight * row[lo:n], corners added in a fixed order.

    All 8 corner rows in one loop: the sum stays in registers instead of being stored
    and reloaded once per corner (2x faster than a loop per corner, same rounding).
    """
    # Sliced to [lo, n) so the loop index starts at 0: numba's negative-index check on a
    # computed index would keep LLVM from vectorising the loop.
    r0 = rows[corner_index[0], lo:n]
    r1 = rows[corner_index[1], lo:n]
    r2 = rows[corner_index[2], lo:n]
    r3 = rows[corner_index[3], lo:n]
    r4 = rows[corner_index[4], lo:n]
    r5 = rows[corner_index[5], lo:n]
    r6 = rows[corner_index[6], lo:n]
    r7 = rows[corner_index[7], lo:n]
    out = acc[lo:n]
    w0, w1, w2, w3 = corner_weight[0], corner_weight[1], corner_weight[2], corner_weight[3]
    w4, w5, w6, w7 = corner_weight[4], corner_weight[5], corner_weight[6], corner_weight[7]
    for i in range(out.shape[0]):
        out[i] = (w0 * r0[i] + w1 * r1[i] + w2 * r2[i] + w3 * r3[i]
                  + w4 * r4[i] + w5 * r5[i] + w6 * r6[i] + w7 * r7[i])


@njit(cache=True, inline="always")
def _divide_or_fall_back(o, den, n_out, band_start, base_light, layer_base, spatial_val, spatial_base, spatial_band,
                         y0, ty, x0, tx, eps, missing_value):
    """o[i] /= den[i] for i < n_out; layers whose weight is below ``eps`` take the spatial-only fallback.

    Every layer is divided in one branch-free pass; light layers (weight <= eps) are then
    overwritten.  Below ``band_start`` the weights repeat a few base channels, and
    ``base_light`` (their check, made where they were summed) says whether any is light:
    rarely, and then those layers are redone one by one.  From ``band_start`` on, the
    left border's missing samples make runs of layers light (on Teddy 8 % of the
    pixels): one select over the run, whose fallback sums vectorise.
    """
    for i in range(n_out):
        o[i] /= den[i]
    base_end = min(band_start, n_out)
    if base_light:
        for i in range(base_end):
            if den[i] <= eps:
                o[i] = _fallback(spatial_val, spatial_base, y0, ty, x0, tx, i, layer_base[i], eps, missing_value)
    if base_end == n_out:
        return
    # The light layers' first and last index (integer min / max reductions vectorise).
    first, last = n_out, -1
    for i in range(base_end, n_out):
        is_light = den[i] <= eps
        first = min(first, i if is_light else n_out)
        last = max(last, i if is_light else -1)
    if last < 0:
        return
    # _bilinear's float64 weights and sums, term by term in its order, over that run.
    wy0, wy1 = 1 - ty, np.float64(ty)
    wx0, wx1 = 1 - tx, np.float64(tx)
    w00, w01, w10, w11 = wy0 * wx0, wy0 * wx1, wy1 * wx0, wy1 * wx1
    last += 1
    v00, v01 = spatial_val[y0, x0, first:last], spatial_val[y0, x0 + 1, first:last]
    v10, v11 = spatial_val[y0 + 1, x0, first:last], spatial_val[y0 + 1, x0 + 1, first:last]
    b00, b01 = spatial_band[y0, x0, first:last], spatial_band[y0, x0 + 1, first:last]
    b10, b11 = spatial_band[y0 + 1, x0, first:last], spatial_band[y0 + 1, x0 + 1, first:last]
    out = o[first:last]
    weight = den[first:last]
    for i in range(out.shape[0]):
        sv = 0.0 + w00 * v00[i]
        sv += w01 * v01[i]
        sv += w10 * v10[i]
        sv += w11 * v11[i]
        sw = 0.0 + w00 * b00[i]
        sw += w01 * b01[i]
        sw += w10 * b10[i]
        sw += w11 * b11[i]
        fallback = sv / sw if sw > eps else missing_value
        out[i] = out[i] if weight[i] > eps else fallback


@njit(cache=True, inline="always")
def _fallback(spatial_val, spatial_weight, y0, ty, x0, tx, value_channel, weight_channel, eps, missing_value):
    """The spatial-only fill of one light layer: its value and weight grids summed over
    intensity, sliced bilinearly and divided (``missing_value`` where that weight is light too)."""
    sv = _bilinear(spatial_val, y0, ty, x0, tx, value_channel)
    sw = _bilinear(spatial_weight, y0, ty, x0, tx, weight_channel)
    return sv / sw if sw > eps else missing_value


class SliceGrids(NamedTuple):
    """Blurred bilateral grids of a normalised fill, ready to be sliced at any pixel.

    Layer ``i`` of the output is ``values`` sliced in channel ``i``, divided by its weight:
    ``base_weights`` sliced in channel ``layer_base[i]``, except where the left border
    band holds that layer's own weights (``i >= first_band_layer[x0]``, see the lattice
    section below).  Where the weight is below ``eps`` a spatial-only fallback
    (``spatial_*``: the grids summed over intensity) is used, then ``missing_value``.
    From layer ``first_missing_layer[x0]`` on, the band's weights are exactly zero at
    both x-cells a pixel reads, so the fill is ``missing_value`` without slicing.

    Attributes
    ----------
    values : ndarray, float32 (GY * GX * GZ, K)
        Signal grid, one row of K channels per cell.
    base_weights : ndarray, float32 (GY * GX * GZ + E, B)
        Weight (mask) grid channels shared by layers: ``layer_base[i]`` picks layer i's;
        the E last rows are zero, read past by the slice's vector loads.
    band_weights : ndarray, float32 (GY * band * GZ, K)
        Per-layer weights of the cells in the first ``band`` x-cells (may be empty).
    spatial_values, spatial_base, spatial_band : ndarray, float32 (GY, GX | band, K | B)
    first_band_layer : ndarray, int64 (GX,)
        First layer whose weight comes from the band, per x-cell (K: none).
    first_missing_layer : ndarray, int64 (GX,)
        First layer whose fill is ``missing_value`` at every pixel of x-cell x0 (no sample
        of it reaches x-cells x0 and x0 + 1), per x-cell (K: none).
    layer_base : ndarray, int64 (K,)
    gy, gx, gz, band : int
        Grid cells per axis and band width in x-cells.
    inv_cell_s, inv_cell_r, eps, missing_value : float32
    """

    values: np.ndarray
    base_weights: np.ndarray
    band_weights: np.ndarray
    spatial_values: np.ndarray
    spatial_base: np.ndarray
    spatial_band: np.ndarray
    first_band_layer: np.ndarray
    first_missing_layer: np.ndarray
    layer_base: np.ndarray
    gy: int
    gx: int
    gz: int
    band: int
    inv_cell_s: np.float32
    inv_cell_r: np.float32
    eps: np.float32
    missing_value: np.float32


def _slice_grids(values, base, band, geom, *, density, missing_value, first_band_layer=None,
                 first_missing_layer=None):
    """Pack blurred grids into :class:`SliceGrids`: ``values``, ``base`` and ``band`` are
    :func:`_blur_grid`'s (grid, spatial sums) pairs of (GY, GX | band, GZ, C) grids
    (``band=None``: no band; ``first_missing_layer=None``: no layer skipped); the base
    grid's are :func:`_blur_base_grid`'s (cells, B) rows."""
    (grid_val, spatial_values), (base_w, spatial_base) = values, base
    gy, gx, gz, k = grid_val.shape
    if base_w.ndim != 2 or (base_w.shape[0] - gy * gx * gz) * base_w.shape[1] < PERIOD_READ_PAST:
        raise ValueError("the base weights need the zero cells of _blur_base_grid")
    n_base = base_w.shape[1]
    if band is None:
        band = np.zeros((gy, 0, gz, k), np.float32), np.zeros((gy, 0, k), np.float32)
        first_band_layer = np.full(gx, k, np.int64)
    if first_missing_layer is None:
        first_missing_layer = np.full(gx, k, np.int64)
    band_w, spatial_band = band
    band = band_w.shape[1]
    # A pixel whose filtered mask weight is this small has, in effect, no sample of its
    # intensity nearby (typical weight is ~ density * cell_s^2).
    eps = np.float32(1e-4 * density * geom.cell_s ** 2)
    return SliceGrids(
        values=grid_val.reshape(gy * gx * gz, k), base_weights=base_w,
        band_weights=band_w.reshape(gy * band * gz, k),
        spatial_values=spatial_values, spatial_base=spatial_base, spatial_band=spatial_band,
        first_band_layer=np.asarray(first_band_layer, np.int64),
        first_missing_layer=np.asarray(first_missing_layer, np.int64),
        layer_base=np.arange(k, dtype=np.int64) % n_base,
        gy=gy, gx=gx, gz=gz, band=band,
        inv_cell_s=np.float32(1.0 / geom.cell_s), inv_cell_r=np.float32(1.0 / geom.cell_r),
        eps=eps, missing_value=np.float32(missing_value))


@njit(cache=True, inline="always")
def _tile_into(period, out, n):
    """``out[i] = period[i % len(period)]`` for ``i < n``: :attr:`SliceGrids.layer_base` as copies.

    The pattern is copied onto itself in doubling blocks, so every copy is a plain
    vectorised loop (a gather through ``layer_base`` costs the slice ~15 %).
    """
    filled = min(period.shape[0], n)
    for i in range(filled):
        out[i] = period[i]
    # ``filled`` stays a multiple of the period, so each block continues the pattern.
    while filled < n:
        count = min(filled, n - filled)
        source = out[:count]
        target = out[filled:filled + count]
        for i in range(count):
            target[i] = source[i]
        filled += count


@njit(cache=True, inline="always")
def slice_scratch(num_layers):
    """Scratch of :func:`slice_pixel` for ``num_layers`` layers: (den, corner_index, band_index, corner_weight)."""
    return (np.empty(num_layers + MAX_PERIOD_LANES, dtype=np.float32), np.empty(8, dtype=np.int64),
            np.empty(8, dtype=np.int64), np.empty(8, dtype=np.float32))


@njit(cache=True, inline="always")
def _layer_weights(base_weights, corner_index, corner_weight, n, den, eps):
    """``den[i]`` = the base weights sliced in layer ``i``'s channel ``i % B``, for ``i < n``
    (and whatever fills a last period past ``n``: ``den`` holds ``n + MAX_PERIOD_LANES``).
    Returns whether one of those layers' weights is ``<= eps``.

    Up to 16 channels, in vectors (:func:`stereobudget._kernels.periodic_corner_sum`);
    more (a per-layer weight grid, no repetition), as a corner sum and a tiling.
    """
    if n <= 0:
        return False
    period = periodic_corner_sum(base_weights, corner_index, corner_weight, n, den, eps)
    if period != 0:
        return period < 0
    channels = base_weights.shape[1]
    used = min(channels, n)
    _add_corners_from(base_weights, corner_index, corner_weight, 0, used, den)
    light = False
    for i in range(used):
        light |= den[i] <= eps
    _tile_into(den[:channels], den, n)
    return light


@njit(cache=True, inline="always")
def slice_pixel(grids, guide, y, x, o, den, corner_index, band_index, corner_weight):
    """Write the normalised fill of pixel (y, x) into ``o`` (K,): Eq. (3) at one pixel.

    ``den`` (K + :data:`~stereobudget._kernels.MAX_PERIOD_LANES`,) float32,
    ``corner_index``/``band_index`` (8,) int64 and ``corner_weight`` (8,) float32 are the
    caller's scratch (:func:`slice_scratch`), reused from pixel to pixel.
    """
    n_out = o.shape[0]
    y0, ty = _hat(y * grids.inv_cell_s, grids.gy)
    x0, tx = _hat(x * grids.inv_cell_s, grids.gx)
    z0, tz = _hat(guide[y, x] * grids.inv_cell_r, grids.gz)
    # Layers from `live` on have zero weight and zero spatial weight here: their slice
    # would end in the fallback's missing value, so it is written without the arithmetic
    # (near the left border of a wide disparity search, most of a pixel's layers).
    live = grids.first_missing_layer[x0]
    # Two calls rather than one with min(live, n_out): bounded by the row's own length the
    # common case compiles as before (one call with a computed bound: Teddy's cost kernel 7 % slower).
    if live >= n_out:
        _slice_layers(grids, y0, ty, x0, tx, z0, tz, o, n_out, den, corner_index, band_index, corner_weight)
    else:
        _slice_layers(grids, y0, ty, x0, tx, z0, tz, o, live, den, corner_index, band_index, corner_weight)
        for i in range(live, n_out):
            o[i] = grids.missing_value


@njit(cache=True, inline="always")
def _slice_layers(grids, y0, ty, x0, tx, z0, tz, o, n, den, corner_index, band_index, corner_weight):
    """Layers ``[0, n)`` of :func:`slice_pixel` at the pixel of cell coordinates (y0, ty, x0, tx, z0, tz)."""
    _trilinear_corners(y0, ty, x0, tx, z0, tz, grids.gx, grids.gz, corner_weight, corner_index)
    _add_corners_from(grids.values, corner_index, corner_weight, 0, n, o)
    start = grids.first_band_layer[x0]
    base_light = _layer_weights(grids.base_weights, corner_index, corner_weight, min(start, n), den, grids.eps)
    if start < n:
        _trilinear_corners(y0, ty, x0, tx, z0, tz, grids.band, grids.gz, corner_weight, band_index)
        _add_corners_from(grids.band_weights, band_index, corner_weight, start, n, den)
    _divide_or_fall_back(o, den, n, start, base_light, grids.layer_base, grids.spatial_values, grids.spatial_base,
                         grids.spatial_band, y0, ty, x0, tx, grids.eps, grids.missing_value)


@njit(cache=True, parallel=True)
def _slice_rows(grids, guide, pixel_of_row, out):
    """Row k of ``out`` (N, K) = :func:`slice_pixel` at pixel ``pixel_of_row[k]`` (row-major)."""
    w = guide.shape[1]
    row_count = out.shape[0]
    for chunk in prange((row_count + _CHUNK - 1) // _CHUNK):
        den, corner_index, band_index, corner_weight = slice_scratch(out.shape[1])
        for k in range(chunk * _CHUNK, min((chunk + 1) * _CHUNK, row_count)):
            y = pixel_of_row[k] // w
            x = pixel_of_row[k] - y * w
            slice_pixel(grids, guide, y, x, out[k], den, corner_index, band_index, corner_weight)
    return out


def slice_volume(guide: np.ndarray, grids: SliceGrids, *, pixel_of_row: np.ndarray | None = None) -> np.ndarray:
    """Slice the grids at every pixel of ``guide``.

    Returns
    -------
    ndarray, float32 (H, W, K), or (H * W, K) rows with ``pixel_of_row`` (row ``k`` holds
    pixel ``pixel_of_row[k]``, row-major)
    """
    h, w = guide.shape
    out = empty_volume((h * w, grids.values.shape[1]))
    _slice_rows(grids, guide, _pixels_of_rows(pixel_of_row, h * w), out)
    return out if pixel_of_row is not None else out.reshape(h, w, -1)


def _pixels_of_rows(pixel_of_row, node_count):
    """The pixel of each row of an output volume: the given layout, or pixel order."""
    if pixel_of_row is None:
        return np.arange(node_count, dtype=np.int64)
    return np.asarray(pixel_of_row, dtype=np.int64)


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
def _layer_block(block, blocks, num_disp):
    """Layers [first, last) of thread block ``block`` of ``blocks``."""
    return block * num_disp // blocks, (block + 1) * num_disp // blocks


@njit(cache=True, inline="always")
def _left_step(guide, y, x, step_spacing, step_weight):
    """I1's gray difference over the sample spacing at (y, x) (NaN: no step term or no neighbour)."""
    if step_weight > 0 and x + step_spacing < guide.shape[1]:
        return guide[y, x + step_spacing] - guide[y, x]
    return np.float32(np.nan)


@njit(cache=True, inline="always")
def _corner_weights(ty, tx, tz, weights):
    """The 8 trilinear hat weights of a point, corners in (y, x, z) order as every splat adds them."""
    c = 0
    for a in range(2):
        wy = ty if a else 1 - ty
        for b in range(2):
            wx = tx if b else 1 - tx
            for e in range(2):
                wz = tz if e else 1 - tz
                weights[c] = wy * wx * wz
                c += 1


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


class SplatTerms(NamedTuple):
    """The scalars every splat kernel of the Sparse DSI takes: Eq. (2)'s cost terms
    (:func:`stereobudget.cost.sparse_pair_cost`) and the grid's scales."""

    truncation: np.float32
    step_spacing: int
    step_weight: np.float32
    step_truncation: np.float32
    census_weight: np.float32
    inv_cs: float       # grid cells per pixel
    inv_cr: float       # grid cells per gray level


class RightSamples(NamedTuple):
    """What the splat kernels read of the right samples, one row per sample."""

    values: np.ndarray  # float32 (K, C), 8-bit units
    steps: np.ndarray   # float32 (K,), difference to the next sample of the row (NaN: none)
    codes: np.ndarray   # int64 (K,), lattice census code (-1: no census term)
    offsets: np.ndarray  # float32 (K, 2) or (0, 2): (dy, dx) of the true position from (row, col)


class LeftPixels(NamedTuple):
    """What the splat kernels read of I1."""

    image: np.ndarray   # float32 (H, W, C), 8-bit units
    guide: np.ndarray   # float32 (H, W), its gray image
    codes: np.ndarray   # uint8 (H, W), lattice census code


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


def _splat_terms(terms: SparseCostTerms, geom: GridGeometry) -> SplatTerms:
    return SplatTerms(np.float32(terms.truncation), int(terms.step_spacing), np.float32(terms.step_weight),
                      np.float32(terms.step_truncation), np.float32(terms.census_weight),
                      1.0 / geom.cell_s, 1.0 / geom.cell_r)


@njit(cache=True, inline="always")
def _bilinear_at(image, y, x, h, w, out):
    """``image`` (H, W, C) at the real position (y, x), bilinear, clamped to the image; into ``out`` (C,)."""
    y = min(max(y, 0.0), h - 1.0)
    x = min(max(x, 0.0), w - 1.0)
    y0 = min(int(y), h - 2) if h > 1 else 0
    x0 = min(int(x), w - 2) if w > 1 else 0
    ty = y - y0
    tx = x - x0
    y1 = min(y0 + 1, h - 1)
    x1 = min(x0 + 1, w - 1)
    for c in range(out.shape[0]):
        top = image[y0, x0, c] * (1 - tx) + image[y0, x1, c] * tx
        bottom = image[y1, x0, c] * (1 - tx) + image[y1, x1, c] * tx
        out[c] = top * (1 - ty) + bottom * ty


@njit(cache=True, parallel=True)
def _splat_sparse_dsi_split(rows, cols, samples, pixels, min_disp, terms, grid_val, band_w, blocks):
    """Splat Eq. (2): right sample k at (row, col) meets left pixel (row, col + d) in layer d.

    The weights of layer i are written only into x-cells [0, B) of ``band_w`` (B = its
    second dimension): the regular-grid path keeps just the left-border band per layer;
    passing a full-width ``band_w`` gives every layer its own complete weight grid.

    The layers are cut into ``blocks`` contiguous blocks, one per thread: every block
    splats all samples into its own layers, so no two threads add into the same grid
    value and every value receives its samples in the same order as on one thread (the
    result does not depend on the thread count).  ``samples``: :class:`RightSamples`,
    ``pixels``: :class:`LeftPixels`, ``terms``: :class:`SplatTerms`.
    """
    right_values, right_steps, right_codes, right_offsets = samples
    left, guide, left_codes = pixels
    truncation, step_spacing, step_weight, step_truncation, census_weight, inv_cs, inv_cr = terms
    gy_n, gx_n, gz_n, num_disp = grid_val.shape
    h, w = left.shape[0], left.shape[1]
    subpixel = right_offsets.shape[0] == rows.shape[0]
    blocks = max(1, min(blocks, num_disp))
    band_n = band_w.shape[1]
    values_flat = grid_val.reshape(grid_val.size)
    band_flat = band_w.reshape(band_w.size)
    for block in prange(blocks):
        first, last = _layer_block(block, blocks, num_disp)
        weights = np.empty(8, dtype=np.float64)
        offsets = np.empty(8, dtype=np.uint64)
        band_offsets = np.empty(8, dtype=np.int64)
        at = np.empty(left.shape[2], dtype=np.float32)
        for k in range(rows.shape[0]):
            y = rows[k]
            y0, ty = _hat(y * inv_cs, gy_n)
            fy = right_offsets[k, 0] if subpixel else np.float32(0.0)
            fx = right_offsets[k, 1] if subpixel else np.float32(0.0)
            for i in range(first, last):
                x = cols[k] + min_disp + i
                if x < 0 or x >= w:
                    continue
                left_step = _left_step(guide, y, x, step_spacing, step_weight)
                if fy != 0 or fx != 0:
                    # The sample's true position is (y + fy, x + fx): I1 read there, bilinear.
                    _bilinear_at(left, y + fy, x + fx, h, w, at)
                    left_pixel = at
                else:
                    left_pixel = left[y, x]
                cost = sparse_pair_cost(left_pixel, right_values[k], left_step, right_steps[k], truncation,
                                        step_weight, step_truncation, left_codes[y, x], right_codes[k],
                                        census_weight)
                x0, tx = _hat(x * inv_cs, gx_n)
                z0, tz = _hat(guide[y, x] * inv_cr, gz_n)
                _corner_weights(ty, tx, tz, weights)
                _corner_offsets(y0, x0, z0, gx_n, gz_n, band_n, num_disp, offsets, band_offsets)
                _splat_cost(values_flat, band_flat, offsets, band_offsets, weights, i, cost)


@njit(cache=True, inline="always")
def _splat_lattice_rows(r_lo, r_hi, cell_lo, cell_hi, lattice, samples, pixels, min_disp, terms, grids):
    """Splat sample rows ``[r_lo, r_hi)`` into the grids' cells whose y index lies in
    ``[cell_lo, cell_hi]``: every layer's cost into ``grid_val``, the band's weights into
    ``band_w`` and each left pixel's mask weight into its base channel of ``base_w``.

    Left pixel x of sample row ``r`` meets a sample in every layer ``i`` whose column
    ``x - min_disp - i`` is on the lattice: one layer in ``stride``.  Its hat weights are
    the same in all of them, so they are computed once per pixel, and the 8 cells it adds
    into stay in cache.  Base channel ``channel_of_residue[x % stride]`` holds the mask of
    the lattice columns congruent to x (-1: none).  Sample ``k = r * n_cols + j`` is at
    column ``offset_x + j * stride``; ``min_disp >= 0``.  ``lattice``: :class:`LatticeRows`,
    ``grids``: :class:`LatticeGrids`; ``samples``, ``pixels``, ``terms`` as
    :func:`_splat_sparse_dsi_split`.
    """
    sample_rows, offset_x, stride, n_cols = lattice
    grid_val, band_w, base_w, channel_of_residue = grids
    right_values, right_steps, right_codes, _ = samples
    left, guide, left_codes = pixels
    truncation, step_spacing, step_weight, step_truncation, census_weight, inv_cs, inv_cr = terms
    gy_n, gx_n, gz_n, num_disp = grid_val.shape
    w = left.shape[1]
    band_n = band_w.shape[1]
    n_base = base_w.shape[3]
    values_flat = grid_val.reshape(grid_val.size)
    band_flat = band_w.reshape(band_w.size)
    base_flat = base_w.reshape(base_w.size)
    weights = np.empty(8, dtype=np.float64)
    offsets = np.empty(8, dtype=np.uint64)
    band_offsets = np.empty(8, dtype=np.int64)
    for r in range(r_lo, r_hi):
        y = sample_rows[r]
        y0, ty = _hat(y * inv_cs, gy_n)
        # The corners a (cell y0 + a) this call may write: 4 of the 8 per allowed a.
        c_lo = 4 * max(0, cell_lo - y0)
        c_hi = 4 * (min(1, cell_hi - y0) + 1)
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
            left_step = _left_step(guide, y, x, step_spacing, step_weight)
            # Sample of layer i: column (reach - i) / stride of the row, one less per step.
            k = r * n_cols + (reach - i_first) // stride
            left_code = left_codes[y, x]
            for i in range(i_first, i_max + 1, stride):
                cost = sparse_pair_cost(left[y, x], right_values[k], left_step, right_steps[k], truncation,
                                        step_weight, step_truncation, left_code, right_codes[k], census_weight)
                if all_corners:  # a fixed trip count: the 8 adds unrolled
                    _splat_cost(values_flat, band_flat, offsets, band_offsets, weights, i, cost)
                else:
                    for c in range(c_lo, c_hi):
                        values_flat[offsets[c] + np.uint64(i)] += weights[c] * cost
                        if band_offsets[c] >= 0:
                            band_flat[np.uint64(band_offsets[c] + i)] += weights[c]
                k -= 1


@njit(cache=True, parallel=True)
def _splat_lattice(lattice, samples, pixels, min_disp, terms, grids, part_rows, shared_cells, zero_cells):
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
    ``[zero_cells[p], zero_cells[p + 1])``, which hold every cell its first loop writes
    and none that another part's first loop writes (a separate pass of zeros over all
    three grids took 0.8 ms of a Teddy decode).
    """
    grid_val, band_w, base_w, _ = grids
    gy_n = grid_val.shape[0]
    parts = part_rows.shape[0] - 1
    val_row = grid_val.size // gy_n
    band_row = band_w.size // gy_n
    base_row = base_w.size // gy_n
    values_flat = grid_val.reshape(grid_val.size)
    band_flat = band_w.reshape(band_w.size)
    base_flat = base_w.reshape(base_w.size)
    for p in prange(parts):
        lo, hi = zero_cells[p], zero_cells[p + 1]
        values_flat[lo * val_row:hi * val_row] = 0.0
        band_flat[lo * band_row:hi * band_row] = 0.0
        base_flat[lo * base_row:hi * base_row] = 0.0
        # Cells up to the last one the part above reaches (shared_cells[p]) wait for the second loop.
        _splat_lattice_rows(part_rows[p], part_rows[p + 1], shared_cells[p] + 1, gy_n, lattice, samples, pixels,
                            min_disp, terms, grids)
    for p in prange(parts):
        if shared_cells[p] >= 0:
            _splat_lattice_rows(part_rows[p], part_rows[p + 1], 0, shared_cells[p], lattice, samples, pixels,
                                min_disp, terms, grids)


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
                   LeftPixels(left, guide, left_codes), int(min_disp), _splat_terms(terms, geom),
                   LatticeGrids(grid_val, band_w, base_w, channel_of_residue),
                   *_lattice_parts(sample_rows, inv_cs, gy, get_num_threads()))
    return _slice_grids(_blur_grid(grid_val, geom), _blur_base_grid(base_w, geom), _blur_grid(band_w, geom), geom,
                        density=len(rows) / float(h * w), missing_value=terms.truncation,
                        first_band_layer=first_band_layer, first_missing_layer=first_missing_layer)


def sparse_joint_bilateral(guide: np.ndarray, rows: np.ndarray, cols: np.ndarray, values: np.ndarray, *,
                           sigma_s: float, sigma_r: float, missing_value: float = 0.0,
                           cells_per_sigma_s: float = 2.0, cells_per_sigma_r: float = 2.0) -> np.ndarray:
    """Normalised joint bilateral filter of sparse samples (Eq. 3 with shared positions).

    Parameters
    ----------
    guide : ndarray, float32 (H, W)
        Guidance image in 8-bit units.
    rows, cols : ndarray of int
        Sample positions.
    values : ndarray, float32 (n, K)
        K channels per sample.
    sigma_s, sigma_r : float
        Spatial (pixels) and range (guide units) standard deviations.
    missing_value : float
        Output where no sample lies within reach.

    Returns
    -------
    ndarray, float32 (H, W, K)
    """
    guide = np.ascontiguousarray(guide, dtype=np.float32)
    h, w = guide.shape
    values = np.ascontiguousarray(values, dtype=np.float32).reshape(len(rows), -1)
    geom = grid_geometry(h, w, float(guide.max(initial=0.0)), sigma_s=sigma_s, sigma_r=sigma_r,
                         cells_per_sigma_s=cells_per_sigma_s, cells_per_sigma_r=cells_per_sigma_r)
    k = values.shape[1]
    grid_val = zeroed_volume(geom.shape + (k,))
    grid_w = zeroed_volume(geom.shape + (1,))
    _splat_points(np.asarray(rows, np.int64), np.asarray(cols, np.int64), values, guide,
                  1.0 / geom.cell_s, 1.0 / geom.cell_r, grid_val, grid_w)
    grids = _slice_grids(_blur_grid(grid_val, geom), _blur_base_grid(grid_w, geom), None, geom,
                         density=len(rows) / float(h * w), missing_value=missing_value)
    volume = slice_volume(guide, grids)
    release_grids(grids)
    return volume


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


def release_grids(grids: SliceGrids) -> None:
    """Hand the large grids of a :class:`SliceGrids` no longer needed to :mod:`stereobudget._kernels._scratch`."""
    recycle(grids.values, grids.base_weights, grids.band_weights)


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
    _splat_sparse_dsi_split(np.asarray(rows, np.int64), np.asarray(cols, np.int64), samples,
                            LeftPixels(left, guide, left_codes), int(min_disp), _splat_terms(terms, geom),
                            grid_val, grid_w, get_num_threads())
    return _slice_grids(_blur_grid(grid_val, geom), _blur_base_grid(grid_w, geom), None, geom,
                        density=len(rows) / float(h * w), missing_value=terms.truncation)
