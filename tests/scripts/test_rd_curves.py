"""scripts/rd_curves.py: one budget of a synthetic scene, and the report drawn from its cache."""

import json
import math

import pytest

pytest.importorskip("imagecodecs")   # the codec rows and the lossless lattice need it

import rd_curves
from stereobudget.scenes import make_scene


@pytest.fixture(scope="module")
def scene():
    return make_scene("planes", height=96, width=128, max_disp=16, seed=0)


def test_ours_row_fits_the_budget_and_reads_only_the_samples(scene):
    budget = int(0.04 * scene.right.size) + 80
    row = rd_curves.ours_row(scene.left, scene.right, scene.disparity, scene.nonocc, scene.max_disp, budget,
                             "lossless")
    assert row["bytes"] <= budget
    assert row["pixels_read"] == math.ceil(96 / row["stride"]) * math.ceil(128 / row["stride"])
    assert row["stride"] <= 5 and 0.0 <= row["bad"] <= 100.0 and row["psnr"] > 15.0


def test_codec_row_fits_the_budget_and_reads_every_pixel(scene):
    budget = int(0.04 * scene.right.size) + 80
    row = rd_curves.codec_row(scene.left, scene.right, scene.disparity, scene.nonocc, scene.max_disp, budget,
                              "WebP")
    assert row["bytes"] <= budget and row["pixels_read"] == 96 * 128
    assert 0.0 <= row["bad_sgbm"] <= 100.0 and 0.0 <= row["bad_ours"] <= 100.0


def test_mean_psnr_averages_the_squared_error():
    assert rd_curves.mean_psnr([20.0, 20.0]) == pytest.approx(20.0)
    assert rd_curves.mean_psnr([20.0, math.inf]) == pytest.approx(20.0 + 10 * math.log10(2))
    assert rd_curves.mean_psnr([math.inf]) == math.inf


def test_report_tables_and_plots_from_a_cache(tmp_path, capsys):
    rows = {}
    for fraction in rd_curves.BUDGETS:
        for label in (*rd_curves.OURS, *rd_curves.CODECS):
            row = {"scene": "s", "group": "realdev", "fraction": fraction, "row": label, "bytes": 100,
                   "pixels": 1000, "psnr": 30.0, "encode_ms": 1.0, "pixels_read": 40}
            row.update({"bad": 10.0, "fit_ms": 2.0} if label in rd_curves.OURS else {"bad_sgbm": 20.0,
                                                                                       "bad_ours": 15.0})
            rows[f"s|{fraction}|{label}"] = row
    cache = tmp_path / "rd.json"
    cache.write_text(json.dumps(rows))
    assert rd_curves.main(["--report", str(cache), "--plot", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "| ours lossless (Hybrid) | 10.00 / 30.0 |" in out and "| AVIF+SGBM | 20.00 / 30.0 |" in out
    assert (tmp_path / "rd_realdev.png").stat().st_size > 0
