"""The full DSI (Eq. 1) against its plain reference."""

import numpy as np
import pytest

from stereobudget.cost import full_dsi, full_dsi_reference


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("min_disp, num_disp", [(0, 12), (3, 7), (-4, 9), (0, 40)])  # 40: past the image width
@pytest.mark.parametrize("grad_weight", [0.0, 0.89])
def test_full_dsi_is_eq_1_summed_directly(channels, min_disp, num_disp, grad_weight):
    rng = np.random.default_rng(channels * 100 + num_disp)
    left = rng.uniform(0, 255, (17, 33, channels)).astype(np.float32)
    right = (np.roll(left, -5, axis=1) + rng.normal(0, 6, left.shape)).astype(np.float32)
    terms = dict(min_disp=min_disp, num_disp=num_disp, truncation=15.0, grad_weight=grad_weight,
                 grad_truncation=2.0)
    fast = full_dsi(left, right, **terms)
    assert fast.dtype == np.float32 and fast.shape == (17, 33, num_disp)
    # float32 sums against float64 ones: a few units in the last place of costs up to 15.
    np.testing.assert_allclose(fast, full_dsi_reference(left, right, **terms), rtol=0, atol=2e-5)


def test_the_true_shift_is_the_cheapest_layer():
    rng = np.random.default_rng(1)
    left = rng.uniform(0, 255, (9, 40, 3)).astype(np.float32)
    right = np.roll(left, -6, axis=1)
    cost = full_dsi(left, right, min_disp=0, num_disp=12)
    assert np.all(np.argmin(cost[:, 12:-1], axis=2) == 6)
