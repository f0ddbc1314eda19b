#!/usr/bin/env python
"""Raw Bayer samples against RGB samples at equal bytes, on the four Middlebury scenes.

The right image is mosaicked (each pixel keeps the colour of its place in the chosen
Bayer pattern, as a raw sensor frame would) and sampled on a grid: a Bayer sample costs
1 byte, an RGB sample 3, so Bayer at stride ``s`` costs about what RGB at stride
``s * sqrt(3)`` does (3 vs 5, 5 vs 9, 7 vs 12).  Each sample file is decoded with the
given method (default Hybrid, the default decoder) and scored as bad pixels > 1 px on
the nonocc mask; ``psnr`` is the recovered right image Î2 against the true one.

    python scripts/bayer_vs_rgb.py --data ../shared/data/middlebury
    python scripts/bayer_vs_rgb.py --configs bayer:3,rgb:3,rgb:5 --method sparse
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from middlebury import SCENES, default_data_dir, load_scene
from stereobudget.decoding import decode
from stereobudget.io import write_samples
from stereobudget.encoding import encode_image
from stereobudget.io._mosaic import mosaic_image
from stereobudget.metrics import bad_pixel_rate, psnr
from stereobudget.sampling import SamplingPattern
from stereobudget.synthesis import recover_right

DEFAULT_CONFIGS = "rgb:3,bayer:3,rgb:5,bayer:5,rgb:9,bayer:7,rgb:12"


def sample_set(right: np.ndarray, kind: str, stride: int, pattern: str):
    grid = SamplingPattern("grid", stride, stride)
    if kind == "rgb":
        return encode_image(right, pattern=grid)
    return encode_image(mosaic_image(right, pattern), pattern=grid, channel_order=f"bayer_{pattern}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=None, help="Middlebury folder (default: ../shared/data/middlebury)")
    parser.add_argument("--configs", default=DEFAULT_CONFIGS, help="comma-separated KIND:STRIDE, KIND rgb or bayer")
    parser.add_argument("--method", default="hybrid")
    parser.add_argument("--bayer-pattern", default="rggb", choices=("rggb", "bggr", "grbg", "gbrg"))
    parser.add_argument("--no-psnr", action="store_true", help="skip the recovery of Î2")
    args = parser.parse_args(argv)
    data_dir = args.data or default_data_dir()
    configs = [(kind, int(stride)) for kind, stride in (c.split(":") for c in args.configs.split(","))]
    scenes = [load_scene(data_dir, name) for name in SCENES]
    print(f"method {args.method}, Bayer pattern {args.bayer_pattern}; bad > 1 px nonocc (%), "
          "bytes per pixel = file size / (W H), PSNR of Î2 (dB, all pixels)")
    head = "| samples | bytes/px | " + " | ".join(s.name for s in scenes) + " | mean | PSNR Î2 |"
    print(head)
    print("|---|---:|" + "---:|" * (len(scenes) + 2))
    for kind, stride in configs:
        bads, sizes, psnrs = [], [], []
        for scene in scenes:
            ss = sample_set(scene.right, kind, stride, args.bayer_pattern)
            h, w = scene.left.shape[:2]
            sizes.append(len(write_samples(ss)) / float(h * w))
            result = decode(scene.left, ss, max_disp=scene.max_disp, method=args.method)
            bads.append(bad_pixel_rate(result.disparity, scene.gt, scene.masks["nonocc"]))
            if not args.no_psnr:
                psnrs.append(psnr(recover_right(scene.left, result.disparity, ss).image, scene.right))
        label = f"{kind} stride {stride}"
        cells = " | ".join(f"{b:.2f}" for b in bads)
        psnr_cell = f"{np.mean(psnrs):.2f}" if psnrs else "-"
        print(f"| {label} | {np.mean(sizes):.4f} | {cells} | {np.mean(bads):.2f} | {psnr_cell} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
