"""Plain references of the fill: Eq. (3) with the filter of Eq. (4), summed directly.

O(N n) in float64, one sample at a time: for tests and for reading, not for decoding.  The
bilateral grid of :mod:`stereobudget.fill._bilateral` approximates these sums (the error
bounds its tests state), and every decoder's fill is held to them.
"""

from __future__ import annotations

import numpy as np

from ..cost._cost import pixel_cost
from ..cost._sparse import SparseCostTerms
from ._bilateral import FillScale


def sparse_joint_bilateral_reference(guide: np.ndarray, rows: np.ndarray, cols: np.ndarray, values: np.ndarray,
                                     *, sigma_s: float, sigma_r: float) -> np.ndarray:
    """Normalised joint bilateral filter of sparse samples, Eq. (3) and (4) summed directly.

    Every output pixel sums the Gaussian spatial and range weights of every sample; the
    reference of :func:`stereobudget.fill.sparse_joint_bilateral`.

    Parameters
    ----------
    guide : ndarray (H, W)
        Guidance image in 8-bit units.
    rows, cols : ndarray of int
        Sample positions.
    values : ndarray (n, K)
        K channels per sample.
    sigma_s, sigma_r : float
        Spatial (pixels) and range (guide units) standard deviations.

    Returns
    -------
    ndarray, float64 (H, W, K)
        NaN where every weight underflows (no sample within reach).
    """
    h, w = guide.shape
    yy, xx = np.mgrid[0:h, 0:w]
    values = np.asarray(values, np.float64).reshape(len(rows), -1)
    numerator = np.zeros((h, w, values.shape[1]))
    denominator = np.zeros((h, w))
    g = np.asarray(guide, np.float64)
    for r, c, v in zip(rows, cols, values):
        weight = np.exp(-((yy - r) ** 2 + (xx - c) ** 2) / (2 * sigma_s ** 2)
                        - (g - g[r, c]) ** 2 / (2 * sigma_r ** 2))
        numerator += weight[:, :, None] * v
        denominator += weight
    with np.errstate(invalid="ignore", divide="ignore"):
        return numerator / denominator[:, :, None]


def filled_sparse_dsi_reference(left: np.ndarray, guide: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                                right_values: np.ndarray, *, min_disp: int, num_disp: int, scale: FillScale,
                                terms: SparseCostTerms) -> np.ndarray:
    """The filled sparse DSI by definition: Eq. (2) at the samples, each layer filled by Eq. (3).

    Layer ``i`` (disparity ``d = min_disp + i``) holds, at the left pixels ``(r, c + d)``
    that a sample ``(r, c)`` meets inside the image, the sample's colour cost
    (:func:`stereobudget.cost.pixel_cost`), spread by
    :func:`sparse_joint_bilateral_reference`; a layer no sample meets is ``terms.truncation``.
    The reference of :func:`stereobudget.fill.filled_sparse_dsi` with the colour term alone.

    Parameters
    ----------
    As :func:`stereobudget.fill.filled_sparse_dsi`; ``terms`` must have no step or census term.

    Returns
    -------
    ndarray, float64 (H, W, num_disp)
    """
    if terms.step_weight > 0 or terms.census_weight > 0:
        raise ValueError("the reference fill has the colour term only (step_weight = census_weight = 0)")
    h, w = guide.shape
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    truncation = np.float32(terms.truncation)
    volume = np.full((h, w, num_disp), float(terms.truncation))
    for i in range(num_disp):
        keep = (cols + min_disp + i >= 0) & (cols + min_disp + i < w)
        if not keep.any():
            continue
        left_rows, left_cols = rows[keep], cols[keep] + min_disp + i
        costs = np.array([pixel_cost(left[r, c], right_values[k], truncation)
                          for r, c, k in zip(left_rows, left_cols, np.flatnonzero(keep))], np.float64)
        volume[..., i] = sparse_joint_bilateral_reference(guide, left_rows, left_cols, costs[:, None],
                                                          sigma_s=scale.sigma_s, sigma_r=scale.sigma_r)[..., 0]
    return volume
