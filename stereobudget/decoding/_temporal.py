"""Frames of one stream: search only the disparities the previous frame had.

A camera pair's consecutive frames see nearly the same depths.  Time per decode grows with
the number of disparities searched (N·D), so a frame that searches the previous frame's
range of disparities, plus a margin, instead of the whole ``min_disp..max_disp`` costs a
fraction of a full decode.  The whole range is searched instead:

* on the first frame, and after :meth:`TemporalSearch.reset`;
* when the caller's whole range (which may change from frame to frame, as an estimated one
  does) holds none of the previous frame's disparities; otherwise the band is cut to it;
* on a scene cut: the previous frame's disparities no longer carry I1 onto the new samples
  (the samples' mismatch at the previous disparities is much larger than the previous frame's
  own), or the samples' brightness histogram has changed;
* when the band would be nearly as wide as the whole range (nothing to gain);
* after a band decode whose winners sit at the band's edge on more than a small share of
  the pixels (the scene has moved out of the band): that frame is decoded again on the whole
  range.

The band is one range of disparities for the whole frame (the previous frame's low and high
percentiles widened by a margin), so every kernel runs unchanged on fewer layers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..errors import MismatchError


@dataclass(frozen=True)
class TemporalParams:
    """How a stream's frame chooses the disparities it searches.

    Attributes
    ----------
    percentile : float
        The previous frame's disparities below this percentile and above ``100 - percentile``
        are ignored (stray pixels, not surfaces).
    margin : float
        Disparities added on both sides of the previous frame's range: at least this share of
        the whole range...
    min_margin : int
        ...and at least this many disparities.
    edge_share : float
        A band decode with more than this share of its valid pixels at a band edge (that is
        not an edge of the whole range) is decoded again on the whole range.
    max_band : float
        A band wider than this share of the whole range is not worth it: the whole range is searched.
    cut_mismatch : float
        Scene cut: the samples' median mismatch against I1 at the previous frame's disparities
        exceeds this multiple of the previous frame's own (plus ``cut_floor`` gray levels).
    cut_floor : float
    cut_histogram : float
        Scene cut: the L1 distance of the samples' 16-bin gray histograms (0 equal, 2 disjoint)
        between the two frames exceeds this.
    """

    percentile: float = 0.5
    margin: float = 0.05
    min_margin: int = 4
    edge_share: float = 0.01
    max_band: float = 0.85
    cut_mismatch: float = 2.0
    cut_floor: float = 4.0
    cut_histogram: float = 0.5


def _gray_samples(samples):
    """(rows, cols, gray values float32) of the samples, or None for a pattern without positions."""
    from ._checks import _pixel_samples
    found = _pixel_samples(samples)
    if found is None:
        return None
    rows, cols, values = found
    values = np.asarray(values, np.float32)
    if values.ndim == 2:
        values = np.nanmean(values, axis=1) if values.shape[1] > 1 else values[:, 0]
    return rows, cols, values


def _histogram(gray):
    hist, _ = np.histogram(gray[np.isfinite(gray)], bins=16, range=(0.0, 256.0))
    total = hist.sum()
    return hist / total if total else hist.astype(np.float64)


def _left_at(left, rows, x):
    """I1's gray value (mean of its channels, 8-bit units like the samples') at (rows, x)."""
    picked = np.asarray(left[rows, x], np.float32)
    if picked.ndim == 2:
        picked = picked.mean(axis=1)
    return picked * np.float32(255.0 / 65535.0) if left.dtype == np.uint16 else picked


def _mismatch(left, disparity, rows, cols, values, step=1):
    """Median |I1(y, x + d(y, x)) - sample| over the samples (gray levels): how well ``disparity``
    carries I1 onto the samples.  The sample at right pixel (y, x) is compared with the left
    pixel ``d`` to its right, ``d`` read at (y, x) of the left view (surfaces are smooth)."""
    rows, cols, values = rows[::step], cols[::step], values[::step]
    d = disparity[rows, cols]
    ok = np.isfinite(d)
    if not ok.any():
        return math.nan
    x = cols[ok] + np.rint(d[ok]).astype(np.int64)
    inside = (x >= 0) & (x < left.shape[1])
    if not inside.any():
        return math.nan
    diff = np.abs(_left_at(left, rows[ok][inside], x[inside]) - values[ok][inside])
    diff = diff[np.isfinite(diff)]
    return float(np.median(diff)) if diff.size else math.nan


class TemporalSearch:
    """The state of a stream between frames: the last frame's size, disparity range and samples.

    :meth:`decode` takes a ``decode(left, samples, min_disp=, max_disp=, **options)`` callable
    and calls it once (or twice, when a band turns out too narrow) per frame.
    """

    def __init__(self, params: TemporalParams | None = None):
        self.params = params or TemporalParams()
        self.reset()
        self.shape = None
        self.frame = -1

    def reset(self) -> None:
        """Forget the previous frame's disparities: the next frame searches the whole range."""
        self._band = None          # (low, high) percentiles of the last disparity
        self._mismatch = None
        self._histogram = None
        self._disparity = None

    def decode(self, decode, left, samples, *, max_disp, min_disp=0, **options):
        """Decode the next frame of the stream (arguments as :func:`stereobudget.decode`).

        Returns the :class:`~stereobudget.decoding.DecodeResult` of the frame, its
        ``stream`` holding ``frame`` (from 0), ``searched`` (the disparities decoded) and
        ``reason`` (``"first"``, ``"cut"``, ``"range"`` (the caller's whole range holds none
        of the previous disparities),
        ``"wide"``, ``"band"``, or ``"edge"`` (a band decoded again on the whole range)).

        Raises
        ------
        MismatchError
            The frame's size differs from the stream's first frame, naming the frame.
        """
        p = self.params
        self.frame += 1
        shape = (int(samples.height), int(samples.width))
        if self.shape is None:
            self.shape = shape
        elif shape != self.shape:
            raise MismatchError(f"frame {self.frame} is {shape[1]}x{shape[0]}, the stream's frames are "
                                f"{self.shape[1]}x{self.shape[0]}")
        min_disp, max_disp = int(min_disp), int(max_disp)
        full = max_disp - min_disp + 1
        gray_samples = _gray_samples(samples)
        histogram = None if gray_samples is None else _histogram(gray_samples[2])

        reason, band = self._choose(histogram, left, gray_samples, min_disp, max_disp, full)
        if band is None:
            result = decode(left, samples, min_disp=min_disp, max_disp=max_disp, **options)
        else:
            result = decode(left, samples, min_disp=band[0], max_disp=band[1], **options)
            if self._at_edges(result.disparity, band, min_disp, max_disp) > p.edge_share:
                reason, band = "edge", None
                band_seconds = sum(result.timings.values())
                result = decode(left, samples, min_disp=min_disp, max_disp=max_disp, **options)
                result.timings["band"] = band_seconds
        searched = band or (min_disp, max_disp)
        result = replace(result, min_disp=min_disp, max_disp=max_disp,
                         stream={"frame": self.frame, "searched": searched, "reason": reason})
        self._remember(result.disparity, histogram, left, gray_samples)
        return result

    def _choose(self, histogram, left, gray_samples, min_disp, max_disp, full):
        p = self.params
        if self._band is None:
            return "first", None
        if histogram is not None and self._histogram is not None \
                and float(np.abs(histogram - self._histogram).sum()) > p.cut_histogram:
            return "cut", None
        if gray_samples is not None and self._mismatch is not None and math.isfinite(self._mismatch):
            now = _mismatch(left, self._disparity, *gray_samples)
            if not math.isfinite(now) or now > p.cut_mismatch * self._mismatch + p.cut_floor:
                return "cut", None
        margin = max(p.min_margin, int(math.ceil(p.margin * full)))
        low = max(min_disp, int(math.floor(self._band[0])) - margin)
        high = min(max_disp, int(math.ceil(self._band[1])) + margin)
        if high - low < 2:
            # The whole range moved away from the previous disparities (a caller's new range).
            return "range", None
        if high - low + 1 > p.max_band * full:
            return "wide", None
        return "band", (low, high)

    @staticmethod
    def _at_edges(disparity, band, min_disp, max_disp):
        valid = disparity[np.isfinite(disparity)]
        if not valid.size:
            return 1.0
        count = 0
        if band[0] > min_disp:
            count += int(np.count_nonzero(valid <= band[0] + 0.5))
        if band[1] < max_disp:
            count += int(np.count_nonzero(valid >= band[1] - 0.5))
        return count / valid.size

    def _remember(self, disparity, histogram, left, gray_samples):
        p = self.params
        valid = disparity[::2, ::2]
        valid = valid[np.isfinite(valid)]
        if not valid.size:
            self.reset()
            return
        low, high = np.percentile(valid, [p.percentile, 100.0 - p.percentile])
        self._band = (float(low), float(high))
        self._histogram = histogram
        self._disparity = disparity
        self._mismatch = None if gray_samples is None else _mismatch(left, disparity, *gray_samples)


__all__ = ["TemporalParams", "TemporalSearch"]
