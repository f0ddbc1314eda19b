"""Checks that a decode, and the setup behind it, look right: the warnings of ``sb-decode``.

Each check returns a :class:`DecodeWarning` with a stable ``code`` (for scripts reading
``--json``) and a one-line message saying what to do:

* ``range_limit`` -- many pixels sit at an end of the disparity range searched: the true
  range is wider (give a larger ``--max-disp``, or ``auto``).
* ``samples_disagree`` -- I1 warped by the result does not reproduce the right camera's
  own samples: the PSNR at the samples is far below what a correct decode gives.
* ``swapped`` -- the samples match I1 with negative disparities: the right image was given
  as the left one (or the cameras are exchanged).
* ``not_rectified`` -- the samples match I1 best two or more rows up or down: the pair is
  not rectified, and a decoder that searches along rows only cannot be right.
* ``left_is_samples`` -- I1 reproduces the samples at zero disparity almost exactly: LEFT
  is the image that was sampled (the right camera's), not the left camera's.
* ``no_texture`` -- the samples' neighbourhoods are (almost) all flat: there is nothing to
  match, and the disparity is a guess however complete the map looks.

The thresholds were calibrated on the Middlebury scenes (docs/cli.md gives the figures).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

#: ``range_limit``: share of the valid pixels within half a pixel of an end of the range.
LIMIT_SHARE = 0.05
#: ``samples_disagree``: PSNR (dB) at the samples of I1 warped by the disparity, below
#: which the decode is taken to be wrong.  Decodes with the true range give 19.4-33.6 dB
#: on the 27 Middlebury and realdev scenes (KITTI's exposure differences the lowest), one
#: scene's I1 with another's samples 11.7 dB (scripts/auto_range.py --calibrate).
MIN_SAMPLE_PSNR = 16.0
#: ``swapped``: share of the confident matches with negative disparity (and at least
#: twice the share of positive ones).
SWAPPED_SHARE = 0.3
#: ``not_rectified``: the estimate's best vertical shift is at least this many rows (it
#: must beat no shift by :data:`stereobudget.decoding._disprange.VERTICAL_MIN_GAIN` in mean
#: ZNCC).  A single row is within the coarse search's error (one clean KITTI frame).
MIN_WARNED_OFFSET = 2
#: ``left_is_samples``: PSNR (dB) of I1 at the sample positions, unshifted, from which I1
#: is taken to be the sampled image itself, when the decode also puts this share of the
#: pixels within a pixel of 0.  The 27 clean Middlebury / realdev pairs give 11.3-20.2 dB;
#: a right image given as LEFT gives infinity with raw samples, 25.2-41.0 dB with WebP at
#: quality 90.
LEFT_IS_SAMPLES_PSNR = 24.0
LEFT_IS_SAMPLES_ZERO_SHARE = 0.9
#: ``no_texture``: share of the sample lattice's windows with any texture below which the
#: pair has nothing to match (clean pairs: 0.76-1.0; a constant pair: 0).
MIN_TEXTURED_SHARE = 0.05


@dataclass(frozen=True)
class DecodeWarning:
    """One warning: a stable ``code`` and a one-line ``message``."""

    code: str
    message: str

    def as_dict(self) -> dict:
        return asdict(self)


def limit_shares(disparity: np.ndarray, *, min_disp: int, max_disp: int) -> tuple[float, float]:
    """Shares of the valid pixels within half a pixel of ``min_disp`` and of ``max_disp``."""
    valid = np.isfinite(disparity)
    count = int(valid.sum())
    if count == 0:
        return 0.0, 0.0
    values = disparity[valid]
    return (float(np.count_nonzero(values <= min_disp + 0.5)) / count,
            float(np.count_nonzero(values >= max_disp - 0.5)) / count)


def _pixel_samples(samples):
    """``(rows, cols, values)`` of samples sent as pixels at known positions, or None (block means,
    or a pattern without positions): what the checks compare I1 with."""
    if samples.pattern.kind == "downsample":
        return None
    from ..synthesis._inpaint import sample_arrays
    try:
        return sample_arrays(samples)
    except Exception:  # noqa: BLE001 -- a pattern without pixel positions: no check
        return None


def psnr_at_samples(left: np.ndarray, disparity: np.ndarray, samples) -> float:
    """PSNR (dB, 8-bit units) of I1 warped into the right view by ``disparity``, at the samples.

    Only samples the warp reaches count (a pixel no left pixel lands on is a hole, which
    says nothing about the disparity).  NaN when the pattern sends no pixels at known
    positions (``downsample``) or no sample is reached.
    """
    from ..synthesis._warp import warp_left_to_right
    found = _pixel_samples(samples)
    if found is None:
        return math.nan
    rows, cols, values = found
    # Each row warps on its own: only the rows that hold samples (a fifth of them on a
    # stride-5 grid) are warped, the same values as the whole image's warp.
    sample_rows = np.unique(rows)
    warped, holes = warp_left_to_right(left[sample_rows], disparity[sample_rows])
    rows = np.searchsorted(sample_rows, rows)
    warped = warped if warped.ndim == 3 else warped[:, :, None]
    reached = ~holes[rows, cols]
    if not reached.any():
        return math.nan
    diff = warped[rows[reached], cols[reached]].astype(np.float64) - values[reached]
    mse = float(np.nanmean(diff * diff))   # NaN: the channels a mosaic sample does not carry
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0 ** 2 / mse)


def psnr_at_zero_disparity(left: np.ndarray, samples) -> float:
    """PSNR (dB, 8-bit units) of I1 read at the samples' own positions (disparity 0 everywhere).

    A real pair cannot reach a high value (the cameras see the scene from two places);
    the right image given as LEFT reproduces its own samples up to the codec's error.  NaN
    when the pattern sends no pixels at known positions.
    """
    found = _pixel_samples(samples)
    if found is None:
        return math.nan
    rows, cols, values = found
    image = left if left.ndim == 3 else left[:, :, None]
    scale = 1.0 / 257.0 if image.dtype == np.uint16 else 1.0
    diff = image[rows, cols].astype(np.float64) * scale - values
    with np.errstate(all="ignore"):
        mse = float(np.nanmean(diff * diff))   # NaN: the channels a mosaic sample does not carry
    if not math.isfinite(mse):
        return math.nan
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0 ** 2 / mse)


def setup_warnings(estimate) -> list[DecodeWarning]:
    """``no_texture``, ``swapped`` and ``not_rectified`` from a :class:`~stereobudget.decoding.RangeEstimate`."""
    out = []
    if estimate is None:
        return out
    textured = getattr(estimate, "textured_fraction", 1.0)
    if textured < MIN_TEXTURED_SHARE:
        out.append(DecodeWarning("no_texture", (
            f"the images have no texture to match: {100 * textured:.0f} % of the samples' neighbourhoods "
            f"vary, so the disparity (and valid_fraction) is a guess (check the exposure and the lens cap)")))
    if estimate.fallback:
        return out
    neg, pos = estimate.negative_fraction, estimate.positive_fraction
    if neg >= SWAPPED_SHARE and neg >= 2 * pos:
        out.append(DecodeWarning("swapped", (
            f"the pair looks swapped: {100 * neg:.0f} % of the confident matches have negative disparity "
            f"(LEFT must be the left camera's image, SAMPLES the right camera's)")))
    offset = estimate.vertical_offset
    if abs(offset) >= MIN_WARNED_OFFSET:
        out.append(DecodeWarning("not_rectified", (
            f"the pair does not look rectified: the samples match I1 best {abs(offset)} row(s) "
            f"{'lower' if offset > 0 else 'higher'} in I1 (rectify the images so that a scene point lies on "
            f"the same row in both)")))
    return out


def result_warnings(disparity: np.ndarray, *, min_disp: int, max_disp: int, psnr: float | None,
                    auto_range: bool = False, zero_psnr: float | None = None) -> list[DecodeWarning]:
    """``left_is_samples``, ``range_limit`` and ``samples_disagree`` for a decoded disparity map.

    ``psnr``: :func:`psnr_at_samples` of the result (None or NaN: not checked).  The low
    end counts only when it is not 0: a pair whose background is at infinity has many
    pixels at 0 rightly.  ``zero_psnr``: :func:`psnr_at_zero_disparity` (None or NaN: not
    checked).
    """
    out = []
    if zero_psnr is not None and not math.isnan(zero_psnr) and zero_psnr >= LEFT_IS_SAMPLES_PSNR:
        valid = np.isfinite(disparity)
        near_zero = float(np.count_nonzero(np.abs(disparity[valid]) <= 1.0)) / max(1, int(valid.sum()))
        if near_zero >= LEFT_IS_SAMPLES_ZERO_SHARE:
            shown = "exactly" if math.isinf(zero_psnr) else f"at {zero_psnr:.1f} dB PSNR"
            out.append(DecodeWarning("left_is_samples", (
                f"LEFT looks like the sampled image itself: it reproduces the samples {shown} with no "
                f"shift (LEFT must be the left camera's image, SAMPLES the right camera's)")))
    low, high = limit_shares(disparity, min_disp=min_disp, max_disp=max_disp)
    if auto_range and high < LIMIT_SHARE:
        # An estimated range was already widened once when its top was crowded
        # (``widened_max``); still crowded, the pair needs a range given by hand.
        from ._disprange import CROWD_BAND, CROWD_SHARE, top_share
        crowd = top_share(disparity, max_disp=max_disp, band=CROWD_BAND)
        high = crowd if crowd >= CROWD_SHARE else high
    where = []
    if high >= LIMIT_SHARE or (auto_range and high >= CROWD_SHARE):
        where.append(f"{100 * high:.0f} % at --max-disp {max_disp}")
    if low >= LIMIT_SHARE and min_disp != 0:
        where.append(f"{100 * low:.0f} % at --min-disp {min_disp}")
    if where:
        hint = ("the estimated range is too narrow; give --max-disp/--min-disp" if auto_range
                else "widen the range, or use --max-disp auto")
        out.append(DecodeWarning("range_limit", f"many pixels sit at the range limits ({', '.join(where)}): "
                                                f"{hint}"))
    if psnr is not None and math.isfinite(psnr) and psnr < MIN_SAMPLE_PSNR:
        out.append(DecodeWarning("samples_disagree", (
            f"the samples disagree with the result: I1 warped by the disparity reproduces them at "
            f"{psnr:.1f} dB PSNR (a correct decode gives over {MIN_SAMPLE_PSNR:.0f} dB); check the range "
            f"and that LEFT and SAMPLES are the same moment's pair")))
    return out


__all__ = ["DecodeWarning", "LIMIT_SHARE", "MIN_SAMPLE_PSNR", "SWAPPED_SHARE", "limit_shares",
           "psnr_at_samples", "psnr_at_zero_disparity", "setup_warnings", "result_warnings"]
