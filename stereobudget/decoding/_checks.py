"""Checks that a decode, and the setup behind it, look right: the warnings of ``sb-decode``.

Each check returns a :class:`DecodeWarning` with a stable ``code`` (for scripts reading
``--json``) and a one-line message saying what to do:

* ``range_limit`` -- many pixels sit at an end of the disparity range searched: the true
  range is wider (give a larger ``--max-disp``, or ``auto``).
* ``samples_disagree`` -- I1 warped by the result does not reproduce the right camera's
  own samples: the PSNR at the samples is far below what a correct decode gives.
* ``swapped`` -- the samples match I1 with negative disparities: the right image was given
  as the left one (or the cameras are exchanged).
* ``not_rectified`` -- the samples match I1 best a few rows up or down: the pair is not
  rectified, and a decoder that searches along rows only cannot be right.

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
#: ``not_rectified``: the estimate's best vertical shift is not 0 (it must beat no shift by
#: :data:`stereobudget.decoding._disprange.VERTICAL_MIN_GAIN` in mean ZNCC).


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


def psnr_at_samples(left: np.ndarray, disparity: np.ndarray, samples) -> float:
    """PSNR (dB, 8-bit units) of I1 warped into the right view by ``disparity``, at the samples.

    Only samples the warp reaches count (a pixel no left pixel lands on is a hole, which
    says nothing about the disparity).  NaN when the pattern sends no pixels at known
    positions (``downsample``) or no sample is reached.
    """
    if samples.pattern.kind == "downsample":
        return math.nan
    from ..synthesis._inpaint import sample_arrays
    from ..synthesis._warp import warp_left_to_right
    try:
        rows, cols, values = sample_arrays(samples)
    except Exception:  # noqa: BLE001 -- a pattern without pixel positions: no check
        return math.nan
    warped, holes = warp_left_to_right(left, disparity)
    warped = warped if warped.ndim == 3 else warped[:, :, None]
    reached = ~holes[rows, cols]
    if not reached.any():
        return math.nan
    diff = warped[rows[reached], cols[reached]].astype(np.float64) - values[reached]
    mse = float(np.nanmean(diff * diff))   # NaN: the channels a mosaic sample does not carry
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0 ** 2 / mse)


def setup_warnings(estimate) -> list[DecodeWarning]:
    """``swapped`` and ``not_rectified`` from a :class:`~stereobudget.decoding.RangeEstimate`."""
    out = []
    if estimate is None or estimate.fallback:
        return out
    neg, pos = estimate.negative_fraction, estimate.positive_fraction
    if neg >= SWAPPED_SHARE and neg >= 2 * pos:
        out.append(DecodeWarning("swapped", (
            f"the pair looks swapped: {100 * neg:.0f} % of the confident matches have negative disparity "
            f"(LEFT must be the left camera's image, SAMPLES the right camera's)")))
    offset = estimate.vertical_offset
    if offset != 0:
        out.append(DecodeWarning("not_rectified", (
            f"the pair does not look rectified: the samples match I1 best {abs(offset)} row(s) "
            f"{'lower' if offset > 0 else 'higher'} in I1 (rectify the images so that a scene point lies on "
            f"the same row in both)")))
    return out


def result_warnings(disparity: np.ndarray, *, min_disp: int, max_disp: int, psnr: float | None,
                    auto_range: bool = False) -> list[DecodeWarning]:
    """``range_limit`` and ``samples_disagree`` for a decoded disparity map.

    ``psnr``: :func:`psnr_at_samples` of the result (None or NaN: not checked).  The low
    end counts only when it is not 0: a pair whose background is at infinity has many
    pixels at 0 rightly.
    """
    out = []
    low, high = limit_shares(disparity, min_disp=min_disp, max_disp=max_disp)
    where = []
    if high >= LIMIT_SHARE:
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
           "psnr_at_samples", "setup_warnings", "result_warnings"]
