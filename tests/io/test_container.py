"""The .sbs sample file: round trips, the spec in docs/format.md, and every corruption class."""

from __future__ import annotations

import json
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stereobudget import io as sbio
from stereobudget import encoding as sbenc
from stereobudget.io import (HEADER_SIZE_V1_0, MAGIC, SampleSet, load_samples, probe, read_samples, save_samples,
                             write_samples)
from stereobudget.encoding import encode_image
from stereobudget.errors import (CorruptHeaderError, CorruptPayloadError, NotASampleFileError,
                                 OutputError, TruncatedFileError, UnsupportedVersionError)
from stereobudget.sampling import SamplingPattern, sample_count, sample_positions


def make_image(h, w, channels=3, dtype=np.uint8, seed=0):
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    shape = (h, w) if channels == 1 else (h, w, channels)
    return rng.integers(0, top, size=shape, endpoint=True, dtype=dtype)


def sample_file(h=12, w=17, channels=3, dtype=np.uint8, pattern=None):
    pattern = pattern or SamplingPattern("grid", 3, 2, offset_x=1, offset_y=1)
    return write_samples(encode_image(make_image(h, w, channels, dtype), pattern=pattern))


def header_with(data: bytes, **changes) -> bytes:
    """Rewrite 1.0 header fields (by the offsets of docs/format.md) and fix the header CRC."""
    offsets = {"version_major": (8, "<B"), "version_minor": (9, "<B"), "header_length": (10, "<H"),
               "width": (12, "<I"), "height": (16, "<I"), "channels": (20, "<B"),
               "channel_order": (21, "<B"), "dtype": (22, "<B"), "pattern": (23, "<B"),
               "stride_x": (24, "<H"), "stride_y": (26, "<H"), "offset_x": (28, "<H"),
               "offset_y": (30, "<H"), "seed": (32, "<Q"), "sample_count": (56, "<Q"),
               "payload_length": (64, "<Q"), "payload_crc32": (72, "<I")}
    head = bytearray(data[:76])
    for name, value in changes.items():
        off, fmt = offsets[name]
        struct.pack_into(fmt, head, off, value)
    return bytes(head) + struct.pack("<I", zlib.crc32(head)) + data[80:]


# --- the spec -------------------------------------------------------------------------

def test_header_layout_matches_the_spec_table():
    img = make_image(375, 450, 3)
    ss = encode_image(img, pattern=SamplingPattern("grid", 5, 5))
    data = write_samples(ss)
    assert data[:8] == b"\x89SBS\r\n\x1a\n" == MAGIC
    assert HEADER_SIZE_V1_0 == 80
    (major, minor, hlen, w, h, ch, order, dtype, pattern, sx, sy, ox, oy, seed) = struct.unpack_from(
        "<BBHIIBBBBHHHHQ", data, 8)
    assert (major, minor, hlen, w, h, ch, order, dtype, pattern) == (1, 0, 80, 450, 375, 3, 1, 1, 0)
    assert (sx, sy, ox, oy, seed) == (5, 5, 0, 0, 0)
    assert data[40:56] == bytes(16)
    n, plen, pcrc, hcrc = struct.unpack_from("<QQII", data, 56)
    assert n == 75 * 90 == 6750
    assert plen == 20250 == len(data) - 80
    assert pcrc == zlib.crc32(data[80:])
    assert hcrc == zlib.crc32(data[:76])


def test_example_file_of_the_spec_is_reproduced_byte_for_byte():
    img = (np.arange(12, dtype=np.uint16) * 1000).reshape(3, 4)
    data = write_samples(encode_image(img, pattern=SamplingPattern("grid", 2, 2, offset_x=1)))
    expected = bytes.fromhex(
        "89 53 42 53 0d 0a 1a 0a 01 00 50 00 04 00 00 00"
        "03 00 00 00 01 00 02 00 02 00 02 00 01 00 00 00" + "00" * 24 +
        "04 00 00 00 00 00 00 00 08 00 00 00 00 00 00 00"
        "22 86 e5 dd 0b 15 03 34 e8 03 b8 0b 28 23 f8 2a")
    assert data == expected


def test_jitter_test_vector_of_the_spec():
    rows, cols = sample_positions(SamplingPattern("jitter", 4, 4, seed=42), 6, 10)
    assert list(zip(rows.tolist(), cols.tolist())) == [(2, 1), (3, 7), (3, 8), (5, 0), (4, 6), (4, 8)]


# --- round trips ----------------------------------------------------------------------

@st.composite
def sample_sets(draw):
    h = draw(st.integers(1, 40))
    w = draw(st.integers(1, 40))
    order = draw(st.sampled_from(["gray", "rgb", "bgr"]))
    dtype = draw(st.sampled_from([np.uint8, np.uint16]))
    sx = draw(st.integers(1, 9))
    sy = draw(st.integers(1, 9))
    kind = draw(st.sampled_from(["grid", "jitter"]))
    if kind == "grid":
        ox = draw(st.integers(0, min(sx - 1, w - 1)))
        oy = draw(st.integers(0, min(sy - 1, h - 1)))
        pattern = SamplingPattern("grid", sx, sy, offset_x=ox, offset_y=oy)
    else:
        pattern = SamplingPattern("jitter", sx, sy, seed=draw(st.integers(0, 2 ** 64 - 1)))
    img = make_image(h, w, 1 if order == "gray" else 3, dtype, seed=draw(st.integers(0, 1000)))
    return img, order, pattern


@settings(max_examples=150, deadline=None)
@given(sample_sets())
def test_round_trip_keeps_exact_source_pixels(case):
    img, order, pattern = case
    ss = encode_image(img, pattern=pattern, channel_order=order)
    back = read_samples(write_samples(ss), source="x.sbs")
    assert (back.height, back.width, back.channel_order, back.pattern) == \
        (img.shape[0], img.shape[1], order, pattern)
    assert back.values.dtype == img.dtype and back.values.flags.writeable
    np.testing.assert_array_equal(back.values, ss.values)
    img3 = img if img.ndim == 3 else img[:, :, None]
    rows, cols = back.positions()
    np.testing.assert_array_equal(back.values, img3[rows, cols])
    if pattern.kind == "grid":
        lattice = img3[pattern.offset_y::pattern.stride_y, pattern.offset_x::pattern.stride_x]
        np.testing.assert_array_equal(back.grid_values(), lattice)
    assert len(write_samples(back)) == 80 + back.values.size * img.dtype.itemsize


def test_uint16_payload_is_little_endian():
    img = np.array([[0x0102, 0xA0B0]], dtype=np.uint16)
    data = write_samples(encode_image(img, pattern=SamplingPattern("grid", 1, 1)))
    assert data[80:] == b"\x02\x01\xb0\xa0"


@pytest.mark.parametrize("h,w,sx,sy", [(375, 450, 5, 5), (288, 384, 4, 4), (1, 1, 1, 1), (7, 3, 9, 9)])
def test_payload_size_is_n_times_channels_times_bytes(h, w, sx, sy):
    for channels, dtype in ((1, np.uint8), (3, np.uint8), (3, np.uint16)):
        data = write_samples(encode_image(make_image(h, w, channels, dtype),
                                          pattern=SamplingPattern("grid", sx, sy)))
        n = -(-h // sy) * -(-w // sx)
        assert len(data) - 80 == n * channels * np.dtype(dtype).itemsize


def test_jitter_positions_are_deterministic_and_one_per_cell():
    h, w, sx, sy = 23, 31, 4, 5
    p = SamplingPattern("jitter", sx, sy, seed=1234)
    rows, cols = sample_positions(p, h, w)
    rows2, cols2 = sample_positions(SamplingPattern("jitter", sx, sy, seed=1234), h, w)
    np.testing.assert_array_equal(rows, rows2)
    np.testing.assert_array_equal(cols, cols2)
    cells = (rows // sy) * (-(-w // sx)) + cols // sx
    np.testing.assert_array_equal(cells, np.arange(sample_count(p, h, w)))   # row-major, one each
    assert rows.max() < h and cols.max() < w
    other, _ = sample_positions(SamplingPattern("jitter", sx, sy, seed=1235), h, w)
    assert not np.array_equal(rows, other)


@pytest.mark.parametrize("kind", ["fps", "adaptive_fps", "downsample"])
def test_every_pattern_code_is_representable(kind):
    pattern = SamplingPattern(kind, 3, 4, seed=7)
    n = sample_count(pattern, 10, 11)
    values = np.arange(n * 3, dtype=np.uint16).reshape(n, 3)
    ss = SampleSet(height=10, width=11, channel_order="bgr", pattern=pattern, values=values)
    data = write_samples(ss)
    assert data[23] == sbio.PATTERN_CODES[kind]
    back = read_samples(data)
    assert back.pattern == pattern and back.channel_order == "bgr"
    np.testing.assert_array_equal(back.values, values)
    np.testing.assert_array_equal(back.values_rgb(), values[:, ::-1])


def test_write_rejects_values_that_do_not_fit_the_format():
    img = make_image(4, 4, 1)
    with pytest.raises(ValueError, match="seed"):
        write_samples(encode_image(img, pattern=SamplingPattern("grid", 2, 2, seed=2 ** 64)))
    with pytest.raises(ValueError, match="stride_x"):
        write_samples(encode_image(img, pattern=SamplingPattern("grid", 70000, 1)))


# --- corruption: one error class per validation step ----------------------------------

def test_truncation_at_every_byte_is_reported_as_truncated():
    data = sample_file(h=6, w=7)
    for cut in range(len(data)):
        with pytest.raises(TruncatedFileError) as info:
            read_samples(data[:cut], source="cam.sbs")
        assert "cam.sbs" in str(info.value)
    assert read_samples(data).values.shape[0] > 0


def test_flipped_header_bytes_are_caught_with_their_class():
    data = sample_file()
    for offset in range(80):
        mangled = bytearray(data)
        mangled[offset] ^= 0xFF
        expected = (NotASampleFileError if offset < 8 else UnsupportedVersionError if offset == 8
                    else CorruptHeaderError)
        with pytest.raises(expected):
            read_samples(bytes(mangled), source="f.sbs")


def test_flipped_payload_bytes_fail_the_payload_crc():
    data = sample_file()
    for offset in range(80, len(data)):
        mangled = bytearray(data)
        mangled[offset] ^= 0x01
        with pytest.raises(CorruptPayloadError, match="payload checksum"):
            read_samples(bytes(mangled), source="f.sbs")


def test_trailing_bytes_are_corrupt_payload():
    with pytest.raises(CorruptPayloadError, match="3 unexpected bytes"):
        read_samples(sample_file() + b"abc")


def test_declared_payload_length_must_match_the_sample_count():
    data = sample_file()
    plen = len(data) - 80
    with pytest.raises(CorruptPayloadError, match="declares"):
        read_samples(header_with(data, payload_length=plen + 1) + b"x")


@pytest.mark.parametrize("major", [0, 2, 255])
def test_unknown_major_version_is_unsupported(major):
    data = header_with(sample_file(), version_major=major)
    with pytest.raises(UnsupportedVersionError, match=f"version {major}.0"):
        read_samples(data, source="new.sbs")
    # even when the rest of a newer-major file is shorter than a 1.0 header
    with pytest.raises(UnsupportedVersionError):
        read_samples(data[:12])


def test_newer_minor_version_with_longer_header_still_reads():
    data = sample_file()
    extra = b"future fields!!!"   # 16 bytes appended by a hypothetical 1.3
    head = bytearray(data[:76])
    head[9] = 3
    struct.pack_into("<H", head, 10, 80 + len(extra))
    head = bytes(head) + extra
    newer = head + struct.pack("<I", zlib.crc32(head)) + data[80:]
    back = read_samples(newer)
    np.testing.assert_array_equal(back.values, read_samples(data).values)
    assert probe(newer)["version"] == "1.3" and probe(newer)["header_length"] == 96


def test_minor_zero_must_have_the_1_0_header_length():
    with pytest.raises(CorruptHeaderError, match="header length 96"):
        read_samples(header_with(sample_file(), header_length=96))


@pytest.mark.parametrize("changes,match", [
    ({"width": 0}, "empty"),
    ({"height": 70000}, "exceeds the limit of 65535"),
    ({"width": 20000, "height": 20000}, "exceeds the limit of 268435456"),
    ({"channels": 2}, "do not match"),
    ({"channel_order": 0}, "do not match"),
    ({"channel_order": 9}, "channel order code 9"),
    ({"dtype": 4}, "dtype code 4"),
    ({"pattern": 5}, "pattern code 5"),
    ({"stride_x": 0}, "stride"),
    ({"offset_y": 2}, "offset"),
    ({"sample_count": 3}, "sample count 3"),
])
def test_impossible_field_values_are_corrupt_header(changes, match):
    with pytest.raises(CorruptHeaderError, match=match):
        read_samples(header_with(sample_file(), **changes), source="odd.sbs")


def test_absurd_size_is_rejected_before_allocation():
    # 65535 x 65535 x 3 x uint16 would be 25 GB; the header alone must be refused.
    data = header_with(sample_file(), width=65535, height=65535, stride_x=1, stride_y=1,
                       sample_count=65535 * 65535, payload_length=65535 * 65535 * 6)
    with pytest.raises(CorruptHeaderError, match="exceeds"):
        read_samples(data)


@pytest.mark.parametrize("mangle,hint", [
    (lambda d: d.replace(b"\r\n", b"\n", 1), "CR-LF was turned into LF"),
    (lambda d: d[:4] + d[4:8].replace(b"\n", b"\r\n") + d[8:], "LF was turned into CR-LF"),
    (lambda d: bytes([d[0] & 0x7F]) + d[1:], "high bit"),
    (lambda d: d.decode("latin-1").encode("utf-8"), "UTF-8"),
])
def test_text_mode_damage_gets_a_specific_hint(mangle, hint):
    with pytest.raises(NotASampleFileError, match=hint) as info:
        read_samples(mangle(sample_file()), source="ftp.sbs")
    assert "ftp.sbs" in str(info.value)


def test_foreign_files_are_not_sample_files():
    with pytest.raises(NotASampleFileError, match="PNG image"):
        read_samples(b"\x89PNG\r\n\x1a\n" + bytes(100))
    with pytest.raises(NotASampleFileError, match="no .sbs signature"):
        read_samples(b"hello world, this is text")
    with pytest.raises(TruncatedFileError, match="empty"):
        read_samples(b"")


# --- files and probe ------------------------------------------------------------------

def test_save_load_and_probe(tmp_path):
    ss = encode_image(make_image(9, 13, 3, np.uint16), pattern=SamplingPattern("jitter", 3, 3, seed=5))
    path = tmp_path / "a.sbs"
    nbytes = save_samples(ss, path)
    assert nbytes == path.stat().st_size
    assert [p.name for p in tmp_path.iterdir()] == ["a.sbs"]     # no temporary left behind
    with pytest.raises(OutputError, match="exists"):
        save_samples(ss, path)
    save_samples(ss, path, overwrite=True)
    back = load_samples(path)
    np.testing.assert_array_equal(back.values, ss.values)
    info = probe(path)
    assert json.loads(json.dumps(info)) == info
    assert info["file_size"] == nbytes and info["pattern"] == "jitter" and info["seed"] == 5
    assert info["dtype"] == "uint16" and info["channel_order"] == "rgb"
    assert info["epsilon"] == pytest.approx(ss.epsilon)
    assert probe(path.read_bytes()) == info
    assert set(info) >= {"version", "header_length", "width", "height", "channels", "stride_x",
                         "stride_y", "offset_x", "offset_y", "sample_count", "payload_length",
                         "payload_crc32", "header_crc32"}


def test_probe_checks_file_size_always_and_payload_crc_on_request(tmp_path):
    data = bytearray(sample_file())
    data[-1] ^= 0xFF
    path = tmp_path / "b.sbs"
    path.write_bytes(bytes(data))
    assert probe(path)["sample_count"] > 0
    with pytest.raises(CorruptPayloadError):
        probe(path, verify_payload=True)
    path.write_bytes(bytes(data[:-1]))
    with pytest.raises(TruncatedFileError, match="1 missing"):
        probe(path)


def test_load_missing_file(tmp_path):
    with pytest.raises(NotASampleFileError, match="no such file"):
        load_samples(tmp_path / "nope.sbs")


# --- raw frames on a grid: the numpy-free path (stereobudget.io._rawgrid) ---------------------

_RAW_FORMATS = {"gray8": (1, np.uint8), "rgb24": (3, np.uint8), "bgr24": (3, np.uint8),
                "gray16le": (1, np.uint16), "bayer_rggb8": (1, np.uint8), "bayer_gbrg16le": (1, np.uint16)}


@st.composite
def raw_grid_cases(draw):
    pix_fmt = draw(st.sampled_from(sorted(_RAW_FORMATS)))
    h = draw(st.integers(1, 40))
    w = draw(st.integers(1, 40))
    sx = draw(st.integers(1, 12))
    sy = draw(st.integers(1, 12))
    ox = draw(st.integers(0, min(sx - 1, w - 1)))
    oy = draw(st.integers(0, min(sy - 1, h - 1)))
    channels, dtype = _RAW_FORMATS[pix_fmt]
    img = make_image(h, w, channels, dtype, seed=draw(st.integers(0, 1000)))
    return pix_fmt, img.astype(img.dtype.newbyteorder("<")).tobytes(), (w, h), \
        SamplingPattern("grid", sx, sy, offset_x=ox, offset_y=oy)


def _numpy_raw_encoding(frame: bytes, size, pix_fmt: str, pattern) -> bytes:
    image, order = sbio.read_raw(frame, width=size[0], height=size[1], pix_fmt=pix_fmt)
    return write_samples(encode_image(image, pattern=pattern, channel_order=order))


@settings(max_examples=200, deadline=None)
@given(raw_grid_cases())
def test_raw_grid_path_writes_the_bytes_of_the_numpy_path(case):
    import tempfile

    pix_fmt, frame, size, pattern = case
    expected = _numpy_raw_encoding(frame, size, pix_fmt, pattern)
    with tempfile.TemporaryDirectory() as tmp:
        src, out = f"{tmp}/frame.raw", f"{tmp}/f.sbs"
        with open(src, "wb") as handle:
            handle.write(frame)
        report = sbenc.encode_file(src, out, pattern=pattern, raw_size=size, pix_fmt=pix_fmt)
        with open(out, "rb") as handle:
            written = handle.read()
    assert written == expected
    ss = read_samples(expected)
    assert report.as_dict() == {
        "source": src, "output": out, "width": size[0], "height": size[1],
        "channels": ss.channels, "channel_order": ss.channel_order, "dtype": str(ss.dtype),
        "pattern": "grid", "stride_x": pattern.stride_x, "stride_y": pattern.stride_y,
        "offset_x": pattern.offset_x, "offset_y": pattern.offset_y, "seed": 0,
        "sample_count": ss.values.shape[0], "epsilon": ss.epsilon, "header_bytes": HEADER_SIZE_V1_0,
        "payload_bytes": len(expected) - HEADER_SIZE_V1_0, "file_size": len(expected),
        "codec": "raw", "value_bits": 8 * ss.dtype.itemsize, "quality": 0,
        "bits_per_pixel": 8.0 * len(expected) / (size[0] * size[1]), "pixel_fraction": ss.epsilon,
        "bytes_fraction": len(expected) / (size[0] * size[1] * ss.channels * ss.dtype.itemsize)}


@pytest.mark.parametrize("pix_fmt", sorted(_RAW_FORMATS))
@pytest.mark.parametrize("h,w,sx,sy,ox,oy", [(375, 450, 5, 5, 0, 0), (375, 450, 4, 3, 3, 2),
                                             (480, 640, 1, 1, 0, 0), (17, 33, 1, 7, 0, 6),
                                             (9, 11, 20, 20, 10, 8), (1, 1, 1, 1, 0, 0),
                                             (64, 300, 299, 2, 298, 1)])
def test_raw_grid_payload_matches_numpy_slicing(pix_fmt, h, w, sx, sy, ox, oy):
    from stereobudget.io import grid_payload

    channels, dtype = _RAW_FORMATS[pix_fmt]
    img = make_image(h, w, channels, dtype, seed=h * w)
    frame = img.astype(img.dtype.newbyteorder("<")).tobytes()
    pattern = SamplingPattern("grid", sx, sy, offset_x=ox, offset_y=oy)
    expected = _numpy_raw_encoding(frame, (w, h), pix_fmt, pattern)
    pixel_bytes = channels * np.dtype(dtype).itemsize
    for data in (frame, bytearray(frame), memoryview(frame)):
        payload = grid_payload(data, width=w, height=h, pixel_bytes=pixel_bytes, stride_x=sx,
                               stride_y=sy, offset_x=ox, offset_y=oy)
        assert payload == expected[HEADER_SIZE_V1_0:]


def test_raw_grid_path_errors_match_the_numpy_path(tmp_path):
    from stereobudget.errors import ImageReadError, OptionError

    src = tmp_path / "f.raw"
    grid = SamplingPattern("grid", 5, 5)
    for data, size, pix_fmt in ((bytes(14 * 10 * 3 + 5), (14, 10), "rgb24"),
                                (bytes(13), (14, 10), "gray16le"),
                                (bytes(10), (10, 1), "yuv420"),
                                (bytes(0), (0, 10), "gray8")):
        src.write_bytes(data)
        with pytest.raises(ImageReadError) as numpy_path:
            sbio.read_raw(data, width=size[0], height=size[1], pix_fmt=pix_fmt, name=str(src))
        with pytest.raises(ImageReadError) as fast_path:
            sbenc.encode_file(src, tmp_path / "o.sbs", pattern=grid, raw_size=size, pix_fmt=pix_fmt)
        assert str(fast_path.value) == str(numpy_path.value)
    src.write_bytes(bytes(4 * 3))
    with pytest.raises(OptionError, match="leaves no sample"):
        sbenc.encode_file(src, tmp_path / "o.sbs", pattern=SamplingPattern("grid", 9, 9, offset_x=5),
                              raw_size=(4, 3), pix_fmt="gray8")
    assert not (tmp_path / "o.sbs").exists()


def test_library_tables_keep_their_numpy_form():
    assert sbio.DTYPE_CODES == {np.dtype(np.uint8): 1, np.dtype(np.uint16): 2}
    assert sbio.RAW_PIXEL_FORMATS["gray16le"] == (1, np.dtype("<u2"), "gray")
    assert sbio.RAW_PIXEL_FORMATS["bgr24"] == (3, np.dtype(np.uint8), "bgr")
