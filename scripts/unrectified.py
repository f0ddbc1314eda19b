#!/usr/bin/env python
"""Unrectified real pairs: ``sb-decode --calibration`` against the decode of the rectified pair.

Each realdev scene (``../shared/data/realdev``) is made unrectified with exact ground truth
(:func:`stereobudget.geometry.unrectify_pair`): ``K`` with f = the image width and the
principal point at the centre, each camera turned by 0.5-2 degrees about each axis
(random signs) and given a radial distortion k1 of +-0.05-0.1, drawn from a seed per
scene; the calibration that undoes it is written as OpenCV YAML.  The raw right image is
encoded (``--epsilon 0.04``: the densest grid whose coded lattice fits 4 % of the raw
image; or a raw grid at stride 5), and decoded through ``stereobudget.pipeline.decode_file``
exactly as ``sb-decode`` does:

* ``rectified``: the rectified pair, scored as ``scripts/evaluate_real.py`` does (bad =
  error > 1 px on ``nonocc.png`` where the scene has one, else on every pixel with ground
  truth);
* ``calibrated``: the raw pair with ``--calibration``, scored on the raw left image: for
  each raw left pixel whose rectified position has ground truth (and is selected by the
  same mask), the raw right position its result implies (mapped back through the
  rectification) against the true one; bad = more than 1 px away, or no result.  Nothing
  is cropped (alpha 1), so no pixel both cameras see is lost.

Both decodes search the disparity range the ground truth needs (in their own frame):
``[min(0, floor(min) - 4), ceil(max) + 4]``, as evaluate_real.py does.

Speed: the time the rectification adds to a frame (I1 resampled and the samples placed,
and the overlay of the maps, made once per stream) against the decode's total, in the
same process; and the calibrated decode's whole time (the maps made before it) against the
decode of the rectified pair (placed samples take the Sparse fill's general route).

Examples
--------
    python scripts/unrectified.py
    python scripts/unrectified.py --scenes Art,Adirondack --configs s5
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

import stereobudget
from stereobudget.pipeline import DecodeJob, decode_arrays, decode_file
from stereobudget.decoding import DecoderParams
from stereobudget.errors import CalibrationError
from stereobudget.geometry import (SelfRectifiedStream, raw_right_positions, rectification_for, rectify_left,
                                   rectify_samples, unrectify_pair, write_calibration)
from stereobudget.io import load_samples, read_disparity, read_image, write_image
from stereobudget.encoding import encode_file
from stereobudget.sampling import SamplingPattern

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
CONFIGS = {"eps4": dict(size_fraction=0.04), "s5": dict()}


def load_scene(folder: Path):
    left = cv2.cvtColor(cv2.imread(str(folder / "left.png"), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    right = cv2.cvtColor(cv2.imread(str(folder / "right.png"), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    gt = cv2.imread(str(folder / "disp_left.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / 256.0
    mask = gt > 0
    if (folder / "nonocc.png").exists():
        mask &= cv2.imread(str(folder / "nonocc.png"), cv2.IMREAD_GRAYSCALE) == 255
    gt[gt <= 0] = np.nan
    return left, right, gt, mask


def camera_turns(seed: int):
    """Rotation vectors (radians) of both cameras and their k1, drawn from ``seed``."""
    rng = np.random.default_rng(seed)

    def signed(low, high, n):
        return rng.uniform(low, high, n) * rng.choice([-1.0, 1.0], n)

    return (np.radians(signed(0.5, 2.0, 3)), np.radians(signed(0.5, 2.0, 3)),
            float(signed(0.05, 0.1, 1)[0]), float(signed(0.05, 0.1, 1)[0]))


def search_range(d_min, d_max):
    return min(0, math.floor(d_min) - 4), math.ceil(d_max) + 4


def encode(image, folder: Path, name: str, config: str) -> str:
    source = folder / f"{name}.png"
    write_image(source, image, channel_order="rgb", overwrite=True)
    out = folder / f"{name}_{config}.sbs"
    if config == "s5":
        encode_file(source, out, pattern=SamplingPattern("grid", 5, 5), overwrite=True)
    else:
        encode_file(source, out, pattern=SamplingPattern("grid"), overwrite=True, **CONFIGS[config])
    return str(out)


def run_scene(folder: Path, configs, work: Path, seed: int, variants=()) -> list[dict]:
    left, right, gt, mask = load_scene(folder)
    h, w = gt.shape
    r1, r2, k1a, k1b = camera_turns(seed)
    pair = unrectify_pair(left, right, gt, rotation_left=r1, rotation_right=r2, k1_left=k1a, k1_right=k1b,
                          mask=mask)
    calibration = work / "stereo.yml"
    write_calibration(calibration, pair.calibration)
    write_image(work / "left.png", left, channel_order="rgb", overwrite=True)
    write_image(work / "raw_left.png", pair.left, channel_order="rgb", overwrite=True)
    t = time.perf_counter()
    rect = rectification_for(str(calibration), w, h)      # the decodes below reuse it, as a stream does
    maps_s = time.perf_counter() - t
    # The true disparity range in the host's rectified frame, from the true matches.
    scored = pair.scored
    xl = rect.left_positions[..., 0][scored]
    c = pair.calibration
    true_r = cv2.undistortPoints(pair.true_right[scored].reshape(-1, 1, 2), c.M2, c.D2, R=rect.R2,
                                 P=rect.P2).reshape(-1, 2)
    d_rect = xl - true_r[:, 0]
    rows = []
    for config in configs:
        samples_rect = encode(right, work, "right", config)
        samples_raw = encode(pair.right, work, "raw_right", config)
        lo, hi = search_range(np.nanmin(gt[mask]), np.nanmax(gt[mask]))
        plain = decode_file(DecodeJob(left=str(work / "left.png"), samples=samples_rect, max_disp=hi, min_disp=lo,
                                      disparity=str(work / "d.pfm"), overwrite=True))
        d = read_disparity(work / "d.pfm")
        bad_rect = 100.0 * np.mean(~(np.abs(d - gt)[mask] <= 1.0))
        # The same result scored on the raw left image, as the calibrated decodes are.
        bad_rect_raw = bad_raw(pair.implied_by_rectified(d), pair)
        lo_c, hi_c = search_range(float(d_rect.min()), float(d_rect.max()))
        cal = decode_file(DecodeJob(left=str(work / "raw_left.png"), samples=samples_raw, max_disp=hi_c,
                                    min_disp=lo_c, disparity=str(work / "dc.pfm"), calibration=str(calibration),
                                    overwrite=True))
        bad_cal = bad_raw(raw_right_positions(read_disparity(work / "dc.pfm"), rect), pair)
        row = {"scene": folder.name, "config": config, "stride": plain["stride_x"],
               "raw_stride": cal["stride_x"], "rectified": bad_rect, "rectified_raw": bad_rect_raw,
               "calibrated": bad_cal, "range": (lo, hi), "range_cal": (lo_c, hi_c),
               "rectify_s": cal["timings"].get("rectify", 0.0), "maps_s": maps_s, "decode_s": cal["timings"]["total"],
               "plain_s": plain["timings"]["total"],
               "placed": cal["calibration"]["samples_placed"], "sent": cal["sample_count"]}
        if variants:
            left_r = rectify_left(read_image(str(work / "raw_left.png"))[0], rect)
            raw_samples = load_samples(samples_raw)
            for name in variants:
                if name == "self":
                    # --calibration auto exactly as sb-decode runs it (the range estimated in the
                    # frame the estimate gives); the estimate is kept to score the result.
                    rectifier = SelfRectifiedStream(check_every=0)
                    job = DecodeJob(left=str(work / "raw_left.png"), samples=samples_raw, calibration="auto",
                                    disparity=str(work / "da.pfm"), overwrite=True)
                    try:
                        decode_arrays(read_image(job.left)[0], raw_samples, job, left_name="raw_left.png",
                                      samples_name=samples_raw, overwrite=True, timings={},
                                      start=time.perf_counter(), self_rectifier=rectifier)
                    except CalibrationError as exc:
                        row["self"], row["self_note"] = math.nan, str(exc).split(": ", 1)[-1][:60]
                        continue
                    report = rectifier.report
                    row["self"] = bad_raw(raw_right_positions(read_disparity(work / "da.pfm"),
                                                              rectifier.rectification), pair)
                    row["self_note"] = (f"{report.matches} matches, residual {report.residual_median:.2f} px "
                                        f"(p90 {report.residual_p90:.2f}), uncertainty {report.uncertainty:.2f} px")
                    continue
                if name == "sgbm":
                    # OpenCV's own pipeline on the full pair: SGBM on the rectified pair, and SGBM on the
                    # raw pair rectified with the calibration (both images resampled), both scored on the
                    # raw left image: what the known-calibration bound is measured against.
                    raw_right = rectify_right(pair.right, rect)
                    row["sgbm_rectified"] = bad_raw(pair.implied_by_rectified(sgbm(left, right, lo, hi)), pair)
                    row[name] = bad_raw(raw_right_positions(sgbm(left_r, raw_right, lo_c, hi_c), rect), pair)
                    continue
                placed = rectify_samples(raw_samples, rect, subpixel=name != "nearest")
                params = DecoderParams(sparse_census_weight=0.0) if name == "no_census" else None
                result = stereobudget.decode(left_r, placed, max_disp=hi_c, min_disp=lo_c, params=params)
                row[name] = bad_raw(raw_right_positions(result.disparity, rect), pair)
        rows.append(row)
    return rows


def sgbm(left, right, lo, hi):
    """OpenCV SGBM 3WAY on an RGB pair over ``lo..hi``, with scripts/evaluate_real.py's settings and row fill."""
    from evaluate_real import fill_row_gaps
    num = int(math.ceil((hi - lo + 1) / 16.0) * 16)
    matcher = cv2.StereoSGBM_create(minDisparity=int(lo), numDisparities=num, blockSize=3, P1=8 * 3 * 9,
                                    P2=32 * 3 * 9, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = matcher.compute(cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR))
    return fill_row_gaps(raw.astype(np.float32) / 16.0, raw >= int(lo) * 16)


def rectify_right(image, rect):
    """The raw right image resampled into the rectified right frame (as cv2's pipeline does)."""
    c = rect.calibration
    map_x, map_y = cv2.initUndistortRectifyMap(c.M2, c.D2, rect.R2, rect.P2, rect.size, cv2.CV_32FC1)
    return cv2.remap(image, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def bad_raw(implied, pair) -> float:
    """Bad pixels (%) of the raw left image: implied raw right position more than 1 px from the true one."""
    error = np.hypot(*(implied - pair.true_right).transpose(2, 0, 1))[pair.scored]
    return 100.0 * float(np.mean(~(error <= 1.0)))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default="", help="comma-separated scene names (default: all of realdev)")
    parser.add_argument("--configs", default="eps4,s5", help="eps4 (--epsilon 0.04) and/or s5 (raw stride 5)")
    parser.add_argument("--seed", type=int, default=50, help="base seed of the camera turns")
    parser.add_argument("--variants", default="", help="extra columns: self (--calibration auto), nearest "
                        "(positions rounded, no sub-pixel offsets), no_census (Sparse census off), sgbm (OpenCV SGBM on "
                        "the rectified pair and on the raw pair rectified with the calibration)")
    args = parser.parse_args(argv)
    root = SHARED / "realdev"
    if not root.is_dir():
        print(f"{root} is absent: nothing to measure", file=sys.stderr)
        return 1
    folders = sorted(p for p in root.iterdir() if p.is_dir())
    if args.scenes:
        wanted = args.scenes.split(",")
        folders = [f for f in folders if f.name in wanted]
    configs = [c for c in args.configs.split(",") if c]
    variants = [v for v in args.variants.split(",") if v]
    # The columns printed: the sgbm variant gives two (the rectified pair's and the calibrated one's).
    columns = [c for v in variants for c in (("sgbm_rectified", "sgbm") if v == "sgbm" else (v,))]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for number, folder in enumerate(folders):
            work = Path(tmp) / folder.name
            work.mkdir()
            seed = args.seed * 1000 + sum(folder.name.encode())
            start = time.perf_counter()
            scene_rows = run_scene(folder, configs, work, seed, variants)
            rows += scene_rows
            for row in scene_rows:
                extra = "".join(f"  {v} {row[v]:6.2f}" for v in columns)
                if "self_note" in row:
                    extra += f" [{row['self_note']}]"
                print(f"{row['scene']:16s} {row['config']:5s} stride {row['stride']}/{row['raw_stride']}  "
                      f"rectified {row['rectified']:6.2f} (on raw {row['rectified_raw']:6.2f})  calibrated "
                      f"{row['calibrated']:6.2f}{extra}  ranges {row['range']} {row['range_cal']}  placed "
                      f"{row['placed']}/{row['sent']}  rectify {1000 * row['rectify_s']:.1f} ms maps "
                      f"{1000 * row['maps_s']:.1f} ms decode {row['decode_s']:.2f} s", flush=True)
            print(f"  ({time.perf_counter() - start:.1f} s)", file=sys.stderr, flush=True)
    print()
    head = "".join(f" {v} |" for v in columns)
    print(f"| scene | config | stride (rect/raw) | rectified | rectified, scored on raw | known calibration |{head}")
    print("|---|---|---|---:|---:|---:|" + "---:|" * len(columns))
    for row in rows:
        extra = "".join(f" {row[v]:.2f} |" for v in columns)
        print(f"| {row['scene']} | {row['config']} | {row['stride']}/{row['raw_stride']} | {row['rectified']:.2f} | "
              f"{row['rectified_raw']:.2f} | {row['calibrated']:.2f} |{extra}")
    for config in configs:
        sel = [r for r in rows if r["config"] == config]
        if not sel:
            continue
        extra = "".join(f" {np.nanmean([r[v] for r in sel]):.2f} ({int(np.sum(np.isnan([r[v] for r in sel])))} "
                        f"refused) |" if v == "self" else f" {np.mean([r[v] for r in sel]):.2f} |" for v in columns)
        print(f"| **mean ({len(sel)})** | {config} | | {np.mean([r['rectified'] for r in sel]):.2f} | "
              f"{np.mean([r['rectified_raw'] for r in sel]):.2f} | {np.mean([r['calibrated'] for r in sel]):.2f} |{extra}")
    for config in configs:
        sel = [r for r in rows if r["config"] == config]
        if not sel:
            continue
        diffs = [r["calibrated"] - r["rectified"] for r in sel]
        diffs_raw = [r["calibrated"] - r["rectified_raw"] for r in sel]
        print(f"{config}: calibrated - rectified: mean {np.mean(diffs):+.2f} pp, worst {max(diffs):+.2f} "
              f"({sel[int(np.argmax(diffs))]['scene']}); against the rectified decode scored on the raw image: "
              f"mean {np.mean(diffs_raw):+.2f}, worst {max(diffs_raw):+.2f}")
        ratio = [r["rectify_s"] / r["decode_s"] for r in sel]
        ratio_maps = [(r["rectify_s"] + r["maps_s"]) / r["decode_s"] for r in sel]
        print(f"{config}: rectification per frame / calibrated decode total: median {100 * statistics.median(ratio):.1f} %, "
              f"max {100 * max(ratio):.1f} %; with the maps (once per stream): median "
              f"{100 * statistics.median(ratio_maps):.1f} %, max {100 * max(ratio_maps):.1f} %")
        # The whole cost: placed samples are no lattice, so the Sparse fill takes its general route.
        whole = [r["decode_s"] / r["plain_s"] for r in sel]   # the maps were made before: not in decode_s
        print(f"{config}: calibrated decode (the maps made before it) / decode of the rectified pair: median "
              f"{statistics.median(whole):.2f}x, max {max(whole):.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
