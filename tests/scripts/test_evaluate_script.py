"""scripts/evaluate.py end to end (small runs: synthetic scenes, and Teddy + Cones when the data exist)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "scripts" / "evaluate.py"
DATA = REPO.parent / "shared" / "data" / "middlebury"


def run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def test_synthetic_run_reports_and_writes_json(tmp_path):
    out = tmp_path / "syn.json"
    proc = run("--synthetic", "--scenes", "planes,fine_texture", "--json", out)
    assert proc.returncode == 0, proc.stderr
    assert "| planes |" in proc.stdout and "| fine_texture |" in proc.stdout
    result = json.loads(out.read_text())
    assert result["synthetic"] is True and list(result["scenes"]) == ["planes", "fine_texture"]
    planes = result["scenes"]["planes"]
    assert planes["epsilon"] == pytest.approx(1 / 25, rel=0.01)
    # fronto-parallel textured planes are the easy case: the sparse decoder must get them right
    assert planes["metrics"]["nonocc"]["bad"] < 5.0
    assert planes["decode_seconds"] > 0


def test_bad_arguments_exit_with_usage_errors():
    proc = run("--scenes", "art")
    assert proc.returncode == 2 and "unknown scene(s) art" in proc.stderr
    proc = run("--stride", "0")
    assert proc.returncode == 2 and "--stride" in proc.stderr


@pytest.mark.skipif(not (DATA / "teddy" / "left.png").is_file(), reason=f"Middlebury data not found at {DATA}")
def test_middlebury_run_compares_with_the_paper(tmp_path):
    out = tmp_path / "mb.json"
    proc = run("--data", DATA, "--scenes", "teddy,cones", "--json", out)
    assert proc.returncode == 0, proc.stderr
    assert "Teddy + Cones" in proc.stdout and "| 34.38 |" in proc.stdout
    result = json.loads(out.read_text())
    teddy, cones = result["scenes"]["teddy"]["metrics"], result["scenes"]["cones"]["metrics"]
    for mask in ("nonocc", "all", "disc"):
        assert result["teddy_plus_cones_bad"][mask]["ours"] == pytest.approx(
            teddy[mask]["bad"] + cones[mask]["bad"])
        assert 0 <= teddy[mask]["bad"] <= 100 and teddy[mask]["rms"] > 0
    assert result["teddy_plus_cones_bad"]["all"]["paper"] == 50.70
