"""Raw Bayer mosaics in the sample file: the four layouts at 8 and 16 bits, the header field, corrupt values."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from stereobudget.errors import CorruptHeaderError, OptionError
from stereobudget.io import probe, read_samples, write_samples
from stereobudget.encoding import encode_file, encode_image
from stereobudget.io import BAYER_PATTERNS, mosaic_image, shifted_order
from stereobudget.sampling import SamplingPattern

PATTERNS = sorted(BAYER_PATTERNS)


def _rgb(h, w, dtype, seed=0):
    return np.random.default_rng(seed).integers(0, np.iinfo(dtype).max, (h, w, 3), endpoint=True, dtype=dtype)


def _fix_crc(head: bytearray) -> bytes:
    return bytes(head[:76]) + struct.pack("<I", zlib.crc32(bytes(head[:76])))


def test_mosaic_image_takes_the_named_colour_of_every_pixel():
    rgb = _rgb(4, 6, np.uint8)
    raw = mosaic_image(rgb, "rggb")
    assert raw[0, 0] == rgb[0, 0, 0] and raw[0, 1] == rgb[0, 1, 1]
    assert raw[1, 0] == rgb[1, 0, 1] and raw[1, 1] == rgb[1, 1, 2] and raw[3, 5] == rgb[3, 5, 2]
    assert mosaic_image(rgb, "bayer_gbrg")[1, 0] == rgb[1, 0, 0]


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("pix_fmt_bits,dtype", [("8", np.uint8), ("16le", np.uint16)])
def test_each_layout_round_trips_through_the_raw_path(tmp_path, pattern, pix_fmt_bits, dtype):
    rgb = _rgb(23, 31, dtype, seed=len(pattern) + dtype().itemsize)
    raw = mosaic_image(rgb, pattern)
    src, out = tmp_path / "f.raw", tmp_path / "f.sbs"
    src.write_bytes(raw.astype(raw.dtype.newbyteorder("<")).tobytes())
    # Odd strides and an odd offset: consecutive samples alternate colours.
    grid = SamplingPattern("grid", 3, 5, offset_x=1, offset_y=3)
    report = encode_file(src, out, pattern=grid, raw_size=(31, 23), pix_fmt=f"bayer_{pattern}{pix_fmt_bits}")
    assert report.channels == 1 and report.channel_order == f"bayer_{pattern}"
    ss = read_samples(out.read_bytes())
    assert ss.channel_order == f"bayer_{pattern}" and ss.mosaic == pattern and ss.dtype == dtype
    assert ss.channels == 1 and ss.colour_channels == 3
    np.testing.assert_array_equal(ss.grid_values()[:, :, 0], raw[3::5, 1::3])
    rows, cols = ss.positions()
    colours = ss.sample_colours()
    assert set(colours.tolist()) == {0, 1, 2}
    np.testing.assert_array_equal(ss.values[:, 0], rgb[rows, cols, colours])
    # The numpy path writes the same bytes.
    assert write_samples(encode_image(raw, pattern=grid, channel_order=f"bayer_{pattern}")) == out.read_bytes()


@pytest.mark.parametrize("pattern,code", [("rggb", 3), ("bggr", 4), ("grbg", 5), ("gbrg", 6)])
def test_header_records_the_pattern_as_channel_order_of_a_1_2_file(pattern, code):
    ss = encode_image(mosaic_image(_rgb(12, 10, np.uint8), pattern), pattern=SamplingPattern("grid", 3, 3),
                      channel_order=f"bayer_{pattern}")
    data = write_samples(ss)
    assert data[9] == 2 and data[20] == 1 and data[21] == code
    assert data[40:56] == bytes(16)      # raw payload: the coding block stays zero
    info = probe(data)
    assert info["version"] == "1.2" and info["channel_order"] == f"bayer_{pattern}" and info["channels"] == 1
    # Other files are written exactly as before.
    plain = write_samples(encode_image(_rgb(12, 10, np.uint8), pattern=SamplingPattern("grid", 3, 3)))
    assert plain[9] == 0


def test_mosaic_payload_coding_round_trips():
    raw = mosaic_image(_rgb(40, 50, np.uint8, seed=4), "grbg")
    ss = encode_image(raw, pattern=SamplingPattern("grid", 3, 3), channel_order="bayer_grbg")
    back = read_samples(write_samples(ss, codec="deflate"))
    assert back.channel_order == "bayer_grbg"
    np.testing.assert_array_equal(back.values, ss.values)


def _mosaic_file() -> bytes:
    ss = encode_image(mosaic_image(_rgb(12, 10, np.uint8), "rggb"), pattern=SamplingPattern("grid", 3, 3),
                      channel_order="bayer_rggb")
    return write_samples(ss)


@pytest.mark.parametrize("offset,value,message", [
    (21, 7, "unknown channel order code 7"),
    (9, 1, "needs format 1.2, the header says 1.1"),
    (9, 0, "needs format 1.2, the header says 1.0"),
    (20, 3, "do not match channel order"),
])
def test_corrupt_mosaic_header_values_are_rejected(offset, value, message):
    data = _mosaic_file()
    head = bytearray(data[:80])
    head[offset] = value
    with pytest.raises(CorruptHeaderError, match=message):
        read_samples(_fix_crc(head) + data[80:], source="m.sbs")


def test_mosaic_with_downsample_is_refused_when_written_and_read():
    raw = mosaic_image(_rgb(12, 10, np.uint8), "rggb")
    with pytest.raises(OptionError, match="mix a Bayer mosaic"):
        encode_image(raw, pattern=SamplingPattern("downsample", 2, 2), channel_order="bayer_rggb")
    gray = write_samples(encode_image(raw, pattern=SamplingPattern("downsample", 2, 2)))
    head = bytearray(gray[:80])
    head[9], head[21] = 2, 3
    with pytest.raises(CorruptHeaderError, match="cannot use the downsample pattern"):
        read_samples(_fix_crc(head) + gray[80:])


def test_shifted_order_is_the_pattern_seen_from_another_origin():
    rgb = _rgb(6, 6, np.uint8)
    for pattern in PATTERNS:
        raw = mosaic_image(rgb, pattern)
        for dy in (0, 1):
            for dx in (0, 1):
                shifted = shifted_order(f"bayer_{pattern}", rows=dy, cols=dx)
                np.testing.assert_array_equal(mosaic_image(rgb[dy:, dx:], shifted), raw[dy:, dx:])
    assert shifted_order("rgb", rows=1) == "rgb"
