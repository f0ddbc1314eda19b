"""Measure the peak memory of stereobudget.decoding.decode and compare it with the estimate.

Each (size, disparities, method, stride) case runs in a fresh subprocess: the decoder is
JIT-warmed on a tiny input, the kernel's peak-RSS counter is reset
(``/proc/self/clear_refs``), the decode runs, and the peak RSS above the resting RSS is
reported next to :func:`stereobudget.decoding.estimate_decode_memory`.

    python scripts/measure_decode_memory.py                 # Teddy size and ~1 MP
    python scripts/measure_decode_memory.py --json out.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

_CHILD = r"""
import json, sys
import numpy as np
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.decoding import decode
from stereobudget.decoding import estimate_decode_memory

height, width, num_disp, method, stride, kind = json.loads(sys.argv[1])
s = 1 if method == "full" else stride

def pair(h, w):
    rng = np.random.default_rng(0)
    # Smooth random texture shifted by a constant disparity: a realistic, cheap input.
    base = rng.integers(0, 256, size=(h // 4 + 2, w // 4 + 2, 3)).astype(np.uint8)
    import cv2
    left = cv2.resize(base, (w + 8, h), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(left[:, 8:]), np.ascontiguousarray(left[:, :-8])

def run(h, w, nd):
    left, right = pair(h, w)
    samples = encode_image(right, pattern=SamplingPattern(kind=kind, stride_x=s, stride_y=s))
    return left, samples, nd

def rss(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024

l, smp, nd = run(128, 160, 8)    # past the two-thread walk's threshold: every kernel is warm
import inspect
# The whole frame at once (no automatic tiling): that is what the estimate describes.
whole = {"tile_rows": 0} if "tile_rows" in inspect.signature(decode).parameters else {}
decode(l, smp, max_disp=nd - 1, method=method, **whole)
left, samples, nd = run(height, width, num_disp)
try:
    from stereobudget._kernels import _scratch as scratch
    scratch.release()       # the warm-up's spare volumes are not this decode's memory
except ImportError:         # older versions of the package, measured for comparison
    pass
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")
rest = rss("VmRSS")
decode(left, samples, max_disp=nd - 1, method=method, **whole)
peak = rss("VmHWM")
print(json.dumps({"height": height, "width": width, "num_disp": num_disp, "method": method,
                  "stride": s, "pattern": kind, "measured": peak - rest,
                  "estimate": estimate_decode_memory(height, width, num_disp, method,
                                                     stride_x=s, stride_y=s)}))
"""

DEFAULT_CASES = [
    (375, 450, 60, "sparse", 5, "grid"), (375, 450, 60, "hybrid", 5, "grid"), (375, 450, 60, "full", 1, "grid"),
    (375, 450, 60, "downsample", 5, "downsample"), (375, 450, 60, "hybrid", 3, "grid"),
    (375, 450, 60, "sparse", 2, "grid"), (375, 450, 60, "hybrid", 5, "jitter"), (375, 450, 60, "sparse", 3, "fps"),
    (900, 1152, 96, "sparse", 5, "grid"), (900, 1152, 96, "hybrid", 5, "grid"), (900, 1152, 96, "full", 1, "grid"),
    (900, 1152, 96, "downsample", 5, "downsample"), (900, 1152, 96, "hybrid", 3, "grid"),
    (900, 1152, 96, "hybrid", 5, "jitter"),
]


def measure(case) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(list(case))], capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="Write the results to this JSON file.")
    args = parser.parse_args(argv)
    results = []
    print(f"{'size':>10} {'D':>4} {'method':>10} {'pattern':>10} {'stride':>6} {'measured':>10} "
          f"{'estimate':>10} {'ratio':>6}")
    for case in DEFAULT_CASES:
        r = measure(case)
        results.append(r)
        print(f"{r['width']:>5}x{r['height']:<4} {r['num_disp']:>4} {r['method']:>10} {r['pattern']:>10} "
              f"{r['stride']:>6} "
              f"{r['measured'] / 2**20:>8.1f}Mi {r['estimate'] / 2**20:>8.1f}Mi "
              f"{r['estimate'] / max(r['measured'], 1):>6.2f}", flush=True)
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(results, handle, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
