"""Decoding raw Bayer samples: each sample against its own colour of I1, on a scene with exact ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from stereobudget.cost import pixel_cost
from stereobudget.decoding import decode
from stereobudget.decoding import band_samples
from stereobudget.errors import MismatchError, OptionError
from stereobudget.io import read_samples, write_samples
from stereobudget.encoding import encode_image
from stereobudget.io import mosaic_image, rgb_with_gaps
from stereobudget.metrics import bad_pixel_rate
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene
from stereobudget.synthesis import recover_right


@pytest.fixture(scope="module")
def scene():
    return make_scene("planes", seed=1)


def _mosaic_samples(image, stride, pattern="rggb", **grid):
    raw = mosaic_image(image, pattern)
    ss = encode_image(raw, pattern=SamplingPattern("grid", stride, stride, **grid), channel_order=f"bayer_{pattern}")
    return read_samples(write_samples(ss))      # through the file, as the host gets it


def test_pixel_cost_compares_only_the_channels_a_sample_carries():
    left = np.array([10.0, 50.0, 200.0], np.float32)
    right = rgb_with_gaps(np.array([60.0], np.float32), np.array([1]))[0]
    assert np.isnan(right[0]) and np.isnan(right[2])
    assert pixel_cost(left, right, np.float32(100.0)) == pytest.approx(10.0)
    assert pixel_cost(left, np.array([12.0, 50.0, 197.0], np.float32), np.float32(100.0)) == pytest.approx(5.0 / 3)


@pytest.mark.parametrize("method", ["sparse", "hybrid"])
def test_bayer_samples_decode_about_as_well_as_rgb_samples_on_the_same_grid(scene, method):
    grid = SamplingPattern("grid", 3, 3)
    rgb = decode(scene.left, encode_image(scene.right, pattern=grid), max_disp=scene.max_disp, method=method)
    bayer = decode(scene.left, _mosaic_samples(scene.right, 3), max_disp=scene.max_disp, method=method)
    rgb_bad = bad_pixel_rate(rgb.disparity, scene.disparity, scene.nonocc)
    bayer_bad = bad_pixel_rate(bayer.disparity, scene.disparity, scene.nonocc)
    assert bayer.params.sparse_census_weight == 0.0 and bayer.params.step_weight == 0.0
    # Measured 6.96 vs 7.23 (sparse), 15.83 vs 22.10 (hybrid): a third of the bytes, close accuracy.
    assert bayer_bad <= rgb_bad + 3.0, (bayer_bad, rgb_bad)


def test_a_one_colour_lattice_keeps_only_the_sparse_fill_in_hybrid(scene):
    ss = _mosaic_samples(scene.right, 4)            # even stride: every sample is red
    assert set(ss.sample_colours().tolist()) == {0}
    result = decode(scene.left, ss, max_disp=scene.max_disp, method="hybrid")
    assert result.params.hybrid_sparse_weight == 1.0
    assert bad_pixel_rate(result.disparity, scene.disparity, scene.nonocc) < 40.0


def test_full_pair_and_gray_left_are_refused_with_a_clear_message(scene):
    with pytest.raises(OptionError, match="stride 1 is a whole raw frame"):
        decode(scene.left, _mosaic_samples(scene.right, 1), max_disp=scene.max_disp)
    with pytest.raises(MismatchError, match="compared with an RGB left image"):
        decode(scene.left[:, :, 1], _mosaic_samples(scene.right, 3), max_disp=scene.max_disp)


@pytest.mark.parametrize("top", [0, 7, 10, 33])
def test_bands_keep_every_sample_colour(scene, top):
    ss = _mosaic_samples(scene.right, 3, offset_x=1, offset_y=2)
    band = band_samples(ss, top, top + 100)
    rows, cols = ss.positions()
    inside = (rows >= top) & (rows < top + 100)
    np.testing.assert_array_equal(band.sample_colours(), ss.sample_colours()[inside])


def test_tiled_decode_of_a_mosaic_matches_the_whole_frame(scene):
    ss = _mosaic_samples(scene.right, 3)
    whole = decode(scene.left, ss, max_disp=scene.max_disp, method="sparse")
    tiled = decode(scene.left, ss, max_disp=scene.max_disp, method="sparse", tile_rows=77, tile_overlap=33)
    whole_bad = bad_pixel_rate(whole.disparity, scene.disparity, scene.nonocc)
    assert abs(bad_pixel_rate(tiled.disparity, scene.disparity, scene.nonocc) - whole_bad) < 2.0


def test_recovered_right_image_is_rgb_with_each_sample_written_back_in_its_colour(scene):
    ss = _mosaic_samples(scene.right, 3, pattern="gbrg")
    disparity = decode(scene.left, ss, max_disp=scene.max_disp).disparity
    recovered = recover_right(scene.left, disparity, ss)
    assert recovered.image.shape == scene.right.shape and recovered.image.dtype == np.uint8
    rows, cols = ss.positions()
    np.testing.assert_array_equal(recovered.image[rows, cols, ss.sample_colours()], ss.values[:, 0])
    assert np.isfinite(recovered.psnr_at_samples_before_enhancement)
    # Î2 is close to the true right image (the warp carries the colours the samples lack).
    error = np.abs(recovered.image.astype(float) - scene.right.astype(float))[scene.nonocc].mean()
    assert error < 12.0
