"""Kernels run on threads (run_parts), and the parallel forms of numpy one-liners: the same values, bit for bit."""

import os
import sys
import threading
import warnings

import numba
import numpy as np
import pytest
from numba import njit

from stereobudget._kernels import fill_zero, part_bounds, run_parts, take
from stereobudget._kernels._parallel import stop_workers
from stereobudget.cost import float_and_gray, to_float_image, to_gray
from stereobudget.aggregate._refine import _stable_levels
from stereobudget.aggregate._mst import _uint16_keys


@njit(nogil=True)
def _count_visits(visits, first, stop):
    for i in range(first, stop):
        visits[i] += 1


@pytest.mark.parametrize("count", [0, 1, 2, 3, 7, 1000])
@pytest.mark.parametrize("parts", [None, 1, 2, 5])
def test_run_parts_runs_every_item_once(count, parts):
    visits = np.zeros(count, np.int64)
    run_parts(_count_visits, count, visits, parts=parts)
    np.testing.assert_array_equal(visits, np.ones(count, np.int64))


@pytest.mark.parametrize("count, parts", [(10, 3), (2, 2), (5, 8), (0, 2)])
def test_part_bounds_are_contiguous_and_even(count, parts):
    bounds = part_bounds(count, parts)
    assert bounds[0] == 0 and bounds[-1] == count and len(bounds) == parts + 1
    sizes = np.diff(bounds)
    assert sizes.min() >= 0 and sizes.max() - sizes.min() <= 1


def test_run_parts_uses_other_threads_and_one_when_numba_has_one():
    threads = []

    def record(first, stop):
        threads.append((threading.get_ident(), first, stop))

    run_parts(record, 4, parts=2)
    if numba.get_num_threads() >= 2:
        assert sorted((a, b) for _, a, b in threads) == [(0, 2), (2, 4)]
        assert len({ident for ident, _, _ in threads}) == 2
    saved = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        threads.clear()
        run_parts(record, 4)
        assert threads == [(threading.get_ident(), 0, 4)]
    finally:
        numba.set_num_threads(saved)


def test_run_parts_raises_a_parts_error_after_every_part_has_finished():
    finished = []

    def part(first, stop):
        if first > 0:
            raise ValueError("bad part")
        finished.append(first)

    with pytest.raises(ValueError, match="bad part"):
        run_parts(part, 4, parts=2)
    assert finished == [0]


def test_stop_workers_leaves_no_pool_thread_and_the_next_call_starts_again():
    visits = np.zeros(6, np.int64)
    run_parts(_count_visits, 6, visits, parts=2)
    stop_workers()
    assert not [t for t in threading.enumerate() if t.name.startswith("stereobudget")]
    run_parts(_count_visits, 6, visits, parts=2)
    np.testing.assert_array_equal(visits, np.full(6, 2))


@pytest.mark.skipif(not hasattr(os, "fork") or sys.platform == "darwin", reason="needs fork")
def test_run_parts_works_in_a_forked_child():
    visits = np.zeros(10, np.int64)
    run_parts(_count_visits, 10, visits, parts=2)   # the parent's pool exists before the fork
    with warnings.catch_warnings():   # Python 3.12 warns of fork() beside threads; the child runs no Python lock
        warnings.simplefilter("ignore", DeprecationWarning)
        pid = os.fork()
    if pid == 0:   # pragma: no cover - the child reports through its exit status
        try:
            child = np.zeros(10, np.int64)
            run_parts(_count_visits, 10, child, parts=2)
            os._exit(0 if child.sum() == 10 else 1)
        except BaseException:
            os._exit(2)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


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
