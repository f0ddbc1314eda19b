"""The disparity range of a pair, estimated from I1 and the samples (``--max-disp auto``).

Every sample of the right view is matched against I1 over the whole image width, for
both signs of disparity: a window of neighbouring samples (5 x 5 points of the sample
lattice) is compared with I1 at the same points shifted by ``d`` by zero-mean normalised
cross-correlation (ZNCC), which ignores the gain and offset differences of two real
cameras.  Samples whose best match is clear (textured window, high and unique peak) vote
with their best ``d``; the range is a high and a low percentile of the votes widened by
a margin.  The same matches say whether the pair looks swapped (the votes are negative)
and whether it is rectified (the best match is found at a vertical shift).

The work is one pass over ``samples x disparities`` (the decode's is ``pixels x
disparities x aggregation``), capped by thinning the lattice and stepping ``d`` by more
than a pixel on wide frames, so the estimate costs a few percent of a decode.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL
from .._kernels._parallel import run_parts

#: Half-width, in lattice points, of the ZNCC window (5 x 5 samples).
WINDOW_RADIUS = 2
#: Vertical shifts (pixels, both ways) tried by the rectification check, the work budget
#: of the coarse search at each, and the gain in mean ZNCC over no shift that counts.
#: Shifts -2..2 are always tried; while the best one is at an end of those tried, the
#: search goes one row further that way, up to MAX_VERTICAL_SHIFT rows (a badly
#: rectified pair, a camera tilted by a fraction of a degree).  The mean score falls off
#: smoothly on both sides of the true shift, so the walk stops there: a rectified pair
#: costs the 5 searches it always did, a pair 5 rows off 9.
MIN_VERTICAL_SHIFT = 2
MAX_VERTICAL_SHIFT = 8
VERTICAL_BUDGET = 80_000
VERTICAL_MIN_GAIN = 0.02
#: A sample votes when its window's gray standard deviation, its best ZNCC and the gap
#: to the best match elsewhere (> 2 steps away) reach these.
MIN_TEXTURE_STD = 3.0
MIN_SCORE = 0.8
MIN_UNIQUENESS = 0.05
#: ... and at least this many of its 8 lattice neighbours vote for about the same disparity.
MIN_AGREEING = 3
#: Votes are cut into runs at gaps wider than this (pixels plus a fraction of the
#: disparity); runs holding less than MIN_RUN_SHARE of the votes are wrong matches.
MAX_GAP_PIXELS = 4.0
MAX_GAP_FRACTION = 0.1
MIN_RUN_SHARE = 0.01
#: The range extends below 0 only when this share of the kept votes is negative.
MIN_NEGATIVE_SHARE = 0.05
#: Percentiles of the votes taken as the ends of the range, and the margin added to them
#: (pixels plus a fraction of the larger end).
HIGH_PERCENTILE = 99.9
LOW_PERCENTILE = 0.5
MARGIN_PIXELS = 4.0
MARGIN_FRACTION = 0.1
#: Upper bound of the work (lattice points x disparities tried) of the search.
WORK_BUDGET = 1_000_000
#: Fewer votes than this: the estimate falls back to a wide range.
MIN_VOTES = 30
#: Winners crowding the top of an estimated range: when this share of the valid pixels
#: lies within CROWD_BAND pixels of ``max_disp``, the estimate missed the nearest
#: surfaces (few confident samples there) and the pair is decoded again over a range
#: widened by WIDEN_PIXELS + WIDEN_FRACTION of it.  On the 27 Middlebury / realdev pairs
#: the three whose estimate is below the truth (Vintage 124 vs 161, Laundry 67 vs 77,
#: Moebius 71 vs 73) have 0.64-3.3 %; every other one at most 0.09 %.  The widening is
#: kept small because a wider search costs the other pixels a little: decoded again over
#: +16 px + 30 %, the pixels beyond the first top go from 58 to 27 % bad (> 2 px) on
#: Vintage and from 84 to 53 % on Laundry, the rest from 27.0 to 27.4 and 22.6 to 22.9 %
#: (+50 %: 27.6 and 22.9 %, and a slower second decode).
CROWD_BAND = 2.0
CROWD_SHARE = 0.005
WIDEN_PIXELS = 16
WIDEN_FRACTION = 0.3


@dataclass(frozen=True)
class RangeEstimate:
    """What :func:`estimate_disparity_range` found.

    Attributes
    ----------
    min_disp, max_disp : int
        The range to search (inclusive), margins included.
    low, high : float
        Low and high percentile of the confident matches (pixels), before the margin;
        NaN when too few samples matched confidently.
    votes : int
        Samples whose best match was confident.
    positive_fraction, negative_fraction : float
        Of the votes, the fractions with disparity > 1 and < -1 pixel.
    vertical_offset : int
        Vertical shift (pixels) at which I1 matches the samples best: a sample of row ``y``
        matches I1's row ``y + vertical_offset``; 0 for a rectified pair.  The range is
        measured at this shift.
    vertical_scores : dict of int to float
        Mean best ZNCC of the textured samples at each vertical shift tried (coarse search).
    disparity_step : int
        Step of the coarse search (pixels; the work is capped, see :data:`WORK_BUDGET`).
    textured_fraction : float
        Share of the sample lattice's windows whose gray values vary (standard deviation
        of at least :data:`MIN_TEXTURE_STD`): 0 for a constant pair, which has nothing
        to match.
    fallback : bool
        Too few confident matches: the range is a wide default, not a measurement.
    seconds : float
    """

    min_disp: int
    max_disp: int
    low: float
    high: float
    votes: int
    positive_fraction: float
    negative_fraction: float
    vertical_offset: int
    vertical_scores: dict = field(default_factory=dict)
    disparity_step: int = 1
    textured_fraction: float = 1.0
    fallback: bool = False
    seconds: float = 0.0

    def summary(self) -> dict:
        """JSON-able dict (NaN as None, rounded floats)."""
        out = asdict(self)
        for key in ("low", "high"):
            out[key] = None if not math.isfinite(out[key]) else round(out[key], 2)
        for key in ("positive_fraction", "negative_fraction", "textured_fraction", "seconds"):
            out[key] = round(out[key], 4)
        out["vertical_scores"] = {str(k): round(v, 4) for k, v in self.vertical_scores.items()}
        return out


@njit(cache=True, **RANGE_KERNEL)
def _zncc_search(lattice, image, ys, xs, d_first, d_count, d_step, shift, radius, best, best_d, second, col_a,
                 col_aa, col_ga, first_k, last_k, col_g, col_gg, win_a, win_aa, win_ga, first, stop):
    """Lattice rows ``radius + [first, stop)`` of the best ZNCC per lattice point over
    disparities ``d_first + k d_step`` at vertical ``shift``, on the range's scratch (``col_*``,
    ``first_k``, ``last_k``: (C, D) and (C,) per lattice row; ``win_*``: (D,)).

    ``lattice`` (R, C) holds the samples' gray values at rows ``ys`` and columns ``xs`` of
    the right view; ``image`` (H, W) is I1's gray.  For lattice point (r, c) the window is
    the points ``r +- radius, c +- radius``, compared with I1 at ``(ys + shift, xs + d)``.
    ``best``, ``best_d`` and ``second`` (the best score more than two steps from
    ``best_d``) are updated in place; points whose window leaves either image keep theirs.
    Per lattice row, the sums over the window's rows are made for every disparity at
    once (I1's pixels at consecutive d are consecutive in memory), then summed over the
    window's columns, so the inner loops run along d.
    """
    rows, cols = lattice.shape
    height, width = image.shape
    n = (2 * radius + 1) ** 2
    for r in range(radius + first, radius + stop):
        if ys[r - radius] + shift < 0 or ys[r + radius] + shift >= height:
            continue
        col_a[:, :] = 0.0
        col_aa[:, :] = 0.0
        col_ga[:, :] = 0.0
        col_g[:] = 0.0
        col_gg[:] = 0.0
        for c in range(cols):
            # Disparities at which column c lands inside I1.
            lo = -(-(-xs[c] - d_first) // d_step)
            hi = (width - 1 - xs[c] - d_first) // d_step
            lo = max(lo, 0)
            hi = min(hi, d_count - 1)
            first_k[c] = lo
            last_k[c] = hi
            x0 = xs[c] + d_first
            for i in range(-radius, radius + 1):
                row = image[ys[r + i] + shift]
                g = lattice[r + i, c]
                col_g[c] += g
                col_gg[c] += g * g
                for k in range(lo, hi + 1):
                    a = row[x0 + k * d_step]
                    col_a[c, k] += a
                    col_aa[c, k] += a * a
                    col_ga[c, k] += g * a
        for c in range(radius, cols - radius):
            lo = first_k[c - radius]
            hi = last_k[c + radius]
            if hi < lo:
                continue
            sum_g = 0.0
            sum_gg = 0.0
            for j in range(-radius, radius + 1):
                sum_g += col_g[c + j]
                sum_gg += col_gg[c + j]
            var_g = sum_gg - sum_g * sum_g / n
            if var_g <= 1e-6:
                continue
            for k in range(lo, hi + 1):
                win_a[k] = 0.0
                win_aa[k] = 0.0
                win_ga[k] = 0.0
            for j in range(-radius, radius + 1):
                for k in range(lo, hi + 1):
                    win_a[k] += col_a[c + j, k]
                    win_aa[k] += col_aa[c + j, k]
                    win_ga[k] += col_ga[c + j, k]
            b = best[r, c]
            bd = best_d[r, c]
            sc = second[r, c]
            for k in range(lo, hi + 1):
                var_a = win_aa[k] - win_a[k] * win_a[k] / n
                if var_a <= 1e-6:
                    continue
                score = (win_ga[k] - sum_g * win_a[k] / n) / math.sqrt(var_a * var_g)
                d = d_first + k * d_step
                if score > b:
                    if abs(d - bd) > 2 * d_step:
                        sc = b
                    b = score
                    bd = d
                elif score > sc and abs(d - bd) > 2 * d_step:
                    sc = score
            best[r, c] = b
            best_d[r, c] = bd
            second[r, c] = sc


def _gray(image: np.ndarray) -> np.ndarray:
    """Gray float32 in 8-bit units; OpenCV's conversion (one pass; ZNCC needs no exact luma)."""
    import cv2
    image = np.ascontiguousarray(image)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    scale = 1.0 / 257.0 if image.dtype == np.uint16 else 1.0
    return image.astype(np.float32) * np.float32(scale) if scale != 1.0 else image.astype(np.float32)


def _match_inputs(left: np.ndarray, samples):
    """(lattice gray (R, C), rows ys, columns xs, I1 gray to compare with) for any pattern.

    A grid is matched as sent (its points are pixels of I2, I1's pixels at the same
    points are the match).  Block means are matched with I1's block means at the block
    centres.  Scattered points are first interpolated with a Gaussian of half the mean
    spacing and read on a regular lattice; I1 gets the same Gaussian.
    """
    p = samples.pattern
    h, w = samples.height, samples.width
    # A raw mosaic's lattice alternates colours: it goes the scattered points' way below,
    # whose interpolation normalises each colour by its own samples.
    if p.is_regular_grid and not getattr(samples, "mosaic", None):
        lattice = _gray(samples.grid_values())
        ys = p.offset_y + p.stride_y * np.arange(lattice.shape[0])
        xs = p.offset_x + p.stride_x * np.arange(lattice.shape[1])
        return lattice, ys, xs, _gray(left)
    if p.kind == "downsample":
        import cv2
        from ..sampling._patterns import downsample_shape
        rows, cols = downsample_shape(p, h, w)
        lattice = _gray(samples.values_rgb().reshape(rows, cols, samples.channels))
        # cv2.blur's window at x covers x - s//2 .. x + (s-1)//2: a whole block at s//2.
        ys = np.minimum(p.stride_y * np.arange(rows) + p.stride_y // 2, h - 1)
        xs = np.minimum(p.stride_x * np.arange(cols) + p.stride_x // 2, w - 1)
        # Only whole blocks: the last partial block's mean is not centred on its centre.
        rows, cols = h // p.stride_y, w // p.stride_x
        box = cv2.blur(_gray(left), (p.stride_x, p.stride_y), borderType=cv2.BORDER_REFLECT)
        return np.ascontiguousarray(lattice[:rows, :cols]), ys[:rows], xs[:cols], box
    from ..fill._lowpass import gaussian_lowpass, lowpass_interpolation
    stride = max(1, int(round(math.sqrt(p.stride_x * p.stride_y))))
    sigma = 0.5 * stride
    dense = lowpass_interpolation(samples, sigma=sigma)
    dense = dense if dense.ndim == 3 else dense[:, :, None]
    # At least one point each way, also in an image smaller than the stride.
    ys = np.arange(min(stride // 2, h - 1), h, stride)
    xs = np.arange(min(stride // 2, w - 1), w, stride)
    lattice = _gray(np.ascontiguousarray(dense[np.ix_(ys, xs)]))
    return lattice, ys, xs, gaussian_lowpass(_gray(left), sigma=sigma)


def _reduction(rows: int, cols: int, disparities: int, budget: int) -> tuple[int, int, int]:
    """(disparity step, lattice row thinning, column thinning) that bring the work within ``budget``.

    The reductions are taken in turn -- a step of 2, every other lattice row, every other
    column, a step of 3... -- so that no one of them grows coarse alone.
    """
    step, thin_r, thin_c = 1, 1, 1
    turn = 0
    while (-(-rows // thin_r)) * (-(-cols // thin_c)) * (-(-disparities // step)) > budget:
        if turn % 3 == 0:
            step += 1
        elif turn % 3 == 1:
            thin_r += 1
        else:
            thin_c += 1
        turn += 1
    return step, thin_r, thin_c


def _triangle_blur_x(image: np.ndarray, step: int) -> np.ndarray:
    """I1 smoothed along x by a triangle of half-width ``step``: a match between two tried shifts is not lost."""
    if step <= 1:
        return image
    import cv2
    taps = 1.0 - np.abs(np.arange(-step + 1, step, dtype=np.float32)) / step
    taps /= taps.sum()
    return cv2.sepFilter2D(image, -1, taps, np.ones(1, np.float32), borderType=cv2.BORDER_REFLECT)


def estimate_disparity_range(left: np.ndarray, samples, *, high_percentile: float = HIGH_PERCENTILE,
                             low_percentile: float = LOW_PERCENTILE, margin_pixels: float = MARGIN_PIXELS,
                             margin_fraction: float = MARGIN_FRACTION,
                             max_vertical_shift: int = MAX_VERTICAL_SHIFT) -> RangeEstimate:
    """Estimate the disparity range of a pair from I1 and the right camera's samples.

    Parameters
    ----------
    left : ndarray, (H, W) or (H, W, 3), uint8 or uint16
        I1.
    samples : SampleSet
        What the right camera sent (any pattern).
    high_percentile, low_percentile : float
        Percentiles of the confident matches taken as the ends of the range.
    margin_pixels, margin_fraction : float
        Each end ``e`` is widened by ``margin_pixels + margin_fraction * |e|`` plus the
        search step less one, and rounded outwards.
    max_vertical_shift : int
        Vertical shifts ``-n..n`` tried by the rectification check (0: none).

    Returns
    -------
    RangeEstimate
        ``min_disp`` is 0 unless the matches put the low end below zero.  With too few
        confident matches (a textureless or unrelated pair) the range is
        ``[0, W // 4]`` and ``fallback`` is set.
    """
    start = time.perf_counter()
    w = samples.width
    lattice, ys, xs, image = _match_inputs(left, samples)
    if lattice.size == 0:   # no whole block of a downsample pattern in an image smaller than one
        min_disp, max_disp = _fitted(*_fallback_range(w), w)
        return RangeEstimate(min_disp=min_disp, max_disp=max_disp, low=math.nan, high=math.nan, votes=0,
                             positive_fraction=0.0, negative_fraction=0.0, vertical_offset=0, fallback=True,
                             seconds=time.perf_counter() - start)
    lattice = np.ascontiguousarray(lattice, np.float32)
    image = np.ascontiguousarray(image, np.float32)
    ys = np.ascontiguousarray(ys, np.int64)
    xs = np.ascontiguousarray(xs, np.int64)
    radius = WINDOW_RADIUS
    textured = _window_std(lattice, radius) >= MIN_TEXTURE_STD
    textured_fraction = float(textured.mean()) if textured.size else 0.0
    # Whole width, both signs, up to where a window still fits.
    span = max(1, int(xs[-1] - xs[0]) if xs.size > 1 else w - 1)

    # Rectification first, on a coarse search per vertical shift: the shift whose best
    # matches are the best overall is where the range is then measured.
    vertical_offset, vertical_scores = 0, {}
    if max_vertical_shift > 0:
        def score_at(shift):
            found = _search(lattice, image, ys, xs, span=span, shift=shift, budget=VERTICAL_BUDGET)
            vertical_scores[shift] = _mean_textured_score(found)

        def best_shift():
            return max(vertical_scores, key=lambda k: (vertical_scores[k], -abs(k)))

        reach = int(max_vertical_shift)
        low, high = -min(MIN_VERTICAL_SHIFT, reach), min(MIN_VERTICAL_SHIFT, reach)
        for shift in range(low, high + 1):
            score_at(shift)
        while True:
            best = best_shift()
            if best == high and high < reach:
                high += 1
                score_at(high)
            elif best == low and low > -reach:
                low -= 1
                score_at(low)
            else:
                break
        vertical_scores = dict(sorted(vertical_scores.items()))
        vertical_offset = best_shift()
        if vertical_scores[vertical_offset] - vertical_scores[0] < VERTICAL_MIN_GAIN:
            vertical_offset = 0   # too close to call: the rows as they are
    lattice, ys, xs, best, best_d, second, step = _search(lattice, image, ys, xs, span=span,
                                                          shift=vertical_offset, budget=WORK_BUDGET)

    # Texture: the window's own standard deviation (uniform windows match anywhere).
    texture = _window_std(lattice, radius)
    confident = ((best >= MIN_SCORE) & (best - second >= MIN_UNIQUENESS) & (texture >= MIN_TEXTURE_STD))
    # A wrong match (a repeated pattern far away) is isolated; a true one agrees with its
    # neighbours, whose windows overlap it.
    confident &= _neighbours_agreeing(best_d, confident, tolerance=step + 1) >= MIN_AGREEING
    votes = best_d[confident].astype(np.float64)
    n_votes = int(votes.size)
    if n_votes >= MIN_VOTES:
        cluster = _main_clusters(votes, gap_pixels=MAX_GAP_PIXELS + step, gap_fraction=MAX_GAP_FRACTION,
                                 min_share=MIN_RUN_SHARE)
        high = float(np.percentile(cluster, high_percentile))
        low = float(np.percentile(cluster, low_percentile))
        def margin(end):
            return margin_pixels + margin_fraction * abs(end) + (step - 1)
        max_disp = int(math.ceil(high + margin(high)))
        # The low end only ever extends the range below 0: a positive low end saves
        # little time, and the nearest-background pixels it would clamp are many.
        # Below 0 only when a real share of the matches is negative (a swapped pair, or
        # cameras converging): single wrong runs there would double the work.
        negative_share = float(np.mean(cluster < 0))
        min_disp = int(math.floor(low - margin(low))) if low < 0 and negative_share >= MIN_NEGATIVE_SHARE else 0
        fallback = False
    else:
        high = low = math.nan
        min_disp, max_disp = _fallback_range(w)
        fallback = True
    min_disp, max_disp = _fitted(min_disp, max_disp, w)

    positive = float(np.mean(votes > 1)) if n_votes else 0.0
    negative = float(np.mean(votes < -1)) if n_votes else 0.0
    return RangeEstimate(min_disp=int(min_disp), max_disp=int(max_disp), low=low, high=high, votes=n_votes,
                         positive_fraction=positive, negative_fraction=negative,
                         vertical_offset=vertical_offset, vertical_scores=vertical_scores,
                         disparity_step=step, textured_fraction=textured_fraction, fallback=fallback,
                         seconds=time.perf_counter() - start)


def _fallback_range(width: int) -> tuple[int, int]:
    """The range searched when the samples do not measure one: ``[0, W // 4]``, at least ``[0, 2]``."""
    return 0, max(2, width // 4)


def _fitted(min_disp: int, max_disp: int, width: int) -> tuple[int, int]:
    """``[min_disp, max_disp]`` clipped to fit an image ``width`` pixels wide (decode's check)."""
    max_disp = min(max_disp, width - 1)
    min_disp = max(min_disp, -(width - 1))
    if max_disp <= min_disp:
        max_disp = min_disp + 1
    if max_disp - min_disp >= width:
        min_disp = max_disp - (width - 1)
    return min_disp, max_disp


def _main_clusters(votes: np.ndarray, *, gap_pixels: float, gap_fraction: float,
                   min_share: float) -> np.ndarray:
    """The votes of the runs that hold at least ``min_share`` of them.

    The votes are cut into runs wherever two consecutive disparities are more than
    ``gap_pixels + gap_fraction |d|`` apart.  A scene's surfaces give runs with many
    votes each (two planes far apart give two runs); the wrong matches that survive the
    other checks (a repeated pattern) make small runs of their own, dropped here.
    """
    values = np.sort(votes)
    gaps = np.diff(values)
    allowed = gap_pixels + gap_fraction * np.maximum(np.abs(values[:-1]), np.abs(values[1:]))
    edges = np.concatenate([[0], np.nonzero(gaps > allowed)[0] + 1, [values.size]])
    keep = [values[a:b] for a, b in zip(edges[:-1], edges[1:]) if b - a >= min_share * values.size]
    return np.concatenate(keep) if keep else values


def _neighbours_agreeing(best_d: np.ndarray, confident: np.ndarray, *, tolerance: int) -> np.ndarray:
    """How many of the 8 lattice neighbours of each point are confident and within ``tolerance`` of its disparity."""
    rows, cols = best_d.shape
    d = np.pad(best_d, 1)
    ok = np.pad(confident, 1)
    count = np.zeros((rows, cols), np.int32)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == 0 and dx == 0:
                continue
            nd = d[1 + dy:1 + dy + rows, 1 + dx:1 + dx + cols]
            nok = ok[1 + dy:1 + dy + rows, 1 + dx:1 + dx + cols]
            count += (nok & (np.abs(nd - best_d) <= tolerance)).astype(np.int32)
    return count


def _window_std(lattice: np.ndarray, radius: int) -> np.ndarray:
    """Standard deviation of the (2 radius + 1)^2 window around each lattice point (0 at the border)."""
    import cv2
    size = 2 * radius + 1
    values = lattice.astype(np.float64)
    mean = cv2.blur(values, (size, size), borderType=cv2.BORDER_REFLECT)
    mean_sq = cv2.blur(values * values, (size, size), borderType=cv2.BORDER_REFLECT)
    return np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))


def _search(lattice, image, ys, xs, *, span, shift, budget):
    """The ZNCC search at one vertical shift within a work budget.

    Returns ``(lattice, ys, xs, best, best_d, second, step)`` on the thinned lattice the
    search used, with I1 smoothed along x for the step (see :func:`_reduction`).
    """
    radius = WINDOW_RADIUS
    step, thin_r, thin_c = _reduction(lattice.shape[0], lattice.shape[1], 2 * span + 1, budget)
    lattice = np.ascontiguousarray(lattice[::thin_r, ::thin_c])
    ys = np.ascontiguousarray(ys[::thin_r])
    xs = np.ascontiguousarray(xs[::thin_c])
    smooth = _triangle_blur_x(image, step)
    rows, cols = lattice.shape
    best = np.full((rows, cols), -2.0, np.float64)
    best_d = np.zeros((rows, cols), np.int64)
    second = np.full((rows, cols), -2.0, np.float64)
    if rows > 2 * radius and cols > 2 * radius:
        d_count = 2 * (span // step) + 1

        def scratch():
            # Per lattice row: column sums of the window at every disparity, and the window's.
            return (np.empty((cols, d_count), np.float32), np.empty((cols, d_count), np.float32),
                    np.empty((cols, d_count), np.float32), np.empty(cols, np.int64), np.empty(cols, np.int64),
                    np.empty(cols, np.float64), np.empty(cols, np.float64), np.empty(d_count, np.float64),
                    np.empty(d_count, np.float64), np.empty(d_count, np.float64))
        run_parts(_zncc_search, rows - 2 * radius, lattice, smooth, ys, xs, -(span // step) * step, d_count, step,
                  int(shift), radius, best, best_d, second, scratch=scratch)
    return lattice, ys, xs, best, best_d, second, step


def _mean_textured_score(found) -> float:
    """Mean best ZNCC of the textured lattice points of a :func:`_search` (-1 when none)."""
    lattice, _, _, best, _, _, _ = found
    textured = (_window_std(lattice, WINDOW_RADIUS) >= MIN_TEXTURE_STD) & (best > -2.0)
    return float(best[textured].mean()) if textured.any() else -1.0


def top_share(disparity: np.ndarray, *, max_disp: int, band: float = CROWD_BAND) -> float:
    """Share of the valid pixels of ``disparity`` within ``band`` pixels of ``max_disp``."""
    valid = np.isfinite(disparity)
    count = int(valid.sum())
    if count == 0:
        return 0.0
    return float(np.count_nonzero(disparity[valid] >= max_disp - band)) / count


def widened_max(disparity: np.ndarray, *, min_disp: int, max_disp: int, width: int) -> int | None:
    """A larger ``max_disp`` when the winners of a decode over an estimated range crowd its top.

    Parameters
    ----------
    disparity : ndarray
        The decode over ``min_disp..max_disp``.
    width : int
        Image width (the range must stay below it).

    Returns
    -------
    int or None
        ``max_disp + WIDEN_PIXELS + WIDEN_FRACTION * (max_disp - min_disp)`` (within the
        image) when at least :data:`CROWD_SHARE` of the valid pixels lie within
        :data:`CROWD_BAND` of ``max_disp``; None when the range holds the result or cannot
        grow.
    """
    if top_share(disparity, max_disp=max_disp) < CROWD_SHARE:
        return None
    wider = int(math.ceil(max_disp + WIDEN_PIXELS + WIDEN_FRACTION * (max_disp - min_disp)))
    wider = min(wider, min_disp + width - 1, width - 1)
    return wider if wider > max_disp else None


#: The value of ``max_disp`` (``--max-disp``) that asks for the estimate.
AUTO = "auto"


def is_auto(value) -> bool:
    """Whether a ``max_disp`` value means "estimate it" (None or ``"auto"``, any case)."""
    return value is None or (isinstance(value, str) and value.strip().lower() == AUTO)


def resolve_range(left: np.ndarray, samples, *, max_disp=None, min_disp=None):
    """The range to decode with, and the estimate behind it.

    Parameters
    ----------
    left, samples
        As :func:`estimate_disparity_range`.
    max_disp : int, "auto" or None
        None or ``"auto"``: estimated.
    min_disp : int or None
        None: the estimate's when ``max_disp`` is estimated, else 0.

    Returns
    -------
    (min_disp, max_disp, estimate) : (int, int, RangeEstimate)
        The estimate is made in every case: the setup checks read it.
    """
    from .._kernels._first_run import compile_notice
    with compile_notice("range"):
        estimate = estimate_disparity_range(left, samples)
    if is_auto(max_disp):
        low = estimate.min_disp if min_disp is None else int(min_disp)
        high = estimate.max_disp
        if high <= low:   # a --min-disp above the estimate: search a little above it
            high = low + max(1, estimate.max_disp - estimate.min_disp)
        return low, min(high, low + samples.width - 1), estimate
    return (0 if min_disp is None else int(min_disp)), int(max_disp), estimate


__all__ = ["AUTO", "RangeEstimate", "estimate_disparity_range", "is_auto", "resolve_range", "top_share",
           "widened_max"]
