"""End-to-end decoder behaviour on synthetic scenes with exact ground truth."""

import cv2
import numpy as np
import pytest

import stereobudget
from stereobudget.encoding import encode_image
from stereobudget.aggregate import winner_take_all
from stereobudget.decoding import DecoderParams
from stereobudget.errors import MismatchError, OptionError
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene


def _good_fraction(disparity, scene):
    m = scene.nonocc
    return float(np.mean(np.abs(disparity[m] - scene.disparity[m]) <= 1.0))


@pytest.fixture(scope="module", params=["planes", "slanted"])
def scene(request):
    return make_scene(request.param, seed=0)


@pytest.mark.parametrize("method", ["sparse", "hybrid"])
def test_stride5_recovers_95_percent_of_visible_pixels(scene, method):
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 5, 5))
    assert samples.epsilon == pytest.approx(0.04, abs=0.005)
    result = stereobudget.decode(scene.left, samples, max_disp=int(np.ceil(scene.max_disp)), method=method)
    assert result.disparity.shape == scene.left.shape[:2]
    assert result.disparity.dtype == np.float32
    assert _good_fraction(result.disparity, scene) >= 0.95


def test_jittered_grid_decodes_as_well(scene):
    samples = encode_image(scene.right, pattern=SamplingPattern("jitter", 5, 5, seed=7))
    result = stereobudget.decode(scene.left, samples, max_disp=int(np.ceil(scene.max_disp)), method="sparse")
    assert _good_fraction(result.disparity, scene) >= 0.95


def test_stride1_is_full_pair_stereo(scene):
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 1, 1))
    result = stereobudget.decode(scene.left, samples, max_disp=int(np.ceil(scene.max_disp)), method="sparse")
    assert result.method == "full"
    assert _good_fraction(result.disparity, scene) >= 0.97


def test_downsample_pattern_decodes_with_downsample_method():
    sc = make_scene("planes", seed=1)
    samples = encode_image(sc.right, pattern=SamplingPattern("downsample", 3, 3))
    result = stereobudget.decode(sc.left, samples, max_disp=int(np.ceil(sc.max_disp)))
    assert result.method == "downsample"
    assert _good_fraction(result.disparity, sc) >= 0.90


def test_min_disp_offsets_the_search_range():
    sc = make_scene("planes", seed=0)
    lo = int(np.floor(np.nanmin(sc.disparity))) - 1
    samples = encode_image(sc.right, pattern=SamplingPattern("grid", 5, 5))
    result = stereobudget.decode(sc.left, samples, min_disp=lo, max_disp=int(np.ceil(sc.max_disp)),
                                 method="sparse")
    assert np.nanmin(result.disparity) >= lo - 0.5
    assert _good_fraction(result.disparity, sc) >= 0.95


def test_uint16_and_gray_inputs_match_uint8_results():
    sc = make_scene("slanted", seed=2)
    p = SamplingPattern("grid", 4, 4)
    ref = stereobudget.decode(sc.left, encode_image(sc.right, pattern=p), max_disp=int(np.ceil(sc.max_disp)),
                              method="sparse").disparity
    left16 = sc.left.astype(np.uint16) * 257
    right16 = sc.right.astype(np.uint16) * 257
    d16 = stereobudget.decode(left16, encode_image(right16, pattern=p), max_disp=int(np.ceil(sc.max_disp)),
                              method="sparse").disparity
    assert np.mean(np.abs(d16 - ref) <= 0.25) > 0.99
    gray_l = sc.left.mean(axis=2).astype(np.uint8)
    gray_r = sc.right.mean(axis=2).astype(np.uint8)
    dg = stereobudget.decode(gray_l, encode_image(gray_r, pattern=p), max_disp=int(np.ceil(sc.max_disp)),
                             method="sparse").disparity
    assert _good_fraction(dg, sc) >= 0.9


def test_mismatched_inputs_are_refused():
    sc = make_scene("planes", seed=0, height=60, width=80)
    samples = encode_image(sc.right, pattern=SamplingPattern("grid", 5, 5))
    with pytest.raises(MismatchError, match="80x60"):
        stereobudget.decode(sc.left[:50], samples, max_disp=10)
    with pytest.raises(MismatchError, match="channel"):
        stereobudget.decode(sc.left[:, :, 0], samples, max_disp=10)
    with pytest.raises(MismatchError, match="uint16"):
        stereobudget.decode(sc.left.astype(np.uint16), samples, max_disp=10)
    with pytest.raises(OptionError):
        stereobudget.decode(sc.left, samples, max_disp=5, min_disp=5)
    with pytest.raises(OptionError):
        stereobudget.decode(sc.left, samples, max_disp=200)
    with pytest.raises(OptionError, match="unknown method"):
        stereobudget.decode(sc.left, samples, max_disp=10, method="magic")
    with pytest.raises(OptionError, match="downsample"):
        stereobudget.decode(sc.left, samples, max_disp=10, method="downsample")
    with pytest.raises(OptionError, match="stride 1"):  # "full" needs every pixel of I2
        stereobudget.decode(sc.left, samples, max_disp=10, method="full")
    with pytest.raises(OptionError, match="median_size"):  # OpenCV filters float32 maps at 3 and 5 only
        DecoderParams(median_size=7)
    with pytest.raises(OptionError, match="median_passes"):
        DecoderParams(median_passes=-1)


def test_winner_take_all_subpixel_parabola():
    d = np.arange(8, dtype=np.float32)
    # Parabola with its minimum at 3.3: the fit must recover it exactly.
    cost = ((d - 3.3) ** 2)[None, None, :].astype(np.float32)
    out = winner_take_all(np.ascontiguousarray(cost), 2)
    assert out[0, 0] == pytest.approx(5.3, abs=1e-4)


def test_timings_and_summary_are_reported(scene):
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 5, 5))
    result = stereobudget.decode(scene.left, samples, max_disp=int(np.ceil(scene.max_disp)), method="hybrid",
                                 params=DecoderParams())
    # The winners are taken inside the aggregation: there is no separate "wta" stage.
    assert {"jbf_fill", "interpolate", "cost", "aggregate", "refine"} == set(result.timings) - {"prepare"}
    tree_route = stereobudget.decode(scene.left, samples, max_disp=int(np.ceil(scene.max_disp)), method="hybrid",
                                     params=DecoderParams(hybrid_aggregation="tree"))
    assert {"tree", "jbf_fill", "interpolate", "cost", "aggregate", "refine"} == set(tree_route.timings) - {"prepare"}
    s = result.summary()
    assert s["method"] == "hybrid" and s["params"]["sigma_r"] == 15.0


def test_noise_level_tracks_added_noise_not_texture():
    from stereobudget.cost import noise_level, to_float_image
    levels = [noise_level(to_float_image(make_scene("slanted", seed=0, noise_sigma=s).left)) for s in (0, 4, 8)]
    assert levels[0] < 0.5  # a clean textured scene reads as (nearly) noise-free
    # Per-channel noise sigma s gives gray noise s / sqrt(3) = 2.3 and 4.6.
    assert 1.5 < levels[1] < 3.0 and 3.0 < levels[2] < 6.0


def test_noise_level_is_the_low_percentile_of_tile_mean_responses():
    # Immerkaer's response averaged over whole 8 x 8 tiles (a partial last tile row and
    # column ignored), read at the 20th percentile: a plain numpy statement of it.
    import cv2
    from stereobudget.cost import noise_level_of_gray
    gray = np.random.default_rng(4).normal(128, 3, (61, 83)).astype(np.float32)
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    response = np.abs(cv2.filter2D(gray.astype(np.float64), -1, kernel.astype(np.float64),
                                   borderType=cv2.BORDER_REFLECT))
    tiles = response[:56, :80].reshape(7, 8, 10, 8).mean(axis=(1, 3))
    expected = np.sqrt(np.pi / 2) / 6 * np.percentile(tiles, 20)
    assert noise_level_of_gray(gray) == pytest.approx(expected, rel=1e-5)
    assert noise_level_of_gray(gray[:20, :83]) == 0.0  # fewer than three tiles high: no estimate


def test_noisy_images_keep_costs_discriminative():
    from stereobudget.decoding import adapt_to_noise
    sc = make_scene("slanted", seed=0, noise_sigma=8)
    p = adapt_to_noise(DecoderParams(), sc.left, method="full")
    assert p.full_truncation > DecoderParams().full_truncation and p.noise_reference is None
    assert adapt_to_noise(DecoderParams(), make_scene("slanted", seed=0).left, method="full") \
        .full_truncation == DecoderParams().full_truncation
    samples = encode_image(sc.right, pattern=SamplingPattern("grid", 3, 3))
    result = stereobudget.decode(sc.left, samples, max_disp=int(np.ceil(sc.max_disp)), method="hybrid")
    assert _good_fraction(result.disparity, sc) >= 0.9
    # decode measures the noise on the gray I1 it makes anyway: the same adaptation.
    from stereobudget.cost import to_float_image, to_gray
    assert result.params == adapt_to_noise(DecoderParams(), sc.left, method="hybrid")
    assert adapt_to_noise(DecoderParams(), sc.left, method="hybrid", gray=to_gray(to_float_image(sc.left))) \
        == result.params


def test_sample_row_steps_are_exact_differences():
    from stereobudget.cost import sample_row_steps
    lattice = np.array([[1, 4, 9], [0, 0, 5]], np.float32)
    steps = sample_row_steps(lattice)
    assert steps[0, 0] == 3 and steps[0, 1] == 5 and steps[1, 1] == 5
    assert np.isnan(steps[:, 2]).all()


@pytest.mark.parametrize("min_disp", [0, -3, 4])
def test_diagonal_right_disparity_equals_the_right_view_winner(min_disp, right_view_reference):
    from stereobudget.aggregate import right_disparity_from_left
    from stereobudget.aggregate import build_tree, tree_layout
    rng = np.random.default_rng(3)
    aggregated = rng.random((7, 23, 9), dtype=np.float32)
    support = rng.uniform(1.0, 300.0, (7, 23)).astype(np.float32)
    # The diagonal search compares the support-normalised costs (weighted means) of left pixels.
    expected = winner_take_all(right_view_reference(aggregated / support[:, :, None], min_disp), min_disp)
    np.testing.assert_array_equal(right_disparity_from_left(aggregated, min_disp, support), expected)
    # The same from the volume in a tree's row layout.
    layout = tree_layout(build_tree(rng.integers(0, 255, (7, 23, 3), dtype=np.uint8)))
    rows = np.ascontiguousarray(aggregated.reshape(-1, 9)[layout.pixel_of_row])
    np.testing.assert_array_equal(right_disparity_from_left(rows, min_disp, support, layout=layout), expected)


def test_diagonal_search_is_not_drawn_to_pixels_of_small_support():
    # A constant-disparity scene whose aggregated costs carry very different supports per
    # pixel: normalised, every right pixel finds the true disparity; unnormalised it would
    # pick whichever left pixel has the least support.
    from stereobudget.aggregate import right_disparity_from_left
    rng = np.random.default_rng(4)
    h, w, nd, true_disparity = 5, 40, 8, 3
    means = np.full((h, w, nd), 5.0, np.float32)
    means[:, :, true_disparity] = 1.0
    support = rng.uniform(1.0, 500.0, (h, w)).astype(np.float32)
    aggregated = means * support[:, :, None]
    found = right_disparity_from_left(aggregated, 0, support)
    inner = found[:, : w - nd]  # right pixels whose whole diagonal lies inside the image
    assert np.allclose(inner, true_disparity, atol=0.5)


def test_diagonal_right_check_decodes_without_a_right_tree(scene):
    import dataclasses
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 5, 5))
    params = dataclasses.replace(DecoderParams(), right_check="diagonal")
    result = stereobudget.decode(scene.left, samples, max_disp=int(np.ceil(scene.max_disp)), method="hybrid",
                                 params=params)
    assert _good_fraction(result.disparity, scene) >= 0.95
    with pytest.raises(OptionError, match="right_check"):
        stereobudget.decode(scene.left, samples, max_disp=int(np.ceil(scene.max_disp)),
                            params=dataclasses.replace(DecoderParams(), right_check="both"))


def test_volume_rows_are_padded_to_whole_vectors():
    from stereobudget.cost import volume_layers
    assert [volume_layers(n) for n in (1, 7, 8, 9, 16, 61, 256)] == [8, 8, 8, 16, 16, 64, 256]


@pytest.mark.parametrize("method", ["sparse", "hybrid"])
def test_disparities_past_max_disp_never_win(method):
    # A fronto-parallel scene at disparity 12 searched up to 9: the padded layers (10..15,
    # computed alongside the 10 real ones) hold the true match and must not be chosen.
    rng = np.random.default_rng(4)
    left = cv2.GaussianBlur(rng.integers(0, 256, (60, 90, 3), dtype=np.uint8), (0, 0), 1.0)
    right = np.roll(left, -12, axis=1)
    samples = encode_image(right, pattern=SamplingPattern("grid", 3, 3))
    disparity = stereobudget.decode(left, samples, max_disp=9, method=method).disparity
    assert disparity.max() <= 9.0


def _exposed(image, gain, offset):
    """Another camera's exposure: a gain and an offset on every channel."""
    return np.clip(image.astype(np.float32) * gain + offset, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("kind", ["slanted", "large_range"])
def test_full_pair_survives_an_exposure_difference(kind):
    # Real camera pairs differ in gain: the census cost reads only the order of
    # neighbouring pixels, and semi-global aggregation keeps slanted planes slanted.
    sc = make_scene(kind, seed=2)
    samples = encode_image(_exposed(sc.right, 0.8, 12), pattern=SamplingPattern("grid", 1, 1))
    result = stereobudget.decode(sc.left, samples, max_disp=int(np.ceil(sc.max_disp)))
    assert result.method == "full"
    assert _good_fraction(result.disparity, sc) >= 0.97
    # The paper's absolute-difference cost on the tree does not survive it over a wide range
    # (measured 68 % good against 99.8 %).  On the slanted scene both do, within 0.02 pp of
    # each other (99.86 / 99.84 %), which is no ordering to test.
    paper = stereobudget.decode(sc.left, samples, max_disp=int(np.ceil(sc.max_disp)),
                                params=DecoderParams(full_cost="ad"))
    if kind == "large_range":
        assert _good_fraction(paper.disparity, sc) < _good_fraction(result.disparity, sc) - 0.1
    else:
        assert _good_fraction(paper.disparity, sc) >= 0.97


def test_unknown_full_cost_is_refused(scene):
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 1, 1))
    with pytest.raises(OptionError, match="full_cost"):
        stereobudget.decode(scene.left, samples, max_disp=8, params=DecoderParams(full_cost="sad"))


@pytest.mark.parametrize("aggregation", ["semiglobal", "semiglobal_census"])
def test_hybrid_on_semiglobal_paths_recovers_a_slanted_scene(aggregation):
    sc = make_scene("slanted", seed=3)
    samples = encode_image(_exposed(sc.right, 0.9, 8), pattern=SamplingPattern("grid", 5, 5))
    result = stereobudget.decode(sc.left, samples, max_disp=int(np.ceil(sc.max_disp)), method="hybrid",
                                 params=DecoderParams(hybrid_aggregation=aggregation))
    assert result.disparity.dtype == np.float32 and np.isfinite(result.disparity).all()
    assert _good_fraction(result.disparity, sc) >= 0.93


def test_an_image_one_pixel_wide_is_refused_for_what_it_is():
    left = np.random.default_rng(0).integers(0, 256, (20, 1, 3), dtype=np.uint8)
    samples = encode_image(left, pattern=SamplingPattern("grid", 5, 5))
    with pytest.raises(OptionError, match="the images are 1 pixel wide: a disparity needs at least two columns"):
        stereobudget.decode(left, samples, max_disp=1)
