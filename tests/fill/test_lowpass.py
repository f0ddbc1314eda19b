import cv2
import numpy as np
import pytest

from stereobudget.cost import to_float_image
from stereobudget.fill import gaussian_lowpass, gaussian_taps, lowpass_interpolation
from stereobudget.io import SampleSet
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern


def _impulse_blur(samples, sigma):
    """The definition: blur the impulse image and its mask with OpenCV, divide where reached."""
    rows, cols = samples.positions()
    values = to_float_image(samples.values_rgb()[:, None, :])[:, 0, :]  # float32 (n, C), 8-bit units
    impulses = np.zeros((samples.height, samples.width, values.shape[1] + 1), np.float32)
    impulses[rows, cols, :-1] = values
    impulses[rows, cols, -1] = 1.0
    blurred = cv2.GaussianBlur(impulses, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_CONSTANT)
    weight = blurred[..., -1:]
    reached = weight > 1e-4 * len(rows) / (samples.height * samples.width)
    return np.where(reached, blurred[..., :-1] / np.maximum(weight, 1e-30), 0.0), reached[..., 0]


@pytest.mark.parametrize("stride,offset_x,offset_y,sigma", [
    (5, 0, 0, 2.5), (5, 2, 3, 2.5), (3, 1, 0, 1.5), (11, 4, 7, 1.0), (11, 0, 10, 5.5), (4, 3, 1, 0.4)])
def test_grid_lowpass_is_the_impulse_image_blur(stride, offset_x, offset_y, sigma):
    rng = np.random.default_rng(stride + offset_x)
    image = rng.integers(0, 256, (61, 83, 3), dtype=np.uint8)
    samples = encode_image(image, pattern=SamplingPattern("grid", stride, stride, offset_x=offset_x,
                                                          offset_y=offset_y))
    expected, reached = _impulse_blur(samples, sigma)
    got = lowpass_interpolation(samples, sigma=sigma)
    assert got.dtype == np.float32 and got.shape == image.shape
    # The same taps summed in another order: equal to float32 rounding.
    np.testing.assert_allclose(got, expected, atol=2e-3)
    # Pixels out of the kernel's reach are 0 on both paths (sigma 1 at stride 11 leaves gaps).
    assert np.array_equal(got.max(axis=2) > 0, reached & (expected.max(axis=2) > 0))


def test_grid_lowpass_keeps_a_constant_image_up_to_the_border():
    image = np.empty((50, 70, 3), np.uint8)
    image[...] = (17, 128, 240)
    samples = encode_image(image, pattern=SamplingPattern("grid", 5, 5, offset_x=2, offset_y=4))
    got = lowpass_interpolation(samples, sigma=2.5)
    # Normalised by the mask's blur: no darkening at the frame's border, where the kernel is cut.
    np.testing.assert_allclose(got, np.broadcast_to(image, got.shape).astype(np.float32), rtol=1e-5)


def test_gaussian_taps_are_opencvs_kernel():
    taps = gaussian_taps(2.5)
    assert taps.dtype == np.float32 and taps.size == 21
    np.testing.assert_allclose(taps.sum(), 1.0, rtol=1e-6)
    impulse = np.zeros((1, 41), np.float32)
    impulse[0, 20] = 1.0
    blurred = cv2.GaussianBlur(impulse, (0, 0), sigmaX=2.5, sigmaY=1e-6, borderType=cv2.BORDER_CONSTANT)
    np.testing.assert_allclose(blurred[0, 10:31], taps, atol=1e-7)


def test_non_grid_patterns_take_the_impulse_path():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (40, 48, 3), dtype=np.uint8)
    samples = encode_image(image, pattern=SamplingPattern("jitter", 4, 4))
    assert isinstance(samples, SampleSet) and not samples.pattern.is_regular_grid
    expected, _ = _impulse_blur(samples, 2.0)
    np.testing.assert_allclose(lowpass_interpolation(samples, sigma=2.0), expected, atol=2e-3)


@pytest.mark.parametrize("shape, sigma", [((37, 45, 3), 2.5), ((37, 45, 3), 1.5), ((7, 5, 3), 2.5),
                                          ((2, 2, 3), 5.0), ((1, 9, 3), 2.5), ((300, 9, 1), 1.0),
                                          ((30, 40), 3.5)])
def test_gaussian_lowpass_is_opencvs_reflected_blur(shape, sigma):
    # The same taps and border as cv2.GaussianBlur(BORDER_REFLECT), summed on every thread:
    # equal to float rounding, also where the kernel is wider than the image (reflected
    # more than once) and where the rows are cut into several bands (300 rows at sigma 1).
    image = (np.random.default_rng(7).random(shape) * 255).astype(np.float32)
    expected = cv2.GaussianBlur(image, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    got = gaussian_lowpass(image, sigma=sigma)
    assert got.shape == image.shape and got.dtype == np.float32
    np.testing.assert_allclose(got, expected.reshape(shape), rtol=0, atol=2e-4)
