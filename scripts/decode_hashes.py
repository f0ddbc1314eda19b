"""Digests of the disparities of many decodes, to show that a change leaves every route bit-identical.

Run it on two source trees and compare the JSON files::

    PYTHONPATH=/path/to/before python scripts/decode_hashes.py before.json
    PYTHONPATH=/path/to/after  python scripts/decode_hashes.py after.json
    python -c "import json,sys; a,b=(json.load(open(f)) for f in sys.argv[1:]); print(a == b)" before.json after.json

Every synthetic scene kind (``stereobudget.scenes.SCENE_KINDS``) at grid strides 5 and 3 and
a jittered pattern, decoded by Sparse and by each Hybrid route; the full pair on two kinds;
and Teddy at strides 3 and 5 when ``../shared/data/middlebury`` is there.  Each default-route
decode also digests the right image recovered from it (``recover_right``, key suffix ``/right``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np

from stereobudget.decoding import DecoderParams, decode
from stereobudget.io import read_image
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import SCENE_KINDS, make_scene
from stereobudget.synthesis import recover_right

from middlebury import default_data_dir

PATTERNS = (SamplingPattern("grid", 5, 5), SamplingPattern("grid", 3, 3, 1, 2), SamplingPattern("jitter", 4, 4, seed=2))
ROUTES = (("sparse", "semiglobal_census"), ("hybrid", "semiglobal_census"), ("hybrid", "tree"),
          ("hybrid", "semiglobal"))


def digest(disparity: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(disparity, np.float32).tobytes()).hexdigest()[:16]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", help="JSON file of {decode: digest}")
    parser.add_argument("--middlebury", type=Path, default=None, help="default: ../shared/data/middlebury")
    args = parser.parse_args()
    digests = {}
    for kind in SCENE_KINDS:
        scene = make_scene(kind, height=90, width=140, max_disp=24, seed=1)
        for pattern in PATTERNS:
            samples = encode_image(scene.right, pattern=pattern)
            for method, aggregation in ROUTES:
                result = decode(scene.left, samples, max_disp=28, method=method,
                                params=DecoderParams(hybrid_aggregation=aggregation))
                key = f"{kind}/{pattern.kind}{pattern.stride_x}/{method}/{aggregation}"
                digests[key] = digest(result.disparity)
                if method == "hybrid" and aggregation == "semiglobal_census":
                    digests[key + "/right"] = digest(recover_right(scene.left, result.disparity, samples).image)
    for kind in SCENE_KINDS[:2]:
        scene = make_scene(kind, height=90, width=140, max_disp=24, seed=3)
        full = encode_image(scene.right, pattern=SamplingPattern("grid", 1, 1))
        digests[f"{kind}/full"] = digest(decode(scene.left, full, max_disp=28).disparity)
    teddy = (args.middlebury or default_data_dir()) / "teddy"
    if teddy.is_dir():
        left, right = read_image(teddy / "left.png")[0], read_image(teddy / "right.png")[0]
        for stride in (3, 5):
            samples = encode_image(right, pattern=SamplingPattern("grid", stride, stride))
            for method in ("sparse", "hybrid"):
                disparity = decode(left, samples, max_disp=60, method=method).disparity
                digests[f"teddy/{stride}/{method}"] = digest(disparity)
                digests[f"teddy/{stride}/{method}/right"] = digest(recover_right(left, disparity, samples).image)
    Path(args.output).write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n")
    print(f"{len(digests)} decodes -> {args.output}")


if __name__ == "__main__":
    main()
