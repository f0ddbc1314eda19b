"""Self-rectification (``--calibration auto``): the epipolar geometry from I1 and a grid of samples, or a
clean refusal; a stream estimates once, checks, and estimates again when the rows drift."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from stereobudget.cli.decode import decode_command
import json

from stereobudget.batch import decode_stream
from stereobudget.errors import CalibrationError, OptionError
from stereobudget.geometry import (SelfRectifiedStream, frame_residual, guided_matches, rectify_stereo,
                                   self_rectification, unrectify_pair)
from stereobudget.io import save_samples, write_image
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene

GRID = SamplingPattern("grid", 5, 5)


def invoke(*args):
    return CliRunner().invoke(decode_command, [str(a) for a in args], prog_name="sb-decode")


def turned(scene):
    return unrectify_pair(scene.left, scene.right, scene.disparity, rotation_left=np.radians([0.8, -1.0, 0.6]),
                          rotation_right=np.radians([-0.6, 0.9, -0.7]), k1_left=0.06, k1_right=-0.05,
                          mask=scene.nonocc)


def test_a_turned_pair_is_rectified_from_the_samples():
    """Slanted synthetic planes seen by turned cameras with distorting lenses: the rig fitted to
    the matches brings the true matches onto common rows and the decode back onto the truth."""
    import cv2

    import stereobudget
    from stereobudget.geometry import raw_right_positions, rectify_left, rectify_samples

    scene = make_scene("slanted", seed=1)
    pair = turned(scene)
    samples = encode_image(pair.right, pattern=GRID)
    rect, report = self_rectification(pair.left, samples)
    assert report.matches >= 100 and report.residual_median < 0.3 and 0 < report.uncertainty < 0.3
    c = rect.calibration
    right = cv2.undistortPoints(pair.true_right[pair.scored].reshape(-1, 1, 2), c.M2, c.D2, R=rect.R2,
                                P=rect.P2).reshape(-1, 2)
    rows_apart = np.abs(rect.left_positions[..., 1][pair.scored] - right[:, 1]) * c.M1[0, 0] / rect.focal
    assert np.median(rows_apart) < 0.25
    disparity = rect.left_positions[..., 0][pair.scored] - right[:, 0]
    result = stereobudget.decode(rectify_left(pair.left, rect), rectify_samples(samples, rect),
                                 min_disp=min(0, int(disparity.min()) - 4), max_disp=int(disparity.max()) + 4)
    error = np.hypot(*(raw_right_positions(result.disparity, rect) - pair.true_right).transpose(2, 0, 1))
    assert np.mean(~(error[pair.scored] <= 1.0)) < 0.03


def test_guided_matches_cover_the_frame_on_the_true_rows():
    """A decode with the first estimate places every sample's match; matched there, the samples
    cover the frame (not only where a patch stands out from a third of the width) and sit on
    the rows the true geometry gives them."""
    import cv2

    import stereobudget
    from stereobudget.geometry import rectify_left, rectify_samples

    scene = make_scene("slanted", seed=1)
    pair = turned(scene)
    samples = encode_image(pair.right, pattern=GRID)
    first, report = self_rectification(pair.left, samples, guide=False)
    assert not report.guided
    disparity = stereobudget.decode(rectify_left(pair.left, first), rectify_samples(samples, first),
                                    min_disp=-4, max_disp=48).disparity
    left_points, right_points = guided_matches(pair.left, samples, first, disparity)
    h, w = pair.left.shape[:2]
    assert len(left_points) > 1000
    assert np.ptp(right_points[:, 0]) > 0.8 * w and np.ptp(right_points[:, 1]) > 0.7 * h
    truth = rectify_stereo(pair.calibration, w, h)
    c = truth.calibration
    a = cv2.undistortPoints(left_points.reshape(-1, 1, 2), c.M1, c.D1, R=truth.R1, P=truth.P1).reshape(-1, 2)
    b = cv2.undistortPoints(right_points.reshape(-1, 1, 2), c.M2, c.D2, R=truth.R2, P=truth.P2).reshape(-1, 2)
    assert np.median(np.abs(a[:, 1] - b[:, 1])) < 0.2
    _, guided = self_rectification(pair.left, samples)
    assert guided.guided and guided.matches > report.matches


def test_a_poor_estimate_is_refused_not_decoded():
    scene = make_scene("slanted", seed=1)
    pair = turned(scene)
    with pytest.raises(CalibrationError, match="median vertical error of .* px"):
        self_rectification(pair.left, encode_image(pair.right, pattern=GRID), max_residual=0.01)


@pytest.mark.parametrize("kind", ["textureless", "stripes"])
def test_a_scene_without_reliable_matches_is_refused(tmp_path, kind):
    rng = np.random.default_rng(5)
    if kind == "textureless":   # a white wall: sensor noise only
        left, right = (np.clip(128 + rng.normal(0, 2, (240, 320, 3)), 0, 255).astype(np.uint8) for _ in range(2))
    else:   # a repetitive texture: vertical stripes with a 10-pixel period
        x = np.arange(320)
        row = (128 + 100 * np.sin(2 * np.pi * x / 10.0)).astype(np.uint8)
        left = np.repeat(np.repeat(row[None, :, None], 240, 0), 3, 2)
        right = np.roll(left, -7, axis=1)
    write_image(tmp_path / "left.png", left, channel_order="rgb")
    save_samples(encode_image(right, pattern=GRID), tmp_path / "right.sbs")
    with pytest.raises(CalibrationError, match="too few .* give a calibration file"):
        self_rectification(left, encode_image(right, pattern=GRID))


def knocked(scene):
    """The same rig after the right camera was knocked half a degree about the baseline."""
    return unrectify_pair(scene.left, scene.right, scene.disparity, rotation_left=np.radians([0.8, -1.0, 0.6]),
                          rotation_right=np.radians([-1.1, 0.9, -0.7]), k1_left=0.06, k1_right=-0.05,
                          mask=scene.nonocc)


@pytest.fixture(scope="module")
def turned_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("turned")
    pair = turned(make_scene("slanted", seed=1))
    write_image(folder / "left.png", pair.left, channel_order="rgb")
    save_samples(encode_image(pair.right, pattern=GRID), folder / "right.sbs")
    return folder, pair


def test_sb_decode_self_rectifies(turned_files, tmp_path):
    folder, pair = turned_files
    result = invoke(folder / "left.png", folder / "right.sbs", "--calibration", "auto", "--frame", "raw",
                    "--disparity", tmp_path / "d.pfm", "--json")
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    facts = summary["calibration"]["self_rectification"]
    assert facts["estimated"] and facts["matches"] >= 100 and facts["residual_vertical_px_median"] < 0.3
    # Estimated from the pair: no baseline, so no metres are claimed.
    assert "baseline_m" not in summary["calibration"]
    assert summary["frame"]["disparity"] == "raw"
    assert (tmp_path / "d.pfm").exists()


def test_sb_decode_auto_has_no_metric_outputs(turned_files, tmp_path):
    folder, _ = turned_files
    result = invoke(folder / "left.png", folder / "right.sbs", "--calibration", "auto", "--depth",
                    tmp_path / "z.tif")
    assert result.exit_code == OptionError.exit_code
    assert "--depth needs a calibration file: --calibration auto" in result.stderr
    assert not (tmp_path / "z.tif").exists()


def test_sb_decode_auto_refuses_a_textureless_pair_in_one_line(tmp_path):
    rng = np.random.default_rng(5)
    left, right = (np.clip(128 + rng.normal(0, 2, (240, 320, 3)), 0, 255).astype(np.uint8) for _ in range(2))
    write_image(tmp_path / "left.png", left, channel_order="rgb")
    save_samples(encode_image(right, pattern=GRID), tmp_path / "right.sbs")
    result = invoke(tmp_path / "left.png", tmp_path / "right.sbs", "--calibration", "auto", "--disparity",
                    tmp_path / "d.pfm")
    assert result.exit_code == CalibrationError.exit_code
    assert len(result.stderr.strip().splitlines()) == 1
    assert "--calibration auto: too few features match" in result.stderr and "right.sbs" in result.stderr
    assert not (tmp_path / "d.pfm").exists()


def test_a_stream_estimates_once_and_again_when_the_rows_drift():
    scene = make_scene("slanted", seed=1)
    steady, moved = turned(scene), knocked(scene)
    frames = [(steady.left, encode_image(steady.right, pattern=GRID))] * 2 + \
        [(moved.left, encode_image(moved.right, pattern=GRID))]
    stream = SelfRectifiedStream(check_every=1)
    facts = [stream.for_frame(left, samples)[1] for left, samples in frames]
    assert [f["estimated"] for f in facts] == [True, False, True]
    assert stream.estimates == 2
    # The check on the steady frame finds the rows where the estimate left them; on the knocked
    # frame, the old estimate leaves them pixels apart.
    assert facts[1]["checked_residual_px"] < 0.3 and facts[2]["checked_residual_px"] > 1.0
    rect, _ = stream.for_frame(*frames[2])
    assert frame_residual(moved.left, frames[2][1], rect) < 0.3


def test_a_stream_file_with_auto_reuses_its_estimate(turned_files, tmp_path):
    folder, _ = turned_files
    (tmp_path / "stream.sbs").write_bytes((folder / "right.sbs").read_bytes() * 2)
    summaries = list(decode_stream(str(folder / "left.png"), str(tmp_path / "stream.sbs"),
                                   disparity=str(tmp_path / "d{index}.pfm"), calibration="auto", max_disp=40))
    facts = [s["calibration"]["self_rectification"] for s in summaries]
    assert [f["estimated"] for f in facts] == [True, False]
    assert facts[0]["matches"] == facts[1]["matches"]
    assert "self_rectify" in summaries[1]["timings"]
    assert (tmp_path / "d1.pfm").exists()


def test_a_batch_with_auto_is_up_to_date_on_its_rerun(turned_files, tmp_path):
    """'auto' is no file: the batch's record keeps the option, and the rerun skips the pair."""
    folder, _ = turned_files
    (tmp_path / "L").mkdir()
    (tmp_path / "S").mkdir()
    (tmp_path / "L" / "a.png").write_bytes((folder / "left.png").read_bytes())
    (tmp_path / "S" / "a.sbs").write_bytes((folder / "right.sbs").read_bytes())
    args = ["--left-dir", tmp_path / "L", "--samples-dir", tmp_path / "S", "--calibration", "auto", "--max-disp",
            "40", "--disparity", str(tmp_path / "D" / "{stem}.pfm"), "--json"]
    first = invoke(*args)
    assert first.exit_code == 0, first.stderr
    assert json.loads(first.stdout.splitlines()[0])["status"] == "ok"
    again = invoke(*args)
    assert again.exit_code == 0, again.stderr
    assert json.loads(again.stdout.splitlines()[0])["status"] == "skipped"
