#!/usr/bin/env python
"""Evaluate a stereobudget decoder on the Middlebury v2 scenes (or on synthetic scenes).

For every scene the right image is encoded with a ``grid`` pattern of the given stride
(the camera's job), decoded together with the left image, and scored with the Middlebury
v2 measures: bad pixels (error > 1) and RMS error over the ``nonocc``, ``all`` and ``disc``
masks.  The result is printed as Markdown tables beside the paper's Table 2 / Table 1
"Uniform grid" row (4 % of I2 = stride 5).  The paper labels its third and fourth scene
columns "Cones" and "Teddy"; both readings (as labelled, and swapped) are shown.

Examples
--------
    python scripts/evaluate.py --data ../shared/data/middlebury --stride 5
    python scripts/evaluate.py --stride 1 --scenes teddy,cones --json full.json
    python scripts/evaluate.py --synthetic --stride 5
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from stereobudget.encoding import encode_image
from stereobudget.errors import StereoBudgetError
from stereobudget.metrics import bad_pixel_rate, evaluate_disparity, rms_error
from middlebury import MASK_NAMES, SCENES, default_data_dir, load_scene, paper_reference
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import SCENE_KINDS, make_scene

PAPER_STRIDE = 5  # the paper's tables use 4 % of I2
PAPER_TEDDY_CONES_SUM = {"nonocc": 34.38, "all": 50.70, "disc": 68.26}
EXIT_NO_DECODER = 3


def _load_decoder():
    """``stereobudget.decode``, or exit with a clear message when it is not available yet."""
    try:
        from stereobudget import decode
    except (ImportError, AttributeError) as exc:
        print(f"evaluate.py: error: stereobudget.decode is not available ({exc}); "
              "the decoder must be installed before evaluating", file=sys.stderr)
        sys.exit(EXIT_NO_DECODER)
    return decode


def _fmt(value, digits=2) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.{digits}f}"


def warm_up(decode, *, stride, method, channels=3):
    """Run the decoder once on a tiny pair so numba compilation does not count as decode time."""
    rng = np.random.default_rng(0)
    shape = (48, 64, channels) if channels > 1 else (48, 64)
    left = rng.integers(0, 256, size=shape, dtype=np.uint8)
    right = np.roll(left, -3, axis=1)
    start = time.perf_counter()
    _decode_pair(decode, left, right, stride=min(stride, 8), max_disp=8, method=method)
    print(f"  warm-up (JIT compile / cache load): {time.perf_counter() - start:.2f} s", file=sys.stderr)


def _decode_pair(decode, left, right, *, stride, max_disp, method):
    pattern = SamplingPattern("grid", stride, stride)
    samples = encode_image(right, pattern=pattern)
    start = time.perf_counter()
    result = decode(left, samples, max_disp=max_disp, method=method)
    seconds = time.perf_counter() - start
    return result, seconds, samples.epsilon


def evaluate_middlebury(decode, data_dir, names, *, stride, method):
    """Decode and score each Middlebury scene; returns {name: record}."""
    records = {}
    for name in names:
        scene = load_scene(data_dir, name)
        result, seconds, epsilon = _decode_pair(decode, scene.left, scene.right, stride=stride,
                                                max_disp=scene.max_disp, method=method)
        records[name] = {
            "size": [int(scene.left.shape[1]), int(scene.left.shape[0])],
            "max_disp": scene.max_disp,
            "epsilon": epsilon,
            "method": getattr(result, "method", method),
            "metrics": evaluate_disparity(result.disparity, scene.gt, scene.masks),
            "decode_seconds": seconds,
            "timings": dict(getattr(result, "timings", {}) or {}),
        }
        bad = records[name]["metrics"]["nonocc"]["bad"]
        print(f"  {name}: bad>1 nonocc {_fmt(bad)} %, {seconds:.2f} s", file=sys.stderr)
    return records


def evaluate_synthetic(decode, kinds, *, stride, method, seed):
    """Decode and score each synthetic scene kind (bad > 1 and RMS on nonocc)."""
    records = {}
    for kind in kinds:
        scene = make_scene(kind, seed=seed)
        result, seconds, epsilon = _decode_pair(decode, scene.left, scene.right, stride=stride,
                                                max_disp=scene.max_disp, method=method)
        records[kind] = {
            "size": [int(scene.left.shape[1]), int(scene.left.shape[0])],
            "max_disp": scene.max_disp,
            "epsilon": epsilon,
            "method": getattr(result, "method", method),
            "metrics": {"nonocc": {
                "bad": bad_pixel_rate(result.disparity, scene.disparity, scene.nonocc),
                "rms": rms_error(result.disparity, scene.disparity, scene.nonocc),
            }},
            "decode_seconds": seconds,
            "timings": dict(getattr(result, "timings", {}) or {}),
        }
    return records


def _timing_table(records) -> list[str]:
    lines = ["| scene | size | max_disp | ε (% of I2) | method | decode (s) | stages (s) |",
             "|---|---|---|---|---|---|---|"]
    for name, r in records.items():
        stages = ", ".join(f"{k} {v:.2f}" for k, v in r["timings"].items()) or "–"
        lines.append(f"| {name} | {r['size'][0]}x{r['size'][1]} | {r['max_disp']} | "
                     f"{100 * r['epsilon']:.2f} | {r['method']} | {r['decode_seconds']:.2f} | {stages} |")
    return lines


def middlebury_report(records, *, stride) -> list[str]:
    labelled_bad = paper_reference("bad")
    swapped_bad = paper_reference("bad", swap_cones_teddy=True)
    labelled_rms = paper_reference("rms")
    swapped_rms = paper_reference("rms", swap_cones_teddy=True)
    lines = []
    if stride != PAPER_STRIDE:
        lines += [f"> Note: the paper's numbers are for stride {PAPER_STRIDE} (4 % of I2); "
                  f"this run used stride {stride}.", ""]
    lines += ["### Bad pixels (error > 1, %) and RMS error (px) vs the paper's \"Uniform grid\" row", "",
              "| scene | mask | bad ours | bad paper (as labelled) | bad paper (Cones/Teddy swapped) "
              "| RMS ours | RMS paper (as labelled) | RMS paper (swapped) |",
              "|---|---|---|---|---|---|---|---|"]
    for name, r in records.items():
        for mask in MASK_NAMES:
            m = r["metrics"][mask]
            lines.append(f"| {name} | {mask} | {_fmt(m['bad'])} | {_fmt(labelled_bad[name][mask])} | "
                         f"{_fmt(swapped_bad[name][mask])} | {_fmt(m['rms'])} | "
                         f"{_fmt(labelled_rms[name][mask])} | {_fmt(swapped_rms[name][mask])} |")
    if {"teddy", "cones"} <= set(records):
        lines += ["", "### Teddy + Cones (bad > 1, sum of the two scenes; the same under both readings)", "",
                  "| mask | ours | paper | difference |", "|---|---|---|---|"]
        for mask in MASK_NAMES:
            ours = records["teddy"]["metrics"][mask]["bad"] + records["cones"]["metrics"][mask]["bad"]
            paper = PAPER_TEDDY_CONES_SUM[mask]
            lines.append(f"| {mask} | {_fmt(ours)} | {_fmt(paper)} | {_fmt(ours - paper)} |")
    lines += ["", "### Decode time", ""] + _timing_table(records)
    return lines


def synthetic_report(records) -> list[str]:
    lines = ["### Synthetic scenes (bad > 1 and RMS on nonocc)", "",
             "| kind | bad ours (%) | RMS ours (px) |", "|---|---|---|"]
    for name, r in records.items():
        m = r["metrics"]["nonocc"]
        lines.append(f"| {name} | {_fmt(m['bad'])} | {_fmt(m['rms'])} |")
    return lines + ["", "### Decode time", ""] + _timing_table(records)


def _json_safe(value):
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, np.integer):
        return int(value)
    return value


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=None,
                        help="folder with one sub-folder per Middlebury scene "
                             "(default: $STEREOBUDGET_MIDDLEBURY or ../shared/data/middlebury)")
    parser.add_argument("--stride", type=int, default=PAPER_STRIDE,
                        help="grid stride of the right-image samples (1 = full right image)")
    parser.add_argument("--method", default="sparse", help="decoder method, passed to stereobudget.decode")
    parser.add_argument("--scenes", default=None,
                        help="comma-separated scene names (Middlebury) or kinds (--synthetic)")
    parser.add_argument("--synthetic", action="store_true",
                        help=f"evaluate on the synthetic scenes ({', '.join(SCENE_KINDS)})")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic scenes")
    parser.add_argument("--json", type=Path, default=None, help="also write all numbers to this JSON file")
    args = parser.parse_args(argv)
    if args.stride < 1:
        parser.error(f"--stride must be >= 1, got {args.stride}")
    known = SCENE_KINDS if args.synthetic else tuple(SCENES)
    names = [s.strip().lower() for s in args.scenes.split(",") if s.strip()] if args.scenes else list(known)
    unknown = [s for s in names if s not in known]
    if unknown or not names:
        parser.error(f"unknown scene(s) {', '.join(unknown) or '(none given)'}; expected some of {', '.join(known)}")
    args.names = names
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    decode = _load_decoder()
    try:
        warm_up(decode, stride=args.stride, method=args.method)
        if args.synthetic:
            records = evaluate_synthetic(decode, args.names, stride=args.stride, method=args.method,
                                         seed=args.seed)
            lines = synthetic_report(records)
        else:
            data_dir = args.data if args.data is not None else default_data_dir()
            records = evaluate_middlebury(decode, data_dir, args.names, stride=args.stride, method=args.method)
            lines = middlebury_report(records, stride=args.stride)
    except StereoBudgetError as exc:
        print(f"evaluate.py: error: {exc}", file=sys.stderr)
        return exc.exit_code
    header = (f"## stereobudget evaluation: method {args.method}, grid stride {args.stride} "
              f"({'synthetic, seed ' + str(args.seed) if args.synthetic else 'Middlebury v2'})")
    print("\n".join([header, ""] + lines))
    if args.json is not None:
        payload = {"method": args.method, "stride": args.stride, "synthetic": args.synthetic,
                   "seed": args.seed if args.synthetic else None, "scenes": records}
        if not args.synthetic and {"teddy", "cones"} <= set(records):
            payload["teddy_plus_cones_bad"] = {
                mask: {"ours": records["teddy"]["metrics"][mask]["bad"] + records["cones"]["metrics"][mask]["bad"],
                       "paper": PAPER_TEDDY_CONES_SUM[mask]} for mask in MASK_NAMES}
        from stereobudget.io import write_output_bytes
        write_output_bytes(args.json, (json.dumps(_json_safe(payload), indent=2) + "\n").encode(), overwrite=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
