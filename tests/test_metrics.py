"""Disparity and image metrics on hand-computed cases."""

import math

import numpy as np
import pytest

from stereobudget.metrics import (bad_pixel_rate, evaluate_disparity, invalid_rate, psnr,
                                  rms_error)


def test_bad_pixel_rate_counts_errors_above_threshold_and_missing_estimates():
    gt = np.array([[10.0, 10.0, 10.0, 10.0, np.nan]])
    disp = np.array([[10.5, 11.0, 11.5, np.nan, 0.0]])
    mask = np.ones(gt.shape, bool)
    # scored: first four (NaN GT never counts); bad: 11.5 and the missing estimate
    assert bad_pixel_rate(disp, gt, mask) == pytest.approx(50.0)
    assert bad_pixel_rate(disp, gt, mask, threshold=0.6) == pytest.approx(75.0)
    assert bad_pixel_rate(disp, gt, mask, threshold=0.4) == pytest.approx(100.0)
    assert bad_pixel_rate(disp, gt, None) == pytest.approx(50.0)
    only_first_two = np.array([[True, True, False, False, True]])
    assert bad_pixel_rate(disp, gt, only_first_two) == 0.0
    assert math.isnan(bad_pixel_rate(disp, gt, np.zeros(gt.shape, bool)))


def test_rms_error_skips_missing_estimates_which_invalid_rate_reports():
    gt = np.array([[1.0, 2.0, 3.0, 4.0]])
    disp = np.array([[2.0, 2.0, 0.0, np.nan]])
    mask = np.ones(gt.shape, bool)
    assert rms_error(disp, gt, mask) == pytest.approx(math.sqrt((1 + 0 + 9) / 3))
    assert invalid_rate(disp, gt, mask) == pytest.approx(25.0)
    assert math.isnan(rms_error(np.full_like(gt, np.nan), gt, mask))


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="shape"):
        bad_pixel_rate(np.zeros((2, 2)), np.zeros((2, 3)), None)
    with pytest.raises(ValueError, match="mask"):
        rms_error(np.zeros((2, 2)), np.zeros((2, 2)), np.ones((3, 2), bool))


def test_psnr_values_and_peak_from_dtype():
    a = np.full((4, 4, 3), 100, np.uint8)
    b = a.copy()
    assert psnr(a, b) == math.inf
    b[0, 0, 0] = 110  # MSE = 100 / 48
    assert psnr(a, b) == pytest.approx(10 * math.log10(255 ** 2 / (100 / 48)))
    mask = np.zeros((4, 4), bool)
    mask[0, :2] = True  # 6 values, one off by 10
    assert psnr(a, b, mask=mask) == pytest.approx(10 * math.log10(255 ** 2 / (100 / 6)))
    assert psnr(a, b, mask=~mask) == math.inf
    wide = a.astype(np.uint16) * 256
    wide_b = b.astype(np.uint16) * 256
    assert psnr(wide, wide_b) == pytest.approx(10 * math.log10(65535 ** 2 / (100 * 256 ** 2 / 48)))
    with pytest.raises(ValueError, match="peak"):
        psnr(a.astype(np.float32), b.astype(np.float32))
    assert psnr(a.astype(np.float32), b.astype(np.float32), peak=255) == pytest.approx(psnr(a, b))


def test_evaluate_disparity_reports_every_mask():
    gt = np.arange(12, dtype=np.float32).reshape(3, 4)
    disp = gt.copy()
    disp[0, 0] += 3.0
    disp[2, 3] = np.nan
    masks = {"nonocc": gt > 4, "all": np.ones(gt.shape, bool), "disc": gt == 0}
    result = evaluate_disparity(disp, gt, masks)
    assert list(result) == ["nonocc", "all", "disc"]
    assert result["nonocc"] == pytest.approx({"bad": 100 / 7, "rms": 0.0, "invalid": 100 / 7, "pixels": 7})
    assert result["all"]["bad"] == pytest.approx(200 / 12)
    assert result["all"]["rms"] == pytest.approx(math.sqrt(9 / 11))
    assert result["disc"] == pytest.approx({"bad": 100.0, "rms": 3.0, "invalid": 0.0, "pixels": 1})
