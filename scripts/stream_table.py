#!/usr/bin/env python
"""Frame streams at 640x480 and 450x375 against OpenCV SGBM 3WAY: the stream table and the in-process table.

Two synthetic streams of ``stereobudget.scenes`` "slanted" pairs (disparities 0-48,
searched 0-``--max-disp``, samples on the default 5x5 grid):

* coherent: a crop that pans 2 px a frame across one scene, cut midway to another scene;
* unrelated: every frame another scene (the worst case of a temporal search).

In-process table: per frame, one decode by a plain :class:`stereobudget.Decoder` (every
frame on the whole range), one by ``Decoder(temporal=True)`` (a band around the previous
frame's disparities) and one SGBM 3WAY on the full pair, alternating; ``--repeats`` passes
over the stream, the median over every frame of every pass (the temporal decoder restarts
its stream each pass), the mean beside it (a fallback frame costs two decodes), and the
bad-pixel rate (> 1 px, non-occluded pixels) of each against the ground truth.

Stream table: ``sb-encode - --raw WxH --pix-fmt rgb24 -o - | sb-decode 'L/{index}.png' -
--max-disp 64 --disparity -``, steady state (time of ``--frames`` frames minus time of 5) /
(frames - 5), median of ``--repeats`` alternating runs with ``--temporal`` and ``--no-temporal``,
and of the same frames as a folder batch (``sb-decode --left-dir L --samples-dir S -j 1``, the
left PNGs and .sbs files matched by stem), timed the same way.

``--profile`` prints instead where the time of one default decode goes (median of
``--repeats``), stage by stage, with I/O (read PNG, parse the .sbs, write the PFM).

    python scripts/stream_table.py --repeats 7                # both tables, both sizes
    python scripts/stream_table.py --profile --repeats 7      # the stages of one decode
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

import stereobudget
from stereobudget.encoding import encode_image
from stereobudget.io import save_samples
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene

SIZES = ((640, 480), (450, 375))
PAN = 2


def coherent_frames(width, height, count, *, scene_disp=48):
    """``count`` (left, right, gt, nonocc) crops panning PAN px a frame, a cut to another scene midway."""
    half = count // 2
    frames = []
    for part, (seed, n) in enumerate(((1, half), (2, count - half))):
        scene = make_scene("slanted", height=height, width=width + PAN * n, max_disp=scene_disp, seed=seed)
        xs = np.arange(width)
        for i in range(n):
            c = PAN * i
            gt = scene.disparity[:, c:c + width]
            nonocc = scene.nonocc[:, c:c + width] & (xs[None, :] - gt >= 0)
            frames.append((np.ascontiguousarray(scene.left[:, c:c + width]),
                           np.ascontiguousarray(scene.right[:, c:c + width]), gt, nonocc))
    return frames


def unrelated_frames(width, height, count, *, scene_disp=48):
    out = []
    for i in range(count):
        scene = make_scene("slanted", height=height, width=width, max_disp=scene_disp, seed=100 + i)
        out.append((scene.left, scene.right, scene.disparity, scene.nonocc))
    return out


def bad_pixels(disp, gt, nonocc):
    err = np.abs(disp - gt)
    return 100.0 * float(np.mean(~(err[nonocc] <= 1.0)))


def sgbm_matcher(max_disp):
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=((max_disp + 16) // 16) * 16, blockSize=5,
                                 P1=8 * 3 * 25, P2=32 * 3 * 25, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)


def in_process(frames, *, max_disp, repeats):
    samples = [encode_image(right, pattern=SamplingPattern("grid", 5, 5)) for _, right, _, _ in frames]
    bgr = [(cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR))
           for left, right, _, _ in frames]
    matcher = sgbm_matcher(max_disp)
    times = {"sgbm": [], "full": [], "temporal": []}
    bad = {"sgbm": [], "full": [], "temporal": []}
    reasons = {}
    with stereobudget.Decoder() as plain, stereobudget.Decoder(temporal=True) as temporal:
        plain.decode(frames[0][0], samples[0], max_disp=max_disp)            # warm-up
        for _ in range(repeats):
            temporal.reset()
            for (left, _, gt, nonocc), sample_set, (lb, rb) in zip(frames, samples, bgr):
                t = time.perf_counter()
                d = matcher.compute(lb, rb)
                times["sgbm"].append(time.perf_counter() - t)
                d = d.astype(np.float32) / 16.0
                d[d < 0] = np.nan
                bad["sgbm"].append(bad_pixels(d, gt, nonocc))
                for name, decoder in (("full", plain), ("temporal", temporal)):
                    t = time.perf_counter()
                    result = decoder.decode(left, sample_set, max_disp=max_disp)
                    times[name].append(time.perf_counter() - t)
                    bad[name].append(bad_pixels(result.disparity, gt, nonocc))
                    if name == "temporal":
                        reasons[result.stream["reason"]] = reasons.get(result.stream["reason"], 0) + 1
    return times, bad, reasons


def stream_run(folder, size, frames, temporal, max_disp):
    raw = folder / f"camera{frames}.raw"
    start = time.perf_counter()
    with open(raw, "rb") as camera:
        encoder = subprocess.Popen([sys.executable, "-m", "stereobudget.cli.encode", "-", "--raw", size,
                                    "--pix-fmt", "rgb24", "-o", "-"], stdin=camera, stdout=subprocess.PIPE,
                                   cwd=folder)
    decoder = subprocess.Popen([sys.executable, "-m", "stereobudget.cli.decode", "L/{index}.png", "-",
                                "--max-disp", str(max_disp), "--disparity", "-", "-q",
                                "--temporal" if temporal else "--no-temporal"],
                               stdin=encoder.stdout, stdout=subprocess.PIPE, cwd=folder)
    encoder.stdout.close()
    out, _ = decoder.communicate()
    assert decoder.returncode == 0 and out.startswith(b"Pf"), decoder.returncode
    assert encoder.wait() == 0
    return time.perf_counter() - start


def batch_run(folder, frames, max_disp):
    """One ``sb-decode --left-dir L{frames} --samples-dir S{frames} -j 1`` into a fresh output folder."""
    out = folder / f"D{frames}"
    if out.exists():
        shutil.rmtree(out)
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "stereobudget.cli.decode", "--left-dir", f"L{frames}",
                             "--samples-dir", f"S{frames}", "--max-disp", str(max_disp), "--disparity",
                             f"D{frames}/{{stem}}.pfm", "-j", "1", "-q"], cwd=folder)
    assert result.returncode == 0, result.returncode
    assert len(list(out.glob("*.pfm"))) == frames
    return time.perf_counter() - start


def stream_table(frames, *, width, height, max_disp, repeats, count):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "L").mkdir()
        for i, (left, right, _, _) in enumerate(frames):
            cv2.imwrite(str(folder / "L" / f"{i}.png"), np.ascontiguousarray(left[:, :, ::-1]))
        for n in (5, count):
            (folder / f"camera{n}.raw").write_bytes(b"".join(np.ascontiguousarray(r).tobytes()
                                                             for _, r, _, _ in frames[:n]))
            # The same frames as a folder batch: left PNGs and .sbs files matched by stem.
            (folder / f"L{n}").mkdir()
            (folder / f"S{n}").mkdir()
            for i, (left, right, _, _) in enumerate(frames[:n]):
                cv2.imwrite(str(folder / f"L{n}" / f"{i:03d}.png"), np.ascontiguousarray(left[:, :, ::-1]))
                save_samples(encode_image(right, pattern=SamplingPattern("grid", 5, 5)),
                             folder / f"S{n}" / f"{i:03d}.sbs")
        size = f"{width}x{height}"
        per_frame = {True: [], False: [], "batch": [], "sgbm": []}
        matcher = sgbm_matcher(max_disp)
        pairs = [(cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR))
                 for left, right, _, _ in frames]
        for _ in range(repeats):
            for temporal in (True, False):
                short = stream_run(folder, size, 5, temporal, max_disp)
                long = stream_run(folder, size, count, temporal, max_disp)
                per_frame[temporal].append((long - short) / (count - 5))
            per_frame["batch"].append((batch_run(folder, count, max_disp) - batch_run(folder, 5, max_disp))
                                      / (count - 5))
            for left, right in pairs:          # SGBM on the same frames, between the runs
                t = time.perf_counter()
                matcher.compute(left, right)
                per_frame["sgbm"].append(time.perf_counter() - t)
    return {k: statistics.median(v) for k, v in per_frame.items()}


def profile(width, height, max_disp, repeats):
    """Median seconds per stage of one default decode of a slanted pair, with the I/O around it."""
    from stereobudget.aggregate import _semiglobal
    from stereobudget.batch import _stream  # noqa: F401  (loads what sb-decode loads)
    from stereobudget.decoding import _full, _hybrid
    from stereobudget.decoding._checks import psnr_at_samples, result_warnings
    from stereobudget.io import read_image, write_disparity
    from stereobudget.io._samples import read_samples, save_samples

    stages: dict[str, list] = {}
    current: dict[str, float] = {}

    def wrap(module, name, label):
        inner = getattr(module, name)

        def timed(*args, **kwargs):
            t = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                current[label] = current.get(label, 0.0) + time.perf_counter() - t
        setattr(module, name, timed)

    wrap(_hybrid, "sparse_filled_cost", "sparse fill (Eq. 2-4 DSI)")
    wrap(_hybrid, "lowpass_interpolation", "low-pass interpolation of the samples")
    wrap(_hybrid, "gaussian_lowpass", "low-pass of I1")
    wrap(_hybrid, "spaced_census", "census codes")
    wrap(_hybrid, "mix_spaced_census", "census cost mixed in")
    wrap(_hybrid, "typical_margin", "typical margin")
    wrap(_semiglobal, "_vertical_sums", "SGM vertical+diagonal paths")
    wrap(_semiglobal, "_horizontal_paths_winners", "SGM horizontal paths + winners + sub-pixel")
    wrap(_full, "left_right_stable", "LR check")
    wrap(_full, "fill_from_row", "row fill")
    wrap(_full, "median_filter_disparity", "median")
    scene = make_scene("slanted", height=height, width=width, max_disp=48, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        left_path = Path(tmp) / "left.png"
        cv2.imwrite(str(left_path), np.ascontiguousarray(scene.left[:, :, ::-1]))
        save_samples(encode_image(scene.right, pattern=SamplingPattern("grid", 5, 5)), Path(tmp) / "r.sbs")
        raw = (Path(tmp) / "r.sbs").read_bytes()
        with stereobudget.Decoder() as decoder:
            for i in range(repeats + 1):
                current.clear()
                t0 = time.perf_counter()
                left, _ = read_image(str(left_path))
                t1 = time.perf_counter()
                samples = read_samples(raw, source="r.sbs")
                t2 = time.perf_counter()
                result = decoder.decode(left, samples, max_disp=max_disp)
                t3 = time.perf_counter()
                result_warnings(result.disparity, min_disp=0, max_disp=max_disp,
                                psnr=psnr_at_samples(left, result.disparity, samples), auto_range=False)
                t4 = time.perf_counter()
                write_disparity(str(Path(tmp) / "d.pfm"), result.disparity, overwrite=True)
                t5 = time.perf_counter()
                if i == 0:
                    continue                                   # warm-up
                row = {"read I1 (PNG)": t1 - t0, "parse .sbs": t2 - t1}
                row.update({f"[stage] {k}": v for k, v in result.timings.items()})
                row.update(current)
                row.update({"decode total": t3 - t2, "checks (PSNR at samples, warnings)": t4 - t3,
                            "write PFM": t5 - t4, "end to end": t5 - t0})
                for k, v in row.items():
                    stages.setdefault(k, []).append(v)
    print(f"\nOne default decode, slanted {width}x{height}, disparities 0-{max_disp}, median of {repeats}\n")
    print("| stage | ms |\n|---|---:|")
    for k, v in stages.items():
        print(f"| {k} | {1000 * statistics.median(v):.1f} |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--frames", type=int, default=24, help="frames per stream (in-process table)")
    parser.add_argument("--stream-frames", type=int, default=25, help="frames of the long stream run")
    parser.add_argument("--max-disp", type=int, default=64)
    parser.add_argument("--sizes", default="640x480,450x375")
    parser.add_argument("--profile", action="store_true", help="print the stages of one decode and stop")
    parser.add_argument("--no-stream", action="store_true", help="only the in-process table")
    parser.add_argument("--no-in-process", action="store_true", help="only the stream table")
    args = parser.parse_args(argv)
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    if args.profile:
        for width, height in sizes:
            profile(width, height, args.max_disp, args.repeats)
        return 0
    if not args.no_in_process:
        print(f"In process, {args.max_disp + 1} disparities, median (mean) ms per frame over {args.repeats} "
              f"passes of {args.frames} frames; bad > 1 px % (non-occluded) mean over frames\n")
        print("| frame | stream | SGBM 3WAY | full range | temporal | full / SGBM | temporal / SGBM "
              "| bad SGBM | bad full | bad temporal | temporal frames |")
        print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    makers = {"coherent": coherent_frames, "unrelated": unrelated_frames}
    for width, height in sizes if not args.no_in_process else ():
        for kind, make in makers.items():
            # Each stream its own length: the coherent one cuts at its middle.
            times, bad, reasons = in_process(make(width, height, args.frames), max_disp=args.max_disp,
                                             repeats=args.repeats)
            med = {k: 1000 * statistics.median(v) for k, v in times.items()}
            mean = {k: 1000 * statistics.fmean(v) for k, v in times.items()}
            print(f"| {width}x{height} | {kind} | {med['sgbm']:.1f} | {med['full']:.1f} ({mean['full']:.1f}) | "
                  f"{med['temporal']:.1f} ({mean['temporal']:.1f}) | {med['full'] / med['sgbm']:.1f}x | "
                  f"{med['temporal'] / med['sgbm']:.1f}x | {statistics.fmean(bad['sgbm']):.2f} | "
                  f"{statistics.fmean(bad['full']):.2f} | {statistics.fmean(bad['temporal']):.2f} | "
                  f"{', '.join(f'{k} {v // args.repeats}' for k, v in sorted(reasons.items()))} |", flush=True)
    if args.no_stream:
        return 0
    print(f"\nStream (sb-encode | sb-decode), {args.max_disp + 1} disparities, steady state ms per frame = "
          f"(t{args.stream_frames} - t5) / {args.stream_frames - 5}, median of {args.repeats} alternating runs\n")
    print("| frame | stream | --no-temporal | frames/s | --temporal | frames/s | folder batch -j 1 | frames/s | "
          "SGBM 3WAY in process | --temporal / SGBM |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for width, height in sizes:
        for kind, make in makers.items():
            per_frame = stream_table(make(width, height, args.stream_frames), width=width, height=height,
                                     max_disp=args.max_disp, repeats=args.repeats, count=args.stream_frames)
            print(f"| {width}x{height} | {kind} | {1000 * per_frame[False]:.0f} | {1 / per_frame[False]:.1f} | "
                  f"{1000 * per_frame[True]:.0f} | {1 / per_frame[True]:.1f} | {1000 * per_frame['batch']:.0f} | "
                  f"{1 / per_frame['batch']:.1f} | {1000 * per_frame['sgbm']:.1f} | "
                  f"{per_frame[True] / per_frame['sgbm']:.1f}x |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
