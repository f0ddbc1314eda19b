"""sb-decode, one pair at a time: formats, stdin, outputs, JSON summary, clean errors.

Decoding runs in this process (CliRunner) so numba's compiled kernels are shared by
every test; the images are small crops of skimage's Middlebury motorcycle.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from stereobudget import __version__
from stereobudget.cli.decode import decode_command
from stereobudget.io import save_samples
from stereobudget.encoding import encode_image
from stereobudget.io import read_disparity
from stereobudget.errors import (ImageReadError, MismatchError, NotASampleFileError, OptionError,
                                 OutputError)
from stereobudget.sampling import SamplingPattern

MAX_DISP = 12


def small_pair():
    """Motorcycle left/right scaled to 1/8 (92x62); true disparities 0..~7.5 px."""
    skdata = pytest.importorskip("skimage.data")
    left, right, _ = skdata.stereo_motorcycle()
    size = (left.shape[1] // 8, left.shape[0] // 8)
    return (cv2.resize(left, size, interpolation=cv2.INTER_AREA),
            cv2.resize(right, size, interpolation=cv2.INTER_AREA))


def write_png(path, rgb):
    image = rgb[:, :, ::-1] if rgb.ndim == 3 else rgb
    assert cv2.imwrite(str(path), np.ascontiguousarray(image))
    return path


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pair")
    left, right = small_pair()
    left_path = write_png(folder / "left.png", left)
    samples = encode_image(right, pattern=SamplingPattern(kind="grid", stride_x=4, stride_y=4))
    samples_path = folder / "right.sbs"
    save_samples(samples, samples_path)
    return left_path, samples_path, left, right


def invoke(*args, input=None):
    return CliRunner().invoke(decode_command, [str(a) for a in args], input=input, prog_name="sb-decode")


def assert_clean_error(result, error_class, *fragments):
    """The error's exit code, one documented stderr line, no traceback."""
    assert result.exit_code == error_class.exit_code, (result.exit_code, result.stderr, result.exception)
    assert not isinstance(result.exception, Exception) or isinstance(result.exception, SystemExit)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("sb-decode: error: "), result.stderr
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


def test_decode_pfm_preview_and_json_summary(pair, tmp_path):
    left_path, samples_path, left, _ = pair
    disparity, preview = tmp_path / "d.pfm", tmp_path / "d.png"
    result = invoke(left_path, samples_path, "--max-disp", MAX_DISP, "--disparity", disparity,
                    "--preview", preview, "--json")
    assert result.exit_code == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 1
    summary = json.loads(lines[0])
    d = read_disparity(disparity)
    assert d.dtype == np.float32 and d.shape == left.shape[:2]
    valid = np.isfinite(d)
    assert valid.mean() > 0.9
    # The motorcycle at 1/8 scale has disparities within the searched range, mostly 2..8 px.
    assert 0 <= np.nanmin(d) and np.nanmax(d) <= MAX_DISP
    assert 2 < np.nanmedian(d) < 9
    assert summary["status"] == "ok"
    assert summary["left"] == str(left_path) and summary["samples"] == str(samples_path)
    assert (summary["width"], summary["height"], summary["channels"]) == (left.shape[1], left.shape[0], 3)
    assert summary["epsilon"] == pytest.approx((-(-left.shape[0] // 4)) * (-(-left.shape[1] // 4))
                                               / (left.shape[0] * left.shape[1]))
    from stereobudget.decoding import DEFAULT_METHOD
    assert summary["method"] == DEFAULT_METHOD
    assert summary["max_disp"] == MAX_DISP and summary["min_disp"] == 0
    assert summary["disparity_range"] == pytest.approx([float(np.nanmin(d)), float(np.nanmax(d))])
    for stage in ("read", "validate", "write", "total"):
        assert summary["timings"][stage] >= 0
    assert summary["outputs"] == {"disparity": str(disparity), "preview": str(preview)}
    rgb = cv2.imread(str(preview))
    assert rgb.shape == left.shape and rgb.dtype == np.uint8


@pytest.mark.parametrize("ext", [".tif", ".png", ".npy"])
def test_disparity_format_follows_extension(pair, tmp_path, ext):
    left_path, samples_path, *_ = pair
    reference, out = tmp_path / "ref.pfm", tmp_path / f"d{ext}"
    assert invoke(left_path, samples_path, "--max-disp", MAX_DISP, "--disparity", reference).exit_code == 0
    result = invoke(left_path, samples_path, "--max-disp", MAX_DISP, "--disparity", out)
    assert result.exit_code == 0, result.stderr
    tolerance = 1 / 256 if ext == ".png" else 0
    np.testing.assert_allclose(read_disparity(out), read_disparity(reference), atol=tolerance)


def test_samples_from_stdin(pair, tmp_path):
    left_path, samples_path, *_ = pair
    out = tmp_path / "d.npy"
    result = invoke(left_path, "-", "--max-disp", MAX_DISP, "--disparity", out, "--json",
                    input=samples_path.read_bytes())
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["samples"] == "<stdin>"
    assert np.load(out).shape == cv2.imread(str(left_path)).shape[:2]


def test_left_from_stdin(pair, tmp_path):
    left_path, samples_path, *_ = pair
    out = tmp_path / "d.npy"
    result = invoke("-", samples_path, "--max-disp", MAX_DISP, "--disparity", out,
                    input=left_path.read_bytes())
    assert result.exit_code == 0, result.stderr
    assert out.exists()


def test_both_inputs_on_stdin_refused(tmp_path):
    result = invoke("-", "-", "--max-disp", MAX_DISP, "--disparity", tmp_path / "d.pfm")
    assert_clean_error(result, OptionError, "only one of LEFT and SAMPLES")


def test_right_image_keeps_channels_and_bit_depth(tmp_path):
    left, right = small_pair()
    # 16-bit gray pair: Î2 must come back 16-bit, one channel.
    left16 = (cv2.cvtColor(left, cv2.COLOR_RGB2GRAY).astype(np.uint16) * 257)
    right16 = (cv2.cvtColor(right, cv2.COLOR_RGB2GRAY).astype(np.uint16) * 257)
    left_path = write_png(tmp_path / "l16.png", left16)
    samples_path = tmp_path / "r16.sbs"
    samples = encode_image(right16, pattern=SamplingPattern(kind="grid", stride_x=3, stride_y=3))
    save_samples(samples, samples_path)
    out = tmp_path / "r_hat.png"
    result = invoke(left_path, samples_path, "--max-disp", MAX_DISP, "--right", out, "--json")
    assert result.exit_code == 0, result.stderr
    recovered = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert recovered.dtype == np.uint16 and recovered.shape == left16.shape
    # The samples the camera sent are exact in Î2, and the rest is close to the true right image.
    np.testing.assert_array_equal(recovered[::3, ::3], right16[::3, ::3])
    err = np.abs(recovered.astype(np.float64) - right16) / 257
    assert np.median(err) < 8
    summary = json.loads(result.stdout)
    assert summary["outputs"] == {"right": str(out)}
    assert "right" in summary["timings"]


def test_size_mismatch(pair, tmp_path):
    _, samples_path, left, _ = pair
    other = write_png(tmp_path / "small.png", left[:-2])
    result = invoke(other, samples_path, "--max-disp", MAX_DISP, "--disparity", tmp_path / "d.pfm")
    assert_clean_error(result, MismatchError, "small.png", "right.sbs", f"{left.shape[1]}x{left.shape[0] - 2}")
    assert not (tmp_path / "d.pfm").exists()


def test_channel_and_depth_mismatch(pair, tmp_path):
    _, samples_path, left, _ = pair
    gray = write_png(tmp_path / "gray.png", cv2.cvtColor(left, cv2.COLOR_RGB2GRAY))
    result = invoke(gray, samples_path, "--max-disp", MAX_DISP, "--disparity", tmp_path / "d.pfm")
    assert_clean_error(result, MismatchError, "channel")
    deep = write_png(tmp_path / "deep.png", left.astype(np.uint16) * 257)
    result = invoke(deep, samples_path, "--max-disp", MAX_DISP, "--disparity", tmp_path / "d.pfm")
    assert_clean_error(result, MismatchError, "uint16")


def test_corrupt_samples_and_unreadable_left(pair, tmp_path):
    left_path, samples_path, *_ = pair
    result = invoke(left_path, left_path, "--max-disp", MAX_DISP, "--disparity", tmp_path / "d.pfm")
    assert_clean_error(result, NotASampleFileError, "looks like a PNG")
    result = invoke(tmp_path / "missing.png", samples_path, "--max-disp", MAX_DISP,
                    "--disparity", tmp_path / "d.pfm")
    assert_clean_error(result, ImageReadError, "missing.png", "no such file")


def test_outputs_are_protected(pair, tmp_path):
    left_path, samples_path, *_ = pair
    out = tmp_path / "d.pfm"
    out.write_bytes(b"keep me")
    result = invoke(left_path, samples_path, "--max-disp", MAX_DISP, "--disparity", out)
    assert_clean_error(result, OutputError, "exists", "--overwrite")
    assert out.read_bytes() == b"keep me"
    result = invoke(left_path, samples_path, "--max-disp", MAX_DISP, "--disparity", out, "--overwrite")
    assert result.exit_code == 0 and read_disparity(out).shape
    result = invoke(left_path, samples_path, "--max-disp", MAX_DISP, "--right", left_path, "--overwrite")
    assert_clean_error(result, OutputError, "same file as the input")
    result = invoke(left_path, samples_path, "--max-disp", MAX_DISP, "--disparity", tmp_path / "x.pfm",
                    "--preview", tmp_path / "x.pfm")
    assert_clean_error(result, OptionError, "same file")
    assert not list(tmp_path.glob(".*tmp"))


@pytest.mark.parametrize("args, fragment", [
    (["--max-disp", MAX_DISP], "nothing to write"),
    (["--max-disp", "wide", "--disparity", "d.pfm"], "--max-disp"),
    (["--max-disp", MAX_DISP, "--disparity", "d.pfm", "--min-disp", MAX_DISP], "greater than"),
    (["--max-disp", MAX_DISP, "--disparity", "d.xyz"], "unknown disparity format"),
])
def test_option_errors(pair, tmp_path, monkeypatch, args, fragment):
    left_path, samples_path, *_ = pair
    monkeypatch.chdir(tmp_path)
    result = invoke(left_path, samples_path, *args)
    assert result.exit_code in (OptionError.exit_code, OutputError.exit_code), result.stderr
    assert fragment in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "d.pfm").exists()


def test_version():
    result = invoke("--version")
    assert result.exit_code == 0 and __version__ in result.stdout


def test_a_single_failed_pair_writes_its_failed_json_line(pair, tmp_path):
    left_path, _, _, _ = pair
    missing = tmp_path / "missing.sbs"
    result = invoke(left_path, missing, "--max-disp", MAX_DISP, "--disparity", tmp_path / "d.pfm", "--json")
    assert_clean_error(result, NotASampleFileError, str(missing), "no such file")
    line = json.loads(result.stdout)
    assert line == {"status": "failed", "left": str(left_path), "samples": str(missing),
                    "outputs": {"disparity": str(tmp_path / "d.pfm")}, "error": f"{missing}: no such file",
                    "error_class": "NotASampleFileError", "exit_code": NotASampleFileError.exit_code}


def test_a_stride_1_bayer_file_is_refused_naming_it(tmp_path):
    from stereobudget.encoding import encode_file

    gray = np.random.default_rng(1).integers(0, 256, (32, 48), dtype=np.uint8)
    raw = tmp_path / "bayer.raw"
    raw.write_bytes(gray.tobytes())
    samples = tmp_path / "bayer1.sbs"
    encode_file(raw, samples, pattern=SamplingPattern("grid", 1, 1), raw_size=(48, 32), pix_fmt="bayer_rggb8")
    left = write_png(tmp_path / "left.png", np.dstack([gray] * 3))
    result = invoke(left, samples, "--max-disp", 4, "--disparity", tmp_path / "d.pfm")
    assert_clean_error(result, OptionError, f"{samples}: a bayer_rggb mosaic at stride 1")
    assert not (tmp_path / "d.pfm").exists()
