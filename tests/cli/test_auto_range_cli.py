"""sb-decode as a user runs it: the estimated range and the warnings, in real processes.

Each test starts ``python -m stereobudget.cli.decode`` on a synthetic scene with exact
ground truth and reads its exit status, stderr and ``--json`` line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from stereobudget.io import read_disparity, save_samples
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene


def write_png(path, rgb):
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[:, :, ::-1]))
    return str(path)


def sb_decode(*args, cwd):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.run([sys.executable, "-m", "stereobudget.cli.decode", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("auto")
    scene = make_scene("planes", seed=5)
    grid = SamplingPattern("grid", 5, 5)
    files = {"left": write_png(folder / "left.png", scene.left), "right": write_png(folder / "right.png", scene.right),
             "flat": write_png(folder / "flat.png", np.full_like(scene.left, 90))}
    for name, image in (("right", scene.right), ("left", scene.left),
                        ("moved", np.roll(scene.right, 3, axis=0)), ("flat", np.full_like(scene.right, 90))):
        path = folder / f"{name}.sbs"
        save_samples(encode_image(image, pattern=grid), path)
        files[f"{name}.sbs"] = str(path)
    return folder, scene, files


def warning_lines(stderr):
    return [line for line in stderr.splitlines() if line.startswith("sb-decode: warning: ")]


def test_default_range_is_estimated_reported_and_right(scene_files, tmp_path):
    folder, scene, files = scene_files
    out = tmp_path / "d.pfm"
    run = sb_decode(files["left"], files["right.sbs"], "--disparity", out, "--json", "-v", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["range_source"] == "estimated"
    assert summary["min_disp"] == 0 and scene.disparity.max() <= summary["max_disp"] <= scene.disparity.max() + 16
    assert summary["range_estimate"]["max_disp"] == summary["max_disp"]
    assert summary["warnings"] == [] and warning_lines(run.stderr) == []
    assert f"disparity range 0..{summary['max_disp']} (estimated" in run.stderr
    d = read_disparity(out)
    bad = np.abs(d - scene.disparity)[scene.nonocc] > 1
    assert bad.mean() < 0.1


def test_too_small_range_warns_on_stderr_and_in_json(scene_files, tmp_path):
    folder, scene, files = scene_files
    run = sb_decode(files["left"], files["right.sbs"], "--max-disp", 10, "--disparity", tmp_path / "d.pfm",
                    "--json", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    codes = [w["code"] for w in summary["warnings"]]
    assert "range_limit" in codes and summary["range_source"] == "given"
    lines = warning_lines(run.stderr)
    assert len(lines) == len(codes) and "at --max-disp 10" in lines[0] and lines[0].endswith("[range_limit]")
    # -q silences the warnings; the JSON keeps them.
    quiet = sb_decode(files["left"], files["right.sbs"], "--max-disp", 10, "--disparity", tmp_path / "q.pfm",
                      "-q", cwd=tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == ""


def test_swapped_and_unrectified_pairs_warn(scene_files, tmp_path):
    folder, scene, files = scene_files
    swapped = sb_decode(files["right"], files["left.sbs"], "--disparity", tmp_path / "s.pfm", "--json", cwd=tmp_path)
    assert swapped.returncode == 0, swapped.stderr
    summary = json.loads(swapped.stdout)
    assert [w["code"] for w in summary["warnings"]][:1] == ["swapped"]
    assert any("looks swapped" in line for line in warning_lines(swapped.stderr))

    moved = sb_decode(files["left"], files["moved.sbs"], "--disparity", tmp_path / "m.pfm", "--json", cwd=tmp_path)
    assert moved.returncode == 0, moved.stderr
    summary = json.loads(moved.stdout)
    assert "not_rectified" in [w["code"] for w in summary["warnings"]]
    # The coarse search may miss the offset by a row; its sign is sure.
    assert summary["range_estimate"]["vertical_offset"] in (-2, -3, -4)
    assert any("does not look rectified" in line and "higher in I1" in line for line in warning_lines(moved.stderr))


def test_right_image_as_left_and_a_constant_pair_warn(scene_files, tmp_path):
    folder, scene, files = scene_files
    same = sb_decode(files["right"], files["right.sbs"], "--disparity", tmp_path / "r.pfm", "--json", cwd=tmp_path)
    assert same.returncode == 0, same.stderr
    assert [w["code"] for w in json.loads(same.stdout)["warnings"]] == ["left_is_samples"]
    lines = warning_lines(same.stderr)
    assert len(lines) == 1 and "LEFT looks like the sampled image itself" in lines[0]

    flat = sb_decode(files["flat"], files["flat.sbs"], "--disparity", tmp_path / "f.pfm", "--json", cwd=tmp_path)
    assert flat.returncode == 0, flat.stderr
    summary = json.loads(flat.stdout)
    assert [w["code"] for w in summary["warnings"]] == ["no_texture"]
    assert summary["range_estimate"]["textured_fraction"] == 0.0
    lines = warning_lines(flat.stderr)
    assert len(lines) == 1 and "no texture to match" in lines[0]


def test_manifest_accepts_auto(scene_files, tmp_path):
    folder, scene, files = scene_files
    manifest = tmp_path / "pairs.csv"
    manifest.write_text(f"left,samples,max_disp\n{files['left']},{files['right.sbs']},auto\n"
                        f"{files['left']},{files['right.sbs']},10\n")
    run = sb_decode("--manifest", manifest, "--disparity", str(tmp_path / "{stem}_{parent}.pfm").replace(
        str(folder), "x"), "--json", "-j", 1, cwd=tmp_path)
    # Both rows have the same left image: the template cannot tell them apart.
    assert run.returncode != 0 and "same output" in run.stderr
    other = tmp_path / "other.png"
    other.write_bytes(open(files["left"], "rb").read())
    manifest.write_text(f"left,samples,max_disp\n{files['left']},{files['right.sbs']},auto\n"
                        f"{other},{files['right.sbs']},10\n")
    run = sb_decode("--manifest", manifest, "--disparity", str(tmp_path / "{stem}.pfm"), "--json", "-j", 1,
                    cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    lines = {json.loads(line)["left"].rsplit("/", 1)[-1]: json.loads(line) for line in run.stdout.splitlines()}
    assert lines["left.png"]["range_source"] == "estimated" and lines["other.png"]["max_disp"] == 10
    # Batch warnings name their file.
    assert any(line.startswith(f"sb-decode: warning: {other}: ") for line in warning_lines(run.stderr))
