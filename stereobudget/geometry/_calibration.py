"""Reading a stereo calibration: OpenCV FileStorage YAML/XML, a JSON equivalent, Middlebury 2014 ``calib.txt``.

The three formats end in one :class:`StereoCalibration`, in OpenCV's convention: camera 1
is the left camera (the one that sends I1), camera 2 the right one (the samples), and a
point ``X1`` in camera 1's coordinates is ``X2 = R @ X1 + T`` in camera 2's.  For a left /
right pair ``T[0]`` is therefore negative (camera 2 sits at ``+B`` along camera 1's x).

* **OpenCV** (``.yml``, ``.yaml``, ``.xml``): the nodes ``M1 D1 M2 D2 R T`` that OpenCV's
  ``stereo_calib`` sample writes (it splits them over ``intrinsics.yml`` and
  ``extrinsics.yml``: put them in one file), plus optional ``image_width`` and
  ``image_height`` (the size the cameras were calibrated at) and ``unit`` (of ``T``:
  ``m``, ``cm`` or ``mm``; default ``m``).
* **JSON** (``.json``): one object with the same keys; matrices as nested lists.
* **Middlebury 2014** (``calib.txt``): ``cam0``, ``cam1`` (``[f 0 cx; 0 f cy; 0 0 1]``),
  ``doffs``, ``baseline`` (mm), ``width``, ``height``, ``ndisp``.  The pair is already
  rectified: ``R = I``, no distortion, ``T = (-baseline, 0, 0)``, and the principal points
  differ by ``doffs`` along x.

Every problem is a :class:`~stereobudget.errors.CalibrationError` naming the file and the
field.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import CalibrationError

#: Units ``T`` (or Middlebury's baseline) may be given in, and their size in metres.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: Distortion vector lengths OpenCV knows (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]]).
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)
#: How far ``R`` may be from a rotation (``|R R^T - I|`` max, and ``|det R - 1|``): what a
#: file written with 6 decimals still meets.
ROTATION_TOLERANCE = 1e-4


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """A stereo pair's calibration (OpenCV's convention; see the module docstring).

    Attributes
    ----------
    M1, M2 : ndarray, float64 (3, 3)
        Camera matrices of the left and right cameras.
    D1, D2 : ndarray, float64 (k,)
        Their distortion coefficients (OpenCV's order).
    R : ndarray, float64 (3, 3)
        Rotation from camera 1's coordinates to camera 2's.
    T : ndarray, float64 (3,)
        Translation, in metres (converted from the file's unit).
    image_size : (width, height) or None
        The size the cameras were calibrated at, when the file says.
    source : str
        The file it came from (for messages).
    rectified : bool
        True when the file describes a rectified pair (Middlebury; or no rotation, no
        distortion, equal focal lengths and rows): no resampling is needed, and the
        principal points' difference along x is ``doffs``.
    """

    M1: np.ndarray
    D1: np.ndarray
    M2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    image_size: tuple | None = None
    source: str = ""
    rectified: bool = False
    extras: dict = field(default_factory=dict, compare=False)

    @property
    def baseline(self) -> float:
        """Distance between the optical centres, in metres."""
        return float(np.linalg.norm(self.T))

    @property
    def doffs(self) -> float:
        """``cx2 - cx1`` of a rectified pair: the disparity of a point at infinity, negated."""
        return float(self.M2[0, 2] - self.M1[0, 2])

    def summary(self) -> dict:
        """JSON-able facts for ``--json``."""
        return {"file": self.source, "baseline_m": round(self.baseline, 6),
                "focal_px": round(float(self.M1[0, 0]), 3),
                "image_size": list(self.image_size) if self.image_size else None,
                "rectified_input": self.rectified}


def _fail(path, message):
    raise CalibrationError(message, path=path)


def _matrix(path, name, value, shape):
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        _fail(path, f"{name} is not a matrix of numbers")
    if shape == (3,) and array.size == 3:
        array = array.reshape(3)
    elif shape == "vector":
        array = array.reshape(-1)
        if array.size not in DISTORTION_LENGTHS:
            _fail(path, f"{name} has {array.size} coefficients; OpenCV's distortion has "
                        f"{', '.join(map(str, DISTORTION_LENGTHS))}")
    if shape != "vector" and array.shape != shape:
        _fail(path, f"{name} must be {'x'.join(map(str, shape))}, got {'x'.join(map(str, array.shape)) or 'a scalar'}")
    if not np.all(np.isfinite(array)):
        _fail(path, f"{name} holds a non-finite number")
    return array


def _check_camera(path, name, m):
    if m[0, 0] <= 0 or m[1, 1] <= 0:
        _fail(path, f"{name}: focal lengths must be positive (fx {m[0, 0]:g}, fy {m[1, 1]:g})")
    if abs(m[2, 0]) > 1e-9 or abs(m[2, 1]) > 1e-9 or abs(m[2, 2] - 1) > 1e-9 or abs(m[1, 0]) > 1e-9:
        _fail(path, f"{name} is not a camera matrix (its last row must be 0 0 1 and M[1,0] 0)")


def _build(path, values: dict, *, unit_scale: float, image_size, rectified_hint=False) -> StereoCalibration:
    m1 = _matrix(path, "M1", values["M1"], (3, 3))
    m2 = _matrix(path, "M2", values["M2"], (3, 3))
    d1 = _matrix(path, "D1", values["D1"], "vector")
    d2 = _matrix(path, "D2", values["D2"], "vector")
    r = _matrix(path, "R", values["R"], (3, 3))
    t = _matrix(path, "T", values["T"], (3,)) * unit_scale
    _check_camera(path, "M1", m1)
    _check_camera(path, "M2", m2)
    if np.abs(r @ r.T - np.eye(3)).max() > ROTATION_TOLERANCE or abs(np.linalg.det(r) - 1) > ROTATION_TOLERANCE:
        _fail(path, f"R is not a rotation (det {np.linalg.det(r):.4f}, |R R^T - I| "
                    f"{np.abs(r @ r.T - np.eye(3)).max():.2g})")
    with np.errstate(over="ignore"):
        norm = float(np.linalg.norm(t))
    if not math.isfinite(norm):
        _fail(path, "T is too large to be a baseline")
    if norm == 0:
        _fail(path, "T is zero: the two cameras are at the same place (no baseline)")
    if abs(t[0]) < 0.5 * norm:
        _fail(path, f"T = ({t[0]:g}, {t[1]:g}, {t[2]:g}) m is not mostly along x: only left/right pairs are "
                    "supported")
    if t[0] > 0:
        _fail(path, f"T[0] = {t[0]:+g} m is positive: camera 2 sits to the left of camera 1, so the pair is "
                    "swapped or T's sign is wrong; calibrate with the left camera (the one sending I1) as camera 1")
    if image_size is not None:
        w, h = image_size
        if not (w >= 1 and h >= 1):
            _fail(path, f"image size {w}x{h} is empty")
    no_distortion = not np.any(d1) and not np.any(d2)
    rectified = bool(rectified_hint or (
        no_distortion and np.abs(r - np.eye(3)).max() < 1e-9 and abs(t[1]) < 1e-12 and abs(t[2]) < 1e-12
        and m1[0, 0] == m2[0, 0] and m1[1, 1] == m2[1, 1] and m1[1, 2] == m2[1, 2]
        and m1[0, 1] == 0 and m2[0, 1] == 0))
    return StereoCalibration(M1=m1, D1=d1, M2=m2, D2=d2, R=r, T=t,
                             image_size=tuple(int(v) for v in image_size) if image_size else None,
                             source=str(path), rectified=rectified)


def _unit_scale(path, unit) -> float:
    if unit is None:
        return 1.0
    unit = str(unit).strip().lower()
    if unit not in UNITS:
        _fail(path, f"unit {unit!r} is not one of {', '.join(UNITS)}")
    return UNITS[unit]


def _size_from(path, width, height):
    if width is None and height is None:
        return None
    if width is None or height is None:
        _fail(path, "image_width and image_height go together")
    try:
        w, h = float(width), float(height)
    except (TypeError, ValueError):
        _fail(path, "image_width/image_height must be integers")
    if w != int(w) or h != int(h) or w < 1 or h < 1:
        _fail(path, f"image size {width}x{height} is not a positive integer size")
    return int(w), int(h)


_KEYS = ("M1", "D1", "M2", "D2", "R", "T")


def _read_filestorage(path: str) -> StereoCalibration:
    import cv2

    try:
        storage = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    except Exception as exc:  # noqa: BLE001 -- cv2.error, or SystemError from the bindings
        message = " ".join(str(exc.__cause__ or exc).split())
        where = re.search(r"\((\d+)\): ([^']*)", message)
        detail = f"line {where.group(1)}: {where.group(2).strip()}" if where else message[-200:]
        _fail(path, f"not a readable OpenCV YAML/XML file: {detail}")
    if not storage.isOpened():
        _fail(path, "not a readable OpenCV YAML/XML file")
    try:
        values = {}
        for key in _KEYS:
            node, mat = _node_matrix(path, storage, key)
            if node is None:
                _fail(path, f"{key} is missing (a stereo calibration needs {' '.join(_KEYS)})")
            if mat is None:
                _fail(path, f"{key} is not a matrix")
            values[key] = mat

        def scalar(key):
            try:
                node = storage.getNode(key)
                if node.empty() or node.isNone():
                    return None
                return node.string() if node.isString() else node.real()
            except Exception as exc:  # noqa: BLE001 -- cv2.error from a malformed node
                _fail(path, f"{key} is not readable: {_opencv_reason(exc)}")

        unit = scalar("unit")
        size = _size_from(path, scalar("image_width"), scalar("image_height"))
    finally:
        storage.release()
    return _build(path, values, unit_scale=_unit_scale(path, unit), image_size=size)


def _node_matrix(path, storage, key):
    """(node, matrix) of ``key`` in an open ``cv2.FileStorage``: (None, None) when absent, matrix
    None when the node is neither a matrix nor a sequence of numbers."""
    # OpenCV asserts on a malformed node (a string where a map is read, a matrix whose data
    # does not fill its declared size, an unknown element type, a size it cannot allocate):
    # each is the file's fault, told in one line.
    try:
        node = storage.getNode(key)
        if node.empty() or node.isNone():
            return None, None
        mat = node.mat()
        if mat is None and node.isSeq():
            mat = [node.at(i).real() for i in range(node.size())]
        return node, mat
    except Exception as exc:  # noqa: BLE001 -- cv2.error
        _fail(path, f"{key} is not a readable matrix: {_opencv_reason(exc)}")


def _opencv_reason(exc) -> str:
    """The part of an OpenCV error that says what failed (``(-215:Assertion failed) isMap()``)."""
    message = " ".join(str(exc).split())
    found = re.search(r"error: (\(-?\d+:[^)]*\).*?)(?: in function .*)?$", message)
    return (found.group(1) if found else message)[:160]


def _read_json(path: str, text: str) -> StereoCalibration:
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:   # RecursionError: arrays nested thousands deep
        _fail(path, f"not valid JSON: {exc}")
    if not isinstance(data, dict):
        _fail(path, "a JSON calibration must be one object with M1 D1 M2 D2 R T")
    for key in _KEYS:
        if key not in data:
            _fail(path, f"{key} is missing (a stereo calibration needs {' '.join(_KEYS)})")
    size = data.get("image_size")
    if size is not None:
        if not isinstance(size, (list, tuple)) or len(size) != 2:
            _fail(path, "image_size must be [width, height]")
        size = _size_from(path, *size)
    else:
        size = _size_from(path, data.get("image_width"), data.get("image_height"))
    return _build(path, data, unit_scale=_unit_scale(path, data.get("unit")), image_size=size)


_MIDDLEBURY_MATRIX = re.compile(r"^\[(.*)\]$")


def _read_middlebury(path: str, text: str) -> StereoCalibration:
    fields = {}
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        if "=" not in line:
            _fail(path, f"line {number} is not 'name=value': {line[:60]!r}")
        key, value = (part.strip() for part in line.split("=", 1))
        fields[key] = value
    for key in ("cam0", "cam1", "doffs", "baseline", "width", "height"):
        if key not in fields:
            _fail(path, f"{key} is missing (Middlebury calib.txt has cam0, cam1, doffs, baseline, width, height)")

    def matrix(key):
        match = _MIDDLEBURY_MATRIX.match(fields[key])
        rows = [row.split() for row in match.group(1).split(";")] if match else None
        try:
            array = np.array(rows, dtype=np.float64)
        except (TypeError, ValueError):
            array = None
        if array is None or array.shape != (3, 3):
            _fail(path, f"{key} must be a 3x3 matrix written [f 0 cx; 0 f cy; 0 0 1]")
        return array

    def number(key):
        try:
            value = float(fields[key])
        except ValueError:
            _fail(path, f"{key} is not a number: {fields[key][:40]!r}")
        if not math.isfinite(value):
            _fail(path, f"{key} is not finite")
        return value

    cam0, cam1 = matrix("cam0"), matrix("cam1")
    doffs, baseline = number("doffs"), number("baseline")
    size = _size_from(path, number("width"), number("height"))
    if baseline <= 0:
        _fail(path, f"baseline {baseline:g} must be positive (mm, camera 1 to the right of camera 0)")
    _check_camera(path, "cam0", cam0)
    _check_camera(path, "cam1", cam1)
    if cam0[0, 0] != cam1[0, 0] or cam0[1, 1] != cam1[1, 1] or cam0[1, 2] != cam1[1, 2]:
        _fail(path, "cam0 and cam1 differ in focal length or cy: not a rectified pair")
    if abs((cam1[0, 2] - cam0[0, 2]) - doffs) > 0.5:
        _fail(path, f"doffs {doffs:g} disagrees with cam1's cx - cam0's cx ({cam1[0, 2] - cam0[0, 2]:g})")
    if "ndisp" in fields:
        ndisp = number("ndisp")
        if ndisp < 1 or ndisp != int(ndisp):
            _fail(path, f"ndisp {fields['ndisp']!r} must be a positive integer")
    # Keep doffs exact: cam1's cx is taken from cam0's cx + doffs.
    cam1 = cam1.copy()
    cam1[0, 2] = cam0[0, 2] + doffs
    return _build(path, {"M1": cam0, "M2": cam1, "D1": np.zeros(5), "D2": np.zeros(5), "R": np.eye(3),
                         "T": [-baseline, 0.0, 0.0]}, unit_scale=UNITS["mm"], image_size=size,
                  rectified_hint=True)


def read_calibration(path: str) -> StereoCalibration:
    """Read a stereo calibration file (OpenCV YAML/XML, JSON or Middlebury ``calib.txt``).

    Parameters
    ----------
    path : str
        The file; its format is told by its content (``%YAML``, ``<?xml``, ``{``,
        ``cam0=``), else by its extension.

    Returns
    -------
    StereoCalibration

    Raises
    ------
    CalibrationError
        Missing or unreadable file, malformed or missing field, an ``R`` that is not a
        rotation, a zero, vertical or positive-x ``T`` (swapped pair), an inconsistent
        Middlebury ``doffs``.
    """
    path = os.fspath(path)
    if not path.strip():
        _fail(repr(path), "an empty file name")
    if os.path.isdir(path):
        _fail(path, "is a directory, not a calibration file")
    try:
        with open(path, "rb") as handle:
            raw = handle.read((1 << 20) + 1)
    except FileNotFoundError:
        _fail(path, "no such file")
    except OSError as exc:
        _fail(path, f"cannot read: {exc.strerror or exc}")
    if len(raw) > 1 << 20:
        _fail(path, "larger than 1 MiB: not a calibration file")
    if not raw.strip():
        _fail(path, "empty file")
    try:
        text = raw.decode("utf-8-sig")      # -sig: a leading byte-order mark, as Windows editors write
    except UnicodeDecodeError:
        _fail(path, "not a text file (a calibration is YAML, XML, JSON or Middlebury calib.txt)")
    head = text.lstrip()
    ext = os.path.splitext(path)[1].lower()
    if head.startswith("{") or (ext == ".json" and not head.startswith(("%YAML", "<"))):
        return _read_json(path, text)
    if head.startswith(("%YAML", "<?xml", "<opencv_storage")) or ext in (".yml", ".yaml", ".xml"):
        return _read_filestorage(path)
    if re.match(r"^\s*cam0\s*=", text):
        return _read_middlebury(path, text)
    _fail(path, "not a calibration file (expected OpenCV YAML/XML, JSON, or Middlebury calib.txt with cam0=...)")


def check_image_size(calibration: StereoCalibration, width: int, height: int, *, path: str | None = None) -> None:
    """Refuse a calibration made for another image size than ``width x height``.

    A file that states its size must match exactly; one that does not must at least put
    both principal points inside the image (a calibration for a 4x larger image puts them
    far outside).

    Raises
    ------
    CalibrationError
    """
    where = calibration.source or path
    if calibration.image_size is not None:
        cw, ch = calibration.image_size
        if (cw, ch) != (width, height):
            scale = f" ({width / cw:.3g}x its size: scale M1 and M2 by that factor, or resize the images back)" \
                if abs(width / cw - height / ch) < 0.01 else ""
            _fail(where, f"calibrated for {cw}x{ch} images but the left image is {width}x{height}{scale}")
        return
    for name, m in (("M1", calibration.M1), ("M2", calibration.M2)):
        cx, cy = m[0, 2], m[1, 2]
        if not (0 <= cx <= width and 0 <= cy <= height):
            _fail(where, f"{name}'s principal point ({cx:g}, {cy:g}) lies outside the {width}x{height} image: "
                         "a calibration for another image size?")


__all__ = ["UNITS", "DISTORTION_LENGTHS", "StereoCalibration", "read_calibration", "check_image_size"]
