"""Write a built-in stereo pair to a folder, so the tools can be tried with nothing else.

``python -m stereobudget.demo OUTDIR`` writes ``left.png``, ``right.png`` and the exact
ground-truth disparity ``disparity_gt.pfm`` of a synthetic scene (textured slanted and
fronto-parallel planes with occlusions, :mod:`stereobudget.scenes`), and prints the
``--max-disp`` to use.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path


def write_demo_pair(out_dir, *, kind: str = "slanted", seed: int = 0) -> dict:
    """Render a synthetic pair into ``out_dir``; returns paths and the disparity range."""
    from .io._disparity import write_disparity
    from .io._images import write_image
    from .scenes._scenes import make_scene

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = make_scene(kind, seed=seed)
    paths = {"left": out / "left.png", "right": out / "right.png", "gt": out / "disparity_gt.pfm"}
    write_image(paths["left"], scene.left, overwrite=True)
    write_image(paths["right"], scene.right, overwrite=True)
    write_disparity(paths["gt"], scene.disparity, overwrite=True)
    return {**{k: str(v) for k, v in paths.items()}, "max_disp": int(math.ceil(scene.max_disp))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m stereobudget.demo", description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", default="demo", help="folder to write (default: ./demo)")
    parser.add_argument("--kind", default="slanted", help="synthetic scene kind (see stereobudget.scenes)")
    args = parser.parse_args(argv)
    info = write_demo_pair(args.out_dir, kind=args.kind)
    print(f"wrote {info['left']}, {info['right']} and {info['gt']}; the disparities are within "
          f"--max-disp {info['max_disp']} (sb-decode estimates the range when it is not given)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
