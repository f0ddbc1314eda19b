"""Image reading/writing at the library boundary and headerless raw frames."""

from __future__ import annotations

import io
import json
import logging
import struct
import subprocess
import tempfile
import sys
import zlib

import cv2
import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from stereobudget.errors import ImageReadError, OutputError
from stereobudget.io import (RAW_PIXEL_FORMATS, parse_raw_size, read_image, read_raw, sniff_image_size,
                             write_image)


def rgb_image(h=7, w=9, dtype=np.uint8, seed=0):
    top = np.iinfo(dtype).max
    return np.random.default_rng(seed).integers(0, top, (h, w, 3), endpoint=True, dtype=dtype)


def png_bytes(rgb: np.ndarray) -> bytes:
    bgr = rgb[:, :, ::-1] if rgb.ndim == 3 and rgb.shape[2] == 3 else rgb
    if rgb.ndim == 3 and rgb.shape[2] == 4:
        bgr = rgb[:, :, [2, 1, 0, 3]]
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr))
    assert ok
    return buf.tobytes()


def png_header_only(width: int, height: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk))


# --- read_image -------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_colour_comes_back_rgb_with_its_bit_depth(tmp_path, dtype):
    rgb = rgb_image(dtype=dtype)
    path = tmp_path / "c.png"
    path.write_bytes(png_bytes(rgb))
    image, order = read_image(path)
    assert order == "rgb" and image.dtype == dtype and image.flags.c_contiguous
    np.testing.assert_array_equal(image, rgb)
    image2, _ = read_image(path.read_bytes())
    np.testing.assert_array_equal(image2, rgb)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_gray_png_and_tiff_are_2d(tmp_path, dtype):
    gray = rgb_image(dtype=dtype)[:, :, 0].copy()
    image, order = read_image(png_bytes(gray))
    assert order == "gray" and image.shape == gray.shape
    np.testing.assert_array_equal(image, gray)
    buf = io.BytesIO()
    tifffile.imwrite(buf, gray, photometric="minisblack")
    image, order = read_image(buf.getvalue())
    assert order == "gray" and image.ndim == 2
    np.testing.assert_array_equal(image, gray)


def test_16bit_rgb_tiff(tmp_path):
    rgb = rgb_image(dtype=np.uint16)
    path = tmp_path / "c.tif"
    tifffile.imwrite(path, rgb, photometric="rgb")
    image, order = read_image(path)
    assert order == "rgb" and image.dtype == np.uint16
    np.testing.assert_array_equal(image, rgb)


def test_ppm_and_jpeg(tmp_path):
    rgb = rgb_image()
    ok, ppm = cv2.imencode(".ppm", rgb[:, :, ::-1].copy())
    image, order = read_image(ppm.tobytes())
    np.testing.assert_array_equal(image, rgb)
    flat = np.full((8, 8, 3), (200, 40, 10), np.uint8)          # JPEG is lossy: use a flat colour
    ok, jpg = cv2.imencode(".jpg", flat[:, :, ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 100])
    image, order = read_image(jpg.tobytes())
    assert order == "rgb"
    assert np.abs(image.astype(int) - flat).max() <= 2


def test_alpha_is_dropped_with_a_logged_note(caplog):
    rgba = np.dstack([rgb_image(), np.full((7, 9), 128, np.uint8)])
    with caplog.at_level(logging.INFO, logger="stereobudget"):
        image, order = read_image(png_bytes(rgba), name="cam.png")
    assert order == "rgb"
    np.testing.assert_array_equal(image, rgba[:, :, :3])
    assert any("alpha" in r.getMessage() and "cam.png" in r.getMessage() for r in caplog.records)


def test_gray_plus_alpha_becomes_gray(caplog):
    la = np.dstack([rgb_image()[:, :, 0], np.full((7, 9), 255, np.uint8)])
    data = iio.imwrite("<bytes>", la, extension=".png", mode="LA")
    with caplog.at_level(logging.INFO, logger="stereobudget"):
        image, order = read_image(data)
    assert order == "gray"
    np.testing.assert_array_equal(image, la[:, :, 0])
    assert any("alpha" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("array,match", [
    (np.ones((4, 5), np.float32), "floating-point image \\(32-bit float\\)"),
    (np.full((4, 5), np.nan, np.float64), "contains NaN"),
    (np.ones((4, 5), np.int16), "unsupported bit depth \\(16-bit signed integer\\)"),
    (np.ones((4, 5), np.uint32), "unsupported bit depth \\(32-bit unsigned integer\\)"),
])
def test_unusable_pixel_types_are_refused(array, match):
    buf = io.BytesIO()
    tifffile.imwrite(buf, array)
    with pytest.raises(ImageReadError, match=match) as info:
        read_image(buf.getvalue(), name="odd.tif")
    assert str(info.value).startswith("odd.tif: ")


def test_bad_files_give_one_line_errors_naming_the_file(tmp_path):
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    cases = [(empty, "empty file"), (tmp_path / "missing.png", "no such file"),
             (tmp_path, "is a directory")]
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"this is not an image at all\n" * 10)
    cases.append((junk, "not an image"))
    sbs = tmp_path / "x.sbs"
    sbs.write_bytes(b"\x89SBS\r\n\x1a\n" + bytes(80))
    cases.append((sbs, "sample file, not an image"))
    for path, match in cases:
        with pytest.raises(ImageReadError, match=match) as info:
            read_image(path)
        message = str(info.value)
        assert message.startswith(f"{path}: ") and "\n" not in message


@pytest.mark.parametrize("width,height,match", [
    (70000, 10, "exceeds the limit of 65535"),
    (20000, 20000, "exceeds the limit of 268435456"),
    (0, 0, "0x0 is empty"),
])
def test_size_limits_are_checked_from_the_header_before_decoding(width, height, match):
    with pytest.raises(ImageReadError, match=match):
        read_image(png_header_only(width, height), name="bomb.png")


def test_sniffed_sizes_match_the_real_sizes(tmp_path):
    rgb = rgb_image(h=13, w=21)
    bgr = rgb[:, :, ::-1].copy()
    for ext in (".png", ".jpg", ".ppm", ".bmp", ".tiff"):
        ok, buf = cv2.imencode(ext, bgr)
        assert sniff_image_size(buf.tobytes()) == (21, 13), ext
    assert sniff_image_size(b"P6\n# comment 99 99\n21 13\n255\n") == (21, 13)
    assert sniff_image_size(b"no image") is None


# --- read_raw ---------------------------------------------------------------------------

def test_raw_formats():
    rgb = rgb_image(h=4, w=6)
    image, order = read_raw(rgb.tobytes(), width=6, height=4, pix_fmt="rgb24")
    assert order == "rgb"
    np.testing.assert_array_equal(image, rgb)
    image, order = read_raw(rgb.tobytes(), width=6, height=4, pix_fmt="bgr24")
    assert order == "bgr"                      # stays BGR: the camera does not touch pixels
    np.testing.assert_array_equal(image, rgb)
    image, order = read_raw(rgb[:, :, 0].tobytes(), width=6, height=4, pix_fmt="gray8")
    assert order == "gray" and image.shape == (4, 6)
    g16 = (np.arange(24, dtype=np.uint16) * 2731).reshape(4, 6)
    image, order = read_raw(g16.astype("<u2").tobytes(), width=6, height=4, pix_fmt="gray16le")
    assert order == "gray" and image.dtype == np.uint16
    np.testing.assert_array_equal(image, g16)
    assert set(RAW_PIXEL_FORMATS) == {"gray8", "rgb24", "bgr24", "gray16le"} | {
        f"bayer_{p}{bits}" for p in ("rggb", "bggr", "grbg", "gbrg") for bits in ("8", "16le")}


@pytest.mark.parametrize("nbytes,what", [(6 * 4 * 3 - 1, "less than one frame"),
                                         (6 * 4 * 3 * 2, "more than one frame")])
def test_raw_needs_exactly_one_frame(nbytes, what):
    with pytest.raises(ImageReadError, match=f"exactly 72 bytes, got {nbytes} \\({what}\\)"):
        read_raw(bytes(nbytes), width=6, height=4, pix_fmt="rgb24", name="<stdin>")


def test_raw_rejects_bad_sizes_and_formats():
    with pytest.raises(ImageReadError, match="exceeds"):
        read_raw(b"", width=100000, height=1, pix_fmt="gray8")
    with pytest.raises(ImageReadError, match="unknown raw pixel format"):
        read_raw(b"", width=1, height=1, pix_fmt="yuv420p")
    assert parse_raw_size("640x480") == (640, 480)
    assert parse_raw_size("640X480") == (640, 480)
    with pytest.raises(ValueError, match="WIDTHxHEIGHT"):
        parse_raw_size("640,480")


def test_raw_path_does_not_import_opencv_or_numba():
    code = ("import sys, json; from stereobudget.io import read_raw, read_samples; "
            "read_raw(bytes(12), width=2, height=2, pix_fmt='rgb24'); "
            "print(json.dumps([m for m in ('cv2', 'numba') if m in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=tempfile.gettempdir())  # keep the source checkout off sys.path
    assert json.loads(out.stdout) == []


# --- write_image ------------------------------------------------------------------------

@pytest.mark.parametrize("ext", [".png", ".tif", ".tiff"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_write_then_read_is_lossless(tmp_path, ext, dtype):
    rgb = rgb_image(dtype=dtype)
    path = tmp_path / f"out{ext}"
    write_image(path, rgb)
    image, order = read_image(path)
    np.testing.assert_array_equal(image, rgb)
    gray_path = tmp_path / f"gray{ext}"
    write_image(gray_path, rgb[:, :, 1], channel_order="gray")
    np.testing.assert_array_equal(read_image(gray_path)[0], rgb[:, :, 1])
    bgr_path = tmp_path / f"bgr{ext}"
    write_image(bgr_path, rgb[:, :, ::-1], channel_order="bgr")
    np.testing.assert_array_equal(read_image(bgr_path)[0], rgb)


def test_write_image_refuses_overwrite_and_unknown_extensions(tmp_path):
    path = tmp_path / "a.png"
    write_image(path, rgb_image())
    before = path.read_bytes()
    with pytest.raises(OutputError, match="exists"):
        write_image(path, rgb_image(seed=1))
    assert path.read_bytes() == before
    write_image(path, rgb_image(seed=1), overwrite=True)
    assert path.read_bytes() != before
    with pytest.raises(OutputError, match="unsupported image extension '.jpg'"):
        write_image(tmp_path / "a.jpg", rgb_image())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


# --- the decoders' stderr capture under an interrupt -------------------------------------


