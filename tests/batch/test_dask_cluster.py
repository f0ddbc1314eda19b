"""sb-decode on a real dask cluster: a scheduler and a worker on 127.0.0.1, started and stopped here.

The worker runs in a folder of its own, as on another machine; the batch is given
relative paths from the user's folder.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereobudget.io import read_disparity, save_samples
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene

DASK = shutil.which("dask", path=str(Path(sys.executable).parent)) or shutil.which("dask")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def stop(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture
def cluster(tmp_path):
    pytest.importorskip("distributed")
    if DASK is None:
        pytest.skip("the 'dask' command (pip install 'stereobudget[dask]') is not installed")
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    elsewhere = tmp_path / "worker-home"
    elsewhere.mkdir()
    logs = tmp_path / "logs"
    logs.mkdir()
    scheduler = subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                  "--no-dashboard"], cwd=elsewhere, stdout=subprocess.DEVNULL,
                                 stderr=open(logs / "scheduler.log", "w"))
    worker = None
    try:
        worker = subprocess.Popen([DASK, "worker", address, "--nthreads", "1", "--nworkers", "1",
                                   "--no-dashboard", "--name", "w1"], cwd=elsewhere, stdout=subprocess.DEVNULL,
                                  stderr=open(logs / "worker.log", "w"))
        from distributed import Client
        deadline = time.monotonic() + 120
        while True:
            try:
                with Client(address, timeout="5s") as client:
                    if client.scheduler_info()["workers"]:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                pytest.fail("the dask worker did not start: " + (logs / "worker.log").read_text()[-2000:])
            time.sleep(0.5)
        yield address, elsewhere
    finally:
        if worker is not None:
            stop(worker)
        stop(scheduler)


def test_relative_paths_on_a_real_scheduler_and_worker(cluster, tmp_path):
    address, elsewhere = cluster
    home = tmp_path / "user"
    for folder in ("L", "S"):
        (home / folder).mkdir(parents=True)
    for i in range(2):
        scene = make_scene("planes", seed=i, height=64, width=96, max_disp=8)
        assert cv2.imwrite(str(home / "L" / f"f{i}.png"), scene.left[:, :, ::-1].copy())
        save_samples(encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4)), home / "S" / f"f{i}.sbs")
    (home / "L" / "lonely.png").write_bytes((home / "L" / "f0.png").read_bytes())
    run = subprocess.run([sys.executable, "-m", "stereobudget.cli.decode", "--left-dir", "L", "--samples-dir", "S",
                          "--max-disp", "12", "--disparity", "D/{stem}.pfm", "--scheduler", address, "--json"],
                         cwd=home, capture_output=True, text=True, timeout=600, env=dict(os.environ))
    lines = {Path(r["left"]).stem: r for r in map(json.loads, run.stdout.splitlines())}
    assert run.returncode == 1, run.stderr          # the lonely left image fails, the others are done
    assert lines["f0"]["status"] == lines["f1"]["status"] == "ok", run.stderr
    assert read_disparity(home / "D" / "f0.pfm").shape == (64, 96)
    # Nothing landed in the worker's own folder.
    assert not (elsewhere / "D").exists() and not (elsewhere / "L").exists()
    failed = lines["lonely"]
    assert failed["status"] == "failed" and "no sample file" in failed["error"]
    assert failed["worker"].startswith("tcp://127.0.0.1:") and "(on worker tcp://127.0.0.1:" in failed["error"]
    assert f"(on worker {failed['worker']})" in run.stderr
