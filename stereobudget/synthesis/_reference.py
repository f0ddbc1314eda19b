"""Plain references of the forward warp, the safety net :func:`warp_left_to_right` is tested against.

Where the fast warp scatters each left pixel onto the right row, these gather: for every
right pixel they list what reaches it, then apply the z-buffer rule to that list.  Plain
Python over pixels in float64, for tiny images only.
"""

from __future__ import annotations

import math

import numpy as np

# Splat weights at or below this do not reach a right pixel: the fast splat's rule.
from ._warp import _MIN_SPLAT_WEIGHT, DEFAULT_Z_TOLERANCE


def _linear_pieces(row_disp, z_tolerance):
    """(lo, hi, x_a, x_b, pos_a, pos_b, d_a, d_b) per piece of a row's piecewise-linear warp."""
    w = len(row_disp)
    pieces = []
    for x in range(w):
        d = row_disp[x]
        if not math.isfinite(d):
            continue
        xr = x - d
        prev = row_disp[x - 1] if x > 0 else math.nan
        if not (math.isfinite(prev) and abs(prev - d) <= z_tolerance and (x - 1) - prev < xr):
            pieces.append((xr - 0.5, xr, x, x, xr, xr, d, d))      # half a pixel before a jump
        following = row_disp[x + 1] if x + 1 < w else math.nan
        x_next = x + 1 - following
        if math.isfinite(following) and abs(following - d) <= z_tolerance and x_next > xr:
            pieces.append((xr, x_next, x, x + 1, xr, x_next, d, following))
        else:
            pieces.append((xr, xr + 0.5, x, x, xr, xr, d, d))      # half a pixel after a jump
    return pieces


def _blend(candidates, shown, z_tolerance):
    """Weighted mean colour of the candidates (depth, colour, weight) within ``z_tolerance`` of ``shown``."""
    kept = [(colour, weight) for z, colour, weight in candidates if abs(z - shown) <= z_tolerance]
    return sum(weight * colour for colour, weight in kept) / sum(weight for _, weight in kept)


def warp_reference(left: np.ndarray, disparity: np.ndarray, *, mode: str = "linear",
                   z_tolerance: float = DEFAULT_Z_TOLERANCE):
    """The forward warp of :func:`stereobudget.synthesis.warp_left_to_right`, pixel by pixel.

    Parameters
    ----------
    left : ndarray, float (H, W, C)
        I1 in 8-bit units.
    disparity : ndarray, float (H, W)
        Left-view disparity; non-finite pixels are skipped.
    mode : {"linear", "splat", "nearest"}
        The rules of :func:`~stereobudget.synthesis.warp_left_to_right`.  ``linear``: each
        run of neighbours within ``z_tolerance`` is a piecewise-linear curve over the right
        row, covering the half-open interval between landing points; an end of a run covers
        half a pixel.  A right pixel takes the mean of the curves within ``z_tolerance`` of
        the nearest one there.  ``splat``: each left pixel gives weights ``1 - t`` and ``t``
        to the columns around ``x - d``; the surface shown is the nearest whose weight is at
        least 1/2 (else the nearest at all), blended weight by weight with the splats within
        ``z_tolerance`` of it.  ``nearest``: the left pixel landing nearest ``x - d`` with
        the largest disparity (the first such pixel on a tie).
    z_tolerance : float
        Disparity difference below which two left pixels are one surface.

    Returns
    -------
    warped : ndarray, float64 (H, W, C)
        0 in holes.
    holes : ndarray, bool (H, W)
    """
    left = np.asarray(left, np.float64)
    disparity = np.asarray(disparity, np.float64)
    h, w, channels = left.shape
    warped = np.zeros((h, w, channels))
    holes = np.ones((h, w), bool)
    for y in range(h):
        reaching = [[] for _ in range(w)]           # per right pixel: (depth, colour, weight)
        if mode == "linear":
            for lo, hi, x_a, x_b, pos_a, pos_b, d_a, d_b in _linear_pieces(disparity[y].tolist(), z_tolerance):
                for p in range(max(math.ceil(lo), 0), min(math.ceil(hi), w)):
                    t = 0.0 if pos_b <= pos_a else min(max((p - pos_a) / (pos_b - pos_a), 0.0), 1.0)
                    reaching[p].append(((1 - t) * d_a + t * d_b, (1 - t) * left[y, x_a] + t * left[y, x_b], 1.0))
        elif mode == "splat":
            for x in range(w):
                d = disparity[y, x]
                if not math.isfinite(d):
                    continue
                x0 = math.floor(x - d)
                t = (x - d) - x0
                for p, weight in ((x0, 1 - t), (x0 + 1, t)):
                    if 0 <= p < w and weight > _MIN_SPLAT_WEIGHT:
                        reaching[p].append((d, left[y, x], weight))
        elif mode == "nearest":
            for x in range(w):
                d = disparity[y, x]
                if not math.isfinite(d):
                    continue
                p = math.floor(x - d + 0.5)
                if 0 <= p < w:
                    reaching[p].append((d, left[y, x], 1.0))
        else:
            raise ValueError(f"unknown warp mode {mode!r}")
        for p, candidates in enumerate(reaching):
            if not candidates:
                continue
            holes[y, p] = False
            nearest = max(z for z, _, _ in candidates)
            if mode == "nearest":
                warped[y, p] = next(colour for z, colour, _ in candidates if z == nearest)
            elif mode == "splat":
                covering = [z for z, _, weight in candidates if weight >= 0.5]
                warped[y, p] = _blend(candidates, max(covering) if covering else nearest, z_tolerance)
            else:
                warped[y, p] = _blend(candidates, nearest, z_tolerance)
    return warped, holes
