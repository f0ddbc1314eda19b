"""A parallel batch whose standard output fails (a full disk, a closed descriptor, a reader that
went away) ends at once: its one line and exit code, no worker left running, nothing half-written.

The failure reaches the batch while its workers are busy, and the pool is stopped under them.
The stop raced with the pool's own queues (a worker could wait for ever on a lock that a
sibling took with it), so every case is run several times, as real processes, each with a
timeout; the batch runs under its own setsid so that any process it leaves is found.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereobudget.errors import OutputError
from stereobudget.io import load_samples
from stereobudget.scenes import make_scene

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="setsid process groups and /dev/full as on Linux")

SB_ENCODE = str(Path(sys.executable).parent / "sb-encode")
RUNS = 5
#: Far above the second or two a run takes on a loaded machine; a hang ends the run here.
TIMEOUT = 120


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    folder = tmp_path_factory.mktemp("frames")
    for i in range(6):
        scene = make_scene("planes", seed=i, height=48, width=64, max_disp=8)
        assert cv2.imwrite(str(folder / f"f{i}.png"), np.ascontiguousarray(scene.right[:, :, ::-1]))
    return folder


def _alive_in_session(sid: int) -> list[str]:
    """Processes of the setsid group ``sid`` still running (a zombie has ended; only its parent is missing)."""
    out = subprocess.run(["ps", "-o", "pid=,stat=,args=", "-s", str(sid)], capture_output=True, text=True).stdout
    return [line for line in out.splitlines() if line.split()[1:2] and not line.split()[1].startswith("Z")]


def run_batch(argv, cwd: Path, **popen) -> tuple[int, str]:
    """Run ``argv`` under its own setsid; (exit code, stderr).  Fails on a hang or a process left behind."""
    proc = subprocess.Popen(argv, cwd=cwd, stderr=subprocess.PIPE, text=True, start_new_session=True, **popen)
    try:
        err = proc.communicate(timeout=TIMEOUT)[1]
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(f"the batch hung: {argv}")
    left = _alive_in_session(proc.pid)
    if left:
        os.killpg(proc.pid, signal.SIGKILL)
    assert left == [], f"processes left running: {left}"
    return proc.returncode, err


def batch_command(out: Path) -> str:
    return f"{SB_ENCODE} f*.png -o '{out}/{{stem}}.sbs' --stride 4 --json -j 2"


def assert_whole_outputs(out: Path) -> None:
    """Only complete sample files and their records: no temporary file, nothing truncated."""
    if not out.exists():
        return
    for path in out.iterdir():
        if path.name.endswith(".sbrecipe"):
            continue
        assert not path.name.startswith("."), f"temporary file left: {path.name}"
        assert path.suffix == ".sbs"
        load_samples(path)


def assert_one_error_line(code: int, err: str, *fragments: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == OutputError.exit_code and len(lines) == 1, (code, err)
    assert lines[0].startswith("sb-encode: error: <stdout>: ")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full on this system")
def test_a_full_standard_output_stops_a_parallel_batch_cleanly(frames, tmp_path):
    for run in range(RUNS):
        out = tmp_path / f"full{run}"
        code, err = run_batch(["sh", "-c", f"{batch_command(out)} > /dev/full"], frames)
        assert_one_error_line(code, err, "No space left on device")
        assert_whole_outputs(out)


def test_a_closed_standard_output_refuses_a_parallel_batch(frames, tmp_path):
    for run in range(RUNS):
        out = tmp_path / f"closed{run}"
        code, err = run_batch(["sh", "-c", f"{batch_command(out)} >&-"], frames)
        assert_one_error_line(code, err, "standard output is closed")
        assert not out.exists()      # refused before any input is read


def test_a_reader_gone_stops_a_parallel_batch_quietly(frames, tmp_path):
    for run in range(RUNS):
        out = tmp_path / f"pipe{run}"
        read, write = os.pipe()
        os.close(read)               # the reader went away before the first line
        try:
            code, err = run_batch(["sh", "-c", batch_command(out)], frames, stdout=write)
        finally:
            os.close(write)
        assert (code, err) == (141, "")
        assert_whole_outputs(out)
