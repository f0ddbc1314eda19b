"""The camera's fast path: a headerless raw frame sampled on a regular grid, in plain Python.

``sb-encode --raw WxH --pix-fmt FMT`` with the default ``grid`` pattern only copies the
bytes of ``I2[oy::sy, ox::sx]``: every kept row is a strided byte slice of the frame.
Doing that with ``bytes``/``memoryview`` slicing (instead of numpy) keeps the encoder
process free of numpy, numba and OpenCV, whose import dominates its run time.  The
payload is byte-identical to what :func:`stereobudget.io.write_samples` produces
from :func:`stereobudget.io.read_raw` + :func:`stereobudget.encoding.encode_image`:
values in row-major transmission order, channels interleaved, uint16 little-endian
(``gray16le`` and the ``bayer_*16le`` mosaics already are).

This module must not import numpy (checked by the tests).
"""

from __future__ import annotations

from ..errors import ImageReadError
from ._limits import dimension_problem

#: Headerless pixel formats: name -> (channels, bytes per value, channel order).  The
#: numpy view of the same table is :data:`stereobudget.io._images.RAW_PIXEL_FORMATS`.
RAW_FORMATS = {
    "gray8": (1, 1, "gray"),
    "rgb24": (3, 1, "rgb"),
    "bgr24": (3, 1, "bgr"),
    "gray16le": (1, 2, "gray"),
}
# Raw sensor mosaics: one value per pixel, its colour given by the Bayer pattern
# (stereobudget.io._mosaic); 16-bit values little-endian, as the camera delivers them.
for _pattern in ("rggb", "bggr", "grbg", "gbrg"):
    RAW_FORMATS[f"bayer_{_pattern}8"] = (1, 1, f"bayer_{_pattern}")
    RAW_FORMATS[f"bayer_{_pattern}16le"] = (1, 2, f"bayer_{_pattern}")
del _pattern


def raw_frame_layout(*, width: int, height: int, pix_fmt: str, name: str = "<bytes>"):
    """Channels, bytes per value and channel order of a ``pix_fmt`` frame; checks format and size.

    Raises
    ------
    ImageReadError
        Unknown ``pix_fmt`` or a size outside the limits.
    """
    if pix_fmt not in RAW_FORMATS:
        raise ImageReadError(f"unknown raw pixel format {pix_fmt!r}; expected one of "
                             f"{', '.join(RAW_FORMATS)}", path=name)
    problem = dimension_problem(width, height)
    if problem:
        raise ImageReadError(f"raw frame: {problem}", path=name)
    return RAW_FORMATS[pix_fmt]


def check_raw_frame(data, *, width: int, height: int, pix_fmt: str, name: str = "<bytes>"):
    """Validate one headerless frame (format, size, byte count); no pixel is read.

    Returns
    -------
    channels, value_bytes, channel_order : int, int, str

    Raises
    ------
    ImageReadError
        Unknown ``pix_fmt``, bad size, or a byte count other than one frame.
    """
    channels, value_bytes, order = raw_frame_layout(width=width, height=height, pix_fmt=pix_fmt, name=name)
    expected = width * height * channels * value_bytes
    if len(data) != expected:
        what = "less than one frame" if len(data) < expected else "more than one frame"
        raise ImageReadError(f"raw {pix_fmt} {width}x{height} frame must be exactly {expected} bytes, "
                             f"got {len(data)} ({what})", path=name)
    return channels, value_bytes, order


def grid_payload(data, *, width: int, height: int, pixel_bytes: int, stride_x: int, stride_y: int,
                 offset_x: int = 0, offset_y: int = 0) -> bytes:
    """The bytes of ``frame[oy::sy, ox::sx]`` in row-major order (pixels kept whole).

    Parameters
    ----------
    data : bytes-like
        One frame: ``height`` rows of ``width`` pixels of ``pixel_bytes`` bytes each.
    width, height, pixel_bytes : int
    stride_x, stride_y, offset_x, offset_y : int
        The grid, ``0 <= offset < stride``.

    Returns
    -------
    bytes
        ``rows * cols * pixel_bytes`` bytes, rows = ``len(range(oy, H, sy))``,
        cols = ``len(range(ox, W, sx))``.
    """
    # bytes slices (strided ones included) are plain bytes; strided memoryviews are not
    # accepted by bytes.join, so work on one bytes object (no copy when given bytes).
    view = data if type(data) is bytes else memoryview(data).cast("B").tobytes()
    row_bytes = width * pixel_bytes
    if len(view) != row_bytes * height:
        raise ValueError(f"frame has {len(view)} bytes, expected {row_bytes * height}")
    rows = range(offset_y, height, stride_y)
    cols = len(range(offset_x, width, stride_x))
    if not rows or not cols:
        return b""
    first = offset_x * pixel_bytes
    if stride_x == 1:
        # Whole rows (minus a leading offset): contiguous slices.
        return b"".join(view[r * row_bytes + first:(r + 1) * row_bytes] for r in rows)
    if pixel_bytes == 1:
        return b"".join(view[r * row_bytes + first:(r + 1) * row_bytes:stride_x] for r in rows)
    step = stride_x * pixel_bytes
    line = cols * pixel_bytes
    out = bytearray(len(rows) * line)
    at = 0
    for r in rows:
        start = r * row_bytes + first
        end = (r + 1) * row_bytes
        for c in range(pixel_bytes):
            # Byte c of every kept pixel of this row, into byte c of every output pixel.
            out[at + c:at + line:pixel_bytes] = view[start + c:end:step]
        at += line
    return bytes(out)
