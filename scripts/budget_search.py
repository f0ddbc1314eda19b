#!/usr/bin/env python
"""The camera's CPU per frame under a byte budget, against AVIF of the whole frame at the same bytes.

For every scene of ``../shared/data/realdev`` and the paper's four Middlebury scenes, at
the budget of a raw stride-5 file (4 % of the raw RGB right image + the 80-byte header),
seven rounds alternate, in one process and one thread for the codecs:

* ``fixed``  -- coding the frame with the setting ``--size`` chose (a camera configured once);
* ``search`` -- the whole ``--size`` search (``fit_budget``);
* ``stream`` -- the search started at the previous frame's choice, as a frame stream does
  (here the previous frame is the same image: a static scene, the search's best case);
* ``AVIF``   -- AVIF (speed 6) of the whole frame at the quality that fits the budget.

Printed: per scene the median process CPU ms of each, and the median over the scenes of each
one's ratio to AVIF.

    cd scripts && python budget_search.py
"""

from __future__ import annotations

import sys
import time

import numpy as np

from evaluate_real import SHARED, _codec, best_quality_under, load_pairs
from stereobudget.io import HEADER_SIZE_V1_0, write_samples
from stereobudget.encoding import encode_image, fit_budget
from stereobudget.sampling import SamplingPattern

ROUNDS = 7


def cpu_ms(func):
    start = time.process_time()
    func()
    return 1000.0 * (time.process_time() - start)


def main(argv=None):
    if not (SHARED / "realdev").is_dir():
        print(f"no real scenes at {SHARED}; nothing to measure", file=sys.stderr)
        return 2
    import cv2
    cv2.setNumThreads(1)
    print("| scene | fixed ms | search ms | stream ms | AVIF ms | stride, codec, bits |")
    print("|---|---:|---:|---:|---:|---|")
    ratios = {"fixed": [], "search": [], "stream": []}
    for name, group, left, right, gt, mask in load_pairs("realdev,middlebury"):
        budget = int(round(0.04 * right.size)) + HEADER_SIZE_V1_0
        sample_set, _, coding = fit_budget(right, budget=budget)
        stride = sample_set.pattern.stride_x
        pattern = SamplingPattern(kind="grid", stride_x=stride, stride_y=stride)
        hint = {"stride": stride, "coding": coding}
        _, quality = best_quality_under("AVIF", right, budget)
        encode, _ = _codec("AVIF")
        runs = {
            "fixed": lambda: write_samples(encode_image(right, pattern=pattern), **coding),
            "search": lambda: fit_budget(right, budget=budget),
            "stream": lambda: fit_budget(right, budget=budget, hint=hint),
            "AVIF": lambda: encode(right, quality),
        }
        times = {key: [] for key in runs}
        for _ in range(ROUNDS):
            for key, run in runs.items():
                times[key].append(cpu_ms(run))
        medians = {key: float(np.median(values)) for key, values in times.items()}
        for key in ratios:
            ratios[key].append(medians[key] / medians["AVIF"])
        print(f"| {name} | {medians['fixed']:.1f} | {medians['search']:.1f} | {medians['stream']:.1f} | "
              f"{medians['AVIF']:.1f} | {stride}, {coding['codec']}, {coding['value_bits']} |", flush=True)
    print()
    for key, values in ratios.items():
        print(f"{key}: median {np.median(values):.3f} of AVIF's CPU (1/{1 / np.median(values):.1f}), "
              f"worst scene {max(values):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
