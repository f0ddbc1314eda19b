#!/usr/bin/env python
"""Sweep decoder parameters: accuracy on every scene and the time of each decoder stage.

Each ``--set FIELD=V1,V2,...`` names a field of :class:`stereobudget.decoding.DecoderParams`
and the values to try; several ``--set`` options sweep their Cartesian product.  For
every combination, method and stride it prints the bad-pixel rate (> 1 px, non-occluded)
on the Middlebury scenes and on the synthetic scenes of :mod:`stereobudget.scenes`, their
mean, and the median total decode time summed over the scenes (with the stages named by
``--stages``).  ``--method full`` always decodes stride 1 (the whole right image).

    python scripts/sweep.py --set grid_cells_per_sigma_s=2,1.5,1 --set grid_cells_per_sigma_r=2,1.5,1
    python scripts/sweep.py --set right_check=tree,diagonal --methods hybrid,full --strides 3,5
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import statistics
import sys
import time

from stereobudget.encoding import encode_image
from stereobudget.decoding import DecoderParams, decode
from stereobudget.metrics import bad_pixel_rate
from middlebury import SCENES, default_data_dir, load_scene
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import SCENE_KINDS, make_scene


def _parse_set(text: str):
    name, _, values = text.partition("=")
    fields = {f.name: f for f in dataclasses.fields(DecoderParams)}
    if name not in fields or not values:
        raise SystemExit(f"sweep.py: error: --set wants FIELD=V1,V2 with FIELD one of {', '.join(fields)}")
    kind = type(getattr(DecoderParams(), name))
    convert = kind if kind in (int, float, str) else float
    return name, [convert(v) for v in values.split(",")]


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=None, help="Middlebury folder (default: ../shared/data/middlebury)")
    parser.add_argument("--set", action="append", default=[], dest="sets", metavar="FIELD=V1,V2",
                        help="a DecoderParams field and its values (repeatable)")
    parser.add_argument("--strides", default="5", help="comma-separated grid strides")
    parser.add_argument("--methods", default="sparse,hybrid")
    parser.add_argument("--repeats", type=int, default=3, help="decodes per point (median time)")
    parser.add_argument("--stages", default="jbf_fill", help="comma-separated stage times to print")
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
    sweeps = [_parse_set(text) for text in args.sets]
    names = [name for name, _ in sweeps]
    stages = [s for s in args.stages.split(",") if s]
    all_scenes = scenes(data_dir, not args.no_synthetic)
    scene_names = [s[0] for s in all_scenes]
    print(f"| method | stride | {' | '.join(names) or 'params'} | {' | '.join(scene_names)} | mean | total s | "
          + "".join(f"{s} s | " for s in stages))
    print("|---|---:|" + "---|" * max(len(names), 1) + "---:|" * (len(scene_names) + 2 + len(stages)))
    for method in args.methods.split(","):
        strides = [1] if method == "full" else [int(s) for s in args.strides.split(",")]
        for stride in strides:
            for values in itertools.product(*(v for _, v in sweeps)):
                params = dataclasses.replace(DecoderParams(), **dict(zip(names, values)))
                bads, total, stage_sums = [], 0.0, dict.fromkeys(stages, 0.0)
                for name, left, right, max_disp, gt, mask in all_scenes:
                    samples = encode_image(right, pattern=SamplingPattern("grid", stride, stride))
                    times, stage_times = [], {s: [] for s in stages}
                    for _ in range(args.repeats):
                        start = time.perf_counter()
                        result = decode(left, samples, max_disp=max_disp, method=method, params=params)
                        times.append(time.perf_counter() - start)
                        for s in stages:
                            stage_times[s].append(result.timings.get(s, 0.0))
                    total += statistics.median(times)
                    for s in stages:
                        stage_sums[s] += statistics.median(stage_times[s])
                    bads.append(bad_pixel_rate(result.disparity, gt, mask))
                label = " | ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in values) or "defaults"
                cells = " | ".join(f"{b:.2f}" for b in bads)
                print(f"| {method} | {stride} | {label} | {cells} | {statistics.mean(bads):.2f} | {total:.3f} | "
                      + "".join(f"{stage_sums[s]:.3f} | " for s in stages), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
