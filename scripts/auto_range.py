#!/usr/bin/env python
"""How good is ``--max-disp auto``?  The estimated disparity range against the true one.

For every scene of ``../shared/data/middlebury`` and ``../shared/data/realdev`` the right
image is encoded on a grid (stride 5 by default, 4 % of I2) and decoded (Hybrid by
default) twice: with the true range ``[0, ceil(max GT) + 4]`` and with the range
:func:`stereobudget.decoding.estimate_disparity_range` finds.  Printed per scene: the
true and the estimated range, whether the estimate contains every ground-truth
disparity, the bad-pixel rate (error > 1 px, on the ``nonocc`` mask where the scene has
one, else every pixel with ground truth) with each range, the time of the estimate and
of the decode, and the warnings each decode gets.

``--calibrate`` adds the figures behind the ``samples_disagree`` threshold: the PSNR at
the samples of a decode with the true range, with half of it, and of a mismatched pair
(one scene's I1 with another's samples), on the Middlebury scenes.

Examples
--------
    nice -n 10 python scripts/auto_range.py
    python scripts/auto_range.py --scenes teddy,Art --calibrate
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from stereobudget.decoding import (estimate_disparity_range, psnr_at_samples, result_warnings, setup_warnings)
from stereobudget.encoding import encode_image
from stereobudget.metrics import bad_pixel_rate
from stereobudget.sampling import SamplingPattern

_SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
#: GT scale of the Middlebury v2 scenes (disp_left.png value / scale = disparity).
MIDDLEBURY_SCALES = {"tsukuba": 16, "venus": 8, "teddy": 4, "cones": 4}


def _rgb(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SystemExit(f"auto_range.py: error: cannot read {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def load_scenes(middlebury: Path, realdev: Path, names=None):
    """(name, left, right, gt (NaN = unknown), mask or None) for every scene found."""
    scenes = []
    for name, scale in MIDDLEBURY_SCALES.items():
        folder = middlebury / name
        if not folder.is_dir():
            continue
        raw = cv2.imread(str(folder / "disp_left.png"), cv2.IMREAD_GRAYSCALE)
        gt = raw.astype(np.float32) / scale
        gt[raw == 0] = np.nan
        mask = cv2.imread(str(folder / "nonocc.png"), cv2.IMREAD_GRAYSCALE) == 255
        scenes.append((name, folder, gt, mask))
    if realdev.is_dir():
        for folder in sorted(p for p in realdev.iterdir() if (p / "disp_left.png").is_file()):
            # realdev/README: uint16, disparity = value / 256, 0 = unknown.
            raw = cv2.imread(str(folder / "disp_left.png"), cv2.IMREAD_UNCHANGED)
            gt = raw.astype(np.float32) / 256
            gt[raw == 0] = np.nan
            nonocc = folder / "nonocc.png"
            mask = cv2.imread(str(nonocc), cv2.IMREAD_GRAYSCALE) == 255 if nonocc.is_file() else None
            scenes.append((folder.name, folder, gt, mask))
    if names:
        wanted = {n.lower() for n in names}
        scenes = [s for s in scenes if s[0].lower() in wanted]
    for name, folder, gt, mask in scenes:
        yield name, _rgb(folder / "left.png"), _rgb(folder / "right.png"), gt, mask


def _decode(left, samples, *, min_disp, max_disp, method):
    from stereobudget import decode
    start = time.perf_counter()
    result = decode(left, samples, min_disp=min_disp, max_disp=max_disp, method=method)
    return result.disparity, time.perf_counter() - start


def _warnings(left, samples, disparity, *, min_disp, max_disp, estimate, auto):
    psnr = psnr_at_samples(left, disparity, samples)
    codes = [w.code for w in setup_warnings(estimate) + result_warnings(
        disparity, min_disp=min_disp, max_disp=max_disp, psnr=psnr, auto_range=auto)]
    return psnr, ",".join(codes) or "-"


def run(args) -> int:
    from stereobudget import decode
    pattern = SamplingPattern("grid", args.stride, args.stride)
    # Compile (or load) the kernels before timing anything.
    rng = np.random.default_rng(0)
    tiny = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    warm = encode_image(np.roll(tiny, -3, axis=1), pattern=pattern)
    estimate_disparity_range(tiny, warm)
    decode(tiny, warm, max_disp=8, method=args.method)

    header = ("| scene | true range | estimated | contains GT | bad % true | bad % est. | estimate s | decode s "
              "(true) | PSNR true / est. | warnings true / est. |")
    print(f"## --max-disp auto: method {args.method}, grid stride {args.stride}\n")
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    rows = []
    for name, left, right, gt, mask in load_scenes(args.middlebury, args.realdev, args.names):
        samples = encode_image(right, pattern=pattern)
        true_max = int(math.ceil(np.nanmax(gt))) + 4
        start = time.perf_counter()
        estimate = estimate_disparity_range(left, samples)
        estimate_seconds = time.perf_counter() - start
        contains = estimate.min_disp <= np.nanmin(gt) and estimate.max_disp >= np.nanmax(gt)
        d_true, t_true = _decode(left, samples, min_disp=0, max_disp=true_max, method=args.method)
        d_est, _ = _decode(left, samples, min_disp=estimate.min_disp, max_disp=estimate.max_disp,
                           method=args.method)
        bad_true = bad_pixel_rate(d_true, gt, mask)
        bad_est = bad_pixel_rate(d_est, gt, mask)
        psnr_true, warn_true = _warnings(left, samples, d_true, min_disp=0, max_disp=true_max, estimate=estimate,
                                         auto=False)
        psnr_est, warn_est = _warnings(left, samples, d_est, min_disp=estimate.min_disp,
                                       max_disp=estimate.max_disp, estimate=estimate, auto=True)
        rows.append((contains, bad_true, bad_est, estimate_seconds, t_true))
        print(f"| {name} | 0..{true_max} | {estimate.min_disp}..{estimate.max_disp} | {'yes' if contains else 'no'} "
              f"| {bad_true:.2f} | {bad_est:.2f} | {estimate_seconds:.3f} | {t_true:.2f} | "
              f"{psnr_true:.1f} / {psnr_est:.1f} | {warn_true} / {warn_est} |", flush=True)
    if not rows:
        print("auto_range.py: error: no scene found (give --middlebury / --realdev)", file=sys.stderr)
        return 3
    contains, bad_true, bad_est, est_s, dec_s = (np.array(c, float) for c in zip(*rows))
    print(f"\n{int(contains.sum())}/{len(rows)} estimated ranges contain the ground truth; mean bad % "
          f"{bad_est.mean():.2f} (estimated range) vs {bad_true.mean():.2f} (true range); estimate "
          f"{est_s.mean():.3f} s mean against {dec_s.mean():.2f} s per decode ({100 * (est_s / dec_s).mean():.0f} %).")
    if args.calibrate:
        calibrate(args, pattern)
    return 0


def calibrate(args, pattern) -> None:
    """PSNR at the samples: true range, half of it, and a mismatched pair (Middlebury)."""
    print("\n## samples_disagree calibration (PSNR at the samples, dB)\n")
    print("| scene | true range | half range | mismatched pair |")
    print("|---|---|---|---|")
    scenes = list(load_scenes(args.middlebury, Path("/nonexistent"), None))
    for index, (name, left, right, gt, _) in enumerate(scenes):
        samples = encode_image(right, pattern=pattern)
        true_max = int(math.ceil(np.nanmax(gt))) + 4
        values = []
        for max_disp in (true_max, true_max // 2):
            d, _ = _decode(left, samples, min_disp=0, max_disp=max_disp, method=args.method)
            values.append(psnr_at_samples(left, d, samples))
        # Another scene of the same size gives the samples of a wrong pair.
        other = next((s for s in scenes[index + 1:] + scenes[:index] if s[2].shape == right.shape), None)
        if other is not None:
            wrong = encode_image(other[2], pattern=pattern)
            d, _ = _decode(left, wrong, min_disp=0, max_disp=true_max, method=args.method)
            values.append(psnr_at_samples(left, d, wrong))
        cells = " | ".join(f"{v:.1f}" for v in values) + (" | -" if other is None else "")
        print(f"| {name} | {cells} |", flush=True)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--middlebury", type=Path,
                        default=Path(os.environ.get("STEREOBUDGET_MIDDLEBURY", _SHARED / "middlebury")))
    parser.add_argument("--realdev", type=Path, default=_SHARED / "realdev")
    parser.add_argument("--stride", type=int, default=5)
    parser.add_argument("--method", default="hybrid")
    parser.add_argument("--scenes", default=None, help="comma-separated scene names (default: all)")
    parser.add_argument("--calibrate", action="store_true", help="also print the samples_disagree calibration")
    args = parser.parse_args(argv)
    args.names = [s.strip() for s in args.scenes.split(",") if s.strip()] if args.scenes else None
    return args


if __name__ == "__main__":
    sys.exit(run(parse_args()))
