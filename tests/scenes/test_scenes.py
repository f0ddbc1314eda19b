"""Synthetic scenes: the ground truth must be exact, so warping the right view reproduces the left."""

import numpy as np
import pytest

from stereobudget.scenes import SCENE_KINDS, SyntheticScene, make_scene

# Small sizes keep the suite fast; large_range needs a wide image for disparities past 100.
SIZES = {kind: dict(height=120, width=200) for kind in SCENE_KINDS}
SIZES["large_range"] = dict(height=100, width=400)


def scene(kind, **kwargs) -> SyntheticScene:
    return make_scene(kind, **{**SIZES[kind], **kwargs})


def warp_right_to_left(right: np.ndarray, disparity: np.ndarray):
    """Bilinear sample of ``right`` at (x - d, y) (float64), and the left neighbour column used."""
    h, w = disparity.shape
    y, x = np.mgrid[0:h, 0:w]
    xr = x - disparity.astype(np.float64)
    x0 = np.clip(np.floor(xr).astype(np.int64), 0, w - 2)
    t = xr - x0
    r = right.astype(np.float64)
    if r.ndim == 3:
        t = t[..., None]
    return (1 - t) * r[y, x0] + t * r[y, x0 + 1], x0


def abs_error(a, b):
    err = np.abs(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))
    return err.max(axis=-1) if err.ndim == 3 else err


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_warping_right_with_exact_disparity_reproduces_left(kind):
    s = scene(kind)
    warped, x0 = warp_right_to_left(s.right, s.disparity)
    err = abs_error(warped, s.left)
    h, w = s.disparity.shape
    rows = np.arange(h)[:, None]
    # Pixels whose two bilinear neighbours in the right view lie on the pixel's own surface:
    # there the only error is linear interpolation of the smooth texture plus 8-bit rounding,
    # which warp_error_bound bounds (curvature / 8 + 1 grey level).
    same_surface = ((s.surface_right[rows, x0] == s.surface_left)
                    & (s.surface_right[rows, x0 + 1] == s.surface_left))
    clean = s.nonocc & same_surface
    assert clean.sum() >= 0.97 * s.nonocc.sum()
    assert err[clean].max() <= s.warp_error_bound
    assert s.warp_error_bound <= 3.0  # the bound itself is tight enough to mean something
    # Over the whole nonocc mask (including pixels beside occlusion edges) the mean error
    # stays within the same tolerance.
    assert err[s.nonocc].mean() <= s.warp_error_bound


@pytest.mark.parametrize("kind", ["planes", "slanted", "fine_texture", "large_range"])
def test_wrong_disparity_breaks_the_warp(kind):
    s = scene(kind)
    good = abs_error(warp_right_to_left(s.right, s.disparity)[0], s.left)[s.nonocc].mean()
    bad = abs_error(warp_right_to_left(s.right, s.disparity + 1.5)[0], s.left)[s.nonocc].mean()
    assert bad > 4 * good + 2.0


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_disparity_range_dtype_and_mask(kind):
    s = scene(kind)
    h, w = SIZES[kind]["height"], SIZES[kind]["width"]
    assert s.left.shape == s.right.shape == (h, w, 3)
    assert s.left.dtype == s.right.dtype == np.uint8
    assert s.disparity.shape == s.nonocc.shape == (h, w)
    assert s.disparity.dtype == np.float32 and s.nonocc.dtype == bool
    assert np.isfinite(s.disparity).all()
    assert s.disparity.min() >= 0 and s.disparity.max() <= s.max_disp
    assert 0.5 < s.nonocc.mean() < 0.995
    # some occlusions are true half-occlusions, not only the strip that leaves the right image
    x = np.arange(w)[None, :]
    inside_right = x - s.disparity >= 0
    assert (~s.nonocc & inside_right).sum() > 20
    # several surfaces are visible, and the left and right views see different layouts
    assert len(np.unique(s.surface_left)) >= 3
    assert (s.surface_left != s.surface_right).any()


@pytest.mark.parametrize("kind", SCENE_KINDS)
def test_same_seed_same_scene_other_seed_other_scene(kind):
    a, b, c = scene(kind, seed=3), scene(kind, seed=3), scene(kind, seed=4)
    for name in ("left", "right", "disparity", "nonocc"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.left, c.left)
    assert not np.array_equal(a.disparity, c.disparity)


def test_kind_specific_properties():
    slanted = scene("slanted")
    step = np.diff(slanted.disparity.astype(np.float64), axis=1)
    assert np.count_nonzero(np.abs(step) > 1e-4) > 0.5 * step.size  # disparity varies inside surfaces

    fine = scene("fine_texture")
    np.testing.assert_array_equal(fine.disparity, np.rint(fine.disparity))
    assert scene("large_range").disparity.max() > 100

    textureless = scene("textureless")
    wall = textureless.surface_left == 0
    assert wall.mean() > 0.6
    assert np.ptp(textureless.left[wall].astype(int), axis=0).max() <= 1  # constant colour


def _high_frequency_share(s: SyntheticScene, cutoff: float) -> float:
    """Share of the texture's spectral energy (left luminance) above ``cutoff`` cycles/pixel.

    Each surface's mean is removed first so that the colour steps between surfaces (edges,
    not texture) do not count.
    """
    gray = s.left.astype(np.float64).mean(axis=-1)
    for label in np.unique(s.surface_left):
        on_surface = s.surface_left == label
        gray[on_surface] -= gray[on_surface].mean()
    spectrum = np.abs(np.fft.fft2(gray)) ** 2
    fy = np.fft.fftfreq(gray.shape[0])[:, None]
    fx = np.fft.fftfreq(gray.shape[1])[None, :]
    high = np.hypot(fx, fy) > cutoff
    return float(spectrum[high].sum() / spectrum.sum())


def test_fine_texture_lies_beyond_what_a_stride_5_grid_resolves():
    # stride 5 resolves at most 0.1 cycles/pixel; the fine texture lives around 0.3-0.45
    assert _high_frequency_share(scene("fine_texture"), 0.2) > 0.8
    assert _high_frequency_share(scene("planes"), 0.2) < 0.1


def test_noise_and_gray_options():
    clean = scene("planes", seed=1)
    noisy = scene("planes", seed=1, noise_sigma=2.0)
    np.testing.assert_array_equal(clean.disparity, noisy.disparity)
    diff = noisy.left.astype(float) - clean.left.astype(float)
    assert 1.0 < diff.std() < 3.0
    assert not np.array_equal(noisy.right, clean.right)

    gray = scene("planes", seed=1, gray=True)
    assert gray.left.shape == gray.disparity.shape and gray.left.dtype == np.uint8
    luma = clean.left.astype(float) @ np.array([0.299, 0.587, 0.114])
    assert np.abs(gray.left - luma).max() <= 1.0
    warped = warp_right_to_left(gray.right, gray.disparity)[0]
    assert abs_error(warped, gray.left)[gray.nonocc].mean() <= gray.warp_error_bound


def test_invalid_arguments_are_rejected():
    with pytest.raises(ValueError, match="unknown synthetic scene kind"):
        make_scene("mountains")
    with pytest.raises(ValueError, match="max_disp"):
        make_scene("planes", height=64, width=64, max_disp=40)
    with pytest.raises(ValueError, match="32x32"):
        make_scene("planes", height=16, width=64, max_disp=8)


