#!/usr/bin/env python
"""Sweep the bilateral-grid resolution of the Sparse fill: accuracy and fill time.

The fill (paper Eq. 3 on a bilateral grid) costs in proportion to the number of grid
cells, i.e. to ``cells_per_sigma_s**2 * cells_per_sigma_r``; the slice is per pixel and
layer whatever the grid.  For every resolution this prints the bad-pixel rate (> 1 px,
non-occluded) of Sparse and Hybrid on the Middlebury scenes and on the synthetic scenes
of :mod:`stereobudget.scenes`, at each stride asked for, and the median fill time on
each scene.

    python scripts/sweep_grid.py --data ../shared/data/middlebury --strides 3,5,8
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time

from stereobudget.container import encode_image
from stereobudget.decoders import DecoderParams, decode
from stereobudget.metrics import bad_pixel_rate
from stereobudget.middlebury import SCENES, default_data_dir, load_scene
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import SCENE_KINDS, make_scene

DEFAULT_RESOLUTIONS = "2:2,1.5:1.5,1.5:1,1:1.5,1:1"


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=None, help="Middlebury folder (default: ../shared/data/middlebury)")
    parser.add_argument("--strides", default="5", help="comma-separated grid strides")
    parser.add_argument("--methods", default="sparse,hybrid")
    parser.add_argument("--resolutions", default=DEFAULT_RESOLUTIONS,
                        help="comma-separated cells_per_sigma_s:cells_per_sigma_r pairs")
    parser.add_argument("--repeats", type=int, default=3, help="decodes per point (median fill time)")
    parser.add_argument("--no-synthetic", action="store_true")
    return parser.parse_args(argv)


def scenes(data_dir, with_synthetic: bool):
    """(name, left, right, max_disp, ground truth, scored mask) of every scene."""
    out = []
    for name in SCENES:
        try:
            scene = load_scene(data_dir, name)
        except Exception as exc:    # noqa: BLE001 - a missing scene is reported, not fatal
            print(f"  skipping {name}: {exc}", file=sys.stderr)
            continue
        out.append((name, scene.left, scene.right, scene.max_disp, scene.gt, scene.masks["nonocc"]))
    if with_synthetic:
        for kind in SCENE_KINDS:
            scene = make_scene(kind, seed=0)
            out.append((kind, scene.left, scene.right, scene.max_disp, scene.disparity, scene.nonocc))
    return out


def main(argv=None) -> int:
    args = parse_args(argv)
    data_dir = args.data or default_data_dir()
    resolutions = [tuple(float(v) for v in item.split(":")) for item in args.resolutions.split(",")]
    strides = [int(s) for s in args.strides.split(",")]
    methods = args.methods.split(",")
    all_scenes = scenes(data_dir, not args.no_synthetic)
    names = [s[0] for s in all_scenes]
    print(f"| method | stride | cells/σ (s:r) | {' | '.join(names)} | mean | fill s (median, sum over scenes) |")
    print("|---|---:|---|" + "---:|" * (len(names) + 2))
    for method in methods:
        for stride in strides:
            for cs, cr in resolutions:
                params = dataclasses.replace(DecoderParams(), grid_cells_per_sigma_s=cs, grid_cells_per_sigma_r=cr)
                bads, fill = [], 0.0
                for name, left, right, max_disp, gt, mask in all_scenes:
                    samples = encode_image(right, pattern=SamplingPattern("grid", stride, stride))
                    times = []
                    for _ in range(args.repeats):
                        result = decode(left, samples, max_disp=max_disp, method=method, params=params)
                        times.append(result.timings.get("jbf_fill", 0.0))
                    fill += statistics.median(times)
                    bads.append(bad_pixel_rate(result.disparity, gt, mask))
                cells = " | ".join(f"{b:.2f}" for b in bads)
                print(f"| {method} | {stride} | {cs:g}:{cr:g} | {cells} | {statistics.mean(bads):.2f} | {fill:.3f} |",
                      flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
