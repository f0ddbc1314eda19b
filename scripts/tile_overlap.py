#!/usr/bin/env python
"""How much overlap tiled decoding needs: bands vs the untiled decode, per overlap.

For each Middlebury scene (at its own size and, with ``--upscale 2``, at twice that
size with twice the disparities), each method and each overlap, the frame is decoded
in bands of ``--band`` rows (``decoders.decode_tiled``) and compared with the untiled
decode: the change of the bad-pixel rate (> 1 px, non-occluded; the threshold scales
with the upscale factor) and the share of pixels whose disparity moved by > 0.5 px.

    python scripts/tile_overlap.py --data ../shared/data/middlebury --scenes teddy,cones --upscale 1,2
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from stereobudget.encoding import encode_image
from stereobudget.decoding import decode, decode_tiled
from stereobudget.metrics import bad_pixel_rate
from middlebury import default_data_dir, load_scene
from stereobudget.sampling import SamplingPattern


def _upscaled(scene, factor: int):
    import cv2
    if factor == 1:
        return scene.left, scene.right, scene.gt, scene.masks["nonocc"], scene.max_disp
    h, w = scene.left.shape[:2]
    size = (w * factor, h * factor)
    left = cv2.resize(scene.left, size, interpolation=cv2.INTER_CUBIC)
    right = cv2.resize(scene.right, size, interpolation=cv2.INTER_CUBIC)
    gt = cv2.resize(scene.gt.astype(np.float32), size, interpolation=cv2.INTER_NEAREST) * factor
    mask = cv2.resize(scene.masks["nonocc"].astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    return left, right, gt, mask, scene.max_disp * factor


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=None)
    parser.add_argument("--scenes", default="teddy,cones")
    parser.add_argument("--methods", default="sparse,hybrid")
    parser.add_argument("--upscale", default="1,2", help="comma-separated integer factors")
    parser.add_argument("--overlaps", default="0,32,64,96,128")
    parser.add_argument("--band", type=int, default=96, help="rows kept per band at upscale 1 (scaled with it)")
    parser.add_argument("--stride", type=int, default=5)
    args = parser.parse_args(argv)
    data_dir = args.data or default_data_dir()
    overlaps = [int(v) for v in args.overlaps.split(",")]
    print("| scene | method | untiled bad % | " + " | ".join(f"overlap {o}" for o in overlaps) + " |")
    print("|---|---|---:|" + "---|" * len(overlaps))
    for name in args.scenes.split(","):
        scene = load_scene(data_dir, name)
        for factor in (int(v) for v in args.upscale.split(",")):
            left, right, gt, mask, max_disp = _upscaled(scene, factor)
            samples = encode_image(right, pattern=SamplingPattern("grid", args.stride, args.stride))
            threshold = 1.0 * factor
            for method in args.methods.split(","):
                whole = decode(left, samples, max_disp=max_disp, method=method, tile_rows=0).disparity
                base = bad_pixel_rate(whole, gt, mask, threshold=threshold)
                cells = []
                for overlap in overlaps:
                    tiled = decode_tiled(left, samples, max_disp=max_disp, method=method,
                                         tile_rows=args.band * factor, overlap=overlap).disparity
                    bad = bad_pixel_rate(tiled, gt, mask, threshold=threshold)
                    moved = float(np.mean(np.abs(tiled - whole) > 0.5)) * 100
                    cells.append(f"{bad - base:+.3f} pp / {moved:.3f} %")
                label = f"{name} x{factor} ({left.shape[1]}x{left.shape[0]}, {max_disp + 1} disp.)"
                print(f"| {label} | {method} | {base:.3f} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
