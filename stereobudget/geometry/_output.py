"""Metric outputs: depth maps in metres and binary PLY point clouds, written atomically.

Depth conventions (one float per pixel, metres, Z along the left camera's optical axis):

* ``.tif``/``.tiff`` (float32) and ``.npy`` (float32): NaN = invalid;
* ``.pfm`` (float32): +inf = invalid, as in the disparity PFMs (Middlebury's convention);
* ``.png``: 16-bit millimetres (``round(Z * 1000)``), 0 = invalid; depths beyond 65.535 m
  are clipped to it (with a warning).

The PLY is ``binary_little_endian 1.0`` with one ``vertex`` element of ``x y z`` float32
(metres, the left camera's coordinates: x right, y down, z forward) and ``red green blue``
uchar; invalid pixels are left out.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import OutputError
from ..io._atomic import write_output_bytes
from ..io._disparity import _as_disparity_array, _encode_npy, _encode_pfm, _encode_tiff

log = logging.getLogger("stereobudget")

DEPTH_EXTENSIONS = (".tif", ".tiff", ".pfm", ".npy", ".png")
#: Millimetres per unit of a 16-bit PNG depth map, and its largest depth in metres.
PNG_DEPTH_MAX_M = 65.535


def encode_depth(depth: np.ndarray, *, extension: str, name: str = "<depth>") -> bytes:
    """The bytes of a depth map file of the format ``extension`` (see the module docstring)."""
    extension = extension.lower()
    d = _as_disparity_array(depth)
    d[d <= 0] = np.nan           # no point lies behind or on the camera
    if extension in (".tif", ".tiff"):
        return _encode_tiff(d)
    if extension == ".pfm":
        return _encode_pfm(d)     # NaN -> +inf on disk
    if extension == ".npy":
        return _encode_npy(d)
    if extension == ".png":
        import cv2

        valid = np.isfinite(d)
        far = int(np.count_nonzero(d[valid] > PNG_DEPTH_MAX_M))
        if far:
            log.warning("%s: 16-bit PNG holds depths up to %.3f m: clipped %d farther pixels", name,
                        PNG_DEPTH_MAX_M, far)
        mm = np.zeros(d.shape, dtype=np.uint16)
        mm[valid] = np.maximum(np.rint(np.minimum(d[valid], PNG_DEPTH_MAX_M) * 1000.0), 1).astype(np.uint16)
        ok, buffer = cv2.imencode(".png", mm)
        if not ok:
            raise OutputError("OpenCV could not encode the 16-bit PNG", path=name)
        return buffer.tobytes()
    raise OutputError(f"unknown depth format {extension or '(no extension)'!r}; use one of "
                      f"{', '.join(DEPTH_EXTENSIONS)}", path=name)


def write_depth(path, depth: np.ndarray, *, overwrite: bool = False) -> None:
    """Write a depth map (metres, NaN = invalid) atomically, in the format of ``path``'s extension.

    Raises
    ------
    OutputError
        Unknown extension, existing file without ``overwrite``, or the file cannot be written.
    """
    write_output_bytes(path, encode_depth(depth, extension=Path(str(path)).suffix, name=str(path)),
                       overwrite=overwrite)


def read_depth(path) -> np.ndarray:
    """Read a depth map written by :func:`write_depth`: float32 metres, NaN = invalid."""
    import cv2

    path = str(path)
    if Path(path).suffix.lower() == ".png":
        mm = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        d = mm.astype(np.float32) / np.float32(1000.0)
        d[mm == 0] = np.nan
        return d
    from ..io._disparity import read_disparity
    return read_disparity(path)


def encode_ply(points: np.ndarray, colours: np.ndarray) -> bytes:
    """A binary little-endian PLY of ``points`` (n, 3) float32 and ``colours`` (n, 3) uint8."""
    points = np.asarray(points, dtype="<f4").reshape(-1, 3)
    colours = np.asarray(colours, dtype=np.uint8).reshape(-1, 3)
    if len(points) != len(colours):
        raise ValueError(f"{len(points)} points but {len(colours)} colours")
    vertex = np.empty(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                          ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vertex["x"], vertex["y"], vertex["z"] = points[:, 0], points[:, 1], points[:, 2]
    vertex["red"], vertex["green"], vertex["blue"] = colours[:, 0], colours[:, 1], colours[:, 2]
    header = ("ply\nformat binary_little_endian 1.0\ncomment stereobudget: metres, left camera, "
              "x right y down z forward\n"
              f"element vertex {len(points)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    return header.encode("ascii") + vertex.tobytes()


def write_ply(path, points: np.ndarray, colours: np.ndarray, *, overwrite: bool = False) -> None:
    """Write a coloured point cloud as a binary little-endian PLY, atomically (see :func:`encode_ply`).

    Raises
    ------
    OutputError
        Existing file without ``overwrite``, or the file cannot be written.
    """
    write_output_bytes(path, encode_ply(points, colours), overwrite=overwrite)


__all__ = ["DEPTH_EXTENSIONS", "PNG_DEPTH_MAX_M", "encode_depth", "write_depth", "read_depth", "encode_ply",
           "write_ply"]
