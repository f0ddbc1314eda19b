"""Reading and writing disparity maps; the file format follows the extension.

In memory a disparity map is always float32 ``(H, W)`` with NaN where invalid.  On disk:

``.pfm``
    float32, Middlebury conventions: header ``Pf\\n{W} {H}\\n-1.0\\n`` (a negative scale
    means little-endian), rows stored bottom-to-top, ``+inf`` = invalid.  The reader also
    accepts big-endian files (positive scale); colour ``PF`` files are refused.
``.tif`` / ``.tiff``
    float32, NaN = invalid, deflate compression with the floating-point predictor when
    the optional ``imagecodecs`` package is installed (plain deflate otherwise).
``.png``
    uint16, ``value = round(d * 256)``, ``0`` = invalid; a valid disparity that would round
    to 0 is stored as 1.  Disparities outside ``[0, 65535/256]`` are clipped (and logged).
``.npy``
    float32 with NaN.

Every write is atomic (:func:`stereobudget.io.write_output_bytes`): the bytes go to a
temporary file in the target directory which is then moved over the target, so a reader
never sees a half-written map.
"""

from __future__ import annotations

import io
import logging
import os
import re
from pathlib import Path

import cv2
import numpy as np

from ._atomic import write_output_bytes
from ..errors import ImageReadError, OutputError

logger = logging.getLogger(__name__)

DISPARITY_EXTENSIONS = (".pfm", ".tif", ".tiff", ".png", ".npy")
#: Formats a disparity map can take on standard output (``-``), the first the default.
STREAM_FORMATS = ("pfm", "png")

PNG_SCALE = 256.0
PNG_MAX_DISPARITY = 65535 / PNG_SCALE  # 255.996...


# --------------------------------------------------------------------------- helpers

def _extension(path) -> str:
    return Path(path).suffix.lower()


def _as_disparity_array(disparity) -> np.ndarray:
    """Validate a disparity map and return it as float32 (H, W) with NaN for every non-finite value."""
    d = np.asarray(disparity)
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[:, :, 0]
    if d.ndim != 2 or d.shape[0] == 0 or d.shape[1] == 0:
        raise ValueError(f"a disparity map must be a non-empty 2-D array, got shape {d.shape}")
    if not (np.issubdtype(d.dtype, np.floating) or np.issubdtype(d.dtype, np.integer)):
        raise ValueError(f"a disparity map must be numeric, got dtype {d.dtype}")
    d = d.astype(np.float32, copy=True)
    d[~np.isfinite(d)] = np.nan
    return d


# --------------------------------------------------------------------------- PFM

_PFM_HEADER = re.compile(rb"\A(P[fF])\s+(\d+)\s+(\d+)\s+(\S+)\s")


def _encode_pfm(d: np.ndarray) -> bytes:
    h, w = d.shape
    on_disk = np.where(np.isnan(d), np.float32(np.inf), d).astype("<f4")
    header = f"Pf\n{w} {h}\n-1.0\n".encode("ascii")
    return header + np.ascontiguousarray(on_disk[::-1]).tobytes()


def _decode_pfm(raw: bytes, path: str) -> np.ndarray:
    match = _PFM_HEADER.match(raw[:256])
    if match is None:
        raise ImageReadError("not a PFM file (expected 'Pf', width, height and scale in the header)",
                             path=path)
    kind, width, height, scale_text = match.groups()
    if kind == b"PF":
        raise ImageReadError("colour PFM ('PF') is not a disparity map; expected single-channel 'Pf'",
                             path=path)
    width, height = int(width), int(height)
    try:
        scale = float(scale_text)
    except ValueError:
        raise ImageReadError(f"PFM scale {scale_text.decode('latin-1')!r} is not a number",
                             path=path) from None
    if width == 0 or height == 0:
        raise ImageReadError(f"PFM declares an empty image ({width}x{height})", path=path)
    if scale == 0 or not np.isfinite(scale):
        raise ImageReadError(f"PFM scale must be a non-zero number, got {scale_text.decode()!r}",
                             path=path)
    expected = width * height * 4
    payload = raw[match.end():]
    if len(payload) < expected:
        raise ImageReadError(f"PFM is truncated: {width}x{height} needs {expected} bytes of data, "
                             f"found {len(payload)}", path=path)
    if len(payload) > expected:
        raise ImageReadError(f"PFM has {len(payload) - expected} bytes after the {width}x{height} data",
                             path=path)
    dtype = "<f4" if scale < 0 else ">f4"
    d = np.frombuffer(payload, dtype=dtype).reshape(height, width)[::-1]
    return _as_disparity_array(d)


def pfm_frames(data: bytes, *, name: str = "<bytes>"):
    """The disparity maps of a PFM stream (``sb-decode ... --disparity -`` on a stream of frames).

    A PFM stream is PFM images one after another, each ``Pf`` + width + height + scale
    and width x height float32 values (bottom row first), as :func:`write_disparity`
    writes them.

    Yields
    ------
    ndarray, float32, (H, W)
        One map per frame, NaN where the disparity is unknown.

    Raises
    ------
    ImageReadError
        Bytes that are no PFM image, or a last image cut short.
    """
    view = memoryview(data)
    position, index = 0, 0
    while position < len(view):
        head = bytes(view[position:position + 256])
        match = _PFM_HEADER.match(head)
        label = f"{name} frame {index}" if index else name
        if match is None:
            _decode_pfm(head, label)            # raises with the reason
        width, height = int(match.group(2)), int(match.group(3))
        end = position + match.end() + width * height * 4
        yield _decode_pfm(bytes(view[position:end]), label)
        position, index = end, index + 1


# --------------------------------------------------------------------------- TIFF

def _float_predictor_available() -> bool:
    """tifffile needs the optional imagecodecs package for the floating-point predictor."""
    try:
        import imagecodecs  # noqa: F401
    except ImportError:
        return False
    return True


def _encode_tiff(d: np.ndarray) -> bytes:
    import tifffile

    buffer = io.BytesIO()
    predictor = 3 if _float_predictor_available() else None
    tifffile.imwrite(buffer, d, compression="zlib", predictor=predictor, photometric="minisblack")
    return buffer.getvalue()


def _decode_tiff(path: str) -> np.ndarray:
    import tifffile

    try:
        d = tifffile.imread(path)
    except KeyError as exc:  # tifffile reports a missing codec (e.g. predictor 3) as KeyError
        raise ImageReadError(f"cannot decode TIFF: {exc.args[0] if exc.args else exc}", path=path) from None
    except Exception as exc:  # tifffile raises several unrelated types for corrupt files
        raise ImageReadError(f"not a readable TIFF ({exc})", path=path) from None
    d = np.squeeze(d) if d.ndim > 2 else d
    if d.ndim != 2 or not np.issubdtype(d.dtype, np.floating):
        raise ImageReadError(f"TIFF disparity must be single-channel float, got shape {d.shape} "
                             f"dtype {d.dtype}", path=path)
    return _as_disparity_array(d)


# --------------------------------------------------------------------------- PNG

def _encode_png16(d: np.ndarray, path: str) -> bytes:
    valid = ~np.isnan(d)
    values = d[valid]
    below = int(np.count_nonzero(values < 0))
    above = int(np.count_nonzero(values > PNG_MAX_DISPARITY))
    if below or above:
        logger.warning("%s: 16-bit PNG holds disparities in [0, %.3f]: clipped %d negative and %d larger "
                       "values", path, PNG_MAX_DISPARITY, below, above)
    scaled = np.rint(np.clip(values, 0.0, PNG_MAX_DISPARITY) * PNG_SCALE)
    encoded = np.zeros(d.shape, dtype=np.uint16)
    # 0 means "invalid" in this format, so a valid disparity below 1/512 is stored as 1/256.
    encoded[valid] = np.maximum(scaled, 1).astype(np.uint16)
    ok, buffer = cv2.imencode(".png", encoded)
    if not ok:
        raise OutputError("OpenCV could not encode the 16-bit PNG", path=path)
    return buffer.tobytes()


def _decode_png16(path: str) -> np.ndarray:
    raw = np.fromfile(path, dtype=np.uint8)
    encoded = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED) if raw.size else None
    if encoded is None:
        raise ImageReadError("not a readable PNG", path=path)
    if encoded.ndim != 2 or encoded.dtype != np.uint16:
        channels = 1 if encoded.ndim == 2 else encoded.shape[2]
        raise ImageReadError(f"PNG disparity must be 16-bit single-channel, got {channels} channel(s) "
                             f"of {encoded.dtype}", path=path)
    d = encoded.astype(np.float32) / np.float32(PNG_SCALE)
    d[encoded == 0] = np.nan
    return d


# --------------------------------------------------------------------------- NPY

def _encode_npy(d: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, d, allow_pickle=False)
    return buffer.getvalue()


def _decode_npy(path: str) -> np.ndarray:
    try:
        d = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise ImageReadError(f"not a readable .npy array ({exc})", path=path) from None
    if not isinstance(d, np.ndarray) or d.dtype.kind not in "fiu":
        raise ImageReadError("the .npy file does not hold a numeric array", path=path)
    try:
        return _as_disparity_array(d)
    except ValueError as exc:
        raise ImageReadError(str(exc), path=path) from None


# --------------------------------------------------------------------------- public API

def write_disparity(path, disparity, *, overwrite: bool = False, stream_format: str | None = None) -> None:
    """Write a disparity map atomically in the format given by the extension of ``path``.

    Parameters
    ----------
    path : str or Path
        Output file; extension ``.pfm``, ``.tif``/``.tiff``, ``.png`` (16-bit, x256) or ``.npy``.
        ``-`` writes to standard output in ``stream_format``.
    disparity : ndarray, (H, W), float
        Disparity of the left view; NaN (or any non-finite value) marks invalid pixels.
    overwrite : bool
        Replace an existing file.  Without it an existing ``path`` raises :class:`OutputError`.
    stream_format : {"pfm", "png"}, optional
        Format on standard output (default ``"pfm"``); also a file's format when given.

    Raises
    ------
    OutputError
        Unknown extension, existing file without ``overwrite``, standard output that is a
        terminal, or the file cannot be written.
    ValueError
        ``disparity`` is not a non-empty numeric 2-D array.
    """
    if stream_format is not None or str(path) == "-":
        fmt = (stream_format or STREAM_FORMATS[0]).lower()
        if fmt not in STREAM_FORMATS:
            raise OutputError(f"unknown disparity stream format {fmt!r}; use {' or '.join(STREAM_FORMATS)}",
                              path="<stdout>" if str(path) == "-" else str(path))
        ext = "." + fmt
    else:
        ext = _extension(path)
    if ext not in DISPARITY_EXTENSIONS:
        raise OutputError(f"unknown disparity format {ext or '(no extension)'!r}; "
                          f"use one of {', '.join(DISPARITY_EXTENSIONS)}", path=str(path))
    d = _as_disparity_array(disparity)
    if ext == ".pfm":
        payload = _encode_pfm(d)
    elif ext in (".tif", ".tiff"):
        payload = _encode_tiff(d)
    elif ext == ".png":
        payload = _encode_png16(d, "<stdout>" if str(path) == "-" else str(path))
    else:
        payload = _encode_npy(d)
    write_output_bytes(path, payload, overwrite=overwrite)


def read_disparity(path) -> np.ndarray:
    """Read a disparity map written by :func:`write_disparity` (or by Middlebury tools, for PFM).

    Parameters
    ----------
    path : str or Path
        ``.pfm``, ``.tif``/``.tiff``, ``.png`` (16-bit, x256) or ``.npy`` file.

    Returns
    -------
    ndarray, (H, W), float32
        Disparity with NaN where invalid.

    Raises
    ------
    ImageReadError
        The file is missing, has an unknown extension, or its content is not a valid
        disparity map of that format.
    """
    path = str(path)
    ext = _extension(path)
    if ext not in DISPARITY_EXTENSIONS:
        raise ImageReadError(f"unknown disparity format {ext or '(no extension)'!r}; "
                             f"expected one of {', '.join(DISPARITY_EXTENSIONS)}", path=path)
    if not os.path.isfile(path):
        raise ImageReadError("no such file", path=path)
    if ext == ".pfm":
        with open(path, "rb") as handle:
            return _decode_pfm(handle.read(), path)
    if ext in (".tif", ".tiff"):
        return _decode_tiff(path)
    if ext == ".png":
        return _decode_png16(path)
    return _decode_npy(path)


def disparity_preview(disparity, *, min_disp: float | None = None,
                      max_disp: float | None = None) -> np.ndarray:
    """Colour-coded view of a disparity map (turbo colour map, invalid pixels black).

    Parameters
    ----------
    disparity : ndarray, (H, W), float
        Disparity map; NaN = invalid.
    min_disp, max_disp : float, optional
        Disparities mapped to the two ends of the colour map (default: the valid range of
        ``disparity``).  Values outside are clipped, so several maps can share one scale.

    Returns
    -------
    ndarray, (H, W, 3), uint8
        RGB image.
    """
    d = _as_disparity_array(disparity)
    valid = ~np.isnan(d)
    if min_disp is None:
        min_disp = float(d[valid].min()) if valid.any() else 0.0
    if max_disp is None:
        max_disp = float(d[valid].max()) if valid.any() else 1.0
    span = max(float(max_disp) - float(min_disp), 1e-6)
    normalised = np.clip((np.nan_to_num(d, nan=float(min_disp)) - float(min_disp)) / span, 0.0, 1.0)
    levels = np.rint(normalised * 255.0).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(levels, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[~valid] = 0
    return rgb


#: Narrowest preview that gets a colour bar (its three labels need the room).
SCALE_BAR_MIN_WIDTH = 96


def with_scale_bar(rgb: np.ndarray, *, min_disp: float, max_disp: float) -> np.ndarray:
    """``rgb`` (a :func:`disparity_preview`) with a colour bar and its disparity scale below it.

    The bar runs through the colour map from ``min_disp`` (left) to ``max_disp`` (right)
    across the image width, labelled at both ends and the middle in pixels of disparity;
    "invalid = black" is implied by the black of the map.  Images narrower than
    :data:`SCALE_BAR_MIN_WIDTH` are returned unchanged.
    """
    h, w = rgb.shape[:2]
    if w < SCALE_BAR_MIN_WIDTH:
        return rgb
    bar_h, text_h = max(8, min(24, h // 24)), 16
    levels = np.rint(np.linspace(0, 255, w)).astype(np.uint8)[None, :].repeat(bar_h, axis=0)
    bar = cv2.cvtColor(cv2.applyColorMap(levels, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    labels = np.full((text_h, w, 3), 255, np.uint8)
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.4

    def label(value, anchor):
        text = f"{value:g}" if anchor != "right" else f"{value:g} px"
        (tw, _), _ = cv2.getTextSize(text, font, scale, 1)
        x = {"left": 1, "middle": (w - tw) // 2, "right": w - tw - 1}[anchor]
        cv2.putText(labels, text, (max(0, x), text_h - 4), font, scale, (0, 0, 0), 1, cv2.LINE_AA)

    label(round(float(min_disp), 2), "left")
    label(round((float(min_disp) + float(max_disp)) / 2, 2), "middle")
    label(round(float(max_disp), 2), "right")
    return np.concatenate([rgb, bar, labels], axis=0)


def write_preview(path, disparity, *, min_disp: float | None, max_disp: float | None,
                  overwrite: bool = False, scale_bar: bool = True) -> None:
    """Write :func:`disparity_preview` of ``disparity`` as an 8-bit RGB PNG, atomically.

    Parameters
    ----------
    path : str or Path
        Output PNG; ``-`` writes it to standard output.
    disparity : ndarray, (H, W), float
        Disparity map; NaN = invalid (drawn black).
    min_disp, max_disp : float or None
        Colour-map range (None: the valid range of ``disparity``).
    overwrite : bool
        Replace an existing file.
    scale_bar : bool
        Append the colour bar and its scale below the map (:func:`with_scale_bar`).
    """
    if str(path) != "-" and _extension(path) != ".png":
        raise OutputError("a disparity preview is written as PNG; use a .png file name", path=str(path))
    rgb = disparity_preview(disparity, min_disp=min_disp, max_disp=max_disp)
    if scale_bar:
        d = _as_disparity_array(disparity)
        valid = ~np.isnan(d)
        low = float(min_disp) if min_disp is not None else (float(d[valid].min()) if valid.any() else 0.0)
        high = float(max_disp) if max_disp is not None else (float(d[valid].max()) if valid.any() else 1.0)
        rgb = with_scale_bar(rgb, min_disp=low, max_disp=high)
    ok, buffer = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise OutputError("OpenCV could not encode the preview PNG", path=str(path))
    write_output_bytes(path, buffer.tobytes(), overwrite=overwrite)
