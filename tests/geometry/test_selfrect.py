"""Self-rectification (experimental, library only): the epipolar geometry from I1 and a grid of samples,
or a clean refusal; sb-decode does not offer it yet."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from stereobudget.cli.decode import decode_command
from stereobudget.errors import CalibrationError, OptionError
from stereobudget.geometry import self_rectification, unrectify_pair
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


def test_sb_decode_does_not_offer_auto(tmp_path):
    result = invoke(tmp_path / "left.png", tmp_path / "right.sbs", "--calibration", "auto", "--disparity",
                    tmp_path / "d.pfm")
    assert result.exit_code == OptionError.exit_code
    assert "--calibration auto (self-rectification) is not available" in result.stderr
