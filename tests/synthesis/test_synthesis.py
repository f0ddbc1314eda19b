"""Recovering I2: forward warp, inpainting from samples, enhancement, sample reinsertion."""

import numpy as np
import pytest

from stereobudget import synthesis
from stereobudget.encoding import encode_image
from stereobudget.errors import MismatchError, OptionError
from stereobudget.metrics import psnr
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene


def grid(stride, offset=0):
    return SamplingPattern("grid", stride, stride, offset, offset)


def covisible_interior(scene):
    """Right pixels whose surface point the left view also shows, away from right-view surface edges.

    Only for fronto-parallel scenes (one disparity per surface).  A right pixel at a
    surface's edge shows whichever surface covers its centre, which depends on where
    inside the pixel the edge lies; the left pixel grid cannot resolve that, so no warp
    can get those pixels right.  A right pixel whose point is hidden in the left view
    (by a third surface) is not a hole either: the warp shows what lies behind it.
    """
    h, w = scene.disparity.shape
    sr, sl = scene.surface_right, scene.surface_left
    per_surface = {k: float(scene.disparity[sl == k][0]) for k in np.unique(sl)}
    d_right = np.full((h, w), np.nan)
    for k, d in per_surface.items():
        d_right[sr == k] = d
    xl = np.arange(w)[None, :] + d_right
    known = np.isfinite(xl) & (xl <= w - 1)
    x0 = np.clip(np.floor(np.nan_to_num(xl)).astype(int), 0, w - 1)
    x1 = np.minimum(x0 + 1, w - 1)
    rows = np.arange(h)[:, None]
    seen = known & (sl[rows, x0] == sr) & (sl[rows, x1] == sr)
    interior = np.ones((h, w), bool)
    interior[:, 1:] &= sr[:, 1:] == sr[:, :-1]
    interior[:, :-1] &= sr[:, :-1] == sr[:, 1:]
    return seen & interior


def two_layer_scene(height=40, width=64, background_d=3, foreground_d=11, box=(30, 10, 50, 30)):
    """Fronto-parallel background + foreground rectangle, integer disparities; exact views.

    Returns left, right (uint8 RGB), left disparity and the exact hole mask of a forward
    warp: right pixels whose surface point the left view does not show (the
    disocclusion beside the rectangle and the background strip beyond I1's right edge).
    """
    x0, y0, x1, y1 = box
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)

    def texture(xl, y, phase):
        return np.stack([128 + 60 * np.sin(0.31 * xl + 0.17 * y + phase + c) for c in range(3)], axis=-1)

    in_box = lambda xl, y: (xl >= x0) & (xl < x1) & (y >= y0) & (y < y1)  # noqa: E731
    fg_left = in_box(xx, yy)
    left = np.where(fg_left[..., None], texture(xx, yy, 1.0), texture(xx, yy, 0.0))
    disparity = np.where(fg_left, foreground_d, background_d).astype(np.float32)
    fg_right = in_box(xx + foreground_d, yy)
    right = np.where(fg_right[..., None], texture(xx + foreground_d, yy, 1.0), texture(xx + background_d, yy, 0.0))
    bg_point = xx + background_d
    holes = ~fg_right & ((bg_point > width - 1) | in_box(bg_point, yy))
    to8 = lambda a: np.clip(np.rint(a), 0, 255).astype(np.uint8)  # noqa: E731
    return to8(left), to8(right), disparity, holes


# ----------------------------------------------------------------------------- warp

@pytest.mark.parametrize("mode", synthesis.WARP_MODES)
@pytest.mark.parametrize("seed", [0, 1])
def test_integer_fronto_parallel_scene_warps_exactly(mode, seed):
    # fine_texture: fronto-parallel layers with integer disparities, so every non-hole
    # right pixel is a copy of one left pixel: the warp must be exact, not just > 40 dB.
    s = make_scene("fine_texture", height=64, width=112, seed=seed)
    warped, holes = synthesis.warp_left_to_right(s.left, s.disparity, mode=mode)
    assert 0.02 < holes.mean() < 0.2
    assert psnr(warped, s.right.astype(np.float32), mask=~holes, peak=255) == np.inf


@pytest.mark.parametrize("kind,size", [("planes", (80, 128)), ("large_range", (64, 400))])
@pytest.mark.parametrize("seed", [0, 1, 3])
def test_fractional_disparity_warp_above_40db(kind, size, seed):
    s = make_scene(kind, height=size[0], width=size[1], seed=seed)
    warped, holes = synthesis.warp_left_to_right(s.left, s.disparity)
    clean = covisible_interior(s)
    assert clean.mean() > 0.75
    assert not (clean & holes).any(), "a pixel both views see must be reached by the warp"
    right = s.right.astype(np.float32)
    assert psnr(warped, right, mask=clean, peak=255) > 40.0
    # Linear interpolation of a smooth texture + 8-bit rounding: the scene's own bound.
    assert np.abs(warped - right)[clean].max() <= s.warp_error_bound
    # Rounding x - d instead of interpolating is measurably worse on the same pixels.
    nearest, _ = synthesis.warp_left_to_right(s.left, s.disparity, mode="nearest")
    assert psnr(nearest, right, mask=clean, peak=255) < psnr(warped, right, mask=clean, peak=255)


@pytest.mark.parametrize("mode", synthesis.WARP_MODES)
def test_holes_are_exactly_the_disoccluded_pixels(mode):
    left, right, disparity, expected_holes = two_layer_scene()
    warped, holes = synthesis.warp_left_to_right(left, disparity, mode=mode)
    np.testing.assert_array_equal(holes, expected_holes)
    # The disocclusion is as wide as the disparity jump, beside the rectangle's right edge.
    assert expected_holes[20].sum() == (11 - 3) + 3
    np.testing.assert_array_equal(warped[~holes], right[~holes].astype(np.float32))
    assert (warped[holes] == 0).all()


def test_nearer_surface_wins_and_blends_only_with_itself():
    # Two left pixels land on the same right pixel: the larger disparity must win.
    left = np.zeros((1, 8, 1), np.uint8)
    left[0, 2, 0], left[0, 5, 0] = 50, 200
    disparity = np.full((1, 8), np.nan, np.float32)
    disparity[0, 2], disparity[0, 5] = 0.0, 3.0      # both land on right column 2
    for mode in synthesis.WARP_MODES:
        warped, holes = synthesis.warp_left_to_right(left, disparity, mode=mode)
        assert warped[0, 2, 0] == 200, mode
        assert holes[0, 2] == np.False_


def test_constant_fractional_disparity_is_linear_interpolation():
    rng = np.random.default_rng(3)
    left = rng.integers(0, 256, (6, 40, 3), dtype=np.uint8)
    d = 2.25
    disparity = np.full((6, 40), d, np.float32)
    xs = np.arange(40)
    src = xs + d                       # where each right pixel's point lies in the left image
    inside = src <= 39
    x0 = np.floor(src[inside]).astype(int)
    t = (src[inside] - x0)[None, :, None]
    expected = (1 - t) * left[:, x0] + t * left[:, x0 + 1]
    # The last left pixel's footprint [38.5, 39.5] reaches half a pixel beyond it.
    edge = (src > 39) & (src <= 39.5)
    for mode in ("linear", "splat"):
        warped, holes = synthesis.warp_left_to_right(left, disparity, mode=mode)
        np.testing.assert_allclose(warped[:, inside], expected, atol=1e-3)
        np.testing.assert_allclose(warped[:, edge], np.repeat(left[:, 39:40], edge.sum(), axis=1), atol=1e-3)
        np.testing.assert_array_equal(holes, np.broadcast_to(src > 39.5, holes.shape))


def test_nan_disparities_are_skipped_and_leave_holes():
    s = make_scene("fine_texture", height=48, width=96, seed=2)
    disparity = s.disparity.copy()
    disparity[10:20, 40:60] = np.nan
    _, holes_full = synthesis.warp_left_to_right(s.left, s.disparity)
    warped, holes = synthesis.warp_left_to_right(s.left, disparity)
    assert holes.sum() > holes_full.sum()
    assert np.isfinite(warped).all()
    assert psnr(warped, s.right.astype(np.float32), mask=~holes, peak=255) == np.inf


def rows_of_surfaces(rng, height, width):
    """Disparity rows of slanted surfaces with jumps both ways and a few invalid pixels, on a
    1/1024 grid so that landing points are exact in float32 as in float64."""
    disparity = np.empty((height, width))
    for y in range(height):
        edges = np.sort(rng.choice(np.arange(3, width - 3), size=4, replace=False))
        for start, stop in zip(np.r_[0, edges], np.r_[edges, width]):
            x = np.arange(start, stop)
            disparity[y, start:stop] = rng.uniform(0, 9) + rng.uniform(-0.6, 0.6) * (x - start)
    disparity = np.clip(disparity, -2, 14)
    disparity[rng.random(disparity.shape) < 0.03] = np.nan
    return (np.round(disparity * 1024) / 1024).astype(np.float32)


@pytest.mark.parametrize("mode", synthesis.WARP_MODES)
@pytest.mark.parametrize("z_tolerance", [1.0, 0.3])
@pytest.mark.parametrize("seed", range(3))
def test_warp_is_the_gathered_reference(mode, z_tolerance, seed):
    rng = np.random.default_rng(seed)
    left = rng.uniform(0, 255, (7, 41, 3)).astype(np.float32)
    disparity = rows_of_surfaces(rng, 7, 41)
    warped, holes = synthesis.warp_left_to_right(left, disparity, mode=mode, z_tolerance=z_tolerance)
    expected, expected_holes = synthesis.warp_reference(left, disparity, mode=mode, z_tolerance=z_tolerance)
    np.testing.assert_array_equal(holes, expected_holes)
    # float32 sums of a few weighted colours against float64 ones
    np.testing.assert_allclose(warped, expected, rtol=0, atol=2e-3)


def test_warp_rejects_unknown_mode_and_wrong_shape():
    s = make_scene("planes", height=40, width=64, max_disp=8)
    with pytest.raises(OptionError):
        synthesis.warp_left_to_right(s.left, s.disparity, mode="cubic")
    with pytest.raises(MismatchError):
        synthesis.warp_left_to_right(s.left, s.disparity[:, :-1])


# ----------------------------------------------------------------------------- inpainting

@pytest.mark.parametrize("offset", [0, 2])
def test_grid_interpolation_passes_through_the_samples(offset):
    s = make_scene("planes", height=60, width=90, max_disp=16)
    samples = encode_image(s.right, pattern=grid(4, offset))
    dense = synthesis.interpolate_samples(samples)
    rows, cols = samples.positions()
    np.testing.assert_allclose(dense[rows, cols], samples.values.astype(np.float32), atol=1e-3)
    # A smooth texture is well interpolated between samples too.
    assert psnr(dense, s.right.astype(np.float32), mask=s.surface_right == 0, peak=255) > 25


def test_jitter_interpolation_is_a_normalised_spatial_fill():
    s = make_scene("textureless", height=64, width=96)
    pattern = SamplingPattern("jitter", 4, 4, seed=7)
    samples = encode_image(s.right, pattern=pattern)
    dense = synthesis.interpolate_samples(samples)
    assert dense.shape == s.right.shape and np.isfinite(dense).all()
    assert psnr(dense, s.right.astype(np.float32), peak=255) > 20


def test_inpainting_changes_only_the_holes():
    left, right, disparity, _ = two_layer_scene()
    samples = encode_image(right, pattern=grid(3))
    warped, holes = synthesis.warp_left_to_right(left, disparity)
    filled = synthesis.inpaint_from_samples(warped, holes, samples)
    np.testing.assert_array_equal(filled[~holes], warped[~holes])
    dense = synthesis.interpolate_samples(samples)
    np.testing.assert_array_equal(filled[holes], dense[holes])


# ----------------------------------------------------------------------------- enhancement / recovery

def perturbed_disparity(scene):
    """Exact disparity with a smooth 1.5-px error over the left half (a typical decoder failure)."""
    d = scene.disparity.copy()
    w = d.shape[1]
    d[:, : w // 2] += 1.5
    return d


@pytest.mark.parametrize("stride,min_gain", [(3, 1.0), (5, 0.25)])
def test_enhancement_raises_psnr_when_the_disparity_is_wrong(stride, min_gain):
    s = make_scene("planes", height=96, width=160, seed=4)
    samples = encode_image(s.right, pattern=grid(stride))
    d = perturbed_disparity(s)
    plain = synthesis.recover_right(s.left, d, samples,
                                    params=synthesis.SynthesisParams(enhance=False, reinsert_samples=False))
    enhanced = synthesis.recover_right(s.left, d, samples,
                                       params=synthesis.SynthesisParams(enhance=True, reinsert_samples=False))
    truth = s.right
    gain = psnr(enhanced.image, truth, mask=~plain.holes) - psnr(plain.image, truth, mask=~plain.holes)
    assert gain > min_gain
    # Holes are not touched by the enhancement.
    np.testing.assert_array_equal(enhanced.image[plain.holes], plain.image[plain.holes])
    # The host's own estimate (PSNR at the samples) sees the improvement too.
    assert enhanced.psnr_at_samples_before_reinsertion > enhanced.psnr_at_samples_before_enhancement
    assert plain.psnr_at_samples_before_reinsertion == plain.psnr_at_samples_before_enhancement


def test_unshrunk_enhancement_is_the_papers_filter_and_also_helps():
    s = make_scene("planes", height=96, width=160, seed=4)
    samples = encode_image(s.right, pattern=grid(3))
    d = perturbed_disparity(s)
    warped, holes = synthesis.warp_left_to_right(s.left, d)
    estimate = synthesis.inpaint_from_samples(warped, holes, samples)
    paper = synthesis.enhance_with_samples(estimate, holes, samples, shrinkage=None)
    truth = s.right.astype(np.float32)
    assert psnr(paper, truth, mask=~holes, peak=255) > psnr(estimate, truth, mask=~holes, peak=255) + 0.5


@pytest.mark.parametrize("pattern", [grid(4), grid(3, 1), SamplingPattern("jitter", 4, 4, seed=11)])
def test_samples_are_reproduced_exactly(pattern):
    s = make_scene("slanted", height=64, width=96, max_disp=16)
    samples = encode_image(s.right, pattern=pattern)
    out = synthesis.recover_right(s.left, perturbed_disparity(s), samples)
    rows, cols = samples.positions()
    np.testing.assert_array_equal(out.image[rows, cols], samples.values)
    assert np.isfinite(out.psnr_at_samples_before_reinsertion)
    assert set(out.timings) == {"warp", "inpaint", "enhance"}


def test_coded_samples_are_trusted_only_as_far_as_their_coding_allows():
    from stereobudget.io import read_samples, write_samples

    s = make_scene("slanted", height=64, width=96, max_disp=16)
    exact = encode_image(s.right, pattern=grid(4))
    rows, cols = exact.positions()
    disparity = perturbed_disparity(s)
    # Dropped bits: each recovered sample pixel lies in the interval its kept bits allow.
    five = read_samples(write_samples(exact, value_bits=5))
    out = synthesis.recover_right(s.left, disparity, five)
    at = out.image[rows, cols].astype(int)
    low = (exact.values >> 3 << 3).astype(int)
    assert ((at >= low) & (at <= low + 7)).all()
    assert not np.array_equal(at, five.values)      # clamped, not the interval's middle written back
    # A lossy codec: no write-back, the estimate stays what the enhancement made of it.
    lossy = read_samples(write_samples(exact, codec="webp", quality=60))
    if lossy.lossy:
        out = synthesis.recover_right(s.left, disparity, lossy)
        kept = synthesis.recover_right(s.left, disparity, lossy,
                                       params=synthesis.SynthesisParams(reinsert_samples=False))
        np.testing.assert_array_equal(out.image, kept.image)


def test_bgr_samples_give_the_same_image_as_rgb():
    s = make_scene("planes", height=64, width=96, max_disp=16)
    rgb = encode_image(s.right, pattern=grid(3))
    bgr = encode_image(np.ascontiguousarray(s.right[:, :, ::-1]), pattern=grid(3), channel_order="bgr")
    a = synthesis.recover_right(s.left, s.disparity, rgb)
    b = synthesis.recover_right(s.left, s.disparity, bgr)
    np.testing.assert_array_equal(a.image, b.image)
    assert a.psnr_at_samples_before_reinsertion == b.psnr_at_samples_before_reinsertion


def test_uint16_round_trip_keeps_dtype_and_matches_8bit():
    s = make_scene("planes", height=64, width=96, max_disp=16)
    left16 = s.left.astype(np.uint16) * 257
    right16 = s.right.astype(np.uint16) * 257
    samples16 = encode_image(right16, pattern=grid(3))
    out16 = synthesis.recover_right(left16, s.disparity, samples16)
    out8 = synthesis.recover_right(s.left, s.disparity, encode_image(s.right, pattern=grid(3)))
    assert out16.image.dtype == np.uint16 and out16.image.shape == s.right.shape
    # Same pipeline in 8-bit units: at most one 8-bit step apart (rounding).
    assert np.abs(out16.image.astype(np.int64) - out8.image.astype(np.int64) * 257).max() <= 257
    rows, cols = samples16.positions()
    np.testing.assert_array_equal(out16.image[rows, cols], samples16.values)
    assert abs(psnr(out16.image, right16) - psnr(out8.image, s.right)) < 0.1


def test_gray_round_trip_keeps_two_dimensions():
    s = make_scene("planes", height=64, width=96, max_disp=16, gray=True)
    samples = encode_image(s.right, pattern=grid(3))
    out = synthesis.recover_right(s.left, s.disparity, samples)
    assert out.image.shape == s.right.shape and out.image.ndim == 2 and out.image.dtype == np.uint8
    rows, cols = samples.positions()
    np.testing.assert_array_equal(out.image[rows, cols], samples.values[:, 0])
    assert psnr(out.image, s.right) > 30


def test_recovery_rejects_mismatched_inputs():
    s = make_scene("planes", height=64, width=96, max_disp=16)
    samples = encode_image(s.right, pattern=grid(3))
    with pytest.raises(MismatchError):
        synthesis.recover_right(s.left[:, :-1], s.disparity[:, :-1], samples)
    with pytest.raises(MismatchError):
        synthesis.recover_right(s.left.astype(np.uint16), s.disparity, samples)
    with pytest.raises(MismatchError):
        synthesis.recover_right(s.left, s.disparity[:-1], samples)
    with pytest.raises(OptionError):
        synthesis.recover_right_from_block_means(s.left, s.disparity, samples)    # not block means


@pytest.mark.parametrize("block", [3, 4])
def test_block_means_are_recovered_by_back_projection(block):
    from stereobudget.sampling import downsample_blocks
    s = make_scene("planes", height=96, width=160, seed=4)
    samples = encode_image(s.right, pattern=SamplingPattern("downsample", block, block))
    d = perturbed_disparity(s)
    plain = synthesis.recover_right(s.left, d, samples, params=synthesis.SynthesisParams(enhance=False))
    out = synthesis.recover_right(s.left, d, samples)
    assert out.image.shape == s.right.shape and out.image.dtype == np.uint8
    # The back-projection corrects the warp errors: better than warp + inpaint ...
    assert psnr(out.image, s.right) > psnr(plain.image, s.right) + 0.5
    # ... and the result's own block means are the camera's (up to rounding and clipping).
    error = np.abs(downsample_blocks(out.image, samples.pattern).astype(int) - samples.values.astype(int))
    assert np.mean(error) < 0.5 and error.max() <= 3
    assert out.psnr_at_samples_before_reinsertion > out.psnr_at_samples_before_enhancement


def test_synthesis_params_refuse_an_unknown_warp_mode():
    from stereobudget.errors import OptionError
    with pytest.raises(OptionError, match="unknown warp mode 'cubic'"):
        synthesis.SynthesisParams(warp_mode="cubic")
