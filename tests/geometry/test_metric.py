"""sb-decode --calibration: rectification at the host, depth in metres and PLY point clouds, on synthetic
scenes with exact geometry.

Decoding runs in this process (CliRunner) so numba's compiled kernels are shared by every test.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from stereobudget.batch import decode_stream
from stereobudget.cli.decode import decode_command
from stereobudget.errors import CalibrationError, OptionError, OutputError
from stereobudget.geometry import (depth_map, raw_left_disparity, raw_points, raw_right_positions, read_calibration,
                                   read_depth,
                                   rectification_for, rectify_stereo, unrectify_pair, write_calibration)
from stereobudget.io import read_disparity, save_samples, write_image
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene

MIDDLEBURY = ("cam0=[400 0 150.5; 0 400 119.5; 0 0 1]\ncam1=[400 0 158.5; 0 400 119.5; 0 0 1]\n"
              "doffs=8\nbaseline=120.5\nwidth=320\nheight=240\nndisp=40\n")
GRID = SamplingPattern("grid", 5, 5)


def invoke(*args):
    return CliRunner().invoke(decode_command, [str(a) for a in args], prog_name="sb-decode")


def assert_clean_error(result, error_class, *fragments):
    assert result.exit_code == error_class.exit_code, (result.exit_code, result.stderr, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sb-decode: error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.fixture(scope="module")
def scene():
    return make_scene("planes", seed=3)


@pytest.fixture(scope="module")
def rectified(tmp_path_factory, scene):
    """The synthetic pair as it is (rectified), with a Middlebury calib.txt."""
    folder = tmp_path_factory.mktemp("rectified")
    write_image(folder / "left.png", scene.left, channel_order="rgb")
    save_samples(encode_image(scene.right, pattern=GRID), folder / "right.sbs")
    (folder / "calib.txt").write_text(MIDDLEBURY)
    return folder


@pytest.fixture(scope="module")
def unrectified(tmp_path_factory, scene):
    """The same scene seen by two turned cameras with distorting lenses, and the calibration that undoes it."""
    folder = tmp_path_factory.mktemp("unrectified")
    pair = unrectify_pair(scene.left, scene.right, scene.disparity, rotation_left=np.radians([1.0, -1.5, 0.8]),
                          rotation_right=np.radians([-0.7, 1.2, -1.0]), k1_left=0.08, k1_right=-0.06,
                          mask=scene.nonocc)
    write_image(folder / "left.png", pair.left, channel_order="rgb")
    save_samples(encode_image(pair.right, pattern=GRID), folder / "right.sbs")
    write_calibration(folder / "stereo.yml", pair.calibration)
    return folder, pair


def test_depth_is_f_b_over_d_plus_doffs(rectified):
    result = invoke(rectified / "left.png", rectified / "right.sbs", "--calibration", rectified / "calib.txt",
                    "--disparity", rectified / "d.pfm", "--depth", rectified / "z.tif", "--overwrite", "--json")
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["frame"] == {"disparity": "rectified", "depth": "raw", "right": "rectified"}
    assert summary["calibration"]["rectified_at_host"] is False
    d = read_disparity(rectified / "d.pfm")
    z = read_depth(rectified / "z.tif")
    expected = 400.0 * 0.1205 / (d.astype(np.float64) + 8.0)
    valid = np.isfinite(d)
    assert valid.mean() > 0.95
    np.testing.assert_array_equal(np.isfinite(z), valid & (d + 8.0 > 0))
    np.testing.assert_allclose(z[valid], expected[valid], rtol=1e-4)


def test_depth_formats_and_their_invalid_values(rectified):
    outputs = {ext: rectified / f"z{ext}" for ext in (".pfm", ".npy", ".png")}
    for ext, path in outputs.items():
        result = invoke(rectified / "left.png", rectified / "right.sbs", "--calibration",
                        rectified / "calib.txt", "--depth", path, "--disparity", rectified / f"d{ext}.pfm",
                        "--overwrite")
        assert result.exit_code == 0, result.stderr
    d = read_disparity(rectified / "d.png.pfm")
    z = 400.0 * 0.1205 / (d.astype(np.float64) + 8.0)
    mm = cv2.imread(str(outputs[".png"]), cv2.IMREAD_UNCHANGED)
    assert mm.dtype == np.uint16
    # Millimetres, rounded (from float32 metres: a value on a .5 may round either way).
    assert np.abs(mm[np.isfinite(d)] - z[np.isfinite(d)] * 1000).max() <= 0.5 + 1e-3
    assert np.all(mm[~np.isfinite(d)] == 0)
    pfm = read_disparity(outputs[".pfm"])     # +inf on disk reads back as NaN
    np.testing.assert_allclose(pfm[np.isfinite(d)], z[np.isfinite(d)], rtol=1e-6)
    npy = np.load(outputs[".npy"])
    assert npy.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(npy), ~np.isfinite(d))


def test_host_rectified_depth_is_exact_on_a_plane(unrectified):
    """A plane at Z0 in the rectified frame has one disparity fB/Z0; every raw left pixel's depth follows
    from its ray alone (undistort, turn into the rectified frame, meet the plane)."""
    _, pair = unrectified
    rect = rectify_stereo(pair.calibration, 320, 240)
    z0 = 2.5
    disparity = np.full((240, 320), rect.focal * rect.baseline / z0, np.float32)
    depth = depth_map(disparity, rect)
    c = pair.calibration
    xs, ys = np.meshgrid(np.arange(320.0), np.arange(240.0))
    rays = cv2.undistortPoints(np.stack([xs, ys], -1).reshape(-1, 1, 2), c.M1, c.D1).reshape(240, 320, 2)
    v = np.concatenate([rays, np.ones((240, 320, 1))], axis=-1)
    expected = z0 / (v @ rect.R1.T)[..., 2]
    inside = np.isfinite(depth)
    assert inside.mean() > 0.99       # alpha 1: (nearly) every raw pixel lands in the rectified frame
    np.testing.assert_allclose(depth[inside], expected[inside], rtol=1e-4)
    rectified_depth = depth_map(disparity, rect, frame="rectified")
    np.testing.assert_allclose(rectified_depth, z0, rtol=1e-6)


def test_point_cloud_opens_in_plyfile_with_count_and_colours(unrectified):
    plyfile = pytest.importorskip("plyfile")
    folder, pair = unrectified
    result = invoke(folder / "left.png", folder / "right.sbs", "--calibration", folder / "stereo.yml",
                    "--disparity", folder / "d.pfm", "--points", folder / "cloud.ply", "--depth",
                    folder / "z.tif", "--overwrite", "--json")
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["calibration"]["rectified_at_host"] is True
    vertex = plyfile.PlyData.read(str(folder / "cloud.ply"))["vertex"]
    z = read_depth(folder / "z.tif")
    valid = np.isfinite(z)
    assert len(vertex) == summary["points"] == int(valid.sum()) > 0.9 * z.size
    colours = np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1)
    np.testing.assert_array_equal(colours, pair.left[valid])
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    np.testing.assert_allclose(xyz[:, 2], z[valid], rtol=1e-6)
    rect = rectification_for(folder / "stereo.yml", 320, 240)
    np.testing.assert_allclose(xyz, raw_points(read_disparity(folder / "d.pfm"), rect)[valid], rtol=1e-5,
                               atol=1e-6)


def test_known_calibration_decodes_an_unrectified_pair(unrectified, rectified, scene):
    """Scored on the raw left image (the implied raw right position against the true one, bad > 1 px):
    close to the rectified pair's decode, and far better than decoding the raw pair as if rectified."""
    folder, pair = unrectified
    for name, extra in (("cal", ["--calibration", folder / "stereo.yml"]), ("raw", [])):
        result = invoke(folder / "left.png", folder / "right.sbs", *extra, "--disparity", folder / f"{name}.pfm",
                        "--overwrite")
        assert result.exit_code == 0, result.stderr
    rect = rectification_for(folder / "stereo.yml", 320, 240)
    identity = rectify_stereo(read_calibration(rectified / "calib.txt"), 320, 240)

    def bad(path, rectification):
        implied = raw_right_positions(read_disparity(path), rectification)
        error = np.hypot(*(implied - pair.true_right).transpose(2, 0, 1))[pair.scored]
        return 100.0 * np.mean(~(error <= 1.0))

    result = invoke(rectified / "left.png", rectified / "right.sbs", "--disparity", rectified / "plain.pfm",
                    "--overwrite")
    assert result.exit_code == 0
    plain = read_disparity(rectified / "plain.pfm")
    bad_rectified = 100.0 * np.mean(~(np.abs(plain - scene.disparity)[scene.nonocc] <= 1.0))
    bad_calibrated = bad(folder / "cal.pfm", rect)
    bad_uncalibrated = bad(folder / "raw.pfm", identity)
    assert bad_calibrated < bad_rectified + 3.0, (bad_calibrated, bad_rectified)
    assert bad_uncalibrated > bad_calibrated + 20.0, (bad_uncalibrated, bad_calibrated)


def test_frame_raw_resamples_the_disparity_to_the_left_image(unrectified):
    folder, _ = unrectified
    result = invoke(folder / "left.png", folder / "right.sbs", "--calibration", folder / "stereo.yml",
                    "--disparity", folder / "raw_frame.pfm", "--frame", "raw", "--overwrite", "--json")
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["frame"]["disparity"] == "raw"
    rect = rectification_for(folder / "stereo.yml", 320, 240)
    result = invoke(folder / "left.png", folder / "right.sbs", "--calibration", folder / "stereo.yml",
                    "--disparity", folder / "rectified_frame.pfm", "--overwrite")
    assert result.exit_code == 0, result.stderr
    rectified = read_disparity(folder / "rectified_frame.pfm")
    raw = read_disparity(folder / "raw_frame.pfm")
    assert raw.shape == (240, 320)
    np.testing.assert_array_equal(raw, raw_left_disparity(rectified, rect))
    # Each raw pixel reads the rectified map at its rectified position: the nearest pixel's value
    # where the surface jumps, and within the four neighbours' values elsewhere.
    x = np.rint(rect.left_positions[..., 0]).astype(int).clip(0, 319)
    y = np.rint(rect.left_positions[..., 1]).astype(int).clip(0, 239)
    ok = np.isfinite(raw)
    assert np.all(np.abs(raw[ok] - rectified[y[ok], x[ok]]) <= 1.0 + 1e-6)


def test_a_stream_computes_the_maps_once(unrectified, tmp_path):
    folder, _ = unrectified
    frame = (folder / "right.sbs").read_bytes()
    (tmp_path / "stream.sbs").write_bytes(frame * 3)
    calibration = tmp_path / "stereo.yml"
    calibration.write_bytes((folder / "stereo.yml").read_bytes())
    before = rectification_for.cache_info()
    summaries = list(decode_stream(str(folder / "left.png"), str(tmp_path / "stream.sbs"),
                                   depth=str(tmp_path / "z{index}.tif"), points=str(tmp_path / "c{index}.ply"),
                                   calibration=str(calibration), max_disp="auto"))
    after = rectification_for.cache_info()
    assert len(summaries) == 3
    assert after.misses == before.misses + 1 and after.hits >= before.hits + 2
    assert [sorted(p.name for p in tmp_path.glob(f"?{i}.*")) for i in range(3)] == \
        [[f"c{i}.ply", f"z{i}.tif"] for i in range(3)]
    assert summaries[0]["calibration"] == summaries[2]["calibration"]


def test_option_and_calibration_errors(unrectified, rectified, tmp_path):
    folder, _ = unrectified
    left, samples = folder / "left.png", folder / "right.sbs"
    assert_clean_error(invoke(left, samples, "--depth", tmp_path / "z.tif"), OptionError,
                       "--depth needs --calibration")
    assert_clean_error(invoke(left, samples, "--calibration", folder / "stereo.yml", "--points",
                              tmp_path / "c.xyz"), OutputError, "use a .ply file name")
    assert_clean_error(invoke(left, samples, "--calibration", folder / "stereo.yml", "--depth",
                              tmp_path / "z.jpg"), OutputError, "unknown depth format '.jpg'")
    bad = tmp_path / "bad.yml"
    bad.write_text("%YAML:1.0\nM1: [1, 2\n")
    assert_clean_error(invoke(left, samples, "--calibration", bad, "--depth", tmp_path / "z.tif"),
                       CalibrationError, f"{bad}: not a readable OpenCV YAML/XML file")
    assert not (tmp_path / "z.tif").exists()
    # calib.txt says 320x240; a 160x120 pair is another image size.
    small = tmp_path / "small.png"
    write_image(small, cv2.resize(cv2.imread(str(left)), (160, 120)), channel_order="bgr")
    right_small = tmp_path / "small.sbs"
    save_samples(encode_image(cv2.resize(cv2.imread(str(left)), (160, 120)), pattern=GRID), right_small)
    assert_clean_error(invoke(small, right_small, "--calibration", rectified / "calib.txt", "--depth",
                              tmp_path / "z.tif"), CalibrationError,
                       "calibrated for 320x240 images but the left image is 160x120")
    swapped = tmp_path / "swapped.txt"
    swapped.write_text(MIDDLEBURY.replace("baseline=120.5", "baseline=-120.5"))
    assert_clean_error(invoke(rectified / "left.png", rectified / "right.sbs", "--calibration", swapped,
                              "--depth", tmp_path / "z.tif"), CalibrationError, "baseline -120.5 must be positive")
    assert not list(tmp_path.glob("z*")) and not list(tmp_path.glob(".z*"))


REALDEV = Path(__file__).resolve().parents[3] / "shared" / "data" / "realdev"


@pytest.mark.skipif(not (REALDEV / "Sawtooth").is_dir(), reason=f"realdev scenes not found at {REALDEV}")
def test_an_unrectified_real_pair_with_its_calibration(tmp_path):
    """Sawtooth turned and distorted as scripts/unrectified.py does it (its seed's draw): --calibration
    decodes the raw pair within 3 pp of the rectified pair's decode (measured: 5.30 against 4.69 %)."""
    folder = REALDEV / "Sawtooth"
    left = cv2.cvtColor(cv2.imread(str(folder / "left.png")), cv2.COLOR_BGR2RGB)
    right = cv2.cvtColor(cv2.imread(str(folder / "right.png")), cv2.COLOR_BGR2RGB)
    gt = cv2.imread(str(folder / "disp_left.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / 256
    gt[gt <= 0] = np.nan
    pair = unrectify_pair(left, right, gt, rotation_left=np.radians([1.597, -1.699, -0.611]),
                          rotation_right=np.radians([-1.027, 1.474, 0.776]), k1_left=0.0676, k1_right=0.0698)
    write_image(tmp_path / "left.png", left, channel_order="rgb")
    write_image(tmp_path / "raw_left.png", pair.left, channel_order="rgb")
    save_samples(encode_image(right, pattern=GRID), tmp_path / "right.sbs")
    save_samples(encode_image(pair.right, pattern=GRID), tmp_path / "raw_right.sbs")
    write_calibration(tmp_path / "stereo.yml", pair.calibration)
    assert invoke(tmp_path / "left.png", tmp_path / "right.sbs", "--max-disp", 22, "--min-disp", -1,
                  "--disparity", tmp_path / "d.pfm").exit_code == 0
    result = invoke(tmp_path / "raw_left.png", tmp_path / "raw_right.sbs", "--calibration", tmp_path / "stereo.yml",
                    "--max-disp", 21, "--min-disp", -1, "--disparity", tmp_path / "dc.pfm")
    assert result.exit_code == 0, result.stderr
    d = read_disparity(tmp_path / "d.pfm")
    bad_rectified = 100.0 * np.mean(~(np.abs(d - gt)[np.isfinite(gt)] <= 1.0))
    implied = raw_right_positions(read_disparity(tmp_path / "dc.pfm"),
                                  rectification_for(tmp_path / "stereo.yml", *pair.left.shape[1::-1]))
    error = np.hypot(*(implied - pair.true_right).transpose(2, 0, 1))[pair.scored]
    bad_calibrated = 100.0 * np.mean(~(error <= 1.0))
    assert bad_calibrated < bad_rectified + 3.0, (bad_calibrated, bad_rectified)


def test_a_grid_is_placed_once_per_rectification_in_row_major_order(unrectified, scene):
    from stereobudget.fill import lowpass_interpolation
    from stereobudget.geometry import rectify_samples
    folder, pair = unrectified
    rectification = rectification_for(str(folder / "stereo.yml"), scene.left.shape[1], scene.left.shape[0])
    first = rectify_samples(encode_image(pair.right, pattern=GRID), rectification)
    brighter = rectify_samples(encode_image(np.clip(pair.right.astype(int) + 20, 0, 255).astype(np.uint8),
                                            pattern=GRID), rectification)
    # The frames of a stream share where their samples land, not their values.
    assert brighter.rows is first.rows and brighter.offsets is first.offsets
    assert not np.array_equal(brighter.values, first.values)
    height, width = first.height, first.width
    assert np.all(np.diff(first.rows * width + first.cols) > 0)       # (row, col) order, one sample a pixel
    # The low-pass of the raw lattice read into the frame is the Gaussian interpolation of
    # the placed samples, up to where each sample sits (within half a pixel) and the edges.
    on_lattice = lowpass_interpolation(first, sigma=5.0)
    impulses = np.zeros((height, width, 4), np.float32)
    impulses[first.rows, first.cols, :3] = first.values_rgb()
    impulses[first.rows, first.cols, 3] = 1.0
    blurred = cv2.GaussianBlur(impulses, (0, 0), 5.0, sigmaY=5.0, borderType=cv2.BORDER_CONSTANT)
    scattered = blurred[..., :3] / np.maximum(blurred[..., 3:], 1e-6)
    inner = (slice(20, height - 20), slice(20, width - 20))
    assert on_lattice.shape == scattered.shape == (height, width, 3)
    assert np.median(np.abs(on_lattice[inner] - scattered[inner])) < 1.0
