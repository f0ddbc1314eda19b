#!/usr/bin/env python
"""Real-scene evaluation: our decoders next to OpenCV SGBM and codecs at the same bytes.

Every scene of ``../shared/data/realdev`` (23 real pairs, README there) and the paper's
four Middlebury scenes is decoded as a user would: the right image is encoded with a grid
pattern, decoded with ``--max-disp`` = ceil(max GT) + 4, and scored as bad pixels
(error > 1 px, in %) on ``nonocc.png`` where the scene has one, else on every pixel with
ground truth.  The columns:

* ``SGBM``: OpenCV StereoSGBM 3WAY on the full pair (block 3, P1 = 8*3*9, P2 = 32*3*9),
  invalid pixels filled from the nearest valid pixel of the row;
* ``AVIF+SGBM``, ``WebP+SGBM``, ``JXL+SGBM``: the right image coded to at most the bytes
  of our stride-5 sample file (AVIF speed 6), decoded, then SGBM;
* ``full``, ``hybrid@3``, ``sparse@5``, ``hybrid@5``...: ``stereobudget.decode`` of a
  grid of that stride (``full`` = stride 1) with the default parameters; ``hybrid@eps0.04``
  decodes the file ``sb-encode --epsilon 0.04`` writes (densest grid and coding within
  4 % of the image's bytes); ``downsample@5``
  sends 5x5 block means instead (the same bytes as a stride-5 grid).

Results are kept in a JSON cache so that a change to one decoder reruns one column.

Examples
--------
    python scripts/evaluate_real.py --cache /tmp/real.json
    python scripts/evaluate_real.py --cache /tmp/real.json --columns SGBM,full --refresh full
    python scripts/evaluate_real.py --cache /tmp/real.json --columns full --param sgm_p2=4 --param sgm_paths=4
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

import stereobudget
from stereobudget.io import write_samples
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
DEFAULT_COLUMNS = "SGBM,AVIF+SGBM,WebP+SGBM,full,hybrid@3,sparse@5,hybrid@5"
CODEC_STRIDE = 5


def load_pairs(which):
    """(name, group, left RGB, right RGB, gt float32, mask bool) of each scene."""
    pairs = []
    if "realdev" in which:
        for folder in sorted(p for p in (SHARED / "realdev").iterdir() if p.is_dir()):
            pairs.append((folder.name, "realdev", *_read_scene(folder, "disp_left.png", 256.0, "nonocc.png")))
    if "middlebury" in which:
        from middlebury import SCENES
        for name, (scale, _) in SCENES.items():
            folder = SHARED / "middlebury" / name
            pairs.append((name, "middlebury", *_read_scene(folder, "disp_left.png", scale, "nonocc.png")))
    return pairs


def _read_scene(folder, gt_name, scale, mask_name):
    left = cv2.cvtColor(cv2.imread(str(folder / "left.png"), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    right = cv2.cvtColor(cv2.imread(str(folder / "right.png"), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    gt = cv2.imread(str(folder / gt_name), cv2.IMREAD_UNCHANGED).astype(np.float32) / np.float32(scale)
    mask = gt > 0
    if (folder / mask_name).exists():
        mask &= cv2.imread(str(folder / mask_name), cv2.IMREAD_GRAYSCALE) == 255
    return left, right, gt, mask


def bad_percent(disparity, gt, mask):
    d = np.nan_to_num(disparity[mask].astype(np.float64), nan=-1e9)
    return float(100.0 * np.mean(np.abs(d - gt[mask]) > 1.0))


def fill_row_gaps(disparity, valid):
    """Each invalid pixel takes the disparity of the nearest valid pixel of its row."""
    h, w = disparity.shape
    cols = np.arange(w)[None, :].repeat(h, 0)
    left_idx = np.where(valid, cols, -1)
    np.maximum.accumulate(left_idx, axis=1, out=left_idx)
    right_idx = np.where(valid, cols, w)
    right_idx = np.minimum.accumulate(right_idx[:, ::-1], axis=1)[:, ::-1]
    use_left = (left_idx >= 0) & ((right_idx >= w) | (cols - left_idx <= right_idx - cols))
    source = np.where(use_left, left_idx, np.minimum(right_idx, w - 1))
    out = np.take_along_axis(disparity, np.clip(source, 0, w - 1), axis=1)
    out[~valid.any(axis=1)] = 0.0
    return out


def sgbm(left, right, max_disp):
    """OpenCV SGBM 3WAY with the issue's parameters and a row fill of invalid pixels."""
    num = int(math.ceil((max_disp + 1) / 16.0) * 16)
    matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num, blockSize=3, P1=8 * 3 * 9, P2=32 * 3 * 9,
                                    mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = matcher.compute(cv2.cvtColor(left, cv2.COLOR_RGB2BGR), cv2.cvtColor(right, cv2.COLOR_RGB2BGR))
    disparity = raw.astype(np.float32) / 16.0
    return fill_row_gaps(disparity, raw >= 0)


def sample_file_bytes(right, stride):
    samples = encode_image(right, pattern=SamplingPattern("grid", stride, stride))
    return len(write_samples(samples))


def _codec(codec):
    """(encode(image, quality) -> bytes, decode(bytes) -> image) of a whole-image codec."""
    import imagecodecs
    if codec == "AVIF":
        return (lambda image, q: imagecodecs.avif_encode(image, level=q, speed=6)), imagecodecs.avif_decode
    if codec == "WebP":
        # This imagecodecs build codes losslessly unless told otherwise.
        return (lambda image, q: imagecodecs.webp_encode(image, level=q, lossless=False)), imagecodecs.webp_decode
    if codec == "JXL":
        return (lambda image, q: imagecodecs.jpegxl_encode(image, level=q, effort=7)), imagecodecs.jpegxl_decode
    raise ValueError(codec)


def best_quality_under(codec, right, budget):
    """(code, quality): the highest quality 0..100 whose code fits ``budget`` bytes, else quality 0.

    The size grows with the quality, so bisection finds it in about seven encodes.
    """
    encode, _ = _codec(codec)
    lo, hi, best = 0, 100, None
    while lo <= hi:
        mid = (lo + hi) // 2
        data = encode(right, mid)
        if len(data) <= budget:
            best, lo = (data, mid), mid + 1
        else:
            hi = mid - 1
    return best if best is not None else (encode(right, 0), 0)


def coded_right(codec, right, budget):
    """(decoded image, bytes) of ``right`` through ``codec`` at the best quality within ``budget``."""
    data, _ = best_quality_under(codec, right, budget)
    return _codec(codec)[1](data), len(data)


def ours(left, right, max_disp, column, params):
    method, _, stride = column.partition("@")
    if stride.startswith("eps"):
        # ``hybrid@eps0.04``: the file sb-encode --epsilon 0.04 writes (the densest grid and
        # coding within 4 % of the raw image bytes), read back as sb-decode reads it.
        from stereobudget.io import read_samples
        from stereobudget.encoding import fit_budget
        budget = int(float(stride[3:]) * right.size * right.dtype.itemsize)
        _, data, _ = fit_budget(right, budget=budget, channel_order="rgb")
        samples = read_samples(data)
        result = stereobudget.decode(left, samples, max_disp=max_disp, params=params, method=method)
        return result.disparity
    stride = int(stride or 1)
    # Downsample sends block means (its own pattern); the other methods read a grid.
    kind = "downsample" if method == "downsample" else "grid"
    samples = encode_image(right, pattern=SamplingPattern(kind, stride, stride))
    result = stereobudget.decode(left, samples, max_disp=max_disp, params=params,
                                 method=None if method == "full" else method)
    return result.disparity


def decoder_params(settings):
    """DecoderParams with ``name=value`` settings (values parsed as Python literals)."""
    import ast
    from stereobudget.decoding import DecoderParams
    changes = {}
    for setting in settings:
        name, _, value = setting.partition("=")
        try:
            changes[name] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            changes[name] = value
    return DecoderParams(**changes)


def run_column(column, left, right, gt, mask, max_disp, params=None):
    start = time.perf_counter()
    if column == "SGBM":
        disparity = sgbm(left, right, max_disp)
    elif column.endswith("+SGBM"):
        coded, _ = coded_right(column.split("+")[0], right, sample_file_bytes(right, CODEC_STRIDE))
        disparity = sgbm(left, coded, max_disp)
    else:
        disparity = ours(left, right, max_disp, column, params)
    return {"bad": bad_percent(disparity, gt, mask), "seconds": time.perf_counter() - start}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--columns", default=DEFAULT_COLUMNS)
    parser.add_argument("--sets", default="realdev,middlebury")
    parser.add_argument("--scenes", default=None, help="comma-separated subset")
    parser.add_argument("--cache", type=Path, default=None, help="JSON file of results kept between runs")
    parser.add_argument("--refresh", default="", help="columns to recompute even when cached")
    parser.add_argument("--markdown", type=Path, default=None, help="also write the table here")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="a DecoderParams field for our columns (repeatable), e.g. sgm_p2=4")
    args = parser.parse_args(argv)
    if not (SHARED / "realdev").is_dir():
        print(f"no real scenes at {SHARED}; nothing to evaluate", file=sys.stderr)
        return 2
    columns = [c for c in args.columns.split(",") if c]
    refresh = set(c for c in args.refresh.split(",") if c)
    cache = json.loads(args.cache.read_text()) if args.cache and args.cache.exists() else {}
    wanted = set(args.scenes.split(",")) if args.scenes else None
    params = decoder_params(args.param)
    suffix = "".join(f" {p}" for p in sorted(args.param))
    rows = []
    for name, group, left, right, gt, mask in load_pairs(args.sets):
        if wanted and name not in wanted:
            continue
        max_disp = int(math.ceil(float(gt[gt > 0].max()))) + 4
        row = {"scene": name, "group": group}
        for column in columns:
            key = f"{name}|{column}" + ("" if column == "SGBM" or column.endswith("+SGBM") else suffix)
            if key not in cache or column in refresh:
                cache[key] = run_column(column, left, right, gt, mask, max_disp, params)
                if args.cache:
                    args.cache.write_text(json.dumps(cache, indent=1))
            row[column] = cache[key]["bad"]
        print(" ".join(f"{row[c]:6.2f}" for c in columns), name, file=sys.stderr, flush=True)
        rows.append(row)
    lines = ["| scene | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
    for row in rows:
        lines.append(f"| {row['scene']} | " + " | ".join(f"{row[c]:.2f}" for c in columns) + " |")
    for group in ("realdev", "middlebury"):
        members = [r for r in rows if r["group"] == group]
        if members:
            means = [np.mean([r[c] for r in members]) for c in columns]
            lines.append(f"| **mean {group} ({len(members)})** | " + " | ".join(f"**{m:.2f}**" for m in means) + " |")
    table = "\n".join(lines)
    print(table)
    if args.markdown:
        args.markdown.write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
