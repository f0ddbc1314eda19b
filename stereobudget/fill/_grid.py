"""Normalised joint bilateral filtering of sparse data on a bilateral grid: splat, blur, slice.

The paper's Eq. (3) spreads a sparse signal known only at sample points to every pixel by a
joint bilateral filter guided by a dense image, normalised by the same filter applied to
the sample mask::

    out(p) = sum_q F(p, q) s(q) m(q) / sum_q F(p, q) m(q)
    F(p, q) = exp(-|p - q|^2 / (2 sigma_s^2)) * exp(-(g(p) - g(q))^2 / (2 sigma_r^2))

A brute-force evaluation costs O(N * sigma_s^2) per layer.  A bilateral grid (Paris &
Durand; Chen et al.) makes it O(N): splat only the sample points into a coarse
(y, x, intensity) grid with trilinear weights, blur the grid with a separable Gaussian,
and slice it trilinearly at every pixel.  The signal and the mask share one grid layout,
so the normalisation costs one extra channel per distinct mask.  This module holds the
grid's blur and slice (and the plain fill of values, :func:`sparse_joint_bilateral`); the
sparse DSI's splats, which put Eq. (2)'s costs into the grid, are in ``_bilateral.py``.

Grid volumes are float32 with shape (GY, GX, GZ, K): K channels (disparity layers)
contiguous so slicing reads one vector per corner.

Accuracy: splatting and slicing with hat functions each add 1/6 cell^2 of variance per
axis; the blur is narrowed by exactly that amount so the effective kernel has the
requested sigma.  ``tests/fill/test_bilateral.py`` states the agreement with a brute-force
filter.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .._kernels._jit import NO_REFCOUNTS, RANGE_KERNEL
from .._kernels._parallel import run_parts
from .._kernels._simd import MAX_PERIOD_LANES, PERIOD_READ_PAST, periodic_corner_sum
from .._kernels._scratch import empty_volume, recycle, zeroed_volume
from ._geometry import GridGeometry, grid_geometry


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


@njit(cache=True, **RANGE_KERNEL)
def _blur_grid_rows(src, dst, spatial, kernel_s, kernel_r, slab, column, first, stop):
    """Grid rows ``[first, stop)`` of ``dst`` = ``src`` (GY, GX, GZ, K) blurred along y and x by
    ``kernel_s``, then along z by ``kernel_r``, with zero boundaries (taps outside the grid
    are left out; each sum starts from its first tap inside), on the range's scratch
    ``slab`` and ``column``; ``spatial`` (GY, GX, K) = ``dst`` summed over
    intensity, the cells added in intensity order from the first (the slice's
    spatial-only fallback), while each column is in cache.

    The three passes run per grid row: row y's y-blurred slab and one x-blurred column
    of cells at a time stay in cache, so the grid is read once and written once instead
    of three times each, and every pass loops over whole contiguous runs (a grid row of
    GX * GZ * K floats, a column of GZ * K) rather than one cell's K channels at a time.
    Empty cells are blurred like the others: skipping them (the splat's occupancy flags)
    saved nothing at one cell per sigma, where ~40 % of the cells are occupied.
    """
    _blur_grid_band(src, dst, spatial, kernel_s, kernel_r, first, stop, slab, column)


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
    run_parts(_blur_grid_rows, gy, grid, out, spatial, _gaussian_kernel(geom.blur_s), _gaussian_kernel(geom.blur_r),
              scratch=lambda: (np.empty(gx * gz * k, np.float32), np.empty(gz * k, np.float32)))
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


def _slice_scratch(num_layers):
    """Scratch of :func:`slice_pixel` for ``num_layers`` layers: (den, corner_index, band_index, corner_weight)."""
    return (np.empty(num_layers + MAX_PERIOD_LANES, dtype=np.float32), np.empty(8, dtype=np.int64),
            np.empty(8, dtype=np.int64), np.empty(8, dtype=np.float32))


#: :func:`_slice_scratch` for a caller's own kernel as well (the range kernels take the
#: plain function's arrays from ``run_parts``: no dispatcher to load).
slice_scratch = njit(cache=True, inline="always")(_slice_scratch)


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
    # One call with the computed bound: a second call for the common case measured no
    # faster, and each call inlines the whole slice again (seconds of compiling apiece).
    n = min(live, n_out)
    _slice_layers(grids, y0, ty, x0, tx, z0, tz, o, n, den, corner_index, band_index, corner_weight)
    for i in range(n, n_out):
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


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _slice_chunk(grids, guide, pixel_of_row, out, first, last, den, corner_index, band_index, corner_weight):
    """Rows ``[first, last)`` of :func:`_slice_rows`, on the scratch of :func:`slice_scratch`."""
    w = guide.shape[1]
    for k in range(first, last):
        y = pixel_of_row[k] // w
        x = pixel_of_row[k] - y * w
        slice_pixel(grids, guide, y, x, out[k], den, corner_index, band_index, corner_weight)


@njit(cache=True, **RANGE_KERNEL)
def _slice_rows(grids, guide, pixel_of_row, out, den, corner_index, band_index, corner_weight, first, stop):
    """Rows ``[first, stop)`` of ``out`` (N, K): row k = :func:`slice_pixel` at pixel
    ``pixel_of_row[k]`` (row-major), on the range's scratch (:func:`slice_scratch`)."""
    _slice_chunk(grids, guide, pixel_of_row, out, first, stop, den, corner_index, band_index, corner_weight)


def slice_volume(guide: np.ndarray, grids: SliceGrids, *, pixel_of_row: np.ndarray | None = None) -> np.ndarray:
    """Slice the grids at every pixel of ``guide``.

    Returns
    -------
    ndarray, float32 (H, W, K), or (H * W, K) rows with ``pixel_of_row`` (row ``k`` holds
    pixel ``pixel_of_row[k]``, row-major)
    """
    h, w = guide.shape
    out = empty_volume((h * w, grids.values.shape[1]))
    run_parts(_slice_rows, h * w, grids, guide, _pixels_of_rows(pixel_of_row, h * w), out,
              scratch=lambda: _slice_scratch(out.shape[1]))
    return out if pixel_of_row is not None else out.reshape(h, w, -1)


def _pixels_of_rows(pixel_of_row, node_count):
    """The pixel of each row of an output volume: the given layout, or pixel order."""
    if pixel_of_row is None:
        return np.arange(node_count, dtype=np.int64)
    return np.asarray(pixel_of_row, dtype=np.int64)


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


def release_grids(grids: SliceGrids) -> None:
    """Hand the large grids of a :class:`SliceGrids` no longer needed to :mod:`stereobudget._kernels._scratch`."""
    recycle(grids.values, grids.base_weights, grids.band_weights)


__all__ = ["SliceGrids", "slice_scratch", "slice_pixel", "slice_volume", "sparse_joint_bilateral", "release_grids"]
