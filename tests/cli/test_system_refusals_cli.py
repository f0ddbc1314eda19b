"""What the system refuses, in real processes: a full or closed standard output, a closed standard
input, names too long for the filesystem, a disk that fills while a file is written, an output that
fails after others were ready -- each ends in one stderr line, the exit code of docs/errors.md, and
nothing left at the outputs (no temporary file either)."""

from __future__ import annotations

import errno
import os
import resource
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from stereobudget.errors import ImageReadError, NotASampleFileError, OptionError, OutputError
from stereobudget.io import save_samples, write_image
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene

BIN = Path(sys.executable).parent
SB_ENCODE = str(BIN / "sb-encode")
SB_DECODE = str(BIN / "sb-decode")
LONG = "x" * 300
FULL = "/dev/full"
needs_dev_full = pytest.mark.skipif(not os.path.exists(FULL), reason="no /dev/full on this system")


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """64x48 left/right PNGs, the right image's stride-5 sample file and a 2-frame raw gray stream."""
    folder = tmp_path_factory.mktemp("pair")
    scene = make_scene("slanted", height=48, width=64, max_disp=8)
    write_image(folder / "L.png", scene.left)
    write_image(folder / "R.png", scene.right)
    save_samples(encode_image(scene.right, pattern=SamplingPattern("grid", 5, 5)), folder / "S.sbs")
    gray = scene.right.mean(axis=2).astype(np.uint8)
    (folder / "frames.raw").write_bytes(gray.tobytes() * 2)
    return folder


def shell(command: str, cwd: Path, *, fsize: int | None = None) -> subprocess.CompletedProcess:
    """``command`` through ``sh`` (as typed: redirections, pipes); ``fsize`` caps every file it writes."""
    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
    return subprocess.run(["sh", "-c", command], cwd=cwd, capture_output=True, text=True, timeout=600,
                          preexec_fn=None if fsize is None else limit)


def run_all(commands, cwd: Path, **kwargs) -> list:
    with ThreadPoolExecutor(max_workers=2) as pool:
        return list(pool.map(lambda c: shell(c, cwd, **kwargs), commands))


def assert_one_line(proc, code: int, *fragments: str) -> None:
    # The first decode after an install may say first that numba compiles (not an error line).
    lines = [line for line in proc.stderr.splitlines() if "compiling kernels, first run only" not in line]
    assert proc.returncode == code and len(lines) == 1, (proc.returncode, proc.stderr)
    assert ": error: " in lines[0] and "Traceback" not in proc.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def leftovers(folder: Path, before: set) -> set:
    return {p.name for p in folder.iterdir()} - before


def test_epsilon_nan_is_a_usage_error(pair):
    before = {p.name for p in pair.iterdir()}
    raw = "frames.raw --raw 64x48 --pix-fmt gray8"
    procs = run_all([f"{SB_ENCODE} R.png -o o.sbs --epsilon nan",
                     f"{SB_ENCODE} R.png -o o.sbs --epsilon NaN",
                     f"{SB_ENCODE} {raw} -o o.sbs --epsilon nan",
                     f"{SB_ENCODE} L.png R.png -o '{{stem}}.e.sbs' --epsilon NaN"], pair)
    for proc in procs:
        assert_one_line(proc, OptionError.exit_code, "--epsilon", "0<x<=1")
    assert leftovers(pair, before) == set()


@needs_dev_full
def test_a_full_standard_output_is_one_line_and_exit_12(pair, tmp_path):
    decode = f"{SB_DECODE} {pair}/L.png {pair}/S.sbs --max-disp 8"
    stream = f"cat {pair}/S.sbs {pair}/S.sbs | {SB_DECODE} {pair}/L.png - --max-disp 8"
    commands = [f"{decode} --disparity - > {FULL}",
                f"{decode} --preview - > {FULL}",
                f"{decode} --right - > {FULL}",
                f"{stream} --disparity - > {FULL}",
                f"{SB_ENCODE} {pair}/R.png -o - > {FULL}",
                f"{SB_ENCODE} {pair}/frames.raw --raw 64x48 --pix-fmt gray8 -o - > {FULL}",
                f"{SB_ENCODE} --info {pair}/S.sbs > {FULL}"]
    for proc in run_all(commands, tmp_path):
        assert_one_line(proc, OutputError.exit_code, "<stdout>", "No space left on device")
    assert list(tmp_path.iterdir()) == []
    # --json after the outputs: the summary cannot be delivered; the outputs are complete.
    for proc in run_all([f"{decode} --disparity d.pfm --json > {FULL}",
                         f"{SB_ENCODE} {pair}/R.png -o o.sbs --json > {FULL}"], tmp_path):
        assert_one_line(proc, OutputError.exit_code, "<stdout>", "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.pfm", "o.sbs"]


def test_closed_standard_streams_are_one_line(pair, tmp_path):
    decode = f"{SB_DECODE} {pair}/L.png {pair}/S.sbs --max-disp 8"
    procs = run_all([f"{decode} --disparity - >&-",
                     f"{SB_ENCODE} {pair}/R.png -o - >&-",
                     f"{decode} --disparity d.pfm --json >&-",
                     f"{SB_DECODE} {pair}/L.png - --max-disp 8 --disparity d.pfm <&-",
                     f"{SB_ENCODE} - -o o.sbs <&-"], tmp_path)
    for proc in procs[:3]:
        assert_one_line(proc, OutputError.exit_code, "<stdout>", "standard output is closed")
    assert_one_line(procs[3], NotASampleFileError.exit_code, "<stdin>", "standard input is closed")
    assert_one_line(procs[4], ImageReadError.exit_code, "<stdin>", "standard input is closed")
    assert list(tmp_path.iterdir()) == []


def test_a_name_too_long_is_refused_before_any_work(pair, tmp_path):
    decode = f"{SB_DECODE} {pair}/L.png {pair}/S.sbs --max-disp 8"
    procs = run_all([f"{decode} --disparity {LONG}.pfm",
                     f"{decode} --disparity d.pfm --preview {LONG}.png",
                     f"{SB_ENCODE} {pair}/R.png -o {LONG}.sbs"], tmp_path)
    for proc in procs:
        assert_one_line(proc, OutputError.exit_code, LONG, "file name too long")
    # In a batch (a template) the file fails, named on its line, and the batch exits 1.
    batch = shell(f"{SB_ENCODE} {pair}/R.png -o '{{stem}}{LONG}.sbs'", tmp_path)
    assert_one_line(batch, 1, f"R{LONG}.sbs", "file name too long")
    assert list(tmp_path.iterdir()) == []


def test_a_disk_that_fills_during_a_raw_stream_file_leaves_nothing(pair, tmp_path):
    # RLIMIT_FSIZE stands for the full disk: the write fails part-way (EFBIG) as it would with ENOSPC.
    proc = shell(f"cat {pair}/frames.raw {pair}/frames.raw | {SB_ENCODE} - --raw 64x48 --pix-fmt gray8 "
                 "--stride 1 -o st.sbs", tmp_path, fsize=4096)
    assert_one_line(proc, OutputError.exit_code, "st.sbs", "cannot write")
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_at_fsync_of_a_stream_file_leaves_nothing(pair, tmp_path, monkeypatch):
    # Some filesystems report a full disk only when the data is flushed (fsync / close).
    from click.testing import CliRunner

    from stereobudget.cli.encode import encode_command

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    result = CliRunner().invoke(encode_command, [str(pair / "frames.raw"), "--raw", "64x48", "--pix-fmt", "gray8",
                                                 "-o", str(tmp_path / "st.sbs")])
    assert result.exit_code == OutputError.exit_code, result.output
    assert "st.sbs: cannot write: No space left on device" in result.output
    assert list(tmp_path.iterdir()) == []


def test_outputs_are_checked_before_any_input_is_read(pair, tmp_path):
    (tmp_path / "f").write_bytes(b"a file, not a folder")
    # LEFT is a pipe that never ends: a command that read it first would never return.
    proc = _with_endless_stdin([SB_DECODE, "-", str(pair / "S.sbs"), "--max-disp", "8", "--disparity", "ok.pfm",
                                "--preview", "ok.png", "--right", "f/r.png"], tmp_path)
    assert_one_line(proc, OutputError.exit_code, "f/r.png", "'f' is a file, not a directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]


def _with_endless_stdin(args, cwd: Path) -> subprocess.CompletedProcess:
    """Run ``args`` with standard input a pipe that never ends: a command that read it would not return."""
    proc = subprocess.Popen(args, cwd=cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        out, err = proc.communicate(timeout=600)
    finally:
        proc.kill()
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


def test_a_stream_checks_its_outputs_before_the_first_frame(pair, tmp_path):
    with ThreadPoolExecutor(max_workers=2) as pool:
        encode, decode = pool.map(lambda args: _with_endless_stdin(args, tmp_path), [
            [SB_ENCODE, "-", "--raw", "64x48", "--pix-fmt", "gray8", "-o", f"S/{{index}}{LONG}.sbs"],
            [SB_DECODE, str(pair / "L.png"), "-", "--max-disp", "8", "--disparity", f"D/{{index}}{LONG}.pfm"]])
    assert_one_line(encode, OutputError.exit_code, f"0{LONG}.sbs", "file name too long")
    assert_one_line(decode, OutputError.exit_code, f"0{LONG}.pfm", "file name too long")


def _sizes(folder: Path) -> dict:
    return {p.name: p.stat().st_size for p in folder.iterdir() if not p.name.startswith(".")}


def test_an_output_that_fails_last_leaves_none_of_the_others(pair, tmp_path):
    outputs = "--disparity d.png --preview p.png --right r.tif"
    command = f"{SB_DECODE} {pair}/L.png {pair}/S.sbs --max-disp 8 {outputs}"
    reference = tmp_path / "reference"
    reference.mkdir()
    assert shell(command, reference).returncode == 0     # also compiles any kernel first, unlimited
    sizes = _sizes(reference)
    if not sizes["r.tif"] > max(sizes["d.png"], sizes["p.png"]):
        pytest.skip(f"the right image is not the largest output here: {sizes}")
    limited = tmp_path / "limited"
    limited.mkdir()
    proc = shell(command, limited, fsize=(sizes["r.tif"] + max(sizes["d.png"], sizes["p.png"])) // 2)
    assert_one_line(proc, OutputError.exit_code, "r.tif", "cannot write")
    assert list(limited.iterdir()) == []


def test_a_failed_batch_item_leaves_none_of_its_outputs(pair, tmp_path):
    left, samples = tmp_path / "L", tmp_path / "S"
    left.mkdir()
    samples.mkdir()
    scene = make_scene("slanted", height=48, width=64, max_disp=8)
    # a: gray (small right image), b: colour (a right image 3x larger); both as large otherwise.
    gray = (scene.left.mean(axis=2).astype(np.uint8), scene.right.mean(axis=2).astype(np.uint8))
    write_image(left / "a.png", gray[0], channel_order="gray")
    save_samples(encode_image(gray[1], pattern=SamplingPattern("grid", 5, 5), channel_order="gray"),
                 samples / "a.sbs")
    os.link(pair / "L.png", left / "b.png")
    os.link(pair / "S.sbs", samples / "b.sbs")
    outputs = "--disparity 'D/{stem}.png' --preview 'P/{stem}.png' --right 'R/{stem}.tif'"
    command = f"{SB_DECODE} --left-dir {left} --samples-dir {samples} --max-disp 8 -j 1 {outputs}"
    reference = tmp_path / "reference"
    reference.mkdir()
    assert shell(command, reference).returncode == 0
    sizes = {f"{kind}/{name}": size for kind in "DPR" for name, size in _sizes(reference / kind).items()}
    others = max(size for name, size in sizes.items() if name != "R/b.tif")
    if not sizes["R/b.tif"] > others:
        pytest.skip(f"b's right image is not the largest output here: {sizes}")
    limited = tmp_path / "limited"
    limited.mkdir()
    proc = shell(command, limited, fsize=(sizes["R/b.tif"] + others) // 2)
    lines = proc.stderr.splitlines()
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert len(lines) == 2 and "R/b.tif" in lines[0] and "cannot write" in lines[0], lines
    assert lines[1].endswith("1 of 2 file(s) failed")
    written = sorted(str(p.relative_to(limited)) for p in limited.rglob("*") if p.is_file())
    assert [name for name in written if "b." in name] == []          # nor b's recipe
    assert {"D/a.png", "P/a.png", "R/a.tif"} <= set(written)
