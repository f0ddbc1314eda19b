"""scripts/reproduce_paper.py on a tiny synthetic stand-in for the Middlebury scenes (seconds)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from middlebury import Scene
from stereobudget.scenes import make_scene

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "reproduce_paper.py"


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("reproduce_paper_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module   # dataclasses look their module up there
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def _stand_in(name, seed):
    syn = make_scene("planes", height=64, width=80, max_disp=10, seed=seed)
    masks = {"nonocc": syn.nonocc, "all": np.ones_like(syn.nonocc), "disc": syn.nonocc.copy()}
    return Scene(name=name, left=syn.left, right=syn.right, gt=syn.disparity, masks=masks, max_disp=10, scale=1)


def test_quick_reproduction_on_synthetic_scenes(script, tmp_path):
    runner = script.Runner([_stand_in("tsukuba", 1), _stand_in("venus", 2)])
    # Fig. 8 reads the Middlebury files themselves (scripts/reproduce_synthesis.py), so it is left out here.
    results = script.reproduce(runner, tmp_path, (5,),
                               experiments=tuple(e for e in script.ALL_EXPERIMENTS if e != "fig8"))
    summary = (tmp_path / "summary.md").read_text()
    for heading in ("Table 1", "Table 2", "Fig. 5(a)", "Fig. 5(b)", "Fig. 5(c)", "Fig. 5(d)", "Headline"):
        assert heading in summary
    # The paper's numbers sit next to ours (Table 2, uniform grid, tsukuba nonocc = 7.30).
    assert "| Uniform grid (paper) | 7.30 |" in summary
    for png in ("fig5a.png", "fig5b.png", "fig5c.png", "fig5d.png", "bars.png"):
        assert (tmp_path / png).read_bytes()[:4] == b"\x89PNG"
    stored = json.loads((tmp_path / "results.json").read_text())
    grid = stored["tables"]["grid"]["tsukuba"]
    # results.json keeps 4 decimals
    assert grid["nonocc"]["bad"] == pytest.approx(results["tables"]["grid"]["tsukuba"]["nonocc"]["bad"], abs=1e-4)
    # Easy textured planes: the sparse decoder and the full pair must both be accurate.
    assert grid["nonocc"]["bad"] < 10.0
    assert script.mean_over_scenes(results["fig5c"]["Full pair"]) < 5.0
    # Every codec point is either scored or explicitly unreachable, with the byte budget recorded.
    for codec in script.CODECS:
        for record in results["fig5d"][codec][5].values():
            assert record["budget"] > 80 and (not record["reachable"] or record["bytes"] <= record["budget"])


def test_row_fill_and_codec_budget(script):
    nan = np.nan
    disp = np.array([[nan, nan, 3.0, nan, 5.0, nan],
                     [nan, nan, nan, nan, nan, nan]], dtype=np.float32)
    filled = script.fill_invalid_from_row_neighbours(disp)
    np.testing.assert_array_equal(filled[0], [3, 3, 3, 3, 5, 5])
    assert np.isnan(filled[1]).all()
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    assert script.compress_to_budget(image, "jpeg", 50) is None
    decoded, size, quality = script.compress_to_budget(image, "jpeg", 6000)
    assert decoded.shape == image.shape and size <= 6000
    # The search returns the best quality that fits: one step up does not fit.
    assert script.compress_to_budget(image, "jpeg", size - 1) is None or \
        script.compress_to_budget(image, "jpeg", size - 1)[2] < quality
