"""Accuracy measures of disparity maps and images (Middlebury v2 style).

Conventions: disparity maps are float arrays ``(H, W)`` with NaN where invalid; masks are
boolean ``(H, W)`` arrays that select the pixels to score.  Pixels whose ground truth is
NaN are never scored, whatever the mask says.  An empty selection gives NaN.
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_BAD_THRESHOLD = 1.0


def _scored_pixels(disp, gt, mask):
    disp = np.asarray(disp, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if disp.shape != gt.shape:
        raise ValueError(f"disparity {disp.shape} and ground truth {gt.shape} differ in shape")
    selected = ~np.isnan(gt)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != gt.shape:
            raise ValueError(f"mask {mask.shape} and ground truth {gt.shape} differ in shape")
        selected &= mask.astype(bool)
    return disp[selected], gt[selected]


def bad_pixel_rate(disp, gt, mask, *, threshold: float = DEFAULT_BAD_THRESHOLD) -> float:
    """Percentage of scored pixels whose disparity error exceeds ``threshold``.

    Parameters
    ----------
    disp : ndarray, (H, W), float
        Estimated disparity; NaN (no estimate) counts as a bad pixel.
    gt : ndarray, (H, W), float
        Ground truth; NaN pixels are not scored.
    mask : ndarray, (H, W), bool, or None
        Pixels to score (None: every pixel with known ground truth).
    threshold : float
        A pixel is bad when ``|disp - gt| > threshold``.

    Returns
    -------
    float
        Percentage in [0, 100]; NaN when no pixel is scored.
    """
    d, g = _scored_pixels(disp, gt, mask)
    if g.size == 0:
        return math.nan
    # Written as "not good" so that NaN estimates land among the bad ones.
    good = np.abs(d - g) <= threshold
    return 100.0 * float(np.count_nonzero(~good)) / g.size


def rms_error(disp, gt, mask) -> float:
    """Root-mean-square disparity error over the scored pixels that have an estimate.

    Pixels without an estimate (NaN) are left out here; :func:`invalid_rate` reports how
    many there were, and :func:`bad_pixel_rate` counts them as bad.

    Parameters
    ----------
    disp, gt : ndarray, (H, W), float
        Estimate and ground truth (NaN = invalid).
    mask : ndarray, (H, W), bool, or None
        Pixels to score.

    Returns
    -------
    float
        RMS error in pixels; NaN when no pixel is scored.
    """
    d, g = _scored_pixels(disp, gt, mask)
    have_estimate = ~np.isnan(d)
    if not have_estimate.any():
        return math.nan
    err = d[have_estimate] - g[have_estimate]
    return float(np.sqrt(np.mean(err * err)))


def invalid_rate(disp, gt, mask) -> float:
    """Percentage of scored pixels that have no estimate (NaN in ``disp``)."""
    d, g = _scored_pixels(disp, gt, mask)
    if g.size == 0:
        return math.nan
    return 100.0 * float(np.count_nonzero(np.isnan(d))) / g.size


def psnr(a, b, *, mask=None, peak: float | None = None) -> float:
    """Peak signal-to-noise ratio between two images, in dB.

    Parameters
    ----------
    a, b : ndarray, (H, W) or (H, W, C)
        Images of the same shape.
    mask : ndarray, (H, W), bool, optional
        Pixels to compare (all channels of each selected pixel are used).
    peak : float, optional
        Largest possible value; default from the dtype of ``a`` (uint8: 255, uint16: 65535).
        Required for float images.

    Returns
    -------
    float
        PSNR in dB; ``inf`` for identical images, NaN for an empty mask.
    """
    a = np.asarray(a)
    b = np.asarray(b)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if peak is None:
        if a.dtype == np.uint8:
            peak = 255.0
        elif a.dtype == np.uint16:
            peak = 65535.0
        else:
            raise ValueError(f"cannot infer the peak value of a {a.dtype} image; pass peak=")
    diff = a.astype(np.float64) - b.astype(np.float64)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != a.shape[:2]:
            raise ValueError(f"mask {mask.shape} does not match image {a.shape[:2]}")
        diff = diff[mask]
    if diff.size == 0:
        return math.nan
    mse = float(np.mean(diff * diff))
    if mse == 0.0:
        return math.inf
    return 10.0 * math.log10(float(peak) ** 2 / mse)


def evaluate_disparity(disp, gt, masks: dict, *, threshold: float = DEFAULT_BAD_THRESHOLD) -> dict:
    """Bad-pixel rate, RMS error and invalid rate for each named mask.

    Parameters
    ----------
    disp, gt : ndarray, (H, W), float
        Estimate and ground truth (NaN = invalid).
    masks : dict of str to ndarray (H, W) bool
        Typically ``{"nonocc": ..., "all": ..., "disc": ...}``.
    threshold : float
        Error above which a pixel is bad.

    Returns
    -------
    dict of str to dict
        ``{name: {"bad": percent, "rms": pixels, "invalid": percent, "pixels": count}}``,
        in the order of ``masks``.
    """
    gt_known = ~np.isnan(np.asarray(gt, dtype=np.float64))
    results = {}
    for name, mask in masks.items():
        results[name] = {
            "bad": bad_pixel_rate(disp, gt, mask, threshold=threshold),
            "rms": rms_error(disp, gt, mask),
            "invalid": invalid_rate(disp, gt, mask),
            "pixels": int(np.count_nonzero(np.asarray(mask, dtype=bool) & gt_known)),
        }
    return results
