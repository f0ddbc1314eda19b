#!/usr/bin/env python
"""Decode time with and without ``DecoderParams(plane_refinement=True)``, next to OpenCV SGBM.

The three run alternately in one process, each scene ``--runs`` times; medians are
reported, with the planes stage's own time (``DecodeResult.timings["planes"]``) as a share
of the decode without it.  On a loaded machine compare the ratios, not the seconds.

Example
-------
    python scripts/plane_cost.py --scenes Adirondack,Kitti15_000007,teddy --stride 5
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

import stereobudget
from evaluate_real import load_pairs, sgbm
from stereobudget.decoding import DecoderParams
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default="Adirondack,Kitti15_000007,teddy")
    parser.add_argument("--stride", type=int, default=5)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args(argv)
    wanted = set(args.scenes.split(","))
    for name, _, left, right, gt, _ in load_pairs("realdev,middlebury"):
        if name not in wanted:
            continue
        max_disp = int(math.ceil(float(gt[gt > 0].max()))) + 4
        samples = encode_image(right, pattern=SamplingPattern("grid", args.stride, args.stride))
        seconds = {"sgbm": [], "off": [], "on": [], "planes": []}
        for _ in range(args.runs):
            start = time.perf_counter()
            sgbm(left, right, max_disp)
            seconds["sgbm"].append(time.perf_counter() - start)
            start = time.perf_counter()
            stereobudget.decode(left, samples, max_disp=max_disp)
            seconds["off"].append(time.perf_counter() - start)
            start = time.perf_counter()
            result = stereobudget.decode(left, samples, max_disp=max_disp,
                                         params=DecoderParams(plane_refinement=True))
            seconds["on"].append(time.perf_counter() - start)
            seconds["planes"].append(result.timings["planes"])
        m = {k: float(np.median(v)) for k, v in seconds.items()}
        print(f"{name} stride {args.stride}: decode {m['off'] / m['sgbm']:.2f}x SGBM, with planes "
              f"{m['on'] / m['sgbm']:.2f}x SGBM (ratio {m['on'] / m['off']:.3f}); planes stage {m['planes']:.3f} s "
              f"= {100 * m['planes'] / m['off']:.1f} % of the decode ({m['off']:.3f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
