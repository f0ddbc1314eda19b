#!/usr/bin/env python
"""Time each decoder route on Teddy against OpenCV SGBM 3WAY, alternating, in one process.

Every round decodes once with each route (after a warm-up) and runs SGBM on the full
pair between them, so a drift of the machine's speed falls on all alike; the table gives
the median over ``--repeats`` rounds and each route's ratio to SGBM's median.

    python scripts/route_times.py --repeats 7
    python scripts/route_times.py --repeats 7 --routes hybrid --decoder plain   # each decode alone

``--decoder shared`` (the default) decodes through one open
:class:`stereobudget.decoding.Decoder`, as ``sb-decode`` and the batch runners do: each
decode takes over the previous one's volumes, and glibc keeps freed blocks mapped.
``--decoder plain`` calls :func:`stereobudget.decode`, which keeps nothing between calls
and leaves the allocator alone.  The allocator setting lasts for the process, so the two
are compared in separate runs (their ratios to SGBM carry the comparison).
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import time

import cv2

import stereobudget
from middlebury import default_data_dir, load_scene
from stereobudget.decoding import DecoderParams
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern

ROUTES = {
    "sparse @5": ("sparse", 5, {}),
    "hybrid @5 (default: census, semi-global)": ("hybrid", 5, {}),
    "hybrid @5, hybrid_aggregation='tree'": ("hybrid", 5, {"hybrid_aggregation": "tree"}),
    "full (default: census, semi-global)": ("full", 1, {}),
    "full, full_cost='ad' (tree)": ("full", 1, {"full_cost": "ad"}),
}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--routes", default="", help="time only the routes whose name contains this text")
    parser.add_argument("--decoder", choices=("shared", "plain"), default="shared",
                        help="decode through one open Decoder (default) or by plain decode() calls")
    args = parser.parse_args(argv)
    scene = load_scene(default_data_dir(), "teddy")
    left, right = scene.left, scene.right
    max_disp = 60
    matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=64, blockSize=5, P1=8 * 3 * 25,
                                    P2=32 * 3 * 25, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    left_bgr, right_bgr = cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR)
    jobs = {}
    for name, (method, stride, changes) in ROUTES.items():
        if args.routes not in name:
            continue
        samples = encode_image(right, pattern=SamplingPattern("grid", stride, stride))
        jobs[name] = (samples, None if method == "full" else method, DecoderParams(**changes))
    times = {name: [] for name in ["SGBM 3WAY, full pair"] + list(jobs)}

    def sgbm():
        start = time.perf_counter()
        matcher.compute(left_bgr, right_bgr)
        return time.perf_counter() - start

    with contextlib.ExitStack() as stack:
        decode = stereobudget.decode
        if args.decoder == "shared":
            decode = stack.enter_context(stereobudget.Decoder()).decode
        for name, (samples, method, params) in jobs.items():       # warm-up: compile, fill caches
            decode(left, samples, max_disp=max_disp, method=method, params=params)
        sgbm()
        for _ in range(args.repeats):
            for name, (samples, method, params) in jobs.items():
                times["SGBM 3WAY, full pair"].append(sgbm())
                start = time.perf_counter()
                decode(left, samples, max_disp=max_disp, method=method, params=params)
                times[name].append(time.perf_counter() - start)
    reference = statistics.median(times["SGBM 3WAY, full pair"])
    print(f"Teddy 450x375, disparities 0-{max_disp}, median of {args.repeats} alternating rounds, "
          f"decoder {args.decoder}\n")
    print("| route | wall s | vs SGBM |\n|---|---:|---:|")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"| {name} | {median:.3f} | {median / reference:.1f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
