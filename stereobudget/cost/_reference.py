"""Plain numpy reference of the full DSI, Eq. (1), the safety net :func:`full_dsi` is tested against."""

from __future__ import annotations

import numpy as np

from ._cost import DEFAULT_TRUNCATION


def full_dsi_reference(left: np.ndarray, right: np.ndarray, *, min_disp: int, num_disp: int,
                       truncation: float = DEFAULT_TRUNCATION, grad_weight: float = 0.0,
                       grad_truncation: float = 2.0) -> np.ndarray:
    """Eq. (1) computed directly in float64, one disparity layer at a time.

    ``C(x, y, d) = min(mean_c |I1_c(x, y) - I2_c(x - d, y)|, truncation)``; with
    ``grad_weight = alpha > 0`` Yang's mix ``(1 - alpha) C + alpha min(|gx1 - gx2|,
    grad_truncation)`` of the central-difference x-gradients of the gray images
    (0 in the first and last column).  Columns ``x - d`` outside I2 read its nearest
    border column.

    Parameters
    ----------
    left, right : ndarray, float (H, W, C)
        Images in 8-bit units, as :func:`stereobudget.cost.full_dsi` takes them.
    min_disp, num_disp : int
        Layer ``i`` holds disparity ``min_disp + i``.
    truncation, grad_weight, grad_truncation : float
        As in :func:`stereobudget.cost.full_dsi`.

    Returns
    -------
    ndarray, float64 (H, W, num_disp)
    """
    left = np.asarray(left, np.float64)
    right = np.asarray(right, np.float64)
    h, w, _ = left.shape

    def x_gradient(image):
        gray = image @ np.array([0.299, 0.587, 0.114]) if image.shape[2] == 3 else image[:, :, 0]  # Rec. 601 luma
        gradient = np.zeros_like(gray)
        gradient[:, 1:-1] = 0.5 * (gray[:, 2:] - gray[:, :-2])
        return gradient

    if grad_weight > 0:
        left_gradient, right_gradient = x_gradient(left), x_gradient(right)
    columns = np.arange(w)
    out = np.empty((h, w, num_disp))
    for layer in range(num_disp):
        source = np.clip(columns - (min_disp + layer), 0, w - 1)
        colour = np.minimum(np.abs(left - right[:, source]).mean(axis=2), truncation)
        if grad_weight > 0:
            gradient = np.minimum(np.abs(left_gradient - right_gradient[:, source]), grad_truncation)
            colour = (1.0 - grad_weight) * colour + grad_weight * gradient
        out[:, :, layer] = colour
    return out
