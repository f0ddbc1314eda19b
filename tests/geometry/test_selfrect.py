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


def test_a_poor_estimate_is_refused_not_decoded(tmp_path):
    """Slanted synthetic planes: the matches are right, but the pose found from them leaves the
    rows more than half a pixel apart; the decode is refused rather than run on it."""
    scene = make_scene("slanted", seed=1)
    pair = turned(scene)
    with pytest.raises(CalibrationError, match="median vertical error of .* px"):
        self_rectification(pair.left, encode_image(pair.right, pattern=GRID))


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
