"""The disparity range estimate and the checks behind sb-decode's warnings, on synthetic scenes with exact truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereobudget.decoding import (estimate_disparity_range, is_auto, limit_shares, psnr_at_samples,
                                   psnr_at_zero_disparity, resolve_range, result_warnings, setup_warnings,
                                   top_share, widened_max)
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene

GRID = SamplingPattern("grid", 5, 5)


@pytest.fixture(scope="module")
def planes():
    return make_scene("planes", seed=3)


@pytest.mark.parametrize("kind", ["planes", "slanted", "large_range"])
@pytest.mark.parametrize("pattern", [GRID, SamplingPattern("jitter", 5, 5, seed=1),
                                     SamplingPattern("downsample", 4, 4)], ids=lambda p: p.kind)
def test_estimate_contains_the_true_range_and_stays_tight(kind, pattern):
    scene = make_scene(kind, seed=1)
    estimate = estimate_disparity_range(scene.left, encode_image(scene.right, pattern=pattern))
    assert not estimate.fallback
    assert estimate.min_disp == 0 <= scene.disparity.min()
    top = float(scene.disparity.max())
    assert top <= estimate.max_disp <= 1.25 * top + 12, (estimate, top)
    assert estimate.vertical_offset == 0
    assert estimate.positive_fraction > 0.9 and estimate.negative_fraction < 0.05


def test_swapped_pair_gives_negative_matches_and_a_warning(planes):
    estimate = estimate_disparity_range(planes.right, encode_image(planes.left, pattern=GRID))
    assert estimate.negative_fraction > 0.9
    assert estimate.min_disp <= -float(planes.disparity.max())
    assert [w.code for w in setup_warnings(estimate)] == ["swapped"]


@pytest.mark.parametrize("rows", [3, -5])
def test_vertical_offset_is_found_and_warned(planes, rows):
    # The right image moved down by `rows`: its row y shows what I1 shows at y - rows.
    moved = np.roll(planes.right, rows, axis=0)
    estimate = estimate_disparity_range(planes.left, encode_image(moved, pattern=GRID))
    assert abs(estimate.vertical_offset + rows) <= 1, estimate.vertical_scores
    warnings = setup_warnings(estimate)
    assert [w.code for w in warnings] == ["not_rectified"]
    assert f"{abs(estimate.vertical_offset)} row(s)" in warnings[0].message
    # The range is measured at the offset found, so it still holds the truth.
    assert estimate.max_disp >= planes.disparity.max()


def test_one_row_is_found_but_not_warned(planes):
    estimate = estimate_disparity_range(planes.left, encode_image(np.roll(planes.right, 1, axis=0), pattern=GRID))
    assert estimate.vertical_offset == -1
    assert setup_warnings(estimate) == []


def test_rectified_pair_gives_no_setup_warning(planes):
    assert setup_warnings(estimate_disparity_range(planes.left, encode_image(planes.right, pattern=GRID))) == []


def test_unrelated_images_fall_back_to_a_wide_range():
    rng = np.random.default_rng(0)
    flat = np.full((96, 128, 3), 120, np.uint8)
    noise = rng.integers(0, 4, size=flat.shape, dtype=np.uint8)
    estimate = estimate_disparity_range(flat, encode_image(flat + noise, pattern=GRID))
    assert estimate.fallback and (estimate.min_disp, estimate.max_disp) == (0, 32)
    # Noise of 0-3 gray levels is no texture: nothing to match, and said so.
    assert estimate.textured_fraction < 0.05
    assert [w.code for w in setup_warnings(estimate)] == ["no_texture"]


def test_textured_pair_has_texture_and_a_constant_one_warns(planes):
    assert estimate_disparity_range(planes.left, encode_image(planes.right, pattern=GRID)).textured_fraction > 0.5
    flat = np.full((96, 128, 3), 77, np.uint8)
    estimate = estimate_disparity_range(flat, encode_image(flat, pattern=GRID))
    assert estimate.textured_fraction == 0.0
    warnings = setup_warnings(estimate)
    assert [w.code for w in warnings] == ["no_texture"] and "no texture to match" in warnings[0].message


def test_left_image_that_is_the_sampled_one_is_told(planes):
    samples = encode_image(planes.right, pattern=GRID)
    assert psnr_at_zero_disparity(planes.right, samples) == math.inf
    assert psnr_at_zero_disparity(planes.left, samples) < 24.0
    zeros = np.zeros_like(planes.disparity)
    codes = [w.code for w in result_warnings(zeros, min_disp=0, max_disp=8, psnr=math.inf, zero_psnr=math.inf)]
    assert codes == ["left_is_samples"]
    # A real pair, decoded right: no such warning.
    assert result_warnings(planes.disparity, min_disp=0, max_disp=40, psnr=30.0,
                           zero_psnr=psnr_at_zero_disparity(planes.left, samples)) == []


def test_crowded_top_of_an_estimated_range_is_widened(planes):
    top = float(planes.disparity.max())
    cut = int(top * 0.6)
    clipped = np.minimum(planes.disparity, cut).astype(np.float32)
    assert top_share(clipped, max_disp=cut) > 0.005
    wider = widened_max(clipped, min_disp=0, max_disp=cut, width=planes.left.shape[1])
    assert wider is not None and wider >= top
    assert widened_max(planes.disparity, min_disp=0, max_disp=int(top) + 8, width=planes.left.shape[1]) is None
    # Still crowded after widening: the estimated range warns (a given one only at 5 %).
    codes = [w.code for w in result_warnings(clipped, min_disp=0, max_disp=cut, psnr=None, auto_range=True)]
    assert codes == ["range_limit"]


def test_resolve_range_rules(planes):
    samples = encode_image(planes.right, pattern=GRID)
    low, high, estimate = resolve_range(planes.left, samples)
    assert (low, high) == (estimate.min_disp, estimate.max_disp)
    assert resolve_range(planes.left, samples, max_disp=20)[:2] == (0, 20)
    assert resolve_range(planes.left, samples, max_disp="AUTO", min_disp=3)[:2] == (3, estimate.max_disp)
    assert is_auto(None) and is_auto(" auto ") and not is_auto(12)


def test_result_warnings_on_a_too_small_range(planes):
    d = np.clip(planes.disparity, 0, 12).astype(np.float32)
    low, high = limit_shares(d, min_disp=0, max_disp=12)
    assert low == 0 and high == pytest.approx(np.mean(planes.disparity >= 11.5), abs=1e-6)
    codes = [w.code for w in result_warnings(d, min_disp=0, max_disp=12, psnr=15.0)]
    assert codes == ["range_limit", "samples_disagree"]
    assert result_warnings(planes.disparity, min_disp=0, max_disp=40, psnr=30.0) == []
    # Pixels at a min_disp of 0 are a far background, not a range problem.
    assert result_warnings(np.zeros_like(d), min_disp=0, max_disp=40, psnr=None) == []


def test_psnr_at_samples_is_high_for_the_truth_and_low_for_a_wrong_map(planes):
    samples = encode_image(planes.right, pattern=GRID)
    good = psnr_at_samples(planes.left, planes.disparity, samples)
    bad = psnr_at_samples(planes.left, np.full_like(planes.disparity, 2.0), samples)
    assert good > 40 and bad < good - 15, (good, bad)
    assert math.isnan(psnr_at_samples(planes.left, planes.disparity,
                                      encode_image(planes.right, pattern=SamplingPattern("downsample", 4, 4))))


@pytest.mark.parametrize("pattern", [GRID, SamplingPattern("jitter", 4, 4)])
def test_psnr_at_samples_equals_the_whole_warp_read_at_the_samples(planes, pattern):
    """The check warps only the rows that hold samples: the same PSNR as the whole image's warp."""
    from stereobudget.synthesis import sample_arrays, warp_left_to_right
    samples = encode_image(planes.right, pattern=pattern)
    disparity = planes.disparity + np.random.default_rng(3).normal(0, 0.7, planes.disparity.shape)
    rows, cols, values = sample_arrays(samples)
    warped, holes = warp_left_to_right(planes.left, disparity)
    reached = ~holes[rows, cols]
    diff = warped[rows[reached], cols[reached]].astype(np.float64) - values[reached]
    want = 10.0 * math.log10(255.0 ** 2 / float(np.mean(diff * diff)))
    assert psnr_at_samples(planes.left, disparity, samples) == want


@pytest.mark.parametrize("kind", ["grid", "jitter", "fps", "adaptive_fps", "downsample"])
@pytest.mark.parametrize("shape", [(2, 7), (1, 50), (7, 2), (3, 3), (10, 4)], ids=lambda s: f"{s[0]}x{s[1]}")
def test_an_image_smaller_than_the_stride_gets_a_range_that_fits_it(kind, shape):
    # Scattered points and block means were read on a lattice with no point in such an image.
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    samples = encode_image(np.roll(left, -1, axis=1), pattern=SamplingPattern(kind, 5, 5, seed=1))
    estimate = estimate_disparity_range(left, samples)
    assert 0 <= estimate.min_disp < estimate.max_disp <= max(1, shape[1] - 1)
    low, high, _ = resolve_range(left, samples, max_disp=1)
    assert (low, high) == (0, 1)
