"""``sb-decode --disparity -``: one frame's disparity on standard output, through a real pipe."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from stereobudget.io import read_disparity, save_samples
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stdout")
    scene = make_scene("slanted", seed=2)
    left = folder / "left.png"
    assert cv2.imwrite(str(left), np.ascontiguousarray(scene.left[:, :, ::-1]))
    samples = folder / "right.sbs"
    save_samples(encode_image(scene.right, pattern=SamplingPattern("grid", 5, 5)), samples)
    return folder, str(left), str(samples)


def sb_decode(*args, cwd):
    return subprocess.run([sys.executable, "-m", "stereobudget.cli.decode", *map(str, args)], cwd=cwd,
                          capture_output=True, timeout=600)


def test_pfm_and_png_on_stdout_equal_the_file_outputs(pair):
    folder, left, samples = pair
    as_file = sb_decode(left, samples, "--max-disp", 40, "--disparity", "d.pfm", "--overwrite", cwd=folder)
    assert as_file.returncode == 0, as_file.stderr
    expected = read_disparity(folder / "d.pfm")

    pfm = sb_decode(left, samples, "--max-disp", 40, "--disparity", "-", cwd=folder)
    assert pfm.returncode == 0, pfm.stderr
    assert pfm.stdout.startswith(b"Pf\n")
    (folder / "stdout.pfm").write_bytes(pfm.stdout)
    np.testing.assert_array_equal(read_disparity(folder / "stdout.pfm"), expected)

    png = sb_decode(left, samples, "--max-disp", 40, "--disparity", "-", "--format", "png", cwd=folder)
    assert png.returncode == 0, png.stderr
    decoded = cv2.imdecode(np.frombuffer(png.stdout, np.uint8), cv2.IMREAD_UNCHANGED)
    assert decoded.dtype == np.uint16 and decoded.shape == expected.shape
    valid = np.isfinite(expected)
    np.testing.assert_allclose(decoded[valid] / 256.0, expected[valid], atol=1 / 512 + 1e-6)
    assert (decoded[~valid] == 0).all()


def test_preview_on_stdout_is_the_file_preview_with_its_colour_bar(pair):
    folder, left, samples = pair
    as_file = sb_decode(left, samples, "--max-disp", 40, "--preview", "p.png", "--overwrite", cwd=folder)
    assert as_file.returncode == 0, as_file.stderr
    piped = sb_decode(left, samples, "--max-disp", 40, "--preview", "-", cwd=folder)
    assert piped.returncode == 0, piped.stderr
    assert piped.stdout == (folder / "p.png").read_bytes()
    image = cv2.imdecode(np.frombuffer(piped.stdout, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape[1] == 320 and image.shape[0] > 240      # the map, then the bar and its scale


@pytest.mark.parametrize("args, fragment", [
    (["--disparity", "d2.pfm", "--format", "png"], "--format sets the format of --disparity -"),
    (["--disparity", "-", "--right", "-"], "only one output can go to standard output"),
    (["--disparity", "-", "--json"], "--json cannot be combined"),
])
def test_stdout_option_errors(pair, args, fragment):
    folder, left, samples = pair
    run = sb_decode(left, samples, "--max-disp", 40, *args, cwd=folder)
    assert run.returncode == 2 and run.stdout == b""
    lines = run.stderr.decode().splitlines()
    assert len(lines) == 1 and fragment in lines[0], lines
