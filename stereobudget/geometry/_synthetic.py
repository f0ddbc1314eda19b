"""Unrectified pairs with exact ground truth, made from a rectified pair (for tests and benchmarks).

A rectified pair is the view of two cameras with the same intrinsics ``K``, no rotation
between them and a baseline ``B`` along x.  Turning each camera by a small rotation
``Q_i`` (``X_raw = Q_i X_rect``) and giving its lens a radial distortion ``k1_i`` gives
the raw images the cameras would have taken; the calibration that undoes it is
``M1 = M2 = K``, ``D_i = (k1_i, 0, 0, 0, 0)``, ``R = Q_2 Q_1^T``, ``T = -Q_2 (B, 0, 0)``.
The true match of each raw left pixel follows from the rectified ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._calibration import StereoCalibration


@dataclass(frozen=True, eq=False)
class UnrectifiedPair:
    """Raw images of a turned, distorting camera pair and their exact geometry.

    Attributes
    ----------
    left, right : ndarray
        The raw images (0 where the camera sees beyond the rectified images).
    calibration : StereoCalibration
        What undoes it (``T`` in metres).
    left_in_rectified : ndarray, float64 (H, W, 2)
        Where each raw left pixel lies in the original rectified left image (x, y).
    true_right : ndarray, float64 (H, W, 2)
        The raw right position (x, y) of each raw left pixel's scene point; NaN where the
        ground truth is unknown or the point lies outside the rectified image.
    scored : ndarray, bool (H, W)
        Raw left pixels with ground truth, inside the rectified image, selected by the
        rectified pair's mask, and seen by both raw cameras: a point whose match the turned
        right camera no longer has in its frame is not scored (no decode could find it).
    right_rotation : ndarray (3, 3)
        ``Q_2``, the right camera's turn.
    """

    left: np.ndarray
    right: np.ndarray
    calibration: StereoCalibration
    left_in_rectified: np.ndarray
    true_right: np.ndarray
    scored: np.ndarray
    right_rotation: np.ndarray

    def implied_by_rectified(self, disparity: np.ndarray) -> np.ndarray:
        """The raw right position (H, W, 2) each raw left pixel gets from a disparity of the original rectified pair.

        What :func:`stereobudget.geometry.raw_right_positions` gives for a result in a
        host-rectified frame, for a decode of the rectified pair: both are then scored on
        the raw left image alike.
        """
        import cv2

        from ._rectify import _sample_smooth
        c = self.calibration
        k = c.M1
        d = _sample_smooth(disparity, self.left_in_rectified).astype(np.float64)
        xr = self.left_in_rectified[..., 0] - d
        yr = self.left_in_rectified[..., 1]
        rays = np.stack([(xr - k[0, 2]) / k[0, 0], (yr - k[1, 2]) / k[1, 1], np.ones_like(xr)], axis=-1)
        valid = np.isfinite(rays).all(axis=-1)
        out = np.full(xr.shape + (2,), np.nan)
        if valid.any():
            projected, _ = cv2.projectPoints(rays[valid].reshape(-1, 1, 3), cv2.Rodrigues(self.right_rotation)[0],
                                             np.zeros(3), c.M2, c.D2)
            out[valid] = projected.reshape(-1, 2)
        return out


def _rectified_positions(width, height, k, distortion, rotation):
    """Raw pixel grid -> positions in the rectified camera (K, no distortion) turned back by ``rotation``."""
    import cv2

    xs, ys = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (3, 100, 1e-12)
    iterated = getattr(cv2, "undistortPointsIter", None)
    if iterated is not None:
        out = iterated(pts, k, distortion, rotation, k, criteria)
    else:
        out = cv2.undistortPoints(pts, k, distortion, R=rotation, P=k, criteria=criteria)
    return out.reshape(height, width, 2)


def unrectify_pair(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, *, rotation_left,
                   rotation_right, k1_left: float, k1_right: float, focal: float | None = None,
                   baseline: float = 0.1, mask: np.ndarray | None = None) -> UnrectifiedPair:
    """Turn and distort both cameras of a rectified pair (see the module docstring).

    Parameters
    ----------
    left, right : ndarray, (H, W) or (H, W, C)
        The rectified pair.
    disparity : ndarray, float (H, W)
        Left-view ground truth (NaN or <= 0 where unknown).
    rotation_left, rotation_right : array_like (3,)
        Rotation vectors (radians, Rodrigues) of each camera.
    k1_left, k1_right : float
        Radial distortion of each lens.
    focal : float, optional
        Focal length of ``K`` in pixels (default: the image width).
    baseline : float
        Baseline in metres.
    mask : ndarray, bool (H, W), optional
        Rectified left pixels to score (default: all with ground truth).

    Returns
    -------
    UnrectifiedPair
    """
    import cv2

    height, width = disparity.shape
    f = float(width if focal is None else focal)
    k = np.array([[f, 0, (width - 1) / 2.0], [0, f, (height - 1) / 2.0], [0, 0, 1]])
    q1 = cv2.Rodrigues(np.asarray(rotation_left, np.float64))[0]
    q2 = cv2.Rodrigues(np.asarray(rotation_right, np.float64))[0]
    d1 = np.array([k1_left, 0, 0, 0, 0], np.float64)
    d2 = np.array([k1_right, 0, 0, 0, 0], np.float64)
    # Raw pixel -> rectified pixel: undistort, turn back (Q^T), project with K.
    pos1 = _rectified_positions(width, height, k, d1, q1.T)
    pos2 = _rectified_positions(width, height, k, d2, q2.T)

    def warp(image, pos):
        maps = pos.astype(np.float32)
        return cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=0)

    raw_left, raw_right = warp(left, pos1), warp(right, pos2)
    # Ground truth at each raw left pixel's rectified position: bilinear on smooth
    # surfaces, the nearest pixel across depth edges.
    from ._rectify import _sample_smooth
    xi = np.rint(pos1[..., 0]).astype(np.int64)
    yi = np.rint(pos1[..., 1]).astype(np.int64)
    inside = (pos1[..., 0] >= 0) & (pos1[..., 0] <= width - 1) & (pos1[..., 1] >= 0) & (pos1[..., 1] <= height - 1)
    truth = np.where(np.asarray(disparity) > 0, disparity, np.nan).astype(np.float64)
    d = _sample_smooth(truth, pos1).astype(np.float64)
    d[~inside] = np.nan
    scored = inside & np.isfinite(d) & (d > 0)
    if mask is not None:
        scored[inside] &= mask[yi[inside], xi[inside]]
    # The scene point's rectified right position, then its raw right position.
    xr = pos1[..., 0] - d
    yr = pos1[..., 1]
    rays = np.stack([(xr - k[0, 2]) / f, (yr - k[1, 2]) / f, np.ones_like(xr)], axis=-1)[scored]
    true_right = np.full((height, width, 2), np.nan)
    if len(rays):
        projected, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), cv2.Rodrigues(q2)[0], np.zeros(3), k, d2)
        true_right[scored] = projected.reshape(-1, 2)
    seen = ((true_right[..., 0] >= 0) & (true_right[..., 0] <= width - 1) & (true_right[..., 1] >= 0)
            & (true_right[..., 1] <= height - 1))
    scored &= seen
    true_right[~scored] = np.nan
    calibration = StereoCalibration(M1=k, D1=d1, M2=k.copy(), D2=d2, R=q2 @ q1.T,
                                    T=-q2 @ np.array([baseline, 0.0, 0.0]), image_size=(width, height),
                                    source="<synthetic>")
    return UnrectifiedPair(left=raw_left, right=raw_right, calibration=calibration, left_in_rectified=pos1,
                           true_right=true_right, scored=scored, right_rotation=q2)


def write_calibration(path, calibration: StereoCalibration) -> None:
    """Write ``calibration`` as an OpenCV FileStorage file (YAML or XML by the extension of ``path``)."""
    import cv2

    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        for key in ("M1", "D1", "M2", "D2", "R"):
            storage.write(key, np.asarray(getattr(calibration, key), np.float64))
        storage.write("T", calibration.T.reshape(3, 1))
        if calibration.image_size is not None:
            storage.write("image_width", int(calibration.image_size[0]))
            storage.write("image_height", int(calibration.image_size[1]))
        storage.write("unit", "m")
    finally:
        storage.release()


__all__ = ["UnrectifiedPair", "unrectify_pair", "write_calibration"]
