"""The pixels a left-right check rejected, given the weighted median of their neighbourhood.

A row fill (:func:`stereobudget.aggregate.fill_from_row`) gives every rejected pixel the
disparity of one pixel of its row: runs of rejected pixels become horizontal streaks that
cross I1's edges.  Rhemann et al. (CVPR 2011) and Hosni et al. (TPAMI 2013) follow the
fill with a median of the filled map over a window around each rejected pixel, each
neighbour weighted by its nearness and by its likeness in I1, as a joint bilateral filter
weighs: the streaks give way to the disparities of the surface the pixel belongs to.

The rule, stated once (:func:`stereobudget.aggregate.weighted_median_fill_reference` spells it out in numpy):

- the window is every ``step``-th pixel within ``radius`` of the rejected pixel ``p`` on
  each axis (``p`` itself included), cut at the image's border; NaN disparities are skipped;
- a neighbour ``q`` weighs ``exp(-|q - p|^2 / (2 sigma_s^2)) * c(g)``, where ``g`` is the
  largest difference of I1's channels between ``q`` and ``p`` (a grey image has one) and
  ``c(g) = exp(-g'^2 / (2 sigma_c^2))`` with ``g'`` = ``g`` rounded to a quarter level, 0
  from ``4 sigma_c`` on;
- the window's disparities are binned to the nearest whole pixel; the median bin is the
  first, counting up, at which the summed weight reaches half the window's weight;
- the pixel takes the weighted mean of the window's disparities in that bin (a median
  to a pixel, the sub-pixel value of its bin).

Binning to a pixel keeps the median one pass over a short histogram; sampling every
third pixel of the 19 x 19 window keeps it 49 reads a pixel.  Both measured the same as
the exact weighted median of every window pixel, and the colours better than I1's grey
image, which misses the edges between surfaces of equal brightness (docs/results.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL
from .._kernels._parallel import run_parts

#: Hosni et al.'s window: radius 9, sigma_s 9; sigma_c in levels of 8-bit units.
DEFAULT_RADIUS = 9
DEFAULT_SIGMA_S = 9.0
DEFAULT_SIGMA_C = 10.0
DEFAULT_STEP = 3
#: Quarter grey levels per step of the likeness table, and its reach in sigma_c.
_LEVELS_PER_GREY = 4
_REACH = 4.0


def likeness_table(sigma_c: float) -> np.ndarray:
    """``c(g)`` at ``g = i / 4`` levels, ``i = 0 ... ceil(16 sigma_c) - 1`` (float64): up to 4 sigma_c."""
    steps = int(np.ceil(_REACH * sigma_c * _LEVELS_PER_GREY))
    grey = np.arange(max(steps, 1), dtype=np.float64) / _LEVELS_PER_GREY
    return np.exp(-grey * grey / (2.0 * sigma_c * sigma_c))


def nearness_table(radius: int, step: int, sigma_s: float) -> np.ndarray:
    """Spatial weights of the window's offsets ``-radius ... radius`` by ``step`` (float64, square)."""
    offsets = np.arange(-(radius // step) * step, radius + 1, step).astype(np.float64)
    return np.exp(-(offsets[:, None] ** 2 + offsets[None, :] ** 2) / (2.0 * sigma_s * sigma_s))


def weighted_median_fill(disparity: np.ndarray, valid: np.ndarray, image: np.ndarray, *,
                         radius: int = DEFAULT_RADIUS, sigma_s: float = DEFAULT_SIGMA_S,
                         sigma_c: float = DEFAULT_SIGMA_C, step: int = DEFAULT_STEP) -> np.ndarray:
    """Each invalid pixel takes the weighted median of the disparities around it (module docstring).

    Parameters
    ----------
    disparity : ndarray, float32 (H, W)
        A filled map (every pixel has a value: :func:`stereobudget.aggregate.fill_from_row`).
    valid : ndarray, bool (H, W)
        The pixels that keep their value (those the left-right check kept).
    image : ndarray, float32 (H, W, C) or (H, W)
        I1 in 8-bit units (its colours, or a grey image).
    radius, step : int, keyword-only
        The window: offsets up to ``radius`` in multiples of ``step`` on each axis.
    sigma_s, sigma_c : float, keyword-only
        Spatial sigma in pixels; sigma of the largest channel difference, in 8-bit levels.

    Returns
    -------
    ndarray, float32 (H, W)
        A new map; valid pixels keep their value.
    """
    radius, step = int(radius), int(step)
    if radius < 0 or step < 1:
        raise ValueError(f"radius must be >= 0 and step >= 1, got {radius} and {step}")
    disparity = np.ascontiguousarray(disparity, np.float32)
    out = disparity.copy()
    targets = np.flatnonzero(~np.asarray(valid, bool).ravel())
    if targets.size == 0:
        return out
    low, high = _finite_range(disparity)
    if low is None:
        return out
    low = np.floor(low)
    bins = int(np.floor(high - low + 0.5)) + 1
    image = np.ascontiguousarray(image, np.float32)
    if image.ndim == 2:
        image = image[:, :, None]
    nearness = nearness_table(radius, step, float(sigma_s))
    likeness = likeness_table(float(sigma_c))
    run_parts(_fill_targets, targets.size, disparity, image, targets, nearness, likeness, (radius // step) * step,
              step, float(low), out, scratch=lambda: (np.zeros(bins, np.float64), np.zeros(bins, np.float64)))
    return out


def _finite_range(disparity):
    """(smallest, largest) finite value of ``disparity``, or (None, None) when it has none."""
    # fmin / fmax skip NaN without a copy of the map; only a map holding infinities
    # takes the masked copy.
    low, high = float(np.fmin.reduce(disparity, axis=None)), float(np.fmax.reduce(disparity, axis=None))
    if not (np.isfinite(low) and np.isfinite(high)):
        finite = disparity[np.isfinite(disparity)]
        if finite.size == 0:
            return None, None
        low, high = float(finite.min()), float(finite.max())
    return low, high


@njit(cache=True, **RANGE_KERNEL)
def _fill_targets(disparity, image, targets, nearness, likeness, reach, step, low, out, bin_weight, bin_sum,
                  first, stop):
    """Targets ``[first, stop)`` of :func:`weighted_median_fill` into ``out``; ``bin_weight`` and
    ``bin_sum`` (bins,) float64 are zero on entry and left zero."""
    h, w = disparity.shape
    bins = bin_weight.shape[0]
    levels = likeness.shape[0]
    channels = image.shape[2]
    for t in range(first, stop):
        p = targets[t]
        y = p // w
        x = p - y * w
        total = 0.0
        lo = bins
        hi = -1
        for iy in range(nearness.shape[0]):
            yy = y - reach + iy * step
            if yy < 0 or yy >= h:
                continue
            for ix in range(nearness.shape[1]):
                xx = x - reach + ix * step
                if xx < 0 or xx >= w:
                    continue
                v = disparity[yy, xx]
                if not np.isfinite(v):
                    continue
                difference = 0.0
                for c in range(channels):
                    difference = max(difference, abs(np.float64(image[yy, xx, c]) - np.float64(image[y, x, c])))
                level = int(difference * 4.0 + 0.5)
                if level >= levels:
                    continue
                weight = nearness[iy, ix] * likeness[level]
                b = int(np.floor(np.float64(v) - low + 0.5))
                bin_weight[b] += weight
                bin_sum[b] += weight * np.float64(v)
                total += weight
                lo = min(lo, b)
                hi = max(hi, b)
        if total > 0.0:
            half = 0.5 * total
            reached = 0.0
            for b in range(lo, hi + 1):
                reached += bin_weight[b]
                if reached >= half and bin_weight[b] > 0.0:
                    out[y, x] = bin_sum[b] / bin_weight[b]
                    break
        for b in range(lo, hi + 1):
            bin_weight[b] = 0.0
            bin_sum[b] = 0.0
