"""Frame streams as a camera pipeline runs them: real processes joined by real pipes."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from stereobudget.io import pfm_frames, read_disparity

SIZE = (96, 64)  # the frames of the camera_frames fixture (conftest.py)


def command(tool):
    return [sys.executable, "-m", f"stereobudget.cli.{tool}"]


@pytest.fixture(scope="module")
def camera(camera_frames):
    return camera_frames


def test_camera_pipe_to_disparity_stream_equals_one_process_per_frame(camera):
    raw = "x".join(map(str, SIZE))
    # The camera is a file on the encoder's stdin (writing a pipe from here while the
    # decoder's output waits to be read could block both); encoder -> decoder is a pipe.
    with open(camera / "rights.raw", "rb") as frames:
        encoder = subprocess.Popen([*command("encode"), "-", "--raw", raw, "--pix-fmt", "rgb24", "-o", "-"],
                                   stdin=frames, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=camera)
    decoder = subprocess.Popen([*command("decode"), "L/{index}.png", "-", "--max-disp", "16", "--disparity", "-",
                                "-v"], stdin=encoder.stdout, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               cwd=camera)
    encoder.stdout.close()          # the decoder holds the pipe's only reader
    out, err = decoder.communicate(timeout=900)
    assert encoder.wait(timeout=60) == 0
    assert decoder.returncode == 0, err
    maps = list(pfm_frames(out, name="<stdout>"))
    assert len(maps) == 3 and b"3 frame(s) in" in err

    # The same frames, one process and one file each.
    for index in range(3):
        frame = (camera / "rights.raw").read_bytes()[index * SIZE[0] * SIZE[1] * 3:][:SIZE[0] * SIZE[1] * 3]
        (camera / f"r{index}.raw").write_bytes(frame)
        subprocess.run([*command("encode"), f"r{index}.raw", "--raw", raw, "--pix-fmt", "rgb24", "-o",
                        f"r{index}.sbs", "--overwrite"], cwd=camera, check=True, capture_output=True)
        single = subprocess.run([*command("decode"), f"L/{index}.png", f"r{index}.sbs", "--max-disp", "16",
                                 "--disparity", f"d{index}.pfm", "--overwrite"], cwd=camera, capture_output=True)
        assert single.returncode == 0, single.stderr
        np.testing.assert_array_equal(maps[index], read_disparity(camera / f"d{index}.pfm"))


def test_stream_file_to_indexed_outputs_with_json_lines(camera):
    raw = "x".join(map(str, SIZE))
    made = subprocess.run([*command("encode"), "rights.raw", "--raw", raw, "--pix-fmt", "rgb24", "-o",
                           "stream.sbs", "--overwrite"], cwd=camera, capture_output=True, text=True)
    assert made.returncode == 0 and "3 frames of 96x64 rgb24, written as one 3-frame stream" in made.stderr
    info = subprocess.run([*command("encode"), "--info", "stream.sbs"], cwd=camera, capture_output=True, text=True)
    assert [json.loads(line)["frame"] for line in info.stdout.splitlines()] == [0, 1, 2]
    run = subprocess.run([*command("decode"), "L", "stream.sbs", "--max-disp", "16", "--disparity",
                          "D/{index:03d}.pfm", "--preview", "P/{stem}.png", "--json"], cwd=camera,
                         capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr
    lines = [json.loads(line) for line in run.stdout.splitlines()]
    assert [(item["frame"], item["left"], item["outputs"]["disparity"]) for item in lines] == [
        (i, f"L/{i}.png", f"D/{i:03d}.pfm") for i in range(3)]
    assert sorted(p.name for p in (camera / "P").iterdir()) == ["0.png", "1.png", "2.png"]


@pytest.mark.parametrize("args, code, fragment", [
    (["L/0.png", "stream.sbs", "--disparity", "one.pfm"], 2, "holds several .sbs frames (a stream) but --disparity"),
    (["L/0.png", "stream.sbs", "--disparity", "-", "--scheduler", "local"], 2, "a stream is decoded in order"),
    (["-", "stream.sbs", "--disparity", "D/{index}.pfm"], 2, "LEFT cannot be '-' for a stream"),
    (["L", "L", "--disparity", "D/{index}.pfm"], 2, "but L is a folder; for a folder of pairs use {stem}"),
])
def test_stream_option_errors(camera, args, code, fragment):
    if not (camera / "stream.sbs").exists():
        test_stream_file_to_indexed_outputs_with_json_lines(camera)
    run = subprocess.run([*command("decode"), *args, "--max-disp", "16"], cwd=camera, capture_output=True,
                         text=True, stdin=subprocess.DEVNULL, timeout=1800)
    assert run.returncode == code and fragment in run.stderr and "Traceback" not in run.stderr, run.stderr


def test_a_cut_stream_on_stdin_fails_after_the_whole_frames(camera):
    raw = "x".join(map(str, SIZE))
    frames = subprocess.run([*command("encode"), "-", "--raw", raw, "--pix-fmt", "rgb24", "-o", "-"],
                            cwd=camera, input=(camera / "rights.raw").read_bytes(), capture_output=True,
                            check=True).stdout
    run = subprocess.run([*command("decode"), "L/{index}.png", "-", "--max-disp", "16", "--disparity",
                          "cut/{index}.pfm", "--json"], cwd=camera, input=frames[:-9], capture_output=True,
                         timeout=900)
    assert run.returncode == 5 and b"frame 2 is truncated" in run.stderr, run.stderr
    assert sorted(p.name for p in (camera / "cut").iterdir()) == ["0.pfm", "1.pfm"]
    # The frame that ended the stream gets its JSON line too: a camera's log keeps the failure.
    lines = [json.loads(line) for line in run.stdout.splitlines()]
    assert [(item["status"], item["frame"]) for item in lines] == [("ok", 0), ("ok", 1), ("failed", 2)]
    assert lines[2]["exit_code"] == 5 and lines[2]["error_class"] == "TruncatedFileError"
    assert "frame 2 is truncated" in lines[2]["error"] and lines[2]["samples"] == "<stdin>"
