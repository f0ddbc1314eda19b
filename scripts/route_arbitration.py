#!/usr/bin/env python
"""Hybrid's semi-global and tree routes, and the samples choosing between them per segment of I1.

Both routes decode the same grid; I1 is cut into segments
(:func:`stereobudget.aggregate.segment_image`) and each segment keeps the route whose
disparities put I1 closer to the samples, I1 interpolated where ``x - d(x)`` crosses a
sample's column (the measure :func:`stereobudget.aggregate.plane_refinement` arbitrates
with).  Bad pixels (> 1 px) per scene and the means of both sets; the arbitrated map costs
both decodes.

Example
-------
    python scripts/route_arbitration.py --stride 5
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

import stereobudget
from evaluate_real import bad_percent, load_pairs
from stereobudget.aggregate import segment_image
from stereobudget.aggregate._planes import _crossing_errors, _lattice_gray
from stereobudget.cost import to_gray
from stereobudget.decoding import DecoderParams
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern


def sample_errors(disparity, gray, labels, samples):
    """(summed error, crossings) per segment of ``disparity`` against the samples."""
    lattice, oy, ox, sy, sx = _lattice_gray(samples)
    n = int(labels.max()) + 1
    err, hits = np.zeros(n), np.zeros(n, np.int64)
    _crossing_errors(np.nan_to_num(disparity).astype(np.float32), gray.astype(np.float64), labels, lattice,
                     oy, ox, sy, sx, err, hits)
    return err, hits


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stride", type=int, default=5)
    parser.add_argument("--segment-size", type=int, default=12)
    parser.add_argument("--scenes", default=None, help="comma-separated subset")
    args = parser.parse_args(argv)
    wanted = set(args.scenes.split(",")) if args.scenes else None
    rows = []
    for name, group, left, right, gt, mask in load_pairs("realdev,middlebury"):
        if wanted and name not in wanted:
            continue
        max_disp = int(math.ceil(float(gt[gt > 0].max()))) + 4
        samples = encode_image(right, pattern=SamplingPattern("grid", args.stride, args.stride))
        semiglobal = stereobudget.decode(left, samples, max_disp=max_disp).disparity
        tree = stereobudget.decode(left, samples, max_disp=max_disp,
                                   params=DecoderParams(hybrid_aggregation="tree")).disparity
        gray = to_gray(left.astype(np.float32))
        labels = segment_image(gray, size=args.segment_size)
        err_s, hits_s = sample_errors(semiglobal, gray, labels, samples)
        err_t, hits_t = sample_errors(tree, gray, labels, samples)
        take_tree = (hits_s > 0) & (hits_t > 0) & (err_t * hits_s < err_s * hits_t)
        chosen = np.where(take_tree[labels], tree, semiglobal)
        row = (name, group, *(bad_percent(d, gt, mask) for d in (semiglobal, tree, chosen)))
        if not rows:
            print("| scene | semi-global | tree | samples choose |\n|---|---:|---:|---:|")
        print(f"| {name} | {row[2]:.2f} | {row[3]:.2f} | {row[4]:.2f} |", flush=True)
        rows.append(row)
    for group in ("realdev", "middlebury"):
        if not any(r[1] == group for r in rows):
            continue
        means = np.mean([r[2:] for r in rows if r[1] == group], axis=0)
        print(f"| **mean {group}** | " + " | ".join(f"**{m:.2f}**" for m in means) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
