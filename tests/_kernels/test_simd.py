"""stereobudget._kernels._simd: each vector kernel equals the scalar loop it replaces, ties and NaN included."""

import numpy as np
import pytest
from numba import njit

from stereobudget._kernels import (MAX_PERIOD_CHANNELS, MAX_PERIOD_LANES, MIN_VECTOR_LENGTH, PERIOD_READ_PAST,
                                blend_rows_first_min, first_min, period_lanes, periodic_corner_sum,
                                skewed_block_copy)


@njit(cache=True)
def _rows_first_min(volume, length, out):
    for k in range(volume.shape[0]):
        out[k] = first_min(volume[k, :length])


@njit(cache=True)
def _strided_first_min(volume, out):
    for k in range(volume.shape[0]):
        out[k] = first_min(volume[k, ::2])  # not contiguous: the scalar scan


def _scan(row):
    """The definition: best starts at 0; an element smaller than the best so far replaces it."""
    best = 0
    for i in range(1, len(row)):
        if row[i] < row[best]:
            best = i
    return best


@pytest.mark.parametrize("kind", ["ties", "specials", "nan"])
def test_first_min_equals_scalar_scan_for_every_length(kind):
    rng = np.random.default_rng(3)
    if kind == "ties":  # few distinct values: many equal minima, the first must win
        volume = rng.integers(0, 3, (400, 70)).astype(np.float32)
    elif kind == "specials":
        volume = rng.choice(np.array([0.0, -0.0, 1.0, np.inf, -np.inf, 2.0], np.float32), (400, 70))
    else:  # NaN never wins, except in the first place, where the scalar scan keeps it
        volume = rng.random((400, 70), dtype=np.float32)
        volume[rng.random(volume.shape) < 0.15] = np.nan
    for length in range(1, 71):
        got = np.empty(volume.shape[0], np.int64)
        _rows_first_min(volume, length, got)
        expected = [_scan(row[:length]) for row in volume]
        assert got.tolist() == expected, length


def test_first_min_on_long_smooth_rows_and_strided_rows():
    rng = np.random.default_rng(4)
    volume = np.cumsum(rng.standard_normal((300, 257)), axis=1).astype(np.float32)
    got = np.empty(300, np.int64)
    _rows_first_min(volume, 257, got)
    assert got.tolist() == np.argmin(volume, axis=1).tolist()  # no NaN: numpy's first minimum
    _strided_first_min(volume, got)
    assert got.tolist() == np.argmin(volume[:, ::2], axis=1).tolist()
    assert MIN_VECTOR_LENGTH <= 257 // 2


@njit(cache=True)
def _copy_block(source, source_start, row_length, target, target_starts):
    skewed_block_copy(source, source_start, row_length, target, target_starts)


def test_skewed_block_copy_reads_diagonals_into_scattered_rows():
    rng = np.random.default_rng(5)
    row_length = 24
    source = rng.random(40 * row_length, dtype=np.float32)
    target = np.zeros(30 * row_length, np.float32)
    starts = (rng.permutation(30)[:8] * row_length + 3).astype(np.int64)
    _copy_block(source, 2 * row_length + 5, row_length, target, starts)
    expected = np.zeros_like(target)
    for r in range(8):
        for j in range(8):
            expected[starts[r] + j] = source[2 * row_length + 5 + (r + j) * row_length + j]
    np.testing.assert_array_equal(target, expected)


@njit(cache=True)
def _blend_all(rows, aboves, similarities, competing, best):
    for k in range(rows.shape[0]):
        s = similarities[k]
        best[k] = blend_rows_first_min(rows[k], aboves[k], s, np.float32(1.0) - s * s, competing)


@pytest.mark.parametrize("layers, competing", [(8, 1), (8, 8), (16, 13), (64, 61), (64, 64), (72, 5)])
def test_blend_rows_first_min_is_the_blend_then_the_first_minimum(layers, competing):
    rng = np.random.default_rng(6)
    rows = rng.integers(0, 4, (300, layers)).astype(np.float32)   # many ties
    rows[rng.random(rows.shape) < 0.05] = np.nan
    rows[:, 0] = np.where(np.isnan(rows[:, 0]), 1.0, rows[:, 0])  # (a NaN first layer: the caller's case)
    rows[:20, 1:] = np.inf
    aboves = rng.integers(0, 4, (300, layers)).astype(np.float32)
    similarities = rng.choice(np.array([0.0, 0.5, 1.0, 0.3], np.float32), 300)
    keep = np.float32(1.0) - similarities * similarities
    with np.errstate(invalid="ignore"):  # 0 * inf: NaN, as in the kernel
        expected_rows = similarities[:, None] * aboves + keep[:, None] * rows   # float32 throughout
    best = np.empty(300, np.int64)
    _blend_all(rows, aboves, similarities, competing, best)
    np.testing.assert_array_equal(rows, expected_rows)
    assert best.tolist() == [_scan(row[:competing]) for row in expected_rows]


@njit(cache=True)
def _periodic_corner_sum(rows, corner_index, corner_weight, count, target, eps):
    return periodic_corner_sum(rows, corner_index, corner_weight, count, target, eps)


@njit(cache=True)
def _scalar_corner_sum(rows, corner_index, corner_weight, out):
    """The slice's loop: the 8 corner rows' weighted sum per channel, corners in order."""
    for i in range(rows.shape[1]):
        total = corner_weight[0] * rows[corner_index[0], i]
        for c in range(1, 8):
            total += corner_weight[c] * rows[corner_index[c], i]
        out[i] = total


@pytest.mark.parametrize("channels", range(1, MAX_PERIOD_CHANNELS + 4))
def test_periodic_corner_sum_is_the_corner_sum_repeated(channels):
    rng = np.random.default_rng(channels)
    cells = 29
    # The rows are followed by the readable floats the loads need, NaN here: never used.
    memory = np.full(cells * channels + PERIOD_READ_PAST, np.nan, np.float32)
    rows = memory[:cells * channels].reshape(cells, channels)
    rows[:] = rng.random(rows.shape, dtype=np.float32) * 1000
    period = period_lanes(channels)
    assert period % 8 == 0 and period % channels == 0
    for count in (1, channels, 8, 61, 64, 200):
        corner_index = rng.integers(0, cells, 8).astype(np.int64)
        corner_index[rng.integers(8)] = cells - 1  # the last row: its loads read the tail
        corner_weight = rng.random(8, dtype=np.float32)
        target = np.full(count + MAX_PERIOD_LANES, -1.0, np.float32)
        written = _periodic_corner_sum(rows, corner_index, corner_weight, count, target, np.float32(0.0))
        if channels > MAX_PERIOD_CHANNELS:
            assert written == 0 and np.all(target == -1.0)  # the caller's scalar path
            continue
        sums = np.empty(channels, np.float32)
        _scalar_corner_sum(rows, corner_index, corner_weight, sums)
        assert written == period <= MAX_PERIOD_LANES
        whole = -(-count // period) * period
        np.testing.assert_array_equal(target[:whole], sums[np.arange(whole) % channels])
        assert np.all(target[whole:] == -1.0)
        # Negated when a sum the first `count` layers use is light (<= eps); the channels
        # past min(B, count) and the lanes read past the row never count.
        used = sums[:min(channels, count)]
        for eps, light in ((used.min(), True), (np.nextafter(used.min(), np.float32(0)), False),
                           (np.float32(np.inf), True)):
            assert _periodic_corner_sum(rows, corner_index, corner_weight, count, target, eps) == \
                (-period if light else period)
        if count < channels:
            unused = np.float32(sums[count:].min())
            if unused < used.min():
                assert _periodic_corner_sum(rows, corner_index, corner_weight, count, target, unused) == period
