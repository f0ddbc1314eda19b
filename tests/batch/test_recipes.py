"""Reruns redo what was made otherwise: the record beside each output, in real sb-encode / sb-decode runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from stereobudget.batch import make_recipe, recipe_difference, recipe_path, write_recipes
from stereobudget.io import load_samples
from stereobudget.scenes import make_scene

BIN = Path(sys.executable).parent
SB_ENCODE, SB_DECODE = str(BIN / "sb-encode"), str(BIN / "sb-decode")


def json_lines(text):
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def run(*args, cwd):
    return subprocess.run([*map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=600)


def test_recipe_difference_names_the_reason(tmp_path):
    src, out = tmp_path / "in.png", tmp_path / "out.sbs"
    src.write_bytes(b"x")
    recipe = make_recipe("sb-encode", [str(src)], {"pattern": {"stride_x": 5}})
    assert recipe_difference([str(out)], recipe) == "missing output"
    out.write_bytes(b"y")
    assert recipe_difference([str(out)], recipe) == "no record of what made it"
    write_recipes([str(out)], recipe)
    assert Path(recipe_path(str(out))).name == ".out.sbs.sbrecipe"
    assert recipe_difference([str(out)], recipe) is None
    assert recipe_difference([str(out)], make_recipe("sb-encode", [str(src)], {"pattern": {"stride_x": 4}})) == \
        "options changed: pattern.stride_x 5 -> 4"
    src.write_bytes(b"xx")
    assert recipe_difference([str(out)], make_recipe("sb-encode", [str(src)], {"pattern": {"stride_x": 5}})) == \
        "inputs changed"
    stored = json.loads(Path(recipe_path(str(out))).read_text())
    Path(recipe_path(str(out))).write_text(json.dumps({**stored, "tool": "stereobudget 0.0.1"}))
    assert recipe_difference([str(out)], recipe) == "made by stereobudget 0.0.1"


def test_encode_rerun_with_another_stride_redoes_every_file(tmp_path):
    (tmp_path / "R").mkdir()
    for i in range(3):
        scene = make_scene("planes", seed=i, height=64, width=96, max_disp=8)
        assert cv2.imwrite(str(tmp_path / "R" / f"f{i}.png"), scene.right[:, :, ::-1].copy())
    base = [SB_ENCODE, "R/*.png", "-o", "S/{stem}.sbs", "-j", "1", "--json"]
    first = run(*base, "--stride", 5, cwd=tmp_path)
    assert first.returncode == 0 and {r["status"] for r in json_lines(first.stdout)} == {"ok"}, first.stderr

    same = run(*base, "--stride", 5, cwd=tmp_path)
    assert same.returncode == 0 and {r["status"] for r in json_lines(same.stdout)} == {"skipped"}
    # Said without -v: nothing was done, and why.
    assert "3 of 3 file(s) skipped: up to date" in same.stderr

    other = run(*base, "--stride", 4, cwd=tmp_path)
    assert other.returncode == 0, other.stderr
    lines = json_lines(other.stdout)
    assert {r["status"] for r in lines} == {"ok"}
    assert all(r["redone"].startswith("options changed: pattern.stride_x 5 -> 4") for r in lines)
    assert "3 file(s) redone: options changed: pattern.stride_x 5 -> 4" in other.stderr
    assert all(load_samples(tmp_path / "S" / f"f{i}.sbs").pattern.stride_x == 4 for i in range(3))


def test_decode_rerun_with_another_method_redoes_it(tmp_path):
    scene = make_scene("planes", seed=1, height=64, width=96, max_disp=8)
    for folder in ("L", "R"):
        (tmp_path / folder).mkdir()
    assert cv2.imwrite(str(tmp_path / "L" / "a.png"), scene.left[:, :, ::-1].copy())
    assert cv2.imwrite(str(tmp_path / "R" / "a.png"), scene.right[:, :, ::-1].copy())
    assert run(SB_ENCODE, "R/*.png", "-o", "S/{stem}.sbs", "--stride", 4, cwd=tmp_path).returncode == 0
    base = [SB_DECODE, "--left-dir", "L", "--samples-dir", "S", "--max-disp", 12, "--disparity", "D/{stem}.pfm",
            "--json", "-q"]
    assert run(*base, cwd=tmp_path).returncode == 0
    hybrid = (tmp_path / "D" / "a.pfm").read_bytes()
    again = run(*base, cwd=tmp_path)
    assert [r["status"] for r in json_lines(again.stdout)] == ["skipped"]
    sparse = run(*base, "--method", "sparse", cwd=tmp_path)
    assert sparse.returncode == 0, sparse.stderr
    (line,) = json_lines(sparse.stdout)
    assert line["status"] == "ok" and line["redone"] == "options changed: method hybrid -> sparse"
    assert (tmp_path / "D" / "a.pfm").read_bytes() != hybrid
