"""The census cost against its plain reference, and its blindness to gain and offset."""

import numpy as np
import pytest

from stereobudget.cost import CENSUS_BITS, census_cost_volume, census_cost_volume_reference, census_transform


@pytest.fixture
def pair():
    rng = np.random.default_rng(3)
    left = rng.uniform(0, 255, (23, 31)).astype(np.float32)
    right = np.roll(left, -4, axis=1) + rng.normal(0, 2, left.shape).astype(np.float32)
    return left, right


@pytest.mark.parametrize("min_disp, num_disp", [(0, 9), (2, 5), (-3, 7)])
def test_volume_matches_reference(pair, min_disp, num_disp):
    left, right = pair
    fast = census_cost_volume(left, right, min_disp=min_disp, num_disp=num_disp)
    assert fast.dtype == np.uint8 and fast.shape == (23, 31, num_disp)
    np.testing.assert_array_equal(fast, census_cost_volume_reference(left, right, min_disp=min_disp,
                                                                     num_disp=num_disp))
    assert fast.max() <= CENSUS_BITS


def test_true_shift_wins_despite_gain_and_offset(pair):
    left, _ = pair
    right = np.roll(left, -4, axis=1) * 0.8 + 20          # another exposure: a monotonic change
    cost = census_cost_volume(left, right, min_disp=0, num_disp=9)
    inner = cost[2:-2, 6:-6]
    assert (inner.argmin(axis=2) == 4).mean() > 0.99
    assert (inner[:, :, 4] == 0).all()


def test_signature_bits():
    gray = np.zeros((5, 5), np.float32)
    gray[2, 2] = 10                                          # every neighbour darker
    assert census_transform(gray)[2, 2] == (1 << CENSUS_BITS) - 1
    gray[0, 0] = 20                                          # the first neighbour is the highest bit
    assert census_transform(gray)[2, 2] == (1 << CENSUS_BITS) - 1 - (1 << (CENSUS_BITS - 1))


def test_lattice_census_equals_the_spaced_census_of_i1_at_the_true_shift():
    # A sample at right (y, x) and I1 at (y, x + d) see the same neighbours at the
    # grid's spacing, so their codes agree wherever the neighbours stay inside.
    from stereobudget.cost import lattice_census, spaced_census
    rng = np.random.default_rng(8)
    left = rng.uniform(0, 255, (40, 60)).astype(np.float32)
    d, sx, sy = 3, 4, 5
    right = np.roll(left, -d, axis=1) * 0.7 + 9              # gain and offset
    lattice = right[::sy, ::sx]
    codes = lattice_census(lattice).reshape(lattice.shape)
    left_codes = spaced_census(left, spacing_x=sx, spacing_y=sy)
    at_samples = left_codes[::sy, ::sx][:, :]                  # I1 at (y, x)...
    shifted = left_codes[::sy, d::sx][:, :lattice.shape[1]]    # ...and at (y, x + d)
    inner = (slice(1, -1), slice(1, -2))
    np.testing.assert_array_equal(codes[inner], shifted[inner])
    assert (codes[inner] != at_samples[inner]).mean() > 0.5


def test_sparse_pair_cost_mixes_the_census_bits():
    from stereobudget.cost import sparse_pair_cost
    pixel = np.array([100.0, 100.0, 100.0], np.float32)
    plain = sparse_pair_cost(pixel, pixel + 10, np.nan, np.nan, 20.0, 0.0, 5.0)
    assert plain == pytest.approx(10.0)
    # Codes 0b1111 against 0: 4 of 8 bits differ -> half the truncation, mixed 1:1.
    mixed = sparse_pair_cost(pixel, pixel + 10, np.nan, np.nan, 20.0, 0.0, 5.0, 0b1111, 0, 0.5)
    assert mixed == pytest.approx(0.5 * 10.0 + 0.5 * 10.0)
    same = sparse_pair_cost(pixel, pixel + 10, np.nan, np.nan, 20.0, 0.0, 5.0, 7, 7, 0.5)
    assert same == pytest.approx(5.0)
    assert sparse_pair_cost(pixel, pixel + 10, np.nan, np.nan, 20.0, 0.0, 5.0, 7, -1, 0.5) == pytest.approx(10.0)


@pytest.mark.parametrize("min_disp, layers", [(0, 9), (4, 20), (-3, 17), (30, 5)])
def test_mix_spaced_census_matches_a_plain_loop(min_disp, layers):
    """Each layer k of pixel (y, x) meets the right code at column x - min_disp - k, clamped to the row."""
    from stereobudget.cost import mix_spaced_census
    rng = np.random.default_rng(min_disp + 50)
    h, w = 4, 23
    volume = rng.uniform(0, 15, (h, w, layers)).astype(np.float32)
    left_codes = rng.integers(0, 256, (h, w)).astype(np.uint8)
    right_codes = rng.integers(0, 256, (h, w)).astype(np.uint8)
    want = volume.copy()
    for y in range(h):
        for x in range(w):
            for k in range(layers):
                xr = min(max(x - min_disp - k, 0), w - 1)
                bits = bin(int(left_codes[y, x]) ^ int(right_codes[y, xr])).count("1")
                want[y, x, k] = want[y, x, k] * np.float32(0.05) + np.float32(0.04) * np.float32(bits)
    got = mix_spaced_census(volume, left_codes, right_codes, min_disp=min_disp, volume_scale=0.05,
                            census_weight=0.04)
    np.testing.assert_array_equal(got, want)
