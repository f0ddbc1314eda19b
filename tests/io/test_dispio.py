"""Disparity files: round trips, on-disk conventions, header validation, atomic writes, previews."""

import logging
import os

import cv2
import numpy as np
import pytest

from stereobudget.io import (disparity_preview, read_disparity, write_disparity,
                                 write_preview)
from stereobudget.errors import ImageReadError, OutputError


@pytest.fixture
def disparity():
    rng = np.random.default_rng(7)
    d = rng.uniform(0.0, 120.0, size=(23, 31)).astype(np.float32)
    d[0, 0] = 0.0
    d[5, 7] = np.nan
    d[10:12, 3:9] = np.nan
    return d


@pytest.mark.parametrize("ext", [".pfm", ".tif", ".tiff", ".npy"])
def test_float_formats_round_trip_exactly(tmp_path, disparity, ext):
    path = tmp_path / f"d{ext}"
    write_disparity(path, disparity)
    back = read_disparity(path)
    assert back.dtype == np.float32 and back.shape == disparity.shape
    np.testing.assert_array_equal(back, disparity)  # NaN positions compare equal


def test_png_round_trip_within_quantisation(tmp_path, disparity):
    path = tmp_path / "d.png"
    write_disparity(path, disparity)
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.ndim == 2
    valid = ~np.isnan(disparity)
    assert (raw[~valid] == 0).all()
    assert raw[0, 0] == 1  # a valid zero disparity must not read back as invalid
    back = read_disparity(path)
    np.testing.assert_array_equal(np.isnan(back), ~valid)
    assert back[0, 0] == np.float32(1 / 256)
    valid[0, 0] = False
    err = np.abs(back[valid] - disparity[valid])
    assert err.max() <= 1 / 512 + 1e-5  # rounding to 1/256 plus float32 representation
    assert raw[3, 4] == round(float(disparity[3, 4]) * 256)


def test_png_clips_out_of_range_values_and_logs(tmp_path, caplog):
    d = np.array([[-3.0, 0.5, 300.0]], dtype=np.float32)
    path = tmp_path / "clip.png"
    with caplog.at_level(logging.WARNING, logger="stereobudget"):
        write_disparity(path, d)
    assert "clipped 1 negative and 1 larger" in caplog.text
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(raw, [[1, 128, 65535]])


def test_pfm_layout_follows_middlebury(tmp_path):
    d = np.array([[1.0, 2.0, 3.0], [4.0, np.nan, 6.0]], dtype=np.float32)
    path = tmp_path / "d.pfm"
    write_disparity(path, d)
    raw = path.read_bytes()
    header = b"Pf\n3 2\n-1.0\n"
    assert raw.startswith(header)
    body = np.frombuffer(raw[len(header):], dtype="<f4").reshape(2, 3)
    # bottom row first, +inf for invalid
    np.testing.assert_array_equal(body, [[4.0, np.inf, 6.0], [1.0, 2.0, 3.0]])


def test_pfm_reader_accepts_big_endian_and_loose_whitespace(tmp_path):
    expected = np.array([[1.5, 2.5], [np.nan, 8.0]], dtype=np.float32)
    rows_bottom_up = np.array([[np.inf, 8.0], [1.5, 2.5]], dtype=">f4")
    path = tmp_path / "be.pfm"
    path.write_bytes(b"Pf\n2 2\n1.0\n" + rows_bottom_up.tobytes())
    np.testing.assert_array_equal(read_disparity(path), expected)
    path.write_bytes(b"Pf 2  2\n-1\n" + rows_bottom_up.astype("<f4").tobytes())
    np.testing.assert_array_equal(read_disparity(path), expected)


@pytest.mark.parametrize("content, message", [
    (b"P5\n2 2\n255\n" + bytes(4), "not a PFM file"),
    (b"PF\n2 2\n-1.0\n" + bytes(48), "colour PFM"),
    (b"Pf\n2 2\n-1.0\n" + bytes(12), "truncated"),
    (b"Pf\n2 2\n-1.0\n" + bytes(20), "bytes after"),
    (b"Pf\n2 2\nabc\n" + bytes(16), "not a number"),
    (b"Pf\n2 2\n0\n" + bytes(16), "non-zero"),
    (b"Pf\n0 2\n-1.0\n", "empty image"),
    (b"", "not a PFM file"),
])
def test_bad_pfm_headers_give_one_line_errors(tmp_path, content, message):
    path = tmp_path / "bad.pfm"
    path.write_bytes(content)
    with pytest.raises(ImageReadError, match=message) as info:
        read_disparity(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    assert info.value.exit_code == ImageReadError.exit_code


def test_reader_rejects_wrong_content(tmp_path):
    eight_bit = tmp_path / "gray8.png"
    cv2.imwrite(str(eight_bit), np.zeros((4, 4), np.uint8))
    with pytest.raises(ImageReadError, match="16-bit single-channel"):
        read_disparity(eight_bit)
    garbage = tmp_path / "garbage.tif"
    garbage.write_bytes(b"not a tiff at all")
    with pytest.raises(ImageReadError, match="TIFF"):
        read_disparity(garbage)
    cube = tmp_path / "cube.npy"
    np.save(cube, np.zeros((2, 3, 4), np.float32))
    with pytest.raises(ImageReadError, match="2-D"):
        read_disparity(cube)
    with pytest.raises(ImageReadError, match="no such file"):
        read_disparity(tmp_path / "missing.pfm")
    with pytest.raises(ImageReadError, match="unknown disparity format"):
        read_disparity(tmp_path / "d.jpg")


def test_writes_are_atomic_and_refuse_to_clobber(tmp_path, disparity):
    path = tmp_path / "d.pfm"
    write_disparity(path, disparity)
    before = path.read_bytes()
    with pytest.raises(OutputError, match="exists"):
        write_disparity(path, disparity * 2)
    assert path.read_bytes() == before
    write_disparity(path, disparity * 2, overwrite=True)
    np.testing.assert_array_equal(read_disparity(path), disparity * 2)
    assert sorted(os.listdir(tmp_path)) == ["d.pfm"]  # no temporary files left behind
    with pytest.raises(OutputError, match="unknown disparity format"):
        write_disparity(tmp_path / "d.bmp", disparity)


def test_tiff_is_deflate_compressed(tmp_path):
    import tifffile

    path = tmp_path / "d.tif"
    write_disparity(path, np.zeros((64, 64), np.float32))
    with tifffile.TiffFile(path) as tif:
        assert tif.pages[0].compression == tifffile.COMPRESSION.ADOBE_DEFLATE
    assert path.stat().st_size < 64 * 64 * 4 / 10


def test_preview_colours_and_invalid_black(tmp_path):
    d = np.tile(np.linspace(0, 10, 16, dtype=np.float32), (4, 1))
    d[1, 3] = np.nan
    rgb = disparity_preview(d, min_disp=0, max_disp=10)
    assert rgb.shape == (4, 16, 3) and rgb.dtype == np.uint8
    assert (rgb[1, 3] == 0).all()
    # turbo runs from dark blue (low) to dark red (high); check channel order is RGB
    assert rgb[0, 0, 2] > rgb[0, 0, 0]
    assert rgb[0, -1, 0] > rgb[0, -1, 2]
    # a fixed range clips values beyond it
    np.testing.assert_array_equal(disparity_preview(d * 3, min_disp=0, max_disp=10)[0, -1], rgb[0, -1])

    path = tmp_path / "p.png"
    write_preview(path, d, min_disp=0, max_disp=10, scale_bar=False)
    on_disk = cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(on_disk, rgb)
    with pytest.raises(OutputError, match="exists"):
        write_preview(path, d, min_disp=None, max_disp=None)


def test_preview_carries_a_colour_bar_with_its_scale(tmp_path):
    from stereobudget.io import SCALE_BAR_MIN_WIDTH, with_scale_bar
    d = np.tile(np.linspace(0, 60, 200, dtype=np.float32), (100, 1))
    path = tmp_path / "p.png"
    write_preview(path, d, min_disp=0, max_disp=60)
    on_disk = cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    plain = disparity_preview(d, min_disp=0, max_disp=60)
    assert on_disk.shape[1] == 200 and on_disk.shape[0] > 100
    np.testing.assert_array_equal(on_disk[:100], plain)
    # The bar under the map runs through the same colours, left to right.
    bar = on_disk[101]
    np.testing.assert_allclose(bar[0], plain[0, 0], atol=2)
    np.testing.assert_allclose(bar[-1], plain[0, -1], atol=2)
    labels = on_disk[-16:]
    assert (labels < 128).any() and (labels == 255).mean() > 0.7      # dark text on white
    narrow = disparity_preview(d[:, :SCALE_BAR_MIN_WIDTH - 1], min_disp=0, max_disp=60)
    assert with_scale_bar(narrow, min_disp=0, max_disp=60) is narrow
