"""Payload coding of the sample file (``.sbs`` 1.1): codecs of the sample values.

A 1.1 file records a codec, the number of bits kept per value and a quality (see
``docs/format.md``).  The codec's input is the *kept values*: every sample value shifted
right by ``8 * dtype_bytes - value_bits`` (dropping the low bits costs the camera nothing),
held in one byte when ``value_bits <= 8``, else two (uint16 little-endian).

* ``raw`` -- the kept values bit-packed, most significant bit first (with all bits kept:
  the 1.0 payload).
* ``deflate`` -- PNG's row filters (RFC 2083, section 6) on the lattice image, then zlib;
  stdlib only on the camera side.
* ``webp_lossless`` / ``webp`` -- WebP of the lattice image through OpenCV (8-bit only).
* ``jxl_lossless`` / ``jxl`` -- JPEG XL of the lattice image through imagecodecs
  (the optional ``[codecs]`` extra), effort 3.

The image codecs need the samples to form an image: the ``grid`` lattice
``I2[oy::sy, ox::sx]`` or the ``downsample`` block means.  Scattered patterns (jitter,
fps) may still drop bits with ``raw``.

Why JPEG XL lossless at effort 3 is what ``lossless`` means: on 27 right images at stride 5
it keeps 0.641 of the raw bytes for 2.1 ms of encoder CPU, against 0.633 / 17.4 ms for
WebP lossless, 0.728 / 0.8 ms for deflate and 0.633 / 23.3 ms for JPEG XL effort 7.
Without imagecodecs, ``lossless`` falls back to WebP lossless (OpenCV is always there).
"""

from __future__ import annotations

import zlib

from ..errors import CorruptPayloadError, OptionError

#: Codec name -> the ``codec`` byte of the 1.1 header.
CODEC_IDS = {"raw": 0, "deflate": 1, "webp_lossless": 2, "jxl_lossless": 3, "webp": 4, "jxl": 5}
CODEC_NAMES = {v: k for k, v in CODEC_IDS.items()}
#: Codecs whose decoded values differ from the kept values.
LOSSY_CODECS = frozenset({"webp", "jxl"})
#: Codecs that code the samples as an image (a lattice pattern is needed).
IMAGE_CODECS = frozenset({"deflate", "webp_lossless", "jxl_lossless", "webp", "jxl"})
#: Patterns whose values form a ``rows x cols`` image in transmission order.
LATTICE_PATTERNS = ("grid", "downsample")
#: Names ``sb-encode --codec`` accepts: the codecs plus ``lossless`` (best available).
CODEC_CHOICES = ("raw", "lossless", "deflate", "webp_lossless", "jxl_lossless", "webp", "jxl")
DEFAULT_QUALITY = 90
JXL_EFFORT = 3
#: WebP's largest image side.
WEBP_MAX_SIDE = 16383
_ZLIB_LEVEL = 9


def have_jxl() -> bool:
    """True when imagecodecs with JPEG XL support is installed."""
    try:
        import imagecodecs
    except ImportError:
        return False
    return bool(getattr(imagecodecs, "JPEGXL", None) and imagecodecs.JPEGXL.available)


def resolve_codec(name: str) -> str:
    """The codec ``name`` stands for: ``lossless`` is JPEG XL if available, else WebP lossless.

    Raises
    ------
    OptionError
        Unknown name, or ``jxl*`` without imagecodecs.
    """
    if name == "lossless":
        return "jxl_lossless" if have_jxl() else "webp_lossless"
    if name not in CODEC_IDS:
        raise OptionError(f"unknown codec {name!r}; expected one of {', '.join(CODEC_CHOICES)}")
    if name.startswith("jxl") and not have_jxl():
        raise OptionError(f"codec {name} needs imagecodecs with JPEG XL "
                          "(pip install 'stereobudget[codecs]')")
    return name


def check_coding(*, codec: str, value_bits: int, quality: int, dtype_bytes: int, pattern_kind: str,
                 channels: int) -> None:
    """OptionError when this coding cannot apply to such samples (before any work)."""
    full = 8 * dtype_bytes
    if not 1 <= value_bits <= full:
        raise OptionError(f"--bits {value_bits} must be between 1 and {full} for {full}-bit samples")
    if codec in IMAGE_CODECS and pattern_kind not in LATTICE_PATTERNS:
        raise OptionError(f"codec {codec} codes the samples as an image and needs a lattice pattern "
                          f"({' or '.join(LATTICE_PATTERNS)}), not {pattern_kind}; use --codec raw "
                          "(--bits still applies)")
    if codec.startswith("webp") and value_bits > 8:
        raise OptionError(f"codec {codec} holds 8-bit values; add --bits 8 (or fewer) for "
                          f"{full}-bit samples, or use jxl")
    if codec == "webp" and value_bits < 8:
        raise OptionError("lossy webp codes 8-bit images; --bits below 8 applies to the other codecs")
    if codec in LOSSY_CODECS and not 1 <= quality <= 100:
        raise OptionError(f"--quality {quality} must be between 1 and 100")


def keep_bits(values, *, value_bits: int):
    """The kept values: ``values >> (full - value_bits)`` in their container dtype."""
    import numpy as np

    shift = 8 * values.dtype.itemsize - value_bits
    kept = values >> shift if shift else values
    return kept.astype(np.uint8 if value_bits <= 8 else np.uint16, copy=False)


def restore_bits(kept, *, value_bits: int, dtype):
    """Full-depth values from kept values: each at the middle of its quantisation interval."""
    import numpy as np

    dtype = np.dtype(dtype)
    shift = 8 * dtype.itemsize - value_bits
    full = kept.astype(dtype)
    if shift:
        full = (full << shift) | dtype.type(1 << (shift - 1))
    return full


def values_crc32(kept) -> int:
    """CRC-32 of the kept values as container bytes (uint16 little-endian)."""
    import numpy as np

    data = np.ascontiguousarray(kept).astype(kept.dtype.newbyteorder("<"), copy=False)
    return zlib.crc32(data.view(np.uint8)) & 0xFFFFFFFF


# --- encoding (camera side) -------------------------------------------------------------------

def encode_payload(kept, *, codec: str, value_bits: int, quality: int, lattice: tuple[int, int] | None,
                   channel_order: str) -> bytes:
    """Code the kept values ``kept`` (n, channels) with ``codec``.

    Parameters
    ----------
    kept : ndarray, (n, channels), uint8 or uint16
        From :func:`keep_bits`.
    codec : str
        A key of :data:`CODEC_IDS` (resolved, see :func:`resolve_codec`).
    value_bits, quality : int
    lattice : (rows, cols), optional
        Shape of the sample image; needed by the image codecs.
    channel_order : str
        ``gray``, ``rgb`` or ``bgr`` (the codecs are told which channel is which).

    Raises
    ------
    OptionError
        The lattice is too large for the codec.
    """
    if codec == "raw":
        return pack_bits(kept.reshape(-1), value_bits)
    rows, cols = lattice
    image = kept.reshape(rows, cols, kept.shape[1])
    if codec == "deflate":
        return zlib.compress(png_filter(image), _ZLIB_LEVEL)
    if codec in ("webp", "webp_lossless"):
        return _webp_encode(image, lossless=codec == "webp_lossless", quality=quality,
                            channel_order=channel_order)
    return _jxl_encode(image, lossless=codec == "jxl_lossless", quality=quality, value_bits=value_bits,
                       channel_order=channel_order)


def pack_bits(flat, value_bits: int) -> bytes:
    """``value_bits`` bits of every value, most significant first, the last byte zero-padded."""
    import numpy as np

    if value_bits == 8 * flat.dtype.itemsize:
        return np.ascontiguousarray(flat).astype(flat.dtype.newbyteorder("<"), copy=False).tobytes()
    out = []
    step = 1 << 20   # bounded scratch: 16 bytes per value while unpacking
    # Chunks of a multiple of 8 values end on a byte boundary, so they concatenate.
    for start in range(0, flat.size, step):
        chunk = flat[start:start + step].astype(">u2").view(np.uint8).reshape(-1, 2)
        bits = np.unpackbits(chunk, axis=1)[:, 16 - value_bits:]
        out.append(np.packbits(bits.reshape(-1)).tobytes())
    return b"".join(out)


def unpack_bits(data, count: int, value_bits: int, dtype):
    """Inverse of :func:`pack_bits`: ``count`` values as ``dtype``."""
    import numpy as np

    dtype = np.dtype(dtype)
    if value_bits == 8 * dtype.itemsize:
        return np.frombuffer(data, dtype.newbyteorder("<")).astype(dtype)
    buf = np.frombuffer(data, np.uint8)
    out = np.empty(count, dtype)
    step = 1 << 20
    for start in range(0, count, step):
        n = min(step, count - start)
        first = start * value_bits // 8
        chunk = np.unpackbits(buf[first:first + -(-n * value_bits // 8)])[:n * value_bits]
        full = np.zeros((n, 16), np.uint8)
        full[:, 16 - value_bits:] = chunk.reshape(n, value_bits)
        out[start:start + n] = np.packbits(full, axis=1).view(">u2").reshape(-1)
    return out


def png_filter(image) -> bytes:
    """PNG-filtered rows of ``image`` (rows, cols, channels): a filter type byte then the row.

    Each row takes the filter (None, Sub, Up, Average, Paeth) with the smallest sum of
    absolute signed residuals, PNG's own heuristic; the bytes are the container bytes,
    uint16 little-endian, with ``bpp = channels * bytes per value``.
    """
    import numpy as np

    bpp = image.shape[2] * image.dtype.itemsize
    x = np.ascontiguousarray(image).astype(image.dtype.newbyteorder("<"), copy=False)
    x = x.view(np.uint8).reshape(image.shape[0], -1).astype(np.int16)
    a = np.zeros_like(x)
    a[:, bpp:] = x[:, :-bpp]
    b = np.zeros_like(x)
    b[1:] = x[:-1]
    c = np.zeros_like(x)
    c[1:, bpp:] = x[:-1, :-bpp]
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    paeth = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
    candidates = np.stack([x, x - a, x - b, x - (a + b) // 2, x - paeth]) & 0xFF
    signed = np.where(candidates >= 128, 256 - candidates, candidates)
    choice = signed.sum(axis=2, dtype=np.int64).argmin(axis=0)
    rows = np.arange(x.shape[0])
    out = np.empty((x.shape[0], x.shape[1] + 1), np.uint8)
    out[:, 0] = choice
    out[:, 1:] = candidates[choice, rows]
    return out.tobytes()


def _webp_encode(image, *, lossless: bool, quality: int, channel_order: str) -> bytes:
    import cv2
    import numpy as np

    rows, cols, channels = image.shape
    if max(rows, cols) > WEBP_MAX_SIDE:
        raise OptionError(f"the {cols}x{rows} sample lattice exceeds WebP's {WEBP_MAX_SIDE} pixels per side")
    bgr = image[:, :, 0] if channels == 1 else (image if channel_order == "bgr" else image[:, :, ::-1])
    ok, data = cv2.imencode(".webp", np.ascontiguousarray(bgr),
                            [cv2.IMWRITE_WEBP_QUALITY, 101 if lossless else int(quality)])
    if not ok:
        raise OptionError("OpenCV could not encode the sample lattice as WebP")
    return data.tobytes()


def _jxl_encode(image, *, lossless: bool, quality: int, value_bits: int, channel_order: str) -> bytes:
    import imagecodecs
    import numpy as np

    channels = image.shape[2]
    rgb = image[:, :, 0] if channels == 1 else (image[:, :, ::-1] if channel_order == "bgr" else image)
    options = {"effort": JXL_EFFORT}
    if value_bits not in (8, 16):
        options["bitspersample"] = value_bits
    if lossless:
        options["lossless"] = True
    else:
        options["level"] = int(quality)
    return bytes(imagecodecs.jpegxl_encode(np.ascontiguousarray(rgb), **options))


# --- decoding (host side) ----------------------------------------------------------------------

def decode_payload(data, *, codec: str, value_bits: int, count: int, channels: int,
                   lattice: tuple[int, int] | None, channel_order: str, name: str = "<bytes>"):
    """Decode a coded payload to the kept values, (count, channels) uint8/uint16.

    Raises
    ------
    CorruptPayloadError
        The payload does not decode to exactly that many values.
    """
    import numpy as np

    dtype = np.dtype(np.uint8 if value_bits <= 8 else np.uint16)
    if codec == "raw":
        return unpack_bits(data, count * channels, value_bits, dtype).reshape(count, channels)
    rows, cols = lattice
    try:
        if codec == "deflate":
            image = _inflate(data, rows=rows, cols=cols, channels=channels, dtype=dtype, name=name)
        elif codec in ("webp", "webp_lossless"):
            size = webp_size(data)
            if size != (cols, rows):
                # Checked before decoding: the decoder would allocate what the stream claims.
                raise CorruptPayloadError(f"{codec} payload is {'not a WebP image' if size is None else 'a %dx%d image' % size}"
                                          f", expected the {cols}x{rows} lattice", path=name)
            image = _webp_decode(data, channels=channels, channel_order=channel_order)
        else:
            image = _jxl_decode(data, rows=rows, cols=cols, channels=channels, dtype=dtype,
                                channel_order=channel_order)
    except CorruptPayloadError:
        raise
    except (ImportError, ModuleNotFoundError):
        raise
    except Exception as exc:   # noqa: BLE001 -- the libraries' error classes vary
        raise CorruptPayloadError(f"{codec} payload does not decode: {exc}", path=name) from None
    if image is None or image.ndim != 3 or image.shape != (rows, cols, channels) or image.dtype != dtype:
        got = "nothing" if image is None else f"{image.shape} {image.dtype}"
        raise CorruptPayloadError(f"{codec} payload decodes to {got}, expected the "
                                  f"{cols}x{rows} lattice of {channels} x {dtype}", path=name)
    if value_bits < 8 * dtype.itemsize and int(image.max(initial=0)) >> value_bits:
        raise CorruptPayloadError(f"{codec} payload holds values beyond {value_bits} bits", path=name)
    return np.ascontiguousarray(image).reshape(count, channels)


def _inflate(data, *, rows: int, cols: int, channels: int, dtype, name: str):
    import numpy as np
    from ._pngfilter import unfilter_rows

    line = cols * channels * dtype.itemsize
    expected = rows * (line + 1)
    inflater = zlib.decompressobj()
    try:
        # max_length bounds the memory a hostile stream can make us allocate.
        raw = inflater.decompress(bytes(data), expected + 1)
    except zlib.error as exc:
        raise CorruptPayloadError(f"deflate payload does not inflate: {exc}", path=name) from None
    if len(raw) != expected or not inflater.eof or inflater.unused_data:
        raise CorruptPayloadError(f"deflate payload inflates to {len(raw)}{'+' if not inflater.eof else ''} "
                                  f"bytes, expected {expected}", path=name)
    out = np.empty((rows, line), np.uint8)
    bad_row = unfilter_rows(np.frombuffer(raw, np.uint8), out, channels * dtype.itemsize)
    if bad_row >= 0:
        raise CorruptPayloadError(f"deflate payload row {bad_row} has an unknown filter type", path=name)
    return out.view(dtype.newbyteorder("<")).astype(dtype).reshape(rows, cols, channels)


def _webp_decode(data, *, channels: int, channel_order: str):
    import cv2
    import numpy as np

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim != 3 or image.shape[2] != 3:
        return image
    if channels == 1:
        return image[:, :, 1:2]    # gray was sent as equal B, G, R
    return image if channel_order == "bgr" else image[:, :, ::-1]


def webp_size(data) -> tuple[int, int] | None:
    """(width, height) a WebP stream declares (simple lossy, lossless or extended), else None."""
    b = bytes(data[:30])
    if len(b) < 30 or b[:4] != b"RIFF" or b[8:12] != b"WEBP":
        return None
    chunk = b[12:16]
    if chunk == b"VP8 " and b[23:26] == b"\x9d\x01\x2a":
        return int.from_bytes(b[26:28], "little") & 0x3FFF, int.from_bytes(b[28:30], "little") & 0x3FFF
    if chunk == b"VP8L" and b[20] == 0x2F:
        bits = int.from_bytes(b[21:25], "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if chunk == b"VP8X":
        return int.from_bytes(b[24:27], "little") + 1, int.from_bytes(b[27:30], "little") + 1
    return None


def _jxl_decode(data, *, rows: int, cols: int, channels: int, dtype, channel_order: str):
    import imagecodecs
    import numpy as np

    # Into an array of the expected lattice: the decoder refuses another size or type
    # from the stream's header, before allocating what a damaged stream may claim.
    out = np.empty((rows, cols) if channels == 1 else (rows, cols, channels), dtype)
    image = imagecodecs.jpegxl_decode(bytes(data), out=out)
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim == 3 and image.shape[2] == 3 and channel_order == "bgr":
        image = image[:, :, ::-1]
    return image
