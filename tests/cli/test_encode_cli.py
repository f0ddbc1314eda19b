"""sb-encode end to end: real console-script processes, OS pipes, signals, exit codes."""

from __future__ import annotations

import json
import os
import pty
import signal
import struct
import subprocess
import tempfile
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from stereobudget import __version__
from stereobudget.cli.encode import encode_command
from stereobudget.io import load_samples, read_samples
from stereobudget.errors import (CorruptHeaderError, CorruptPayloadError, ImageReadError,
                                 NotASampleFileError, OptionError, OutputError, TruncatedFileError,
                                 UnsupportedVersionError)

SB_ENCODE = str(Path(sys.executable).parent / "sb-encode")
DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "middlebury"


def rgb_image(h=23, w=31, dtype=np.uint8, seed=0):
    top = np.iinfo(dtype).max
    return np.random.default_rng(seed).integers(0, top, (h, w, 3), endpoint=True, dtype=dtype)


@pytest.fixture()
def png(tmp_path):
    rgb = rgb_image()
    path = tmp_path / "right.png"
    assert cv2.imwrite(str(path), rgb[:, :, ::-1].copy())
    return path, rgb


def run(*args, stdin=None, **kwargs):
    return subprocess.run([SB_ENCODE, *map(str, args)], input=stdin, capture_output=True,
                          timeout=60, **kwargs)


def assert_clean_error(proc, code, *fragments):
    """Exit ``code``, exactly one line on stderr in the documented form, no traceback."""
    err = proc.stderr.decode()
    assert proc.returncode == code, err
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("sb-encode: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, err)


def invoke(*args, input=None):
    return CliRunner().invoke(encode_command, [str(a) for a in args], input=input,
                              prog_name="sb-encode")


# --- encoding -------------------------------------------------------------------------

def test_encode_png_subprocess_and_json(png, tmp_path):
    path, rgb = png
    out = tmp_path / "right.sbs"
    proc = run(path, "-o", out, "--stride", 4, "--offset", "1,2", "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    ss = load_samples(out)
    np.testing.assert_array_equal(ss.grid_values(), rgb[2::4, 1::4])
    assert summary["sample_count"] == ss.values.shape[0] == 6 * 8
    assert summary["payload_bytes"] == 6 * 8 * 3 and summary["header_bytes"] == 80
    assert summary["file_size"] == out.stat().st_size
    assert summary["epsilon"] == pytest.approx(48 / (23 * 31))


def test_stride_x_y_and_jitter(png, tmp_path):
    path, rgb = png
    out = tmp_path / "j.sbs"
    result = invoke(path, "-o", out, "--pattern", "jitter", "--stride-x", 3, "--stride-y", 5,
                    "--seed", 2 ** 64 - 1)
    assert result.exit_code == 0, result.output
    ss = load_samples(out)
    assert (ss.pattern.kind, ss.pattern.stride_x, ss.pattern.stride_y, ss.pattern.seed) == \
        ("jitter", 3, 5, 2 ** 64 - 1)
    rows, cols = ss.positions()
    np.testing.assert_array_equal(ss.values, rgb[rows, cols])


def test_16bit_png(tmp_path):
    rgb = rgb_image(dtype=np.uint16)
    path = tmp_path / "deep.png"
    cv2.imwrite(str(path), rgb[:, :, ::-1].copy())
    out = tmp_path / "deep.sbs"
    assert invoke(path, "-o", out, "--stride", 2).exit_code == 0
    ss = load_samples(out)
    assert ss.dtype == np.uint16
    np.testing.assert_array_equal(ss.grid_values(), rgb[::2, ::2])


def test_alpha_is_dropped(tmp_path):
    rgba = np.dstack([rgb_image(), np.full((23, 31), 7, np.uint8)])
    path = tmp_path / "rgba.png"
    cv2.imwrite(str(path), rgba[:, :, [2, 1, 0, 3]].copy())
    out = tmp_path / "rgba.sbs"
    proc = run(path, "-o", out, "--stride", 3, "-v")
    assert proc.returncode == 0
    assert "alpha" in proc.stderr.decode()
    np.testing.assert_array_equal(load_samples(out).grid_values(), rgba[::3, ::3, :3])


def test_verbose_logs_epsilon_and_size(png, tmp_path):
    proc = run(png[0], "-o", tmp_path / "v.sbs", "-v")
    assert proc.returncode == 0
    err = proc.stderr.decode()
    assert "(4.91 % of the pixels)" in err and "header 80 + payload" in err
    quiet = run(png[0], "-o", tmp_path / "q.sbs")
    assert quiet.returncode == 0 and quiet.stderr == b"" and quiet.stdout == b""


def test_stdin_to_stdout_through_a_real_pipe(png):
    path, rgb = png
    with open(path, "rb") as image:
        encode = subprocess.Popen([SB_ENCODE, "-", "-o", "-", "--stride", "5"], stdin=image,
                                  stdout=subprocess.PIPE)
        info = subprocess.Popen([SB_ENCODE, "--info", "-"], stdin=encode.stdout,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        encode.stdout.close()     # so that the first process sees a closed pipe if the second dies
        out, err = info.communicate(timeout=60)
        assert encode.wait(timeout=60) == 0
    assert info.returncode == 0, err
    header = json.loads(out)
    assert (header["width"], header["height"], header["sample_count"]) == (31, 23, 5 * 7)
    assert header["payload_length"] == 5 * 7 * 3


def test_stdout_sample_file_matches_file_output(png, tmp_path):
    out = tmp_path / "f.sbs"
    assert run(png[0], "-o", out).returncode == 0
    piped = run("-", "-o", "-", stdin=png[0].read_bytes())
    assert piped.returncode == 0 and piped.stdout == out.read_bytes()


@pytest.mark.parametrize("pix_fmt,channels,dtype,order", [
    ("rgb24", 3, np.uint8, "rgb"), ("bgr24", 3, np.uint8, "bgr"),
    ("gray8", 1, np.uint8, "gray"), ("gray16le", 1, np.uint16, "gray")])
def test_raw_frames_from_stdin(tmp_path, pix_fmt, channels, dtype, order):
    frame = rgb_image(h=10, w=14, dtype=dtype)[:, :, :channels]
    out = tmp_path / "raw.sbs"
    proc = run("-", "--raw", "14x10", "--pix-fmt", pix_fmt, "--stride", 3, "-o", out,
               stdin=frame.astype(frame.dtype.newbyteorder("<")).tobytes())
    assert proc.returncode == 0, proc.stderr
    ss = load_samples(out)
    assert ss.channel_order == order and ss.dtype == dtype
    np.testing.assert_array_equal(ss.grid_values(), frame[::3, ::3])


def test_raw_frame_of_the_wrong_size(tmp_path):
    proc = run("-", "--raw", "14x10", "--pix-fmt", "rgb24", "-o", tmp_path / "x.sbs",
               stdin=bytes(14 * 10 * 3 + 5))
    # Standard input is a stream of frames: the cut one is named, and nothing is written.
    assert_clean_error(proc, ImageReadError.exit_code, "<stdin>", "frames are 420 bytes each",
                       "frame 1 is cut short at 5 bytes")
    assert not (tmp_path / "x.sbs").exists()
    short = run("-", "--raw", "14x10", "--pix-fmt", "rgb24", "-o", tmp_path / "x.sbs", stdin=bytes(400))
    assert_clean_error(short, ImageReadError.exit_code, "<stdin>", "exactly 420 bytes, got 400")


def _loaded_heavy_modules(args) -> list:
    code = ("import sys, json\n"
            "from stereobudget.cli.encode import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "print(json.dumps(sorted(m for m in ('cv2', 'numba') if m in sys.modules)))\n")
    # cwd outside the checkout: `python -c` puts the cwd first on sys.path, and the source
    # tree's stereobudget/ lacks the stereobudget.cli subpackage that installation maps in.
    proc = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True,
                          text=True, timeout=60, cwd=tempfile.gettempdir())
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def test_raw_encoding_imports_neither_opencv_nor_numba(tmp_path):
    frame = tmp_path / "f.raw"
    frame.write_bytes(bytes(40 * 30 * 3))
    assert _loaded_heavy_modules([frame, "--raw", "40x30", "--pix-fmt", "rgb24",
                                  "-o", tmp_path / "f.sbs"]) == []


def test_png_encoding_never_imports_numba(png, tmp_path):
    assert _loaded_heavy_modules([png[0], "-o", tmp_path / "p.sbs"]) == ["cv2"]


def _run_main_without_numpy(args, *, stdin: bytes | None = None) -> subprocess.CompletedProcess:
    """Run sb-encode's main in a fresh interpreter; it fails if numpy, numba or cv2 got imported."""
    code = ("import sys\n"
            "from stereobudget.cli.encode import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "assert 'numpy' not in sys.modules, 'numpy imported'\n"
            "assert 'numba' not in sys.modules, 'numba imported'\n"
            "assert 'cv2' not in sys.modules, 'cv2 imported'\n")
    # cwd outside the checkout: see _loaded_heavy_modules.
    proc = subprocess.run([sys.executable, "-c", code, *map(str, args)], input=stdin,
                          capture_output=True, timeout=60, cwd=tempfile.gettempdir())
    assert proc.returncode == 0, proc.stderr.decode()
    return proc


@pytest.mark.parametrize("pix_fmt,channels,dtype", [
    ("rgb24", 3, np.uint8), ("bgr24", 3, np.uint8), ("gray8", 1, np.uint8), ("gray16le", 1, np.uint16),
    ("bayer_grbg8", 1, np.uint8), ("bayer_gbrg16le", 1, np.uint16)])
def test_raw_grid_encoding_and_info_import_no_numpy(tmp_path, pix_fmt, channels, dtype):
    frame = rgb_image(h=37, w=45, dtype=dtype, seed=3)[:, :, :channels]
    raw = frame.astype(frame.dtype.newbyteorder("<")).tobytes()
    path = tmp_path / "f.raw"
    path.write_bytes(raw)
    out = tmp_path / "f.sbs"
    _run_main_without_numpy([path, "--raw", "45x37", "--pix-fmt", pix_fmt, "--stride-x", 4,
                             "--stride-y", 3, "--offset", "1,2", "-o", out, "--json"])
    ss = load_samples(out)
    np.testing.assert_array_equal(ss.grid_values(), frame.reshape(37, 45, channels)[2::3, 1::4])
    # Standard input to standard output, with the default --codec raw spelt out: the same bytes.
    piped = _run_main_without_numpy(["-", "--raw", "45x37", "--pix-fmt", pix_fmt, "--stride-x", 4,
                                     "--stride-y", 3, "--offset", "1,2", "-o", "-", "--codec", "raw"],
                                    stdin=raw)
    assert piped.stdout == out.read_bytes()
    # --info, with and without the payload check.
    for extra in ([], ["--header-only"]):
        info = _run_main_without_numpy(["--info", out, *extra])
        assert json.loads(info.stdout)["sample_count"] == ss.values.shape[0]


# --- --info ----------------------------------------------------------------------------

def _corrupt_variants(good: bytes) -> dict:
    def fixed_crc(head: bytearray) -> bytes:
        return bytes(head[:76]) + struct.pack("<I", zlib.crc32(bytes(head[:76])))

    newer_major = bytearray(good[:80])
    newer_major[8] = 2
    bad_dims = bytearray(good[:80])
    struct.pack_into("<I", bad_dims, 12, 0)
    flipped_payload = bytearray(good)
    flipped_payload[-1] ^= 0x40
    return {
        "truncated": (good[:-10], TruncatedFileError, "truncated"),
        "empty": (b"", TruncatedFileError, "empty file"),
        "not_sbs": (b"P6\n3 3\n255\n" + bytes(27), NotASampleFileError, "PGM/PPM image"),
        "crlf": (good.replace(b"\r\n", b"\n", 1), NotASampleFileError, "text-mode transfer"),
        "major": (fixed_crc(newer_major) + good[80:], UnsupportedVersionError, "version 2.0"),
        "header_crc": (good[:30] + bytes([good[30] ^ 1]) + good[31:], CorruptHeaderError,
                       "header checksum"),
        "dims": (fixed_crc(bad_dims) + good[80:], CorruptHeaderError, "0x"),
        "payload_crc": (bytes(flipped_payload), CorruptPayloadError, "payload checksum"),
        "trailing": (good + b"\n", CorruptPayloadError, "1 unexpected bytes"),
    }


@pytest.fixture()
def good_sbs(png, tmp_path):
    out = tmp_path / "good.sbs"
    assert run(png[0], "-o", out).returncode == 0
    return out.read_bytes()


def test_info_prints_one_json_line(good_sbs, tmp_path):
    path = tmp_path / "g.sbs"
    path.write_bytes(good_sbs)
    proc = run("--info", path)
    assert proc.returncode == 0 and proc.stderr == b""
    lines = proc.stdout.decode().splitlines()
    assert len(lines) == 1
    header = json.loads(lines[0])
    assert header["file_size"] == len(good_sbs) and header["version"] == "1.0"
    assert header["epsilon"] == pytest.approx(read_samples(good_sbs).epsilon)


def test_info_rejects_every_corruption_with_its_exit_code(good_sbs, tmp_path):
    codes = set()
    for label, (data, error, fragment) in _corrupt_variants(good_sbs).items():
        path = tmp_path / f"{label}.sbs"
        path.write_bytes(data)
        proc = run("--info", path)
        assert_clean_error(proc, error.exit_code, str(path), fragment)
        assert proc.stdout == b""
        codes.add(error.exit_code)
    assert codes == {4, 5, 6, 7, 8}


def test_header_only_skips_the_payload_crc(good_sbs, tmp_path):
    data, _, _ = _corrupt_variants(good_sbs)["payload_crc"]
    path = tmp_path / "p.sbs"
    path.write_bytes(data)
    assert invoke("--info", path).exit_code == CorruptPayloadError.exit_code
    result = invoke("--info", path, "--header-only")
    assert result.exit_code == 0 and json.loads(result.stdout)["payload_length"] == len(data) - 80


def test_info_on_stdin(good_sbs):
    proc = run("--info", "-", stdin=good_sbs[:-1])
    assert_clean_error(proc, TruncatedFileError.exit_code, "<stdin>", "1 missing")


# --- option and output errors -------------------------------------------------------------

@pytest.mark.parametrize("args,fragment", [
    (["--offset", "5,0"], "must be smaller than the stride 5x5"),
    (["--offset", "1;2"], "X,Y"),
    (["--pattern", "jitter", "--offset", "1,1"], "grid only"),
    (["--seed", "3"], "jitter only"),
    (["--raw", "10x10"], "together"),
    (["--raw", "10by10", "--pix-fmt", "gray8"], "WIDTHxHEIGHT"),
    (["--header-only"], "--info"),
    (["--check"], "--info"),
    (["--stride", "7", "--epsilon", "0.04"], "drop --stride"),
    (["--stride-x", "3", "--size", "900"], "drop --stride-x"),
])
def test_inconsistent_options_exit_2(png, tmp_path, args, fragment):
    result = invoke(png[0], "-o", tmp_path / "o.sbs", *args)
    assert result.exit_code == OptionError.exit_code == 2
    assert result.stderr.startswith("sb-encode: error: ") and fragment in result.stderr
    assert not (tmp_path / "o.sbs").exists()


def test_missing_arguments(png, tmp_path):
    assert "missing -o" in invoke(png[0]).stderr
    assert "missing RIGHT_IMAGE" in invoke("-o", tmp_path / "x.sbs").stderr
    assert invoke("--info", tmp_path / "x.sbs", png[0]).exit_code == 2
    assert "--json cannot" in invoke(png[0], "-o", "-", "--json").stderr
    assert invoke(png[0], "-o", tmp_path / "o.sbs", "--stride", 0).exit_code == 2   # click range


def test_output_errors(png, tmp_path):
    path, _ = png
    out = tmp_path / "o.sbs"
    out.write_bytes(b"precious")
    assert_clean_error(run(path, "-o", out), OutputError.exit_code, str(out), "--overwrite")
    assert out.read_bytes() == b"precious"
    assert run(path, "-o", out, "--overwrite").returncode == 0
    assert_clean_error(run(path, "-o", path, "--overwrite"), OutputError.exit_code, "same file")
    assert_clean_error(run(path, "-o", tmp_path / "nodir" / "o.sbs"), OutputError.exit_code,
                       "does not exist")


def test_input_errors(tmp_path):
    missing = tmp_path / "missing.png"
    assert_clean_error(run(missing, "-o", tmp_path / "o.sbs"), ImageReadError.exit_code,
                       str(missing), "no such file")
    text = tmp_path / "notes.png"
    text.write_text("hello\n")
    assert_clean_error(run(text, "-o", tmp_path / "o.sbs"), ImageReadError.exit_code,
                       "not an image")
    assert_clean_error(run("-", "-o", tmp_path / "o.sbs", stdin=b""), ImageReadError.exit_code,
                       "<stdin>", "empty")
    assert list(tmp_path.iterdir()) == [text]


def test_refuses_binary_output_to_a_terminal(png):
    leader, follower = pty.openpty()
    try:
        proc = subprocess.run([SB_ENCODE, str(png[0]), "-o", "-"], stdout=follower,
                              stderr=subprocess.PIPE, timeout=60)
    finally:
        os.close(follower)
        os.close(leader)
    assert_clean_error(proc, OutputError.exit_code, "terminal")


def test_cli_pixel_formats_match_the_library():
    from stereobudget.io import RAW_PIXEL_FORMATS
    (option,) = [param for param in encode_command.params if param.name == "pix_fmt"]
    assert set(option.type.choices) == set(RAW_PIXEL_FORMATS)


def test_version():
    result = invoke("--version")
    assert result.exit_code == 0 and __version__ in result.output


# --- signals and pipes ----------------------------------------------------------------------

def test_sigterm_exits_130_without_traceback(tmp_path):
    proc = subprocess.Popen([SB_ENCODE, "-", "-o", str(tmp_path / "o.sbs"), "-vv"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        # -vv logs "reading <stdin>" once the handlers are installed and it blocks on stdin.
        first = proc.stderr.readline().decode()
        assert "reading <stdin>" in first
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130
    assert "Traceback" not in err.decode() and "interrupted" in err.decode()
    assert list(tmp_path.iterdir()) == []


def test_closed_stdout_is_a_quiet_exit(png):
    proc = subprocess.Popen([SB_ENCODE, str(png[0]), "-o", "-"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    proc.stdout.close()          # the reader goes away before anything is written
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 141
    assert err == b""


# --- the real data ----------------------------------------------------------------------------

def test_teddy_payload_is_exactly_the_grid(tmp_path):
    right = DATA / "teddy" / "right.png"
    if not right.exists():
        pytest.skip(f"Middlebury data not found at {DATA}")
    out = tmp_path / "teddy.sbs"
    result = invoke(right, "--stride", 5, "-o", out, "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["payload_bytes"] == 75 * 90 * 3 == 20250
    assert out.stat().st_size == 80 + 20250
    rgb = cv2.imread(str(right), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
    np.testing.assert_array_equal(load_samples(out).grid_values(), rgb[::5, ::5])


# --- payload coding, byte budget ----------------------------------------------------------------

def smooth_png(tmp_path, h=60, w=80):
    yy, xx = np.mgrid[0:h, 0:w]
    rgb = np.stack([128 + 100 * np.sin(xx / (6 + c) + yy / (9 + c)) for c in range(3)], -1).astype(np.uint8)
    path = tmp_path / "smooth.png"
    assert cv2.imwrite(str(path), rgb[:, :, ::-1].copy())
    return path, rgb


@pytest.mark.parametrize("args,codec", [(["--codec", "lossless"], None), (["--codec", "deflate"], "deflate"),
                                        (["--codec", "webp", "--quality", "80"], "webp"),
                                        (["--bits", "5"], "raw")])
def test_coded_files_and_what_info_says_of_them(tmp_path, args, codec):
    path, rgb = smooth_png(tmp_path)
    out = tmp_path / "c.sbs"
    proc = run(path, "-o", out, "--stride", 2, "--json", *args)
    assert proc.returncode == 0, proc.stderr.decode()
    report = json.loads(proc.stdout)
    info = json.loads(run("--info", out).stdout)
    assert info["version"] == "1.1" and info["codec"] == report["codec"]
    assert codec is None or info["codec"] == codec
    assert info["bits_per_pixel"] == pytest.approx(8 * out.stat().st_size / (60 * 80))
    assert report["bits_per_pixel"] == pytest.approx(info["bits_per_pixel"])
    ss = load_samples(out)
    if info["codec"] in ("deflate", "jxl_lossless", "webp_lossless"):
        np.testing.assert_array_equal(ss.grid_values(), rgb[::2, ::2])
    if "--bits" in args:
        assert info["value_bits"] == 5
        assert np.abs(ss.grid_values().astype(int) - rgb[::2, ::2]).max() <= 4


@pytest.mark.parametrize("budget", [300, 1000, 4000, 12000])
def test_size_never_exceeds_its_budget(tmp_path, budget):
    path, _ = smooth_png(tmp_path)
    out = tmp_path / "b.sbs"
    proc = run(path, "-o", out, "--size", budget, "--json")
    assert proc.returncode == 0, proc.stderr.decode()
    assert out.stat().st_size <= budget and json.loads(proc.stdout)["file_size"] <= budget
    # --epsilon is the same budget as a fraction of the raw image bytes.
    proc = run(path, "-o", out, "--epsilon", budget / (60 * 80 * 3), "--json", "--overwrite", "--codec", "jxl")
    assert proc.returncode == 0, proc.stderr.decode()
    assert out.stat().st_size <= budget


@pytest.mark.parametrize("args,fragment", [
    (["--size", "50"], "fits in 50 bytes"),
    (["--size", "1k"], "--size must be a positive number of bytes"),
    (["--size", "900", "--epsilon", "0.1"], "not both"),
    (["--epsilon", "inf"], "0<x<=1"),
    (["--quality", "50"], "--quality applies to --codec webp or jxl"),
    (["--pattern", "fps", "--codec", "deflate"], "needs a lattice pattern"),
    (["--pattern", "jitter", "--size", "900"], "need --pattern grid"),
    (["--bits", "9"], "between 1 and 8"),
])
def test_coding_option_errors(png, tmp_path, args, fragment):
    proc = run(png[0], "-o", tmp_path / "x.sbs", *args)
    assert_clean_error(proc, OptionError.exit_code, fragment)
    assert not (tmp_path / "x.sbs").exists()


def test_a_raw_frame_can_be_coded_too(tmp_path):
    frame = rgb_image(h=30, w=40)
    path = tmp_path / "f.raw"
    path.write_bytes(frame.tobytes())
    out = tmp_path / "f.sbs"
    proc = run(path, "--raw", "40x30", "--pix-fmt", "rgb24", "--bits", 4, "-o", out)
    assert proc.returncode == 0, proc.stderr.decode()
    ss = load_samples(out)
    assert ss.value_bits == 4 and np.abs(ss.grid_values().astype(int) - frame[::5, ::5]).max() <= 8


def test_the_line_names_pixels_and_bytes_apart(png, tmp_path):
    proc = run(png[0], "-o", tmp_path / "b.sbs", "--epsilon", "0.5", "--json", "-v")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["bytes_fraction"] <= 0.5 and report["pixel_fraction"] == report["epsilon"]
    raw_bytes = report["width"] * report["height"] * 3
    assert report["bytes_fraction"] == pytest.approx(report["file_size"] / raw_bytes)
    line = proc.stderr.decode()
    assert f"({100 * report['pixel_fraction']:.2f} % of the pixels)" in line
    assert f"({100 * report['bytes_fraction']:.2f} % of the raw image;" in line


def _deflate_that_does_not_inflate(tmp_path) -> Path:
    """A deflate file whose payload is valid zlib of the wrong length, container CRCs all correct."""
    from stereobudget.io import write_samples
    from stereobudget.encoding import encode_image
    from stereobudget.sampling import SamplingPattern

    smooth = np.repeat(np.arange(40, dtype=np.uint8)[None, :, None], 3, axis=2).repeat(40, axis=0)
    good = write_samples(encode_image(smooth, pattern=SamplingPattern("grid", 2, 2)), codec="deflate")
    assert read_samples(good).codec == "deflate"
    payload = zlib.compress(b"not the lattice")
    head = good[:64] + struct.pack("<QI", len(payload), zlib.crc32(payload))
    path = tmp_path / "bad_payload.sbs"
    path.write_bytes(head + struct.pack("<I", zlib.crc32(head)) + payload)
    return path


def test_info_check_decodes_the_payload(tmp_path, good_sbs):
    bad = _deflate_that_does_not_inflate(tmp_path)
    unchecked = run("--info", bad)
    assert unchecked.returncode == 0 and json.loads(unchecked.stdout)["payload_verified"] is False
    assert_clean_error(run("--info", bad, "--check"), CorruptPayloadError.exit_code, str(bad), "inflates")
    good = tmp_path / "good_again.sbs"
    good.write_bytes(good_sbs)
    checked = run("--info", good, "--check")
    assert checked.returncode == 0 and json.loads(checked.stdout)["payload_verified"] is True


def test_a_single_failed_file_writes_its_failed_json_line(tmp_path):
    proc = run(tmp_path / "missing.png", "-o", tmp_path / "o.sbs", "--json")
    assert_clean_error(proc, ImageReadError.exit_code, "missing.png")
    line = json.loads(proc.stdout)
    assert line["status"] == "failed" and line["exit_code"] == ImageReadError.exit_code
    assert line["error_class"] == "ImageReadError" and line["output"] == str(tmp_path / "o.sbs")


def test_misleading_folder_messages(png, tmp_path):
    (tmp_path / "f").write_bytes(b"")
    assert_clean_error(run(png[0], "-o", tmp_path / "f" / "o.sbs"), OutputError.exit_code,
                       f"{str(tmp_path / 'f')!r} is a file, not a directory")
    if os.path.isdir("/proc"):
        assert_clean_error(run(png[0], "-o", "/proc/o.sbs"), OutputError.exit_code,
                           "cannot create a file in '/proc': this filesystem does not allow it")
