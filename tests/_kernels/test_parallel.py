"""Parallel kernels that replace numpy one-liners between stages: the same values, bit for bit."""

import numpy as np
import pytest

from stereobudget._kernels import fill_zero, take
from stereobudget.cost import float_and_gray, to_float_image, to_gray
from stereobudget.aggregate._refine import _stable_levels
from stereobudget.aggregate._mst import _uint16_keys


@pytest.mark.parametrize("size", [0, 1, 5, 70_000, 200_003])
def test_take_is_numpy_fancy_indexing(size):
    rng = np.random.default_rng(size)
    values = rng.normal(size=max(size, 1)).astype(np.float32)
    index = rng.permutation(max(size, 1))[:size].astype(np.int64)
    np.testing.assert_array_equal(take(values, index), values[index])


@pytest.mark.parametrize("size", [0, 1, 65_535, 65_536, 65_537, 300_001])
def test_fill_zero_clears_every_element(size):
    flat = np.full(size, 3.5, np.float32)
    fill_zero(flat)
    assert not flat.any()


@pytest.mark.parametrize("shape", [(1, 1, 3), (7, 5, 3), (375, 450, 3), (9, 11, 4)])
def test_luma_kernel_is_numpys_float32_expression(shape):
    image = np.random.default_rng(3).uniform(-20, 300, shape).astype(np.float32)
    r, g, b = image[:, :, 0], image[:, :, 1], image[:, :, 2]
    expected = np.float32(0.299) * r + np.float32(0.587) * g + np.float32(0.114) * b
    np.testing.assert_array_equal(to_gray(image), expected)
    # float64 input still goes through numpy (then float32), as documented.
    assert to_gray(image.astype(np.float64)).dtype == np.float32


@pytest.mark.parametrize("shape, dtype", [((37, 41, 3), np.uint8), ((1, 1, 3), np.uint8), ((5, 3, 3), np.uint16),
                                          ((9, 7), np.uint8), ((4, 4, 1), np.uint8)])
def test_float_and_gray_are_the_float_image_and_its_luma(shape, dtype):
    image = np.random.default_rng(7).integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    image_f32, gray = float_and_gray(image)
    np.testing.assert_array_equal(image_f32, to_float_image(image))
    np.testing.assert_array_equal(gray, to_gray(to_float_image(image)))
    assert image_f32.dtype == gray.dtype == np.float32


def test_uint16_keys_round_half_to_even_and_clip_like_numpy():
    rng = np.random.default_rng(4)
    image = rng.uniform(-10, 300, (31, 17, 3)).astype(np.float32)
    image[0, 0] = np.array([0.5, 1.5, 2.5], np.float32) / np.float32(257.0)  # ties
    expected = np.clip(np.rint(image * np.float32(257.0)), 0, 65535).astype(np.uint16)
    np.testing.assert_array_equal(_uint16_keys(image), expected)


def test_stable_levels_gather_rows_and_mark_unstable_pixels_nan():
    rng = np.random.default_rng(5)
    disp = rng.uniform(0, 60, 500).astype(np.float32)
    stable = rng.random(500) < 0.7
    order = rng.permutation(500).astype(np.int64)
    expected = np.where(stable, disp, np.float32(np.nan))[order]
    np.testing.assert_array_equal(_stable_levels(disp, stable, order), expected)
