#!/usr/bin/env python
"""Frames per second of a frame stream in one process against one process per frame.

A synthetic camera (``--frames`` different slanted-plane pairs of ``--size``, right frames
as raw rgb24) is run both ways, alternating, ``--repeats`` times:

* stream: ``sb-encode - --raw WxH -o -`` piped into ``sb-decode 'L/{index}.png' - --disparity -``;
* per frame: for every frame one ``sb-encode`` process and one ``sb-decode`` process.

The kernels are compiled (cached) before timing, so both pay only the loading.  The table
gives the median wall time of each and the frames per second; it also times the encoder
alone both ways (the camera side).

    python scripts/stream_fps.py --frames 10 --repeats 7
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from stereobudget.scenes import make_scene


def tool(name):
    return [sys.executable, "-m", f"stereobudget.cli.{name}"]


def make_camera(folder: Path, frames: int, width: int, height: int) -> bytes:
    (folder / "L").mkdir()
    rights = []
    for index in range(frames):
        scene = make_scene("slanted", height=height, width=width, max_disp=48, seed=index)
        cv2.imwrite(str(folder / "L" / f"{index}.png"), np.ascontiguousarray(scene.left[:, :, ::-1]))
        right = np.ascontiguousarray(scene.right).tobytes()
        (folder / f"r{index}.raw").write_bytes(right)
        rights.append(right)
    return b"".join(rights)


def stream_run(folder: Path, raw: bytes, size: str, decode: bool) -> float:
    start = time.perf_counter()
    # The camera's frames come from a file: a pipe written from here could fill while the
    # decoder's own output waits to be read, and both would wait for ever.
    with open(folder / "camera.raw", "rb") as frames:
        encoder = subprocess.Popen([*tool("encode"), "-", "--raw", size, "--pix-fmt", "rgb24", "-o", "-"],
                                   stdin=frames, stdout=subprocess.PIPE, cwd=folder)
    if decode:
        decoder = subprocess.Popen([*tool("decode"), "L/{index}.png", "-", "--max-disp", "48", "--disparity",
                                    "-", "-q"], stdin=encoder.stdout, stdout=subprocess.PIPE, cwd=folder)
        encoder.stdout.close()
        out, _ = decoder.communicate()
        assert decoder.returncode == 0 and out.startswith(b"Pf")
    else:
        out, _ = encoder.communicate()
    assert encoder.wait() == 0
    return time.perf_counter() - start


def per_frame_run(folder: Path, frames: int, size: str, decode: bool) -> float:
    start = time.perf_counter()
    for index in range(frames):
        subprocess.run([*tool("encode"), f"r{index}.raw", "--raw", size, "--pix-fmt", "rgb24", "-o",
                        f"r{index}.sbs", "--overwrite"], cwd=folder, check=True)
        if decode:
            subprocess.run([*tool("decode"), f"L/{index}.png", f"r{index}.sbs", "--max-disp", "48",
                            "--disparity", f"d{index}.pfm", "--overwrite", "-q"], cwd=folder, check=True)
    return time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--size", default="450x375", help="WxH of the frames (Teddy's size by default)")
    args = parser.parse_args(argv)
    width, height = map(int, args.size.split("x"))
    with tempfile.TemporaryDirectory() as name:
        folder = Path(name)
        raw = make_camera(folder, args.frames, width, height)
        (folder / "camera.raw").write_bytes(raw)
        stream_run(folder, raw, args.size, True)          # compile / load the kernels once
        times = {key: [] for key in ("stream", "per_frame", "encode_stream", "encode_per_frame")}
        for _ in range(args.repeats):
            times["stream"].append(stream_run(folder, raw, args.size, True))
            times["per_frame"].append(per_frame_run(folder, args.frames, args.size, True))
            times["encode_stream"].append(stream_run(folder, raw, args.size, False))
            times["encode_per_frame"].append(per_frame_run(folder, args.frames, args.size, False))
    print(f"{args.frames} frames of {args.size} rgb24, Hybrid @ 5, --max-disp 48; median of {args.repeats} "
          "alternating runs")
    print("| run | wall s | frames/s |")
    print("|---|---|---|")
    labels = {"stream": "sb-encode piped into sb-decode, one stream", "per_frame": "one sb-encode + one sb-decode per frame",
              "encode_stream": "sb-encode alone, one stream", "encode_per_frame": "sb-encode alone, per frame"}
    for key, label in labels.items():
        median = statistics.median(times[key])
        print(f"| {label} | {median:.2f} | {args.frames / median:.1f} |")
    speedup = statistics.median(times["per_frame"]) / statistics.median(times["stream"])
    print(f"stream vs per frame: {speedup:.1f}x the frames per second")


if __name__ == "__main__":
    main()
