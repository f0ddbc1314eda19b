#!/usr/bin/env python
"""Î2 from a ``downsample`` sample file: PSNR against the true right image per back-projection rounds.

For each Middlebury scene and block size the file's disparity is decoded (the default
method for the pattern, Downsample), and Î2 is recovered with 0, 1, 3 and 6 rounds of
block-mean back-projection (:func:`stereobudget.synthesis.recover_right_from_block_means`;
0 = warp + inpaint).  The bilinearly upsampled block means are the baseline.  PSNR in dB
over all pixels.

    python scripts/downsample_recovery.py --data ../shared/data/middlebury --blocks 3,5
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from stereobudget.encoding import encode_image
from stereobudget.cost import to_float_image
from stereobudget.decoding import decode
from stereobudget.fill import upsample_block_means
from stereobudget.metrics import psnr
from middlebury import SCENES, default_data_dir, load_scene
from stereobudget.sampling import SamplingPattern
from stereobudget.synthesis import SynthesisParams, recover_right_from_block_means


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=None)
    parser.add_argument("--blocks", default="3,5")
    parser.add_argument("--rounds", default="0,1,3,6")
    args = parser.parse_args(argv)
    data_dir = args.data or default_data_dir()
    rounds = [int(v) for v in args.rounds.split(",")]
    print("| scene | block | upsampled means | " + " | ".join(f"{r} rounds" for r in rounds) + " |")
    print("|---|---:|---:|" + "---:|" * len(rounds))
    for name in SCENES:
        scene = load_scene(data_dir, name)
        h, w = scene.left.shape[:2]
        for block in (int(v) for v in args.blocks.split(",")):
            samples = encode_image(scene.right, pattern=SamplingPattern("downsample", block, block))
            disparity = decode(scene.left, samples, max_disp=scene.max_disp).disparity
            sent = to_float_image(samples.values_rgb()[:, None, :])[:, 0, :].reshape(-(-h // block),
                                                                                 -(-w // block), -1)
            upsampled = np.clip(np.rint(upsample_block_means(sent, block, block, h, w)), 0, 255).astype(np.uint8)
            recovered = [recover_right_from_block_means(scene.left, disparity, samples,
                                                        params=SynthesisParams(block_mean_iterations=r)).image
                         for r in rounds]
            cells = [f"{psnr(image, scene.right):.2f}" for image in recovered]
            print(f"| {name} | {block} | {psnr(upsampled, scene.right):.2f} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
