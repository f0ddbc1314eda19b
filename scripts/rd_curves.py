#!/usr/bin/env python
"""Rate-distortion curves: depth and recovered-image quality against bytes, ours next to whole-image codecs.

For every scene of ``../shared/data/realdev`` and the paper's four Middlebury scenes, and
for each budget of 1, 2, 4, 6, 8, 11 and 15 % of the raw RGB right image (0.24 ... 3.6
bits per pixel) plus the sample file's header (so 4 % is exactly a raw stride-5 file), the right camera's data is made to fit the budget in these ways:

* ``raw``, ``lossless``, ``jxl`` -- a sample file from :func:`stereobudget.encoding.fit_budget`
  (the densest grid whose raw / lossless-or-raw / JPEG XL-coded file fits, what
  ``sb-encode --size`` writes), decoded with the default Hybrid decoder; the recovered
  right image is :func:`stereobudget.synthesis.recover_right` of that disparity;
* ``AVIF``, ``WebP``, ``JXL`` -- the whole right image at the highest quality within the
  budget (``evaluate_real.best_quality_under``), then OpenCV SGBM (``+SGBM``) and our
  full-pair decoder (``+ours``) on the decoded image; its "recovered right image" is the
  decoded image itself.

Each row records the bytes, bad pixels (error > 1 px, %, scored as in
``evaluate_real.py``), the PSNR of the right image the host ends with against the true
one, and the camera's cost: process CPU time of coding one frame with the chosen setting
(``encode_ms``; for ours also ``fit_ms``, the budget search) and the pixels it reads.

Results go to a JSON cache (one entry per scene, budget and row) so that runs resume and
can be split across processes with ``--shard``; ``--report`` prints the mean curves as a
table and draws them (matplotlib) without decoding anything.

    python scripts/rd_curves.py --cache /tmp/rd0.json --shard 0/2 &
    python scripts/rd_curves.py --cache /tmp/rd1.json --shard 1/2
    python scripts/rd_curves.py --report /tmp/rd0.json /tmp/rd1.json --plot docs/results
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

import stereobudget
from evaluate_real import SHARED, _codec, bad_percent, best_quality_under, load_pairs, sgbm
from stereobudget.io import HEADER_SIZE_V1_0, read_samples, write_samples
from stereobudget.encoding import encode_image, fit_budget
from stereobudget.metrics import psnr
from stereobudget.sampling import SamplingPattern
from stereobudget.synthesis import recover_right

BUDGETS = (0.01, 0.02, 0.04, 0.06, 0.08, 0.11, 0.15)
OURS = {"raw": "raw", "lossless": None, "jxl": "jxl"}
CODECS = ("AVIF", "WebP", "JXL")


def cpu_ms(func):
    """(result, process CPU time of one call in ms)."""
    start = time.process_time()
    result = func()
    return result, 1000.0 * (time.process_time() - start)


def ours_row(left, right, gt, mask, max_disp, budget, label):
    codec = OURS[label]
    (_, data, coding), fit_ms = cpu_ms(lambda: fit_budget(right, budget=budget, codec=codec))
    samples = read_samples(data)
    stride = samples.pattern.stride_x
    # The camera of a fixed setting codes its frame without the search.
    pattern = SamplingPattern(kind="grid", stride_x=stride, stride_y=stride)
    _, encode_ms = cpu_ms(lambda: write_samples(encode_image(right, pattern=pattern), **coding))
    disparity = stereobudget.decode(left, samples, max_disp=max_disp, method="hybrid").disparity
    recovered = recover_right(left, disparity, samples).image
    return {"bytes": len(data), "stride": stride, "codec": coding["codec"], "value_bits": coding["value_bits"],
            "quality": coding["quality"], "bad": bad_percent(disparity, gt, mask),
            "psnr": psnr(recovered, right), "encode_ms": encode_ms, "fit_ms": fit_ms,
            "pixels_read": int(len(samples.values))}


def codec_row(left, right, gt, mask, max_disp, budget, codec):
    data, quality = best_quality_under(codec, right, budget)
    encode, decode = _codec(codec)
    _, encode_ms = cpu_ms(lambda: encode(right, quality))
    coded = decode(data)
    full = encode_image(coded, pattern=SamplingPattern(kind="grid", stride_x=1, stride_y=1))
    ours_full = stereobudget.decode(left, full, max_disp=max_disp).disparity
    return {"bytes": len(data), "quality": quality, "bad_sgbm": bad_percent(sgbm(left, coded, max_disp), gt, mask),
            "bad_ours": bad_percent(ours_full, gt, mask), "psnr": psnr(coded, right), "encode_ms": encode_ms,
            "pixels_read": int(right.shape[0] * right.shape[1])}


def measure(cache_path, shard, count):
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    pairs = load_pairs("realdev,middlebury")
    for index, (name, group, left, right, gt, mask) in enumerate(pairs):
        if index % count != shard:
            continue
        max_disp = int(math.ceil(float(gt[gt > 0].max()))) + 4
        raw_rgb = right.shape[0] * right.shape[1] * 3
        for fraction in BUDGETS:
            # The header rides on top, so that 1/s^2 is exactly a raw stride-s file.
            budget = int(round(fraction * raw_rgb)) + HEADER_SIZE_V1_0
            for label in (*OURS, *CODECS):
                key = f"{name}|{fraction}|{label}"
                if key in cache:
                    continue
                start = time.perf_counter()
                if label in OURS:
                    row = ours_row(left, right, gt, mask, max_disp, budget, label)
                else:
                    row = codec_row(left, right, gt, mask, max_disp, budget, label)
                row.update(scene=name, group=group, fraction=fraction, budget=budget, row=label,
                           pixels=int(right.shape[0] * right.shape[1]))
                cache[key] = row
                cache_path.write_text(json.dumps(cache, indent=1))
                print(f"{name} {fraction:.2f} {label}: {row.get('bad', row.get('bad_sgbm')):.2f} "
                      f"({time.perf_counter() - start:.1f} s)", file=sys.stderr, flush=True)


def mean_psnr(values):
    """PSNR (dB) of the scenes' mean squared error: a scene recovered exactly (inf) counts as zero error."""
    errors = [0.0 if math.isinf(v) else 10.0 ** (-v / 10.0) for v in values]
    mean = float(np.mean(errors))
    return float("inf") if mean == 0.0 else -10.0 * math.log10(mean)


def curves(rows, group):
    """{series: [(budget fraction, mean bad %, mean PSNR dB, mean bits/pixel, scenes)]} of one set."""
    series = {}
    for label, bad_key, name in ([(k, "bad", f"ours {k} (Hybrid)") for k in OURS]
                                 + [(c, "bad_sgbm", f"{c}+SGBM") for c in CODECS]
                                 + [(c, "bad_ours", f"{c}+ours full") for c in CODECS]):
        points = []
        for fraction in BUDGETS:
            members = [r for r in rows if r["group"] == group and r["row"] == label and r["fraction"] == fraction]
            if members:
                points.append((fraction, float(np.mean([r[bad_key] for r in members])),
                               mean_psnr([r["psnr"] for r in members]),
                               float(np.mean([8.0 * r["bytes"] / r["pixels"] for r in members])), len(members)))
        series[name] = points
    return series


def camera_costs(rows, group):
    """{row: (median encode ms, median pixels read as % of the frame)} at the 4 % budget."""
    out = {}
    for label in (*OURS, *CODECS):
        members = [r for r in rows if r["group"] == group and r["row"] == label and r["fraction"] == 0.04]
        if members:
            out[label] = (float(np.median([r["encode_ms"] for r in members])),
                          float(np.median([100.0 * r["pixels_read"] / r["pixels"] for r in members])),
                          float(np.median([r.get("fit_ms", float("nan")) for r in members])))
    return out


def report(paths, plot_dir):
    rows = []
    for path in paths:
        rows += json.loads(Path(path).read_text()).values()
    for group in ("realdev", "middlebury"):
        series = curves(rows, group)
        if not any(series.values()):
            continue
        scenes = max(p[4] for points in series.values() for p in points)
        print(f"\n### {group}: mean bad pixels % (> 1 px) / PSNR of the mean squared error of the right image (dB), "
              f"{scenes} scenes\n")
        print("| budget (% of raw RGB) | " + " | ".join(f"{100 * f:g} %" for f in BUDGETS) + " |")
        print("|---|" + "---:|" * len(BUDGETS))
        for name, points in series.items():
            cells = {p[0]: f"{p[1]:.2f} / {p[2]:.1f}" for p in points}
            print(f"| {name} | " + " | ".join(cells.get(f, "") for f in BUDGETS) + " |")
        print(f"\nCamera side at the 4 % budget ({group}, medians): encoder CPU ms per frame, pixels read")
        for label, (ms, read, fit) in camera_costs(rows, group).items():
            extra = f", budget search {fit:.1f} ms" if not math.isnan(fit) else ""
            print(f"- {label}: {ms:.1f} ms, {read:.1f} % of the pixels{extra}")
        if plot_dir:
            draw(series, group, scenes, Path(plot_dir) / f"rd_{group}.png")


def draw(series, group, scenes, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"raw": "tab:blue", "lossless": "tab:cyan", "jxl": "tab:purple",
               "AVIF": "tab:red", "WebP": "tab:orange", "JXL": "tab:green"}
    figure, (depth, image) = plt.subplots(1, 2, figsize=(12, 4.6))
    for name, points in series.items():
        if not points:
            continue
        key = name.split()[1] if name.startswith("ours") else name.split("+")[0]
        style = "-" if name.startswith("ours") else ("--" if name.endswith("SGBM") else ":")
        x = [100 * p[0] for p in points]
        depth.plot(x, [p[1] for p in points], style, marker="o", color=colours[key], label=name)
        if not name.endswith("ours full"):   # the image the host holds does not depend on the matcher
            label = name.replace(" (Hybrid)", " (recovered)").replace("+SGBM", " (decoded)")
            image.plot(x, [p[2] for p in points], style, marker="o", color=colours[key], label=label)
    depth.set(xlabel="bytes, % of the raw RGB right image", ylabel="bad pixels > 1 px, % (mean)",
              title=f"Depth, {group} ({scenes} scenes)")
    image.set(xlabel="bytes, % of the raw RGB right image", ylabel="PSNR of the right image, dB (of the mean MSE)",
              title=f"Right image, {group}")
    for axes in (depth, image):
        axes.grid(alpha=0.3)
        axes.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    print(f"\nwrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", type=Path, default=Path("rd_curves.json"))
    parser.add_argument("--shard", default="0/1", help="i/n: measure every n-th scene from the i-th")
    parser.add_argument("--report", nargs="+", default=None, help="caches to summarise (no measuring)")
    parser.add_argument("--plot", default=None, help="folder for rd_<set>.png (with --report)")
    args = parser.parse_args(argv)
    if args.report:
        report(args.report, args.plot)
        return 0
    if not (SHARED / "realdev").is_dir():
        print(f"no real scenes at {SHARED}; nothing to measure", file=sys.stderr)
        return 2
    shard, count = (int(v) for v in args.shard.split("/"))
    measure(args.cache, shard, count)
    return 0


if __name__ == "__main__":
    sys.exit(main())
