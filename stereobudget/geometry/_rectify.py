"""Rectification at the host: I1 resampled, the right camera's samples moved to where they land.

The camera sends its raw, unrectified grid and computes nothing.  The host rectifies with
the calibration (``cv2.stereoRectify``, alpha 1 so that nothing either camera sees is
cropped, at the raw image's size), resamples I1 once per frame through maps computed once
per calibration and size (``cv2.initUndistortRectifyMap``), and maps each sample's raw
position (undistort, rotate, project) into the rectified right frame.  There the positions
are no longer a lattice: each sample is placed at the nearest pixel of its true position
(:class:`PlacedSamples`, an irregular sample set the decoders read like jitter or fps
samples).  The disparity then belongs to the rectified left frame; :func:`raw_left_disparity`
takes it back to the left image as it was given.
"""

from __future__ import annotations

import functools
import os
import weakref
from dataclasses import dataclass

import numpy as np

from ..errors import CalibrationError
from ..io._samples import SampleSet
from ..sampling._patterns import SamplingPattern
from ._calibration import StereoCalibration, check_image_size, read_calibration

#: ``cv2.undistortPointsIter``'s stopping rule: enough iterations for k1 up to a few tenths.
_UNDISTORT_CRITERIA = (3, 50, 1e-9)   # cv2.TERM_CRITERIA_COUNT | EPS


@dataclass(frozen=True, eq=False)
class Rectification:
    """How a calibrated pair of a given image size is rectified (see the module docstring).

    Attributes
    ----------
    calibration : StereoCalibration
    raw_size, size : (width, height)
        The images as given, and the rectified frame (equal: alpha 1 keeps every pixel
        of the raw images at the raw size).
    R1, R2 : ndarray (3, 3)
        Rotations from each raw camera's coordinates to its rectified one.
    P1, P2 : ndarray (3, 4)
        Projection matrices of the rectified cameras.
    identity : bool
        The pair was rectified already: no resampling, the frames are the raw ones.
    left_map : tuple of ndarray or None
        ``cv2.remap`` maps from the rectified left frame to raw I1 (None when identity).
    left_positions : ndarray, float32 (H, W, 2)
        Where each raw left pixel lands in the rectified left frame (x, y).
    """

    calibration: StereoCalibration
    raw_size: tuple
    size: tuple
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    identity: bool
    left_map: tuple | None
    left_positions: np.ndarray

    @property
    def focal(self) -> float:
        """Focal length of the rectified cameras, in pixels."""
        return float(self.P1[0, 0])

    @property
    def baseline(self) -> float:
        """Baseline in metres."""
        return float(-self.P2[0, 3] / self.P2[0, 0])

    @property
    def doffs(self) -> float:
        """``cx2 - cx1`` of the rectified cameras (0 after a host rectification)."""
        return float(self.P2[0, 2] - self.P1[0, 2])

    @functools.cached_property
    def right_map(self) -> tuple | None:
        """``cv2.remap`` maps from the rectified right frame to the raw right image (None when identity)."""
        import cv2

        if self.identity:
            return None
        c = self.calibration
        return cv2.initUndistortRectifyMap(c.M2, c.D2, self.R2, self.P2, self.size, cv2.CV_32FC1)

    def summary(self) -> dict:
        """JSON-able facts for ``--json``: the frame the disparity is in, f, B, doffs."""
        return {"rectified_at_host": not self.identity, "rectified_size": list(self.size),
                "rectified_focal_px": round(self.focal, 4), "baseline_m": round(self.baseline, 6),
                "doffs_px": round(self.doffs, 4)}


def _pixel_grid(width, height):
    xs, ys = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


def _undistort(points, camera, distortion, rotation, projection):
    """Raw pixel positions (n, 2) -> rectified pixel positions (n, 2) float64."""
    import cv2

    if len(points) == 0:
        return np.zeros((0, 2))
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 1, 2)
    iterated = getattr(cv2, "undistortPointsIter", None)     # OpenCV 4; 5 takes criteria in undistortPoints
    if iterated is not None:
        out = iterated(pts, camera, distortion, rotation, projection, _UNDISTORT_CRITERIA)
    else:
        out = cv2.undistortPoints(pts, camera, distortion, R=rotation, P=projection, criteria=_UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def rectify_stereo(calibration: StereoCalibration, width: int, height: int, *,
                   size: tuple | None = None) -> Rectification:
    """The rectification of a calibrated pair for ``width x height`` images.

    Parameters
    ----------
    calibration : StereoCalibration
    width, height : int
        Size of the images as the cameras give them.
    size : (width, height), optional
        Size of the rectified frame (default: the raw size).

    Returns
    -------
    Rectification

    Raises
    ------
    CalibrationError
        The calibration was made for another image size.
    """
    import cv2

    check_image_size(calibration, width, height)
    c = calibration
    if c.rectified:
        r1 = np.eye(3)
        p1 = np.hstack([c.M1, np.zeros((3, 1))])
        p2 = np.hstack([c.M2, np.array([[-c.M2[0, 0] * c.baseline], [0.0], [0.0]])])
        pos = _pixel_grid(width, height).astype(np.float32).reshape(height, width, 2)
        return Rectification(calibration=c, raw_size=(width, height), size=(width, height), R1=r1, R2=r1.copy(),
                             P1=p1, P2=p2, identity=True, left_map=None, left_positions=pos)
    size = (width, height) if size is None else (int(size[0]), int(size[1]))
    r1, r2, p1, p2, _q, _roi1, _roi2 = cv2.stereoRectify(
        c.M1, c.D1, c.M2, c.D2, (width, height), c.R, c.T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=1.0, newImageSize=size)
    if not (np.all(np.isfinite(p1)) and np.all(np.isfinite(p2))) or p1[0, 0] <= 0:
        raise CalibrationError("cv2.stereoRectify found no rectification for this calibration", path=c.source)
    map_x, map_y = cv2.initUndistortRectifyMap(c.M1, c.D1, r1, p1, size, cv2.CV_32FC1)
    pos = _undistort(_pixel_grid(width, height), c.M1, c.D1, r1, p1).astype(np.float32).reshape(height, width, 2)
    return Rectification(calibration=c, raw_size=(width, height), size=size, R1=r1, R2=r2, P1=p1,
                         P2=p2, identity=False, left_map=(map_x, map_y), left_positions=pos)


@functools.lru_cache(maxsize=8)
def _cached(path, absolute, mtime_ns, size, width, height):
    return rectify_stereo(read_calibration(path), width, height)


def rectification_for(path: str, width: int, height: int) -> Rectification:
    """:func:`rectify_stereo` of the calibration file ``path``, computed once per file and image size.

    A stream of frames (or a batch in one process) reads the file and computes the maps
    for its first frame and reuses them (a changed file is read again).
    """
    path = os.fspath(path)
    try:
        st = os.stat(path)
        key = (st.st_mtime_ns, st.st_size)
    except OSError:
        key = (None, None)     # read_calibration reports it
    return _cached(path, os.path.abspath(path), *key, int(width), int(height))


rectification_for.cache_info = _cached.cache_info
rectification_for.cache_clear = _cached.cache_clear


def rectify_left(image: np.ndarray, rectification: Rectification) -> np.ndarray:
    """I1 resampled into the rectified left frame (bicubic; outside the raw image: 0).

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, C)
    rectification : Rectification

    Returns
    -------
    ndarray, the input's shape and dtype (the input itself when no resampling is needed)
    """
    import cv2

    if rectification.identity:
        return image
    map_x, map_y = rectification.left_map
    return cv2.remap(image, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


@dataclass(frozen=True, eq=False)
class SampleLattice:
    """The grid a placed sample set came from: its neighbours are still lattice neighbours.

    Attributes
    ----------
    shape : (rows, cols)
        The raw grid.
    index : ndarray of int64 (n,)
        Row-major index in the raw grid of each placed sample.
    values : ndarray (rows * cols, C)
        Every sample of the raw grid (RGB order), placed or not.
    spacing : (int, int)
        Median distance, in pixels of the frame, between placed row and column neighbours.
    raw : SampleSet or None
        The grid as the camera sent it.
    right_map : tuple of ndarray or None
        ``cv2.remap`` maps from this frame to the raw right image: what is computed on the
        raw grid (its low-pass) is read into this frame through them.
    """

    shape: tuple
    index: np.ndarray
    values: np.ndarray
    spacing: tuple
    raw: SampleSet | None = None
    right_map: tuple | None = None


@dataclass(frozen=True, eq=False)
class PlacedSamples(SampleSet):
    """Samples at explicit positions (rows, cols) of a ``height x width`` frame.

    What :func:`rectify_samples` gives: the decoders read it like any irregular sample
    set (its pattern's kind is ``jitter``; its strides, the spacing the samples have in
    this frame, set the fill's scale).  Samples of a grid keep their lattice (``lattice``),
    so the Sparse cost's steps and census still compare lattice neighbours; ``offsets``
    (float32 (n, 2), ``(dy, dx)``) says where each sample truly lies from its pixel, and
    the Sparse cost reads I1 there.  It is not written to a sample file.
    """

    rows: np.ndarray | None = None
    cols: np.ndarray | None = None
    lattice: SampleLattice | None = None
    offsets: np.ndarray | None = None

    def __post_init__(self):
        v = self.values
        if v.ndim != 2 or v.shape[1] != self.channels:
            raise ValueError(f"values must have shape (n, {self.channels}), got {v.shape}")
        if self.rows is None or self.cols is None or not (len(self.rows) == len(self.cols) == len(v)):
            raise ValueError("rows, cols and values must have one entry per sample")

    def positions(self):
        return self.rows, self.cols


def map_sample_positions(samples: SampleSet, rectification: Rectification) -> np.ndarray:
    """Where each sample's raw position lands in the rectified right frame: float64 (n, 2) as (x, y)."""
    rows, cols = samples.positions()
    c = rectification.calibration
    points = np.stack([np.asarray(cols, np.float64), np.asarray(rows, np.float64)], axis=1)
    if rectification.identity:
        return points
    return _undistort(points, c.M2, c.D2, rectification.R2, rectification.P2)


@dataclass(frozen=True, eq=False)
class _Placement:
    """Where a sample set's raw positions land in a rectified right frame (see :func:`rectify_samples`)."""

    keep: np.ndarray        # int64 (n,): the samples placed, in (row, col) order of their pixels
    rows: np.ndarray        # int64 (n,)
    cols: np.ndarray        # int64 (n,)
    offsets: np.ndarray     # float32 (n, 2): (dy, dx) of each true position from its pixel
    spacing: tuple          # (x, y) spacing the samples have in the rectified frame
    grid_shape: tuple | None


#: Placements of regular grids, per rectification: a stream's frames share their positions.
_PLACEMENTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _placement(samples: SampleSet, rectification: Rectification) -> _Placement:
    key = (samples.pattern, samples.height, samples.width) if samples.pattern.is_regular_grid else None
    cached = _PLACEMENTS.get(rectification, {}).get(key) if key is not None else None
    if cached is not None:
        return cached
    width, height = rectification.size
    xy = map_sample_positions(samples, rectification)
    xr, yr = np.rint(xy[:, 0]), np.rint(xy[:, 1])
    inside = np.isfinite(xr) & np.isfinite(yr) & (xr >= 0) & (xr < width) & (yr >= 0) & (yr < height)
    index = np.flatnonzero(inside)
    pixel = (yr[index] * width + xr[index]).astype(np.int64)
    # Of several samples on one pixel keep the nearest: sort by distance, keep each pixel's
    # first.  np.unique leaves the pixels ascending: the placed samples in (row, col) order.
    distance = np.hypot(xy[index, 0] - xr[index], xy[index, 1] - yr[index])
    order = np.lexsort((distance, pixel))
    _, first = np.unique(pixel[order], return_index=True)
    keep = index[order[first]].astype(np.int64)
    spacing = (samples.pattern.stride_x, samples.pattern.stride_y)
    shape = None
    if samples.pattern.is_regular_grid:
        from ..sampling._patterns import grid_shape
        shape = grid_shape(samples.pattern, samples.height, samples.width)
        grid_xy = xy.reshape(shape + (2,))
        # The spacing the grid has where it landed (alpha 1 shrinks the frame a little).
        dx = np.median(np.hypot(*(grid_xy[:, 1:] - grid_xy[:, :-1]).reshape(-1, 2).T)) if shape[1] > 1 else spacing[0]
        dy = np.median(np.hypot(*(grid_xy[1:] - grid_xy[:-1]).reshape(-1, 2).T)) if shape[0] > 1 else spacing[1]
        spacing = (max(1, int(round(dx))), max(1, int(round(dy))))
    placement = _Placement(keep=keep, rows=yr[keep].astype(np.int64), cols=xr[keep].astype(np.int64),
                           offsets=np.stack([xy[keep, 1] - yr[keep], xy[keep, 0] - xr[keep]], axis=1).astype(np.float32),
                           spacing=spacing, grid_shape=shape)
    if key is not None:
        _PLACEMENTS.setdefault(rectification, {})[key] = placement
    return placement


def rectify_samples(samples: SampleSet, rectification: Rectification, *, subpixel: bool = True) -> SampleSet:
    """The right camera's samples placed in the rectified right frame.

    Each sample goes to the pixel nearest its true rectified position; samples landing
    outside the frame are dropped, and of two landing on one pixel the nearer one is
    kept.  The placed samples come in (row, col) order of their pixels.  A regular grid's
    placement is computed once per rectification, size and pattern.  A rectified
    calibration returns ``samples`` itself.

    Parameters
    ----------
    samples : SampleSet
        What the right camera sent (its raw positions).
    rectification : Rectification
    subpixel : bool
        Keep each sample's offset from its pixel, so that the Sparse cost compares it
        with I1 at its true position (else it is compared at the pixel).

    Returns
    -------
    SampleSet (PlacedSamples after a host rectification)
    """
    if rectification.identity:
        return samples
    if samples.mosaic or samples.pattern.kind == "downsample":
        raise CalibrationError(f"host rectification needs pixel samples, not {samples.channel_order} "
                               f"{samples.pattern.kind} samples",
                               path=rectification.calibration.source)
    width, height = rectification.size
    placed = _placement(samples, rectification)
    lattice = None
    if placed.grid_shape is not None:
        lattice = SampleLattice(shape=placed.grid_shape, index=placed.keep, values=samples.values_rgb(),
                                spacing=placed.spacing, raw=samples, right_map=rectification.right_map)
    return PlacedSamples(height=height, width=width, channel_order=samples.channel_order,
                         pattern=SamplingPattern("jitter", *placed.spacing),
                         values=np.ascontiguousarray(samples.values[placed.keep]), codec=samples.codec,
                         value_bits=samples.value_bits, quality=samples.quality, rows=placed.rows, cols=placed.cols,
                         lattice=lattice, offsets=placed.offsets if subpixel else None)


def _sample_smooth(image, positions, *, jump: float = 1.0):
    """``image`` (H, W) read at float positions (H', W', 2) (x, y); NaN outside.

    Bilinear where the four pixels around a position are valid and within ``jump`` of each
    other; the nearest pixel elsewhere, so that a value is never blended across a depth
    edge.
    """
    h, w = image.shape[:2]
    x = positions[..., 0].astype(np.float64)
    y = positions[..., 1].astype(np.float64)
    xi = np.rint(x).astype(np.int64)
    yi = np.rint(y).astype(np.int64)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out = np.full(positions.shape[:2], np.nan, dtype=np.float32)
    out[inside] = image[yi[inside], xi[inside]]
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    ok = (x0 >= 0) & (x0 + 1 < w) & (y0 >= 0) & (y0 + 1 < h)
    x0, y0, tx, ty = x0[ok], y0[ok], (x - np.floor(x))[ok], (y - np.floor(y))[ok]
    a, b = image[y0, x0].astype(np.float64), image[y0, x0 + 1].astype(np.float64)
    c, d = image[y0 + 1, x0].astype(np.float64), image[y0 + 1, x0 + 1].astype(np.float64)
    with np.errstate(invalid="ignore"):
        corners = np.stack([a, b, c, d])
        smooth = np.all(np.isfinite(corners), axis=0) & (corners.max(axis=0) - corners.min(axis=0) <= jump)
        blend = (a * (1 - tx) + b * tx) * (1 - ty) + (c * (1 - tx) + d * tx) * ty
    values = out[ok]
    values[smooth] = blend[smooth]
    out[ok] = values
    return out


def raw_left_disparity(disparity: np.ndarray, rectification: Rectification) -> np.ndarray:
    """The rectified disparity read at each raw left pixel's rectified position.

    Bilinear inside smooth surfaces, the nearest pixel where the four neighbours differ
    by more than 1 px or one is invalid (never a blend across a depth edge).

    Parameters
    ----------
    disparity : ndarray, float32 (H', W')
        Disparity in the rectified left frame (NaN = invalid).
    rectification : Rectification

    Returns
    -------
    ndarray, float32 (H, W)
        Rectified disparity per raw left pixel (still in rectified pixels).
    """
    if rectification.identity:
        return disparity
    return _sample_smooth(disparity, rectification.left_positions)


def _rectified_points(disparity, rectification, positions):
    """Rectified-left camera coordinates (H, W, 3) float64 of pixels at ``positions`` with ``disparity``."""
    f, fy = rectification.P1[0, 0], rectification.P1[1, 1]
    cx, cy = rectification.P1[0, 2], rectification.P1[1, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        denominator = disparity.astype(np.float64) + rectification.doffs
        z = np.where(denominator > 0, f * rectification.baseline / denominator, np.nan)
    x = (positions[..., 0] - cx) * z / f
    y = (positions[..., 1] - cy) * z / fy
    return np.stack([x, y, z], axis=-1)


def depth_map(disparity: np.ndarray, rectification: Rectification, *, frame: str = "raw") -> np.ndarray:
    """Depth in metres (Z along the left camera's optical axis) from a rectified disparity.

    ``Z = f B / (d + doffs)`` in the rectified left camera; for ``frame="raw"`` each raw
    left pixel takes its point's Z in the raw left camera's coordinates.

    Parameters
    ----------
    disparity : ndarray, float32 (H', W')
        Disparity in the rectified left frame (NaN = invalid).
    rectification : Rectification
    frame : {"raw", "rectified"}
        Pixels of the left image as given, or of the rectified left frame.

    Returns
    -------
    ndarray, float32
        NaN where there is no valid disparity or ``d + doffs <= 0`` (at or beyond infinity).
    """
    if frame not in ("raw", "rectified"):
        raise ValueError(f"frame must be 'raw' or 'rectified', got {frame!r}")
    if frame == "rectified":
        h, w = disparity.shape
        points = _rectified_points(disparity, rectification, _pixel_grid(w, h).reshape(h, w, 2))
        return points[..., 2].astype(np.float32)
    return raw_points(disparity, rectification)[..., 2].astype(np.float32)


def raw_points(disparity: np.ndarray, rectification: Rectification) -> np.ndarray:
    """The 3-D point of each raw left pixel, in the raw left camera's coordinates (metres).

    x right, y down, z forward (OpenCV).  NaN where the pixel has no valid disparity.

    Returns
    -------
    ndarray, float64 (H, W, 3)
    """
    d = raw_left_disparity(disparity, rectification)
    points = _rectified_points(d, rectification, rectification.left_positions.astype(np.float64))
    if rectification.identity:
        return points
    # Rectified -> raw left camera: X_raw = R1^T X_rect (row vectors: X_rect @ R1).
    return points @ rectification.R1


def point_cloud(disparity: np.ndarray, rectification: Rectification, left: np.ndarray):
    """The valid pixels of the raw left image as coloured 3-D points.

    Parameters
    ----------
    disparity : ndarray, float32
        Disparity in the rectified left frame.
    rectification : Rectification
    left : ndarray, (H, W) or (H, W, 3), uint8 or uint16
        I1 as given (RGB): the points' colours (16-bit values keep their high byte).

    Returns
    -------
    xyz : ndarray, float32 (n, 3)
        Points in metres in the raw left camera's coordinates, in row-major pixel order.
    rgb : ndarray, uint8 (n, 3)
    """
    points = raw_points(disparity, rectification)
    valid = np.all(np.isfinite(points), axis=-1)
    colours = left if left.ndim == 3 else np.repeat(left[:, :, None], 3, axis=2)
    if colours.dtype == np.uint16:
        colours = (colours >> 8).astype(np.uint8)
    return points[valid].astype(np.float32), np.ascontiguousarray(colours[valid][:, :3], dtype=np.uint8)


def raw_right_positions(disparity: np.ndarray, rectification: Rectification) -> np.ndarray:
    """Where each raw left pixel's match lies in the raw right image, as the disparity implies.

    The frame-free reading of a result: raw left pixel -> rectified left position ->
    minus the disparity -> rectified right position -> back through the right camera's
    rotation and distortion.

    Returns
    -------
    ndarray, float64 (H, W, 2) as (x, y); NaN where there is no valid disparity.
    """
    import cv2

    d = raw_left_disparity(disparity, rectification).astype(np.float64)
    pos = rectification.left_positions.astype(np.float64)
    xr = pos[..., 0] - d
    yr = pos[..., 1]
    if rectification.identity:
        return np.stack([xr, yr], axis=-1)
    p2 = rectification.P2
    valid = np.isfinite(xr)
    rays = np.stack([(xr[valid] - p2[0, 2]) / p2[0, 0], (yr[valid] - p2[1, 2]) / p2[1, 1],
                     np.ones(int(valid.sum()))], axis=1)
    rays = rays @ rectification.R2          # R2^T applied to row vectors
    c = rectification.calibration
    out = np.full(pos.shape, np.nan)
    if len(rays):
        projected, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), c.M2, c.D2)
        out[valid] = projected.reshape(-1, 2)
    return out


__all__ = ["Rectification", "rectify_stereo", "rectification_for", "rectify_left", "PlacedSamples", "SampleLattice",
           "map_sample_positions", "rectify_samples", "raw_left_disparity", "depth_map", "raw_points",
           "point_cloud", "raw_right_positions"]
