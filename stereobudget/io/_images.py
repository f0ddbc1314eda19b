"""Image input/output at the library boundary: files or bytes in, RGB/gray arrays out.

Inside stereobudget, images are ``(row, col[, channel])`` arrays of uint8 or uint16 with
colour in RGB order.  :func:`read_image` converts whatever OpenCV (or, as a fallback,
imageio/tifffile) decodes into that convention, and rejects what the library cannot use
with a one-line :class:`~stereobudget.errors.ImageReadError` naming the file.

:func:`read_raw` decodes headerless camera frames (``--raw``).  It needs numpy only:
OpenCV is imported lazily inside the functions that use it.  numpy too is imported
inside the functions, so importing this module is cheap; the camera-side
``sb-encode --raw`` on a grid does not even call :func:`read_raw` (see
:mod:`stereobudget.io._rawgrid`) and starts without numpy, OpenCV or numba.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import struct
import sys
import tempfile
import threading
import warnings
from pathlib import Path

from ._atomic import STDIO, display_name, read_input_bytes, write_output_bytes
from ..errors import ImageReadError, OutputError
from ._limits import dimension_problem

log = logging.getLogger("stereobudget")

# RAW_PIXEL_FORMATS -- headerless pixel formats of :func:`read_raw`: name -> (channels,
# numpy dtype, channel order) -- is built on first access (module ``__getattr__`` below)
# from :data:`stereobudget.io.RAW_FORMATS`: importing this module needs no numpy.


def _raw_pixel_formats() -> dict:
    table = globals().get("RAW_PIXEL_FORMATS")
    if table is None:
        import numpy as np

        from ._rawgrid import RAW_FORMATS
        table = {fmt: (channels, np.dtype(np.uint8) if size == 1 else np.dtype("<u2"), order)
                 for fmt, (channels, size, order) in RAW_FORMATS.items()}
        globals()["RAW_PIXEL_FORMATS"] = table
    return table


def __getattr__(name):
    if name == "RAW_PIXEL_FORMATS":
        return _raw_pixel_formats()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

_SBS_MAGIC_PREFIX = b"\x89SBS"


# --- header sniffing: the size of an image before it is decoded -----------------------

def _png_size(data: bytes):
    # Signature (8) + IHDR length (4) + b"IHDR" (4) + width (4, BE) + height (4, BE).
    if len(data) >= 24 and data[12:16] == b"IHDR":
        return struct.unpack(">II", data[16:24])
    return None


def _png_is_gray(data: bytes) -> bool:
    # IHDR colour type (byte 25): 0 = gray, 4 = gray + alpha.
    return len(data) >= 26 and data[12:16] == b"IHDR" and data[:4] == b"\x89PNG" and data[25] in (0, 4)


def _pnm_size(data: bytes):
    # P1..P7 header: whitespace-separated ASCII tokens, '#' starts a comment.
    if data[:1] != b"P" or data[1:2] not in b"123456":
        return None
    tokens, i, end = [], 2, min(len(data), 4096)
    while len(tokens) < 2 and i < end:
        ch = data[i:i + 1]
        if ch == b"#":
            nl = data.find(b"\n", i)
            i = end if nl < 0 else nl + 1
        elif ch.isspace():
            i += 1
        else:
            j = i
            while j < end and not data[j:j + 1].isspace() and data[j:j + 1] != b"#":
                j += 1
            tokens.append(data[i:j])
            i = j
    if len(tokens) == 2 and all(t.isdigit() for t in tokens):
        return int(tokens[0]), int(tokens[1])
    return None


def _jpeg_size(data: bytes):
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    # Start-of-frame markers carry the size; C4/C8/CC are other segments in that range.
    sof = set(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:          # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        seg_len = struct.unpack(">H", data[i + 2:i + 4])[0]
        if marker in sof and i + 9 <= len(data):
            height, width = struct.unpack(">HH", data[i + 5:i + 9])
            return width, height
        i += 2 + seg_len
    return None


def _bmp_size(data: bytes):
    if data[:2] == b"BM" and len(data) >= 26:
        width, height = struct.unpack("<ii", data[18:26])
        return abs(width), abs(height)
    return None


def _tiff_size(data: bytes):
    if data[:4] not in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return None
    try:
        import tifffile
        with tifffile.TiffFile(io.BytesIO(data)) as tif:
            page = tif.pages[0]
            return int(page.imagewidth), int(page.imagelength)
    except Exception:        # a broken TIFF is reported by the decoder below
        return None


def sniff_image_size(data: bytes):
    """``(width, height)`` read from the header of a PNG, PNM, JPEG, BMP or TIFF, else None.

    Used to refuse oversized images before decoding (decompression bombs).
    """
    for sniff in (_png_size, _pnm_size, _jpeg_size, _bmp_size, _tiff_size):
        size = sniff(data)
        if size is not None:
            return size
    return None


# --- decoding --------------------------------------------------------------------------

@contextlib.contextmanager
def _native_stderr_captured():
    """Collect what the C decoders print on file descriptor 2 meanwhile (a list of lines).

    libpng, libjpeg and libtiff (through OpenCV), OpenCV's own log and tifffile's warnings
    write damage reports straight to stderr; a command must print one line per problem
    in its own format, so the text is captured here and reported by the caller.
    """
    lines: list = []
    if threading.current_thread() is not threading.main_thread():
        # fd 2 is process-wide: swapping it from several threads could lose it for good.
        yield lines
        return
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):   # no real fd 2 (embedded use): leave it alone
        yield lines
        return
    try:
        with tempfile.TemporaryFile() as sink:
            try:
                # The swap is inside the try: an interrupt raised just after it still
                # restores fd 2.
                os.dup2(sink.fileno(), 2)
                yield lines
                _flush_quietly(sys.stderr)      # Python-level text written meanwhile: to the sink
            finally:
                # The first call here: an interrupt raised in any call before it would
                # leave fd 2 on the sink, and the command's last message would go there.
                os.dup2(saved, 2)
            sink.seek(0)
            text = sink.read(64 * 1024).decode("utf-8", "replace")
            lines.extend(line.strip() for line in text.splitlines() if line.strip())
    finally:
        os.close(saved)


def _flush_quietly(stream) -> None:
    try:
        stream.flush()
    except (OSError, ValueError):
        pass


def _decode_with_opencv(data: bytes):
    import cv2
    import numpy as np
    buf = np.frombuffer(data, dtype=np.uint8)
    try:
        image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        return None
    return image


def _decode_fallback(data: bytes):
    """Decode what OpenCV cannot (exotic TIFF layouts, GIF...). Colour comes back RGB(A)."""
    if data[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        try:
            import tifffile
            image = tifffile.imread(io.BytesIO(data), key=0)
            if image.size:          # a TIFF without readable pages comes back as an empty float array
                return image
        except Exception:
            pass
    try:
        import imageio.v3 as iio
        with warnings.catch_warnings():
            # imageio tries every plugin on unknown data; their deprecation notes are noise here.
            warnings.simplefilter("ignore")
            image = iio.imread(io.BytesIO(data), index=0)
    except Exception:
        return None
    import numpy as np
    image = np.asarray(image)
    return image if image.size else None


_KIND_NAMES = {"f": "float", "i": "signed integer", "u": "unsigned integer", "c": "complex"}


def _describe_dtype(dtype: np.dtype) -> str:
    return f"{dtype.itemsize * 8}-bit {_KIND_NAMES.get(dtype.kind, dtype.name)}"


def _normalise(image: np.ndarray, *, name: str, bgr: bool):
    """Check dtype/shape, drop alpha, squeeze, convert BGR to RGB. Returns (array, order)."""
    import numpy as np

    if image.dtype.kind == "f":
        has_nan = bool(np.isnan(image).any())
        raise ImageReadError(
            f"floating-point image ({_describe_dtype(image.dtype)}{', contains NaN' if has_nan else ''}) "
            "is not supported; convert it to 8- or 16-bit integers", path=name)
    if image.dtype == np.bool_:
        image = image.astype(np.uint8) * np.uint8(255)
    if image.dtype not in (np.uint8, np.uint16):
        raise ImageReadError(f"unsupported bit depth ({_describe_dtype(image.dtype)}); "
                             "only 8- and 16-bit unsigned images are supported", path=name)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim not in (2, 3):
        raise ImageReadError(f"unsupported array shape {image.shape} (expected rows x cols [x channels])",
                             path=name)
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ImageReadError(f"image has zero size ({image.shape[1]}x{image.shape[0]})", path=name)
    problem = dimension_problem(image.shape[1], image.shape[0])
    if problem:
        raise ImageReadError(problem, path=name)
    if image.ndim == 2:
        return np.ascontiguousarray(image), "gray"
    channels = image.shape[2]
    if channels == 2:
        log.info("%s: dropping the alpha channel (gray + alpha image)", name)
        return np.ascontiguousarray(image[:, :, 0]), "gray"
    if channels not in (3, 4):
        raise ImageReadError(f"unsupported number of channels ({channels}); expected 1, 3 or 4",
                             path=name)
    if channels == 4:
        log.info("%s: dropping the alpha channel", name)
    colour = image[:, :, 2::-1] if bgr else image[:, :, :3]
    return np.ascontiguousarray(colour), "rgb"


def read_image(source, *, name: str | None = None):
    """Read an 8- or 16-bit gray or colour image as a library array.

    Parameters
    ----------
    source : str, os.PathLike or bytes
        A file name, ``-`` for standard input, or the encoded file contents (PNG, TIFF,
        JPEG, PPM/PGM, BMP... whatever OpenCV decodes, with imageio/tifffile as fallback).
    name : str, optional
        Name used in error messages; defaults to the file name (``<stdin>``, ``<bytes>``).

    Returns
    -------
    image : ndarray, (H, W) or (H, W, 3), uint8 or uint16
        Colour in RGB order; an alpha channel is dropped (logged at INFO level).
    channel_order : str
        ``"gray"`` or ``"rgb"``.

    Raises
    ------
    ImageReadError
        Missing/empty file, not a decodable image, zero size, floating point or NaN
        pixels, unsupported bit depth or channel count, or larger than
        :data:`stereobudget.io.MAX_PIXELS`.
    """
    if isinstance(source, (bytes, bytearray, memoryview)):
        data = bytes(source)
        name = name or "<bytes>"
    else:
        name = name or display_name(source)
        data = read_input_bytes(source, error=ImageReadError)
    if not data:
        raise ImageReadError("empty file (0 bytes)", path=name)
    if data.startswith(_SBS_MAGIC_PREFIX):
        raise ImageReadError("this is a .sbs sample file, not an image", path=name)
    with _native_stderr_captured() as decoder_messages:
        size = sniff_image_size(data)
        if size is not None:
            problem = dimension_problem(*size)
            if problem:
                raise ImageReadError(problem, path=name)
        image = _decode_with_opencv(data)
        bgr = True
        if image is not None and image.ndim == 3 and _png_is_gray(data):
            # OpenCV expands gray+alpha PNGs to BGRA; keep them gray as stored.
            image = image[:, :, [0, 3]] if image.shape[2] == 4 else image[:, :, 0]
        if image is None:
            image = _decode_fallback(data)
            bgr = False
    for message in decoder_messages:
        log.debug("%s: decoder: %s", name, message)
    if image is None:
        raise ImageReadError("not an image, or a format that cannot be decoded", path=name)
    result = _normalise(image, name=name, bgr=bgr)
    if decoder_messages:
        # Decoded, but the decoder saw damage (e.g. a corrupt JPEG stream): say so once.
        log.warning("%s: the image decoder reported damage: %s", name,
                    " | ".join(decoder_messages)[:300])
    return result


def parse_raw_size(text: str):
    """``"WxH"`` -> ``(width, height)``; raises ValueError with a readable message."""
    parts = text.lower().replace(" ", "").split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise ValueError(f"raw frame size must look like WIDTHxHEIGHT (e.g. 640x480), got {text!r}")
    return int(parts[0]), int(parts[1])


def read_raw(data: bytes, *, width: int, height: int, pix_fmt: str, name: str = "<bytes>"):
    """Interpret ``data`` as exactly one headerless frame.

    Parameters
    ----------
    data : bytes
        The frame: rows top to bottom, pixels left to right, channels interleaved.
    width, height : int
        Frame size in pixels.
    pix_fmt : str
        One of :data:`RAW_PIXEL_FORMATS`: ``gray8``, ``rgb24``, ``bgr24``, ``gray16le``.
    name : str
        Name used in error messages.

    Returns
    -------
    image : ndarray, (H, W) or (H, W, 3), uint8 or uint16
        A view of ``data`` where possible (no pixel is touched: the camera computes nothing).
    channel_order : str
        ``"gray"``, ``"rgb"`` or ``"bgr"`` (``bgr24`` frames stay BGR; the sample file records it).

    Raises
    ------
    ImageReadError
        Unknown ``pix_fmt``, bad size, or a byte count other than one frame.
    """
    import numpy as np

    from ._rawgrid import check_raw_frame

    check_raw_frame(data, width=width, height=height, pix_fmt=pix_fmt, name=name)
    channels, dtype, order = _raw_pixel_formats()[pix_fmt]
    # A view on little-endian hosts; only a big-endian host converts gray16le.
    pixels = np.frombuffer(data, dtype=dtype).astype(dtype.newbyteorder("="), copy=False)
    shape = (height, width) if channels == 1 else (height, width, channels)
    return pixels.reshape(shape), order


# --- writing ---------------------------------------------------------------------------

_WRITE_EXTENSIONS = {".png": ".png", ".tif": ".tiff", ".tiff": ".tiff"}


def encode_image_bytes(image: np.ndarray, *, fmt: str = ".png", channel_order: str = "rgb") -> bytes:
    """Encode a uint8/uint16 gray or colour array as PNG or TIFF bytes.

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, 3), uint8 or uint16
    fmt : str
        ``".png"`` or ``".tiff"``.
    channel_order : str
        ``"gray"``, ``"rgb"`` or ``"bgr"``: the order of ``image``'s channels.
    """
    import cv2
    import numpy as np
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"only uint8 and uint16 images can be written, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3:
        if image.shape[2] != 3:
            raise ValueError(f"expected 1 or 3 channels, got {image.shape[2]}")
        if channel_order == "rgb":
            image = image[:, :, ::-1]
    ok, buf = cv2.imencode(fmt, np.ascontiguousarray(image))
    if not ok:
        raise ValueError(f"OpenCV could not encode a {image.dtype} {image.shape} image as {fmt}")
    return buf.tobytes()


def write_image(path, image: np.ndarray, *, channel_order: str = "rgb", overwrite: bool = False) -> None:
    """Write an 8- or 16-bit image atomically as PNG or TIFF (chosen by the extension).

    Parameters
    ----------
    path : str or os.PathLike
        ``*.png``, ``*.tif`` or ``*.tiff``; ``-`` writes PNG to standard output.
    image : ndarray, (H, W) or (H, W, 3), uint8 or uint16
    channel_order : str
        Order of ``image``'s channels (``"rgb"`` is the library convention).
    overwrite : bool
        Replace an existing file.

    Raises
    ------
    OutputError
        Unsupported extension, existing file without ``overwrite``, unwritable directory.
    """
    if str(path) == STDIO:
        fmt = ".png"
    else:
        suffix = Path(path).suffix.lower()
        if suffix not in _WRITE_EXTENSIONS:
            raise OutputError(f"unsupported image extension {suffix or '(none)'!r}; use .png, .tif or .tiff",
                              path=str(path))
        fmt = _WRITE_EXTENSIONS[suffix]
    data = encode_image_bytes(image, fmt=fmt, channel_order=channel_order)
    write_output_bytes(path, data, overwrite=overwrite)


__all__ = ["RAW_PIXEL_FORMATS", "read_image", "read_raw", "parse_raw_size", "write_image",
           "encode_image_bytes", "sniff_image_size"]
