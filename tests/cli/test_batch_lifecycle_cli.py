"""Batches as a user runs them, when their surroundings go wrong: damaged records and outputs,
two identical runs at once, a parent killed outright, Ctrl-C.

Every test runs the installed ``sb-encode`` / ``sb-decode`` as a real process (real FIFOs,
real SIGKILL and SIGINT) on small synthetic frames, and checks the exit status, the one
line on stderr and that nothing is left behind.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereobudget.scenes import make_scene

BIN = Path(sys.executable).parent
SB_ENCODE, SB_DECODE = str(BIN / "sb-encode"), str(BIN / "sb-decode")


def run(*args, cwd, timeout=300):
    return subprocess.run([*map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=timeout)


def lines(text):
    return [line for line in text.splitlines() if line.strip()]


def write_frames(folder: Path, count: int, *, left: bool = False, size=(48, 64)) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(count):
        scene = make_scene("planes", seed=i, height=size[0], width=size[1], max_disp=8)
        image = scene.left if left else scene.right
        assert cv2.imwrite(str(folder / f"f{i}.png"), np.ascontiguousarray(image[:, :, ::-1]))


def leftovers(folder: Path) -> list[str]:
    """Temporary files of the atomic writers (anything hidden that is not a recipe)."""
    return [p.name for p in folder.rglob(".*") if not p.name.endswith(".sbrecipe")]


ENCODE = [SB_ENCODE, "R/*.png", "-o", "S/{stem}.sbs", "--stride", "4", "-j", "1", "--json"]


@pytest.fixture
def encoded(tmp_path):
    write_frames(tmp_path / "R", 1)
    first = run(*ENCODE, cwd=tmp_path)
    assert first.returncode == 0 and json.loads(first.stdout)["status"] == "ok", first.stderr
    return tmp_path


def _wrong_shape(path: Path, value):
    stored = json.loads(path.read_text())
    path.write_text(json.dumps({**stored, "options": value}))


DAMAGED_RECIPES = {
    "options a string": lambda p: _wrong_shape(p, "abc"),
    "options a nested list": lambda p: _wrong_shape(p, [[1]]),
    "not an object": lambda p: p.write_text("[[1]]"),
    "100,000 nested brackets": lambda p: p.write_text("[" * 100_000 + "]" * 100_000),
    "a FIFO": lambda p: (p.unlink(), os.mkfifo(p)),
    "a link to /dev/zero": lambda p: (p.unlink(), p.symlink_to("/dev/zero")),
}


@pytest.mark.parametrize("damage", list(DAMAGED_RECIPES))
def test_a_damaged_recipe_means_redo_never_an_error_or_a_hang(encoded, damage):
    recipe = encoded / "S" / ".f0.sbs.sbrecipe"
    DAMAGED_RECIPES[damage](recipe)
    rerun = run(*ENCODE, cwd=encoded, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    assert json.loads(rerun.stdout)["status"] == "ok"
    assert lines(rerun.stderr) == ["sb-encode: 1 file(s) redone: no record of what made it"]
    # The record is whole again: the next run skips.
    assert recipe.is_file() and not recipe.is_symlink()
    assert json.loads(run(*ENCODE, cwd=encoded).stdout)["status"] == "skipped"
    assert leftovers(encoded) == []


def _flip_byte(path: Path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))


DAMAGED_OUTPUTS = {
    "truncated": lambda p: os.truncate(p, 100),
    "one flipped byte": _flip_byte,
    "a foreign file": lambda p: p.write_bytes(p.parent.joinpath("other.sbs").read_bytes()),
}


@pytest.mark.parametrize("damage", list(DAMAGED_OUTPUTS))
def test_a_damaged_output_with_its_recipe_intact_is_redone(encoded, damage):
    output = encoded / "S" / "f0.sbs"
    original = output.read_bytes()
    other = run(SB_ENCODE, "R/f0.png", "-o", "S/other.sbs", "--stride", "3", cwd=encoded)
    assert other.returncode == 0, other.stderr
    DAMAGED_OUTPUTS[damage](output)
    rerun = run(*ENCODE, cwd=encoded)
    assert rerun.returncode == 0, rerun.stderr
    assert json.loads(rerun.stdout)["status"] == "ok"
    assert lines(rerun.stderr) == ["sb-encode: 1 file(s) redone: output changed since it was written"]
    assert output.read_bytes() == original
    assert leftovers(encoded) == []


def test_an_output_replaced_by_a_folder_is_not_up_to_date(encoded):
    output = encoded / "S" / "f0.sbs"
    output.unlink()
    output.mkdir()
    rerun = run(*ENCODE, cwd=encoded)
    assert rerun.returncode == 1
    assert lines(rerun.stderr) == ["sb-encode: error: S/f0.sbs: output is a directory; give a file name"]
    assert json.loads(rerun.stdout)["status"] == "failed"


def test_two_identical_batches_at_once_both_succeed(tmp_path):
    write_frames(tmp_path / "R", 16)
    command = [*ENCODE[:-3], "-j", "1", "--json"]
    runs = [subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for _ in range(2)]
    results = [(p.communicate(timeout=300), p.returncode) for p in runs]
    for (out, err), code in results:
        assert code == 0, err
        assert {json.loads(line)["status"] for line in lines(out)} <= {"ok", "skipped"}
        assert "failed" not in err and "exists" not in err
    # Between them every file was made once and recorded; a third run skips them all.
    third = run(*command, cwd=tmp_path)
    assert {json.loads(line)["status"] for line in lines(third.stdout)} == {"skipped"}
    assert leftovers(tmp_path) == []


@pytest.fixture
def decode_batch(tmp_path):
    """Enough small pairs that a -j 2 decode runs for a few seconds."""
    write_frames(tmp_path / "L", 40, left=True, size=(96, 128))
    write_frames(tmp_path / "R", 40, size=(96, 128))
    enc = run(SB_ENCODE, "R/*.png", "-o", "S/{stem}.sbs", "-j", "1", cwd=tmp_path)
    assert enc.returncode == 0, enc.stderr
    return tmp_path


def _start_decode(folder):
    return subprocess.Popen([SB_DECODE, "L/*.png", "S/", "--disparity", "D/{stem}.pfm", "-j", "2"], cwd=folder,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _wait_for_first_output(folder, proc, limit=300):
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline and proc.poll() is None:
        if (folder / "D").is_dir() and any((folder / "D").glob("*.pfm")):
            return
        time.sleep(0.05)
    pytest.fail("the batch wrote nothing")


def _session_processes(sid):
    out = subprocess.run(["ps", "-o", "pid=", "-s", str(sid)], capture_output=True, text=True).stdout
    return [int(x) for x in out.split()]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ps -s and setsid process groups as on Linux")
def test_workers_die_with_a_parent_killed_outright(decode_batch):
    proc = _start_decode(decode_batch)
    _wait_for_first_output(decode_batch, proc)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 30
    while _session_processes(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _session_processes(proc.pid) == []
    written = sorted(p.name for p in (decode_batch / "D").iterdir())
    time.sleep(2)
    assert sorted(p.name for p in (decode_batch / "D").iterdir()) == written
    assert leftovers(decode_batch / "D") == []


def test_ctrl_c_during_a_parallel_batch_says_one_line(decode_batch):
    proc = _start_decode(decode_batch)
    _wait_for_first_output(decode_batch, proc)
    os.killpg(proc.pid, signal.SIGINT)     # a terminal's Ctrl-C reaches the whole group
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 130
    assert err == "sb-decode: interrupted\n"
    assert leftovers(decode_batch / "D") == []
