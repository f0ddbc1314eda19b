"""Depth per byte: Hybrid decodes of coded sample files next to AVIF of the whole right image + SGBM.

For each Middlebury scene the budget is the size of today's raw stride-5 sample file.
Rows, each with its file bytes, bits per image pixel, bad-pixel % (error > 1, nonocc)
and the camera's encoder CPU time (the fastest of three runs, one thread):

* ``raw s5`` -- the budget itself; ``raw s3``, ``lossless s4`` (8 and 7 bits), ``jxl s3
  q90`` -- denser grids at their own bytes;
* ``size`` -- ``sb-encode --size BUDGET`` (raw, or lossless keeping 8 to 5 bits: the
  densest that fits);
* ``size jxl`` -- ``sb-encode --size BUDGET --codec jxl`` (lossy allowed);
* ``AVIF+SGBM`` -- AVIF (speed 6) of the whole right image at the highest quality
  within the budget, decoded, then OpenCV SGBM 3WAY on the full pair.

    python scripts/rate_distortion.py --scenes teddy,cones
    python scripts/rate_distortion.py --scenes "" --realdev Art,Adirondack

Decodes are the library's Hybrid (``stereobudget.decode``); the first one compiles the
numba kernels (minutes), so its time is not reported.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

import stereobudget
from stereobudget.io import read_samples, write_samples
from stereobudget.encoding import encode_image, fit_budget
from stereobudget.metrics import bad_pixel_rate
from stereobudget.sampling import SamplingPattern

from middlebury import load_scene

REPEATS = 3
REALDEV = Path(__file__).resolve().parents[2] / "shared" / "data" / "realdev"


@dataclass
class RealScene:
    """A realdev scene in the shape :func:`evaluate` reads (nonocc = the occlusion mask, else valid GT)."""

    name: str
    left: np.ndarray
    right: np.ndarray
    gt: np.ndarray
    masks: dict
    max_disp: int


def load_realdev(name, folder=REALDEV):
    folder = Path(folder) / name
    left = cv2.cvtColor(cv2.imread(str(folder / "left.png"), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    right = cv2.cvtColor(cv2.imread(str(folder / "right.png"), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    gt = cv2.imread(str(folder / "disp_left.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / 256
    valid = gt > 0
    gt[~valid] = np.nan
    nonocc = folder / "nonocc.png"
    mask = cv2.imread(str(nonocc), cv2.IMREAD_UNCHANGED) == 255 if nonocc.exists() else valid
    return RealScene(name=name, left=left, right=right, gt=gt, masks={"nonocc": mask},
                     max_disp=int(math.ceil(float(np.nanmax(gt)))) + 2)


def cpu_ms(func):
    """(result, fastest process CPU time of ``REPEATS`` calls in ms)."""
    best, result = float("inf"), None
    for _ in range(REPEATS):
        start = time.process_time()
        result = func()
        best = min(best, time.process_time() - start)
    return result, 1000.0 * best


def grid(stride):
    return SamplingPattern(kind="grid", stride_x=stride, stride_y=stride)


def sample_file(right, stride, **coding):
    """(file bytes, encoder CPU ms): select the samples of ``right`` and code them."""
    return cpu_ms(lambda: write_samples(encode_image(right, pattern=grid(stride)), **coding))


def budget_file(right, budget, **coding):
    return cpu_ms(lambda: fit_budget(right, budget=budget, **coding)[1])


def avif_within(right, budget):
    """(decoded image, bytes, CPU ms of the final encode, quality): best AVIF quality within ``budget``."""
    import imagecodecs

    def encode(q):
        return imagecodecs.avif_encode(right, level=q, speed=6, numthreads=1)

    lo, hi, best = 0, 100, None
    while lo <= hi:     # size grows with quality: bisect for the highest that fits
        mid = (lo + hi) // 2
        data = encode(mid)
        if len(data) <= budget:
            best, lo = (mid, data), mid + 1
        else:
            hi = mid - 1
    if best is None:
        best = (0, encode(0))
    quality, data = best
    _, ms = cpu_ms(lambda: encode(quality))
    return imagecodecs.avif_decode(data), len(data), ms, quality


def sgbm(left, right, max_disp):
    """OpenCV StereoSGBM 3WAY (block 3, P1 = 8 * 3 * 9, P2 = 32 * 3 * 9); NaN where invalid."""
    matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=-(-(max_disp + 1) // 16) * 16, blockSize=3,
                                    P1=8 * 3 * 9, P2=32 * 3 * 9, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = matcher.compute(cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR))
    disparity = raw.astype(np.float32) / 16.0
    disparity[raw < 0] = np.nan
    return disparity


def hybrid_bad(scene, data):
    samples = read_samples(data)
    result = stereobudget.decode(scene.left, samples, max_disp=scene.max_disp, method="hybrid")
    return bad_pixel_rate(result.disparity, scene.gt, scene.masks["nonocc"]), samples.pattern.stride_x


def evaluate(scene, log=print):
    right = scene.right
    pixels = right.shape[0] * right.shape[1]
    rows = []
    budget = len(write_samples(encode_image(right, pattern=grid(5))))
    files = {
        "raw s5": sample_file(right, 5),
        "raw s3": sample_file(right, 3),
        "lossless s4": sample_file(right, 4, codec="lossless"),
        "lossless s4 7 bits": sample_file(right, 4, codec="lossless", value_bits=7),
        "jxl s3 q90": sample_file(right, 3, codec="jxl", quality=90),
        "size": budget_file(right, budget),
        "size jxl": budget_file(right, budget, codec="jxl"),
    }
    for label, (data, ms) in files.items():
        bad, stride = hybrid_bad(scene, data)
        info = read_samples(data)
        rows.append({"row": label, "stride": stride, "codec": info.codec, "bytes": len(data),
                     "bpp": 8.0 * len(data) / pixels, "bad": bad, "encode_ms": ms})
        log(f"  {scene.name} {label}: {rows[-1]}")
    coded, size, ms, quality = avif_within(right, budget)
    bad = bad_pixel_rate(sgbm(scene.left, coded, scene.max_disp), scene.gt, scene.masks["nonocc"])
    rows.append({"row": "AVIF+SGBM", "stride": 1, "codec": f"avif q{quality}", "bytes": size,
                 "bpp": 8.0 * size / pixels, "bad": bad, "encode_ms": ms})
    log(f"  {scene.name} AVIF+SGBM: {rows[-1]}")
    return budget, rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default="teddy,cones", help="comma-separated Middlebury scenes")
    parser.add_argument("--data-dir", default=None, help="Middlebury folder (default: ../shared/data/middlebury)")
    parser.add_argument("--realdev", default="", help="comma-separated realdev scenes (../shared/data/realdev)")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    print("| scene | row | stride | codec | bytes | bits/pixel | bad % nonocc | encoder CPU ms |")
    print("|---|---|---:|---|---:|---:|---:|---:|")
    scenes = [(n, lambda n=n: load_scene(args.data_dir, n)) for n in args.scenes.split(",") if n]
    scenes += [(n, lambda n=n: load_realdev(n)) for n in args.realdev.split(",") if n]
    for name, load in scenes:
        scene = load()
        budget, rows = evaluate(scene, log=lambda text: print(text, file=sys.stderr))
        for r in rows:
            print(f"| {name} | {r['row']} | {r['stride']} | {r['codec']} | {r['bytes']} | {r['bpp']:.3f} | "
                  f"{r['bad']:.2f} | {r['encode_ms']:.2f} |")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
