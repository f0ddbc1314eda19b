#!/usr/bin/env python
"""How many low bits ``sb-encode --size`` may drop for a denser grid: a sweep over every scene.

For budgets of 2, 4, 8 and 11 % of the raw RGB right image (+ the 80-byte header), each
value depth from 8 down to 4 bits is fitted on its own (``fit_budget(value_bits=b)``: the
densest grid whose lossless lattice of b-bit values fits) and decoded with the default
Hybrid.  A rule "drop up to k bits" takes the densest of those grids for b >= 8 - k and, at
that grid, the most bits that fit (stride 1 only with all 8, as ``fit_budget`` does); its
mean bad pixels (> 1 px, %) per set is printed for k = 0 ... 4.

    cd scripts && python budget_bits.py --cache /tmp/bits.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

import stereobudget
from evaluate_real import SHARED, bad_percent, load_pairs
from stereobudget.io import HEADER_SIZE_V1_0, read_samples
from stereobudget.encoding import fit_budget

BUDGETS = (0.02, 0.04, 0.08, 0.11)
BITS = (8, 7, 6, 5, 4)


def measure(cache_path):
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    for name, group, left, right, gt, mask in load_pairs("realdev,middlebury"):
        max_disp = int(math.ceil(float(gt[gt > 0].max()))) + 4
        for fraction in BUDGETS:
            budget = int(round(fraction * right.size)) + HEADER_SIZE_V1_0
            for bits in BITS:
                key = f"{name}|{fraction}|{bits}"
                if key in cache:
                    continue
                _, data, coding = fit_budget(right, budget=budget, codec="lossless", value_bits=bits)
                samples = read_samples(data)
                disparity = stereobudget.decode(left, samples, max_disp=max_disp, method="hybrid").disparity
                cache[key] = {"group": group, "stride": samples.pattern.stride_x, "codec": coding["codec"],
                              "bits": bits, "bytes": len(data), "bad": bad_percent(disparity, gt, mask)}
                cache_path.write_text(json.dumps(cache, indent=1))
                print(f"{name} {fraction} {bits} bits: stride {cache[key]['stride']}, {cache[key]['bad']:.2f}",
                      file=sys.stderr, flush=True)
    return cache


def rule(results, drop):
    """The row a "drop up to ``drop`` bits" search keeps among one scene's fixed-bit rows."""
    # As fit_budget: stride 1 (the full pair) only with every bit.
    allowed = [results[b] for b in BITS if b >= 8 - drop and (b == 8 or results[b]["stride"] > 1)]
    densest = min(r["stride"] for r in allowed)
    return max((r for r in allowed if r["stride"] == densest), key=lambda r: r["bits"])


def report(cache):
    scenes = sorted({k.split("|")[0] for k in cache})
    print("| set | budget | " + " | ".join(f"drop <= {k}" for k in range(len(BITS))) + " |")
    print("|---|---|" + "---:|" * len(BITS))
    for group in ("realdev", "middlebury"):
        for fraction in BUDGETS:
            means = []
            for drop in range(len(BITS)):
                bads = []
                for scene in scenes:
                    rows = {b: cache.get(f"{scene}|{fraction}|{b}") for b in BITS}
                    if all(rows.values()) and rows[8]["group"] == group:
                        bads.append(rule(rows, drop)["bad"])
                means.append(np.mean(bads) if bads else float("nan"))
            print(f"| {group} | {100 * fraction:g} % | " + " | ".join(f"{m:.2f}" for m in means) + " |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", type=Path, default=Path("budget_bits.json"))
    args = parser.parse_args(argv)
    if not (SHARED / "realdev").is_dir():
        print(f"no real scenes at {SHARED}; nothing to measure", file=sys.stderr)
        return 2
    report(measure(args.cache))
    return 0


if __name__ == "__main__":
    sys.exit(main())
