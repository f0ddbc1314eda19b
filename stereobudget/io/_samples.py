"""The sample container: what the right camera sends (in memory: :class:`SampleSet`).

The binary ``.sbs`` encoding of a :class:`SampleSet` is specified in ``docs/format.md``
and implemented by :func:`write_samples` / :func:`read_samples` / :func:`probe`
(files: :func:`save_samples` / :func:`load_samples`).  Selecting the samples and the
camera-side job (read, select, code, write) are :mod:`stereobudget.encoding`'s.

numpy is imported inside the functions that need it, never at module level: a raw
frame on a ``grid`` (``sb-encode --raw``) is encoded by :mod:`stereobudget.io._rawgrid` with
bytes slicing, and ``probe`` (``sb-encode --info``) checks files without numpy, so the
camera-side process starts without loading it.
"""

from __future__ import annotations

import logging
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

from ._atomic import STDIO, display_name, read_input_bytes, reading_error, write_output_bytes
from ..errors import (CorruptHeaderError, CorruptPayloadError, NotASampleFileError, TruncatedFileError,
                     UnsupportedVersionError)
from ._limits import dimension_problem
from ._mosaic import MOSAIC_ORDERS, mosaic_of
from ._codecs import (CODEC_IDS, CODEC_NAMES, DEFAULT_QUALITY, IMAGE_CODECS, LATTICE_PATTERNS, LOSSY_CODECS,
                      check_coding, resolve_codec)
from ..sampling._patterns import SamplingPattern, sample_count, sample_positions, grid_shape

log = logging.getLogger("stereobudget")

#: gray, colour, and raw Bayer mosaics (one value per sample, its colour set by its position).
CHANNEL_ORDERS = ("gray", "rgb", "bgr") + MOSAIC_ORDERS


def channel_count(channel_order: str) -> int:
    """Values per sample of a channel order: 3 for ``rgb`` / ``bgr``, 1 for gray and mosaics."""
    return 3 if channel_order in ("rgb", "bgr") else 1


@dataclass(frozen=True, eq=False)
class SampleSet:
    """Samples of the right image and everything needed to place them.

    Attributes
    ----------
    height, width : int
        Size of the full right image I2.
    channel_order : str
        ``"gray"`` (1 channel), ``"rgb"`` or ``"bgr"`` (3 channels), or a raw Bayer mosaic
        ``"bayer_rggb"``, ``"bayer_bggr"``, ``"bayer_grbg"``, ``"bayer_gbrg"`` (1 value per
        sample, the colour of the sample's pixel in the mosaic: :meth:`sample_colours`).
    pattern : SamplingPattern
        Where the samples lie.
    values : ndarray, shape (n, channels), uint8 or uint16
        Sample values in transmission order (see :func:`stereobudget.sampling.sample_positions`).
    codec : str
        Payload codec the values came through (``raw`` unless read from a coded file).
    value_bits : int, optional
        Bits per value the camera kept (None = all): dropped bits come back as the
        middle of their interval, so each value is within ``2 ** (full - value_bits - 1)``.
    quality : int
        Quality of a lossy codec (0 otherwise).
    """

    height: int
    width: int
    channel_order: str
    pattern: SamplingPattern
    values: np.ndarray
    codec: str = "raw"
    value_bits: int | None = None
    quality: int = 0

    def __post_init__(self):
        if self.channel_order not in CHANNEL_ORDERS:
            raise ValueError(f"channel_order must be one of {CHANNEL_ORDERS}, got {self.channel_order!r}")
        import numpy as np

        v = self.values
        if v.ndim != 2 or v.shape[1] != self.channels:
            raise ValueError(f"values must have shape (n, {self.channels}), got {v.shape}")
        if v.dtype not in (np.uint8, np.uint16):
            raise ValueError(f"values must be uint8 or uint16, got {v.dtype}")
        if self.mosaic and self.pattern.kind == "downsample":
            raise ValueError("a raw mosaic cannot be block-averaged (downsample would mix its colours)")
        n = sample_count(self.pattern, self.height, self.width)
        if v.shape[0] != n:
            raise ValueError(f"pattern {self.pattern.kind} on {self.width}x{self.height} has {n} samples, "
                             f"values has {v.shape[0]}")

    @property
    def channels(self) -> int:
        """Values per sample."""
        return channel_count(self.channel_order)

    @property
    def mosaic(self) -> str | None:
        """Bayer pattern of a raw-mosaic sample set (``"rggb"`` ...), None otherwise."""
        return mosaic_of(self.channel_order)

    @property
    def colour_channels(self) -> int:
        """Channels of the left image the samples are compared with (3 for a mosaic)."""
        return 3 if self.mosaic else self.channels

    def sample_colours(self):
        """RGB channel index (int64 (n,), 0 R 1 G 2 B) of every sample of a mosaic, in transmission order."""
        from ._mosaic import sample_colours
        if not self.mosaic:
            raise ValueError(f"channel order {self.channel_order!r} is not a mosaic")
        rows, cols = self.positions()
        return sample_colours(self.channel_order, rows, cols)

    @property
    def exact(self) -> bool:
        """True when the values are the camera's pixels bit for bit (no lossy coding, all bits)."""
        return self.codec not in LOSSY_CODECS and self.value_bits in (None, 8 * self.values.dtype.itemsize)

    @property
    def lossy(self) -> bool:
        """True when a lossy codec (not just dropped bits) coded the values."""
        return self.codec in LOSSY_CODECS

    @property
    def dtype(self) -> np.dtype:
        return self.values.dtype

    @property
    def epsilon(self) -> float:
        """Fraction of I2's pixels that were sent (n / (H W))."""
        return self.values.shape[0] / float(self.height * self.width)

    def positions(self):
        """(rows, cols) of every sample, in transmission order.

        ``adaptive_fps`` positions are regenerated from the values; ``downsample`` gives
        the centre pixel of each block.
        """
        return sample_positions(self.pattern, self.height, self.width, values=self.values)

    def values_rgb(self) -> np.ndarray:
        """Sample values as (n, channels) with colour in RGB order (gray stays 1 channel)."""
        return self.values[:, ::-1] if self.channel_order == "bgr" else self.values

    def grid_values(self) -> np.ndarray:
        """Values of a ``grid`` pattern as a (rows, cols, channels) lattice ``I2[oy::sy, ox::sx]``."""
        if not self.pattern.is_regular_grid:
            raise ValueError(f"pattern {self.pattern.kind!r} is not a regular grid")
        r, c = grid_shape(self.pattern, self.height, self.width)
        return self.values.reshape(r, c, self.channels)


# =====================================================================================
# The binary sample file (.sbs), version 1.0 -- specified in docs/format.md
# =====================================================================================

#: PNG-style signature: a non-ASCII first byte, CR-LF, Ctrl-Z and LF catch 7-bit and
#: text-mode transfers (see docs/format.md).
MAGIC = b"\x89SBS\r\n\x1a\n"
VERSION_MAJOR = 1
#: Newest minor version written: 1.1 adds payload coding (raw full-depth files stay 1.0),
#: 1.2 the raw Bayer mosaics (channel orders 3-6; every other file is written as before).
VERSION_MINOR = 2
#: First minor version with the mosaic channel orders.
MOSAIC_MINOR = 2
#: Size of the version-1.0 header, in bytes; later 1.x headers may be longer.
HEADER_SIZE_V1_0 = 80
#: Largest header_length a reader accepts (the field is a u16).
MAX_HEADER_LENGTH = 0xFFFF

# Fields of the 1.0 header after the magic, little-endian, in file order (offset 8..75);
# the header CRC-32 is always the *last* four bytes of the header (offset header_length-4).
_FIELDS = struct.Struct("<BBHIIBBBBHHHHQ16sQQI")
_FIELD_NAMES = ("version_major", "version_minor", "header_length", "width", "height",
                "channels", "channel_order_code", "dtype_code", "pattern_code",
                "stride_x", "stride_y", "offset_x", "offset_y", "seed", "pattern_reserved",
                "sample_count", "payload_length", "payload_crc32")
assert len(MAGIC) + _FIELDS.size + 4 == HEADER_SIZE_V1_0
# 1.1: pattern_reserved holds codec, value_bits (0 = all), quality, a zero byte, the CRC-32
# of the kept values (0 = none: lossy codecs) and 8 zero bytes.
_CODING = struct.Struct("<BBBBI8s")
assert _CODING.size == 16

CHANNEL_ORDER_CODES = {"gray": 0, "rgb": 1, "bgr": 2,
                       "bayer_rggb": 3, "bayer_bggr": 4, "bayer_grbg": 5, "bayer_gbrg": 6}
#: dtype code == bytes per value: 1 = uint8, 2 = uint16 little-endian.  (``DTYPE_CODES``,
#: the same table keyed by numpy dtypes, is built on first access: see ``__getattr__``.)
_DTYPE_NAMES = {1: "uint8", 2: "uint16"}
_DTYPE_CODE_BY_NAME = {v: k for k, v in _DTYPE_NAMES.items()}
PATTERN_CODES = {"grid": 0, "jitter": 1, "fps": 2, "adaptive_fps": 3, "downsample": 4}
_PATTERN_BY_CODE = {v: k for k, v in PATTERN_CODES.items()}
_ORDER_BY_CODE = {v: k for k, v in CHANNEL_ORDER_CODES.items()}

# Text-mode / 7-bit transfer damage to the signature, with the explanation we give.
_MANGLED_MAGIC = (
    (b"\x89SBS\n\x1a\n", "CR-LF was turned into LF: the file went through a text-mode transfer "
                         "(FTP ASCII mode, git autocrlf, a text editor); copy it in binary mode"),
    (b"\x89SBS\r\r\n", "LF was turned into CR-LF: the file went through a text-mode transfer "
                       "(FTP ASCII mode, git autocrlf, Windows text I/O); copy it in binary mode"),
    (b"\x09SBS\r\n\x1a\n", "the high bit of the first byte was cleared: the file went through a "
                           "7-bit channel; copy it in binary mode"),
    (b"\xc2\x89SBS", "the file was re-encoded as UTF-8 text; copy it in binary mode"),
    (b"\xef\xbf\xbdSBS", "the file was decoded and re-encoded as text (U+FFFD replacement); "
                         "copy it in binary mode"),
)
_MAX_U64 = 2 ** 64 - 1


def __getattr__(name):
    # Public numpy-keyed table, built lazily so that importing this module needs no numpy.
    if name == "DTYPE_CODES":
        import numpy as np
        table = {np.dtype(np.uint8): 1, np.dtype(np.uint16): 2}
        globals()["DTYPE_CODES"] = table
        return table
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _crc32(data) -> int:
    return zlib.crc32(data) & 0xFFFFFFFF


def write_samples(sample_set: SampleSet, *, codec: str = "raw", value_bits: int | None = None,
                  quality: int | None = None) -> bytes:
    """Serialise a :class:`SampleSet` to the ``.sbs`` format.

    Raw full-depth values give a version-1.0 file; any other coding a 1.1 file.  A coded
    payload that is not shorter than the raw one is written raw instead (with the same
    ``value_bits``), so coding never costs bytes.

    Parameters
    ----------
    sample_set : SampleSet
    codec : str
        ``raw`` (default, no computation), ``lossless`` (the best lossless codec
        installed), ``deflate``, ``webp_lossless``, ``jxl_lossless``, ``webp`` or ``jxl``
        (see :mod:`stereobudget.io._codecs`).
    value_bits : int, optional
        Keep only the top ``value_bits`` bits of every value (None = all).
    quality : int, optional
        Quality 1..100 of a lossy codec (default 90).

    Returns
    -------
    bytes
        An 80-byte header followed by the payload.

    Raises
    ------
    ValueError
        The sample set does not fit the format (size beyond the limits, stride or
        offset beyond 65535, seed outside ``[0, 2**64)``).
    OptionError
        A coding that does not apply to these samples (an image codec on scattered
        samples, WebP on more than 8 bits...).
    """
    return _coded_file(sample_set, codec=codec, value_bits=value_bits, quality=quality)[0]


def _coded_file(ss: SampleSet, *, codec: str, value_bits: int | None, quality: int | None):
    """(file bytes, codec written, value_bits written, quality written) of :func:`write_samples`."""
    import numpy as np

    from ._codecs import encode_payload, keep_bits, pack_bits, values_crc32

    _check_writable(ss.width, ss.height, ss.pattern)
    full = 8 * ss.values.dtype.itemsize
    bits = full if value_bits is None else int(value_bits)
    codec = resolve_codec(codec)
    lossy = codec in LOSSY_CODECS
    quality = (DEFAULT_QUALITY if quality is None else int(quality)) if lossy else 0
    check_coding(codec=codec, value_bits=bits, quality=quality, dtype_bytes=ss.values.dtype.itemsize,
                 pattern_kind=ss.pattern.kind, channels=ss.channels)
    dtype_code = _DTYPE_CODE_BY_NAME[ss.values.dtype.name]
    n = ss.values.shape[0]
    if codec == "raw" and bits == full:
        payload = np.ascontiguousarray(ss.values).astype(ss.values.dtype.newbyteorder("<"),
                                                         copy=False).tobytes()
        return (_pack_file(width=ss.width, height=ss.height, channel_order=ss.channel_order,
                           dtype_code=dtype_code, pattern=ss.pattern, sample_count=n, payload=payload),
                "raw", bits, 0)
    kept = keep_bits(ss.values, value_bits=bits)
    lattice = grid_shape(ss.pattern, ss.height, ss.width) if codec in IMAGE_CODECS else None
    payload = encode_payload(kept, codec=codec, value_bits=bits, quality=quality, lattice=lattice,
                             channel_order=ss.channel_order)
    raw_length = -(-n * ss.channels * bits // 8)
    if codec != "raw" and len(payload) >= raw_length:
        log.debug("%s payload (%d bytes) is not shorter than raw (%d): writing raw", codec,
                  len(payload), raw_length)
        if bits == full:
            return _coded_file(ss, codec="raw", value_bits=None, quality=None)
        codec, quality, payload = "raw", 0, pack_bits(kept.reshape(-1), bits)
        lossy = False
    coding = _CODING.pack(CODEC_IDS[codec], 0 if bits == full else bits, quality, 0,
                          0 if lossy else values_crc32(kept), bytes(8))
    return (_pack_file(width=ss.width, height=ss.height, channel_order=ss.channel_order,
                       dtype_code=dtype_code, pattern=ss.pattern, sample_count=n, payload=payload,
                       minor=1, coding=coding),
            codec, bits, quality)


def _check_writable(width: int, height: int, p: SamplingPattern) -> None:
    """ValueError when the size or the pattern's fields do not fit the 1.0 header."""
    problem = dimension_problem(width, height)
    if problem:
        raise ValueError(problem)
    for label, value in (("stride_x", p.stride_x), ("stride_y", p.stride_y),
                         ("offset_x", p.offset_x), ("offset_y", p.offset_y)):
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"{label}={value} does not fit the format (0..65535)")
    if not 0 <= p.seed <= _MAX_U64:
        raise ValueError(f"seed={p.seed} does not fit the format (0..2**64-1)")


def _pack_file(*, width: int, height: int, channel_order: str, dtype_code: int, pattern: SamplingPattern,
               sample_count: int, payload: bytes, minor: int = 0, coding: bytes = bytes(16)) -> bytes:
    """Header + ``payload`` (already in file byte order): the whole file, numpy-free.

    ``minor`` 0 is a 1.0 file; 1.1 puts the 16 ``coding`` bytes in ``pattern_reserved``;
    a mosaic is always written as 1.2 (its channel order is unknown before).
    """
    p = pattern
    channels = channel_count(channel_order)
    if mosaic_of(channel_order):
        minor = max(minor, MOSAIC_MINOR)
    fields = _FIELDS.pack(
        VERSION_MAJOR, minor, HEADER_SIZE_V1_0, width, height,
        channels, CHANNEL_ORDER_CODES[channel_order], dtype_code,
        PATTERN_CODES[p.kind], p.stride_x, p.stride_y, p.offset_x, p.offset_y, p.seed,
        coding, sample_count, len(payload), _crc32(payload))
    head = MAGIC + fields
    return head + struct.pack("<I", _crc32(head)) + payload


def _check_magic(data, name: str) -> None:
    head = bytes(data[:len(MAGIC)])
    if head == MAGIC:
        return
    for mangled, why in _MANGLED_MAGIC:
        if bytes(data[:len(mangled)]) == mangled:
            raise NotASampleFileError(f"damaged .sbs signature: {why}", path=name)
    if len(data) == 0:
        raise TruncatedFileError("empty file (0 bytes)", path=name)
    if MAGIC.startswith(head):
        return      # a prefix of a valid signature: the caller reports the truncation
    kind = _guess_kind(bytes(data[:16]))
    raise NotASampleFileError(
        f"not a stereobudget sample file (no .sbs signature{'; it looks like ' + kind if kind else ''})",
        path=name)


def _guess_kind(head: bytes) -> str | None:
    signatures = ((b"\x89PNG", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"),
                  (b"II*\x00", "a TIFF image"), (b"MM\x00*", "a TIFF image"), (b"BM", "a BMP image"),
                  (b"\x93NUMPY", "a .npy array"), (b"PK\x03\x04", "a zip archive"),
                  (b"\x1f\x8b", "a gzip file"), (b"Pf", "a PFM image"), (b"PF", "a PFM image"))
    for sig, kind in signatures:
        if head.startswith(sig):
            return kind
    if head[:2] in (b"P5", b"P6", b"P2", b"P3"):
        return "a PGM/PPM image"
    return None


def _parse_header(data, name: str, *, file_size: int | None = None) -> dict:
    """Validate everything up to the payload; return the header fields.

    ``data`` holds at least the header (or the whole file); ``file_size`` is the real
    size when ``data`` is only a prefix.  Steps and errors in order: fixed-header length
    (Truncated), magic (NotASampleFile), major version (UnsupportedVersion), header
    CRC (CorruptHeader), field values (CorruptHeader), payload length vs header
    (CorruptPayload), payload length vs file size (Truncated / CorruptPayload).
    """
    size = len(data) if file_size is None else file_size
    _check_magic(data, name)
    # The version comes before the length check: another major version may have a
    # shorter header, and "unsupported version" is the useful message then.
    if len(data) >= len(MAGIC) + 2 and data[len(MAGIC)] != VERSION_MAJOR:
        major, minor = data[len(MAGIC)], data[len(MAGIC) + 1]
        raise UnsupportedVersionError(
            f"format version {major}.{minor} is not supported (this reader understands "
            f"{VERSION_MAJOR}.x); upgrade stereobudget", path=name)
    if len(data) < HEADER_SIZE_V1_0:
        raise TruncatedFileError(f"file ends inside the header ({size} of at least "
                                 f"{HEADER_SIZE_V1_0} bytes)", path=name)
    fields = dict(zip(_FIELD_NAMES, _FIELDS.unpack_from(data, len(MAGIC))))
    minor = fields["version_minor"]
    header_length = fields["header_length"]
    if minor == 0 and header_length != HEADER_SIZE_V1_0:
        raise CorruptHeaderError(f"header length {header_length} is wrong for format 1.0 "
                                 f"(must be {HEADER_SIZE_V1_0})", path=name)
    if header_length < HEADER_SIZE_V1_0:
        raise CorruptHeaderError(f"header length {header_length} is shorter than the "
                                 f"{HEADER_SIZE_V1_0} bytes of format 1.0", path=name)
    if len(data) < header_length:
        raise TruncatedFileError(f"file ends inside the header ({size} of {header_length} bytes)",
                                 path=name)
    stored_crc = struct.unpack_from("<I", data, header_length - 4)[0]
    actual_crc = _crc32(data[:header_length - 4])
    if stored_crc != actual_crc:
        raise CorruptHeaderError(f"header checksum mismatch (stored {stored_crc:08x}, computed "
                                 f"{actual_crc:08x}): the header is damaged", path=name)
    fields["header_crc32"] = stored_crc
    _check_fields(fields, name)
    _parse_coding(fields, name)
    n = fields["sample_count"]
    full = 8 * fields["dtype_code"]
    declared = fields["payload_length"]
    if fields["codec"] == "raw":
        bits = fields["value_bits"]
        expected_payload = -(-n * fields["channels"] * bits // 8)
        if declared != expected_payload:
            per_value = f"{fields['dtype_code']} byte(s)" if bits == full else f"{bits} bit(s)"
            raise CorruptPayloadError(
                f"header declares a {declared}-byte payload but {n} samples x {fields['channels']} "
                f"channel(s) x {per_value} = {expected_payload} bytes", path=name)
    else:
        raw_payload = n * fields["channels"] * fields["dtype_code"]
        if not 0 < declared < raw_payload:
            raise CorruptPayloadError(
                f"header declares a {declared}-byte {fields['codec']} payload; a coded payload is "
                f"shorter than the {raw_payload} raw bytes and not empty", path=name)
    actual_payload = size - header_length
    if actual_payload < declared:
        raise TruncatedFileError(f"file is truncated: payload has {actual_payload} of {declared} bytes "
                                 f"({declared - actual_payload} missing)", path=name)
    if actual_payload > declared:
        end = header_length + declared
        if bytes(data[end:end + len(MAGIC)]) == MAGIC:
            raise CorruptPayloadError(f"another .sbs frame follows the first one at byte {end}: this is a "
                                      "stream of frames; sb-decode takes it with {index} in the output names "
                                      "or an output on '-' (docs/cli.md, \"Frame streams\")", path=name)
        raise CorruptPayloadError(f"{actual_payload - declared} unexpected bytes after the "
                                  f"{declared}-byte payload", path=name)
    fields["file_size"] = size
    return fields


def _check_fields(f: dict, name: str) -> None:
    def bad(message):
        raise CorruptHeaderError(message, path=name)

    problem = dimension_problem(f["width"], f["height"])
    if problem:
        bad(problem)
    if f["channel_order_code"] not in _ORDER_BY_CODE:
        bad(f"unknown channel order code {f['channel_order_code']}")
    order = _ORDER_BY_CODE[f["channel_order_code"]]
    if f["channels"] != channel_count(order):
        bad(f"{f['channels']} channel(s) do not match channel order {order!r}")
    if mosaic_of(order) and f["version_minor"] < MOSAIC_MINOR:
        bad(f"channel order {order!r} (code {f['channel_order_code']}) needs format "
            f"1.{MOSAIC_MINOR}, the header says 1.{f['version_minor']}")
    if f["dtype_code"] not in _DTYPE_NAMES:
        bad(f"unknown sample dtype code {f['dtype_code']}")
    if f["pattern_code"] not in _PATTERN_BY_CODE:
        bad(f"unknown sampling pattern code {f['pattern_code']}")
    if mosaic_of(order) and _PATTERN_BY_CODE[f["pattern_code"]] == "downsample":
        bad(f"a {order} mosaic cannot use the downsample pattern (block means would mix its colours)")
    if f["stride_x"] < 1 or f["stride_y"] < 1:
        bad(f"stride {f['stride_x']}x{f['stride_y']} must be >= 1")
    if f["offset_x"] >= f["stride_x"] or f["offset_y"] >= f["stride_y"]:
        bad(f"offset ({f['offset_x']},{f['offset_y']}) must be smaller than the stride "
            f"({f['stride_x']},{f['stride_y']})")
    expected = sample_count(_pattern_from_fields(f), f["height"], f["width"])
    if f["sample_count"] != expected:
        bad(f"sample count {f['sample_count']} does not match pattern "
            f"{_PATTERN_BY_CODE[f['pattern_code']]} on {f['width']}x{f['height']} "
            f"({expected} samples)")


def _parse_coding(f: dict, name: str) -> None:
    """Add ``codec``, ``value_bits`` (resolved: 0 = all), ``quality``, ``values_crc32`` to ``f``.

    A 1.0 file is raw at full depth whatever its reserved bytes hold; 1.1 and later read
    them (an all-zero block is raw at full depth too).
    """
    full = 8 * f["dtype_code"]
    if f["version_minor"] == 0:
        f.update(codec="raw", value_bits=full, quality=0, values_crc32=0)
        return
    codec_id, bits, quality, _, crc, _ = _CODING.unpack(f["pattern_reserved"])
    if codec_id not in CODEC_NAMES:
        raise UnsupportedVersionError(f"payload codec {codec_id} is not supported (this reader knows "
                                      f"{', '.join(f'{v} = {k}' for k, v in CODEC_IDS.items())}); "
                                      "upgrade stereobudget", path=name)
    codec = CODEC_NAMES[codec_id]
    bits = bits or full
    if bits > full:
        raise CorruptHeaderError(f"value_bits {bits} exceeds the {full} bits of the samples", path=name)
    if codec in IMAGE_CODECS and _PATTERN_BY_CODE[f["pattern_code"]] not in LATTICE_PATTERNS:
        raise CorruptHeaderError(f"codec {codec} needs a lattice pattern, not "
                                 f"{_PATTERN_BY_CODE[f['pattern_code']]}", path=name)
    if codec.startswith("webp") and bits > 8:
        raise CorruptHeaderError(f"codec {codec} cannot hold {bits}-bit values", path=name)
    if (codec in LOSSY_CODECS) != (1 <= quality <= 100) or quality > 100:
        raise CorruptHeaderError(f"quality {quality} is invalid for codec {codec} (1..100 for a "
                                 "lossy codec, 0 otherwise)", path=name)
    f.update(codec=codec, value_bits=bits, quality=quality, values_crc32=crc)


def _pattern_from_fields(f: dict) -> SamplingPattern:
    return SamplingPattern(kind=_PATTERN_BY_CODE[f["pattern_code"]], stride_x=f["stride_x"],
                           stride_y=f["stride_y"], offset_x=f["offset_x"], offset_y=f["offset_y"],
                           seed=f["seed"])


def read_samples(data, *, source: str = "<bytes>") -> SampleSet:
    """Parse and fully validate ``.sbs`` bytes.

    Parameters
    ----------
    data : bytes-like
        The whole file.
    source : str
        Name used in error messages.

    Returns
    -------
    SampleSet

    Raises
    ------
    TruncatedFileError, NotASampleFileError, UnsupportedVersionError,
    CorruptHeaderError, CorruptPayloadError
        One class per validation step, in the order of ``docs/format.md``.
    """
    import numpy as np

    view = memoryview(data).cast("B")
    fields, payload = _validate_file(view, source)
    dtype = np.dtype("<u1" if fields["dtype_code"] == 1 else "<u2")
    order = _ORDER_BY_CODE[fields["channel_order_code"]]
    pattern = _pattern_from_fields(fields)
    codec, bits, full = fields["codec"], fields["value_bits"], 8 * fields["dtype_code"]
    if codec == "raw" and bits == full:
        values = np.frombuffer(payload, dtype=dtype).astype(dtype.newbyteorder("="))  # a writable copy
        values = values.reshape(fields["sample_count"], fields["channels"])
    else:
        values = _decode_values(fields, payload, pattern=pattern, channel_order=order, name=source)
    return SampleSet(height=fields["height"], width=fields["width"], channel_order=order,
                     pattern=pattern, values=values, codec=codec,
                     value_bits=None if bits == full else bits, quality=fields["quality"])


def _decode_values(fields: dict, payload, *, pattern: SamplingPattern, channel_order: str, name: str):
    """Full-depth values of a coded payload; CorruptPayloadError when it does not decode."""
    from ._codecs import decode_payload, have_jxl, restore_bits, values_crc32

    codec, bits = fields["codec"], fields["value_bits"]
    if codec.startswith("jxl") and not have_jxl():
        raise UnsupportedVersionError(f"the payload is JPEG XL ({codec}); decoding it needs imagecodecs "
                                      "(pip install 'stereobudget[codecs]')", path=name)
    lattice = grid_shape(pattern, fields["height"], fields["width"]) if codec in IMAGE_CODECS else None
    kept = decode_payload(payload, codec=codec, value_bits=bits, count=fields["sample_count"],
                          channels=fields["channels"], lattice=lattice, channel_order=channel_order,
                          name=name)
    stored = fields["values_crc32"]
    if stored and codec not in LOSSY_CODECS:
        actual = values_crc32(kept)
        if actual != stored:
            raise CorruptPayloadError(f"decoded sample values do not match their checksum (stored "
                                      f"{stored:08x}, computed {actual:08x})", path=name)
    return restore_bits(kept, value_bits=bits, dtype="u1" if fields["dtype_code"] == 1 else "u2")


def _validate_file(view: memoryview, source: str):
    """Every check of :func:`read_samples` (header, size, payload CRC); (fields, payload view)."""
    fields = _parse_header(view, source)
    payload = view[fields["header_length"]:]
    stored, actual = fields["payload_crc32"], _crc32(payload)
    if stored != actual:
        raise CorruptPayloadError(f"payload checksum mismatch (stored {stored:08x}, computed "
                                  f"{actual:08x}): sample values are damaged", path=source)
    return fields, payload


def save_samples(sample_set: SampleSet, path, *, overwrite: bool = False) -> int:
    """Write ``sample_set`` to ``path`` atomically (``-`` = standard output).

    Returns
    -------
    int
        Number of bytes written.

    Raises
    ------
    OutputError
        ``path`` exists without ``overwrite``, or cannot be written.
    """
    data = write_samples(sample_set)
    write_output_bytes(path, data, overwrite=overwrite)
    return len(data)


def load_samples(path) -> SampleSet:
    """Read and validate the sample file ``path`` (``-`` = standard input).

    Raises
    ------
    SampleFileError
        The subclass naming the first problem found (see :func:`read_samples`); a
        missing or unreadable file raises :class:`NotASampleFileError`.
    """
    data = read_input_bytes(path, error=NotASampleFileError)
    return read_samples(data, source=display_name(path))


def header_dict(fields: dict) -> dict:
    """JSON-able description of a parsed header (what ``sb-encode --info`` prints)."""
    f = fields
    n, w, h = f["sample_count"], f["width"], f["height"]
    return {
        "format": "sbs",
        "version": f"{f['version_major']}.{f['version_minor']}",
        "version_major": f["version_major"],
        "version_minor": f["version_minor"],
        "header_length": f["header_length"],
        "width": w,
        "height": h,
        "channels": f["channels"],
        "channel_order": _ORDER_BY_CODE[f["channel_order_code"]],
        "dtype": _DTYPE_NAMES[f["dtype_code"]],
        "pattern": _PATTERN_BY_CODE[f["pattern_code"]],
        "stride_x": f["stride_x"],
        "stride_y": f["stride_y"],
        "offset_x": f["offset_x"],
        "offset_y": f["offset_y"],
        "seed": f["seed"],
        "sample_count": n,
        "payload_length": f["payload_length"],
        "payload_crc32": f"{f['payload_crc32']:08x}",
        "header_crc32": f"{f['header_crc32']:08x}",
        "epsilon": n / float(w * h),
        "file_size": f["file_size"],
        "codec": f["codec"],
        "value_bits": f["value_bits"],
        "quality": f["quality"],
        "bits_per_pixel": 8.0 * (f["header_length"] + f["payload_length"]) / float(w * h),
    }


def probe(source, *, verify_payload: bool = False, decode_payload: bool = False, name: str | None = None) -> dict:
    """Validate a sample file's header (and optionally payload) without decoding values.

    Parameters
    ----------
    source : bytes-like, str or os.PathLike
        The file contents, a path, or ``-`` for standard input.  For a path only the
        header is read (plus the payload when ``verify_payload`` or ``decode_payload``).
    verify_payload : bool
        Also check the payload CRC-32 (the container's checksum of the coded bytes).
    decode_payload : bool
        Also decode the payload and check the decoded values exactly as
        :func:`read_samples` does (a codec this install lacks, a payload that does not
        decode, values that do not match their checksum are errors).
    name : str, optional
        Name used in messages.

    Returns
    -------
    dict
        Every header field, ``epsilon`` (samples / pixels), ``file_size`` and
        ``payload_verified``: true only when the payload was decoded (``decode_payload``);
        JSON-able.  The size of the file is always checked against the header.

    Raises
    ------
    SampleFileError
        As :func:`read_samples`.
    """
    verify_payload = verify_payload or decode_payload
    if isinstance(source, (bytes, bytearray, memoryview)) or str(source) == STDIO:
        if not isinstance(source, (bytes, bytearray, memoryview)):
            name = name or display_name(source)
            source = read_input_bytes(source, error=NotASampleFileError)
        name = name or "<bytes>"
        view = memoryview(source).cast("B")
        if verify_payload:
            info = header_dict(_validate_file(view, name)[0])
        else:
            info = header_dict(_parse_header(view, name))
        if decode_payload:
            read_samples(view, source=name)
        info["payload_verified"] = decode_payload
        return info
    name = name or str(source)
    path = Path(source)
    if verify_payload:
        data = read_input_bytes(path, error=NotASampleFileError)
        return probe(data, verify_payload=True, decode_payload=decode_payload, name=name)
    try:
        with open(path, "rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            head = handle.read(MAX_HEADER_LENGTH)
    except OSError as exc:
        raise reading_error(exc, NotASampleFileError, name) from None
    info = header_dict(_parse_header(memoryview(head), name, file_size=size))
    info["payload_verified"] = False
    return info
