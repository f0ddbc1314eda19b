"""Compile every decoder's kernels now, so that no method's first decode waits for them.

``python -m stereobudget.warm`` decodes a small synthetic pair with every method (the range
estimate, the decode, the check of the result against the samples and the recovered right
image, as ``sb-decode`` runs them), in two processes side by side by default so that numba
(which compiles on one thread) uses two cores.  numba keeps the compiled kernels in its
cache (``__pycache__`` beside the package, or ``$NUMBA_CACHE_DIR``); a later run finds them
there and returns in seconds.

    python -m stereobudget.warm                 # every method, 8-bit RGB and gray input
    python -m stereobudget.warm --methods hybrid --jobs 1
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import time
from pathlib import Path

from .decoding._methods import METHODS

#: Methods by process when warming on two: each group about half of the compile time
#: (docs/performance.md has the figures), the methods that share kernels together.
GROUPS = (("hybrid", "full"), ("sparse", "downsample"))
KINDS = ("rgb", "gray")


def _tiny_pair(kind: str, pattern):
    """A small synthetic scene (``kind`` "rgb" or "gray") and its right image's samples on ``pattern``.

    Large enough (24576 pixels) for the tree walks' two-thread paths, which a small image
    does not take and a camera frame does.  Compiling is what the caller asked for, so the
    first-use notice is silenced.
    """
    from .encoding import encode_image
    from .scenes._scenes import make_scene
    from ._kernels import _first_run

    _first_run._announced.set()
    scene = make_scene("slanted", height=128, width=192, max_disp=8, gray=kind == "gray")
    return scene, encode_image(scene.right, pattern=pattern)


#: Methods that also run on samples placed off the pixel grid: a pair rectified at the host
#: (``--calibration``) sends them through the Sparse fill's general route.
PLACED_METHODS = ("hybrid", "sparse")


def _placed_pair(scene, samples):
    """The tiny pair as ``--calibration`` gives it to the decoder: I1 resampled and the samples
    placed where a slightly turned, distorting camera pair puts them."""
    import cv2
    import numpy as np

    from .geometry._calibration import StereoCalibration
    from .geometry._rectify import rectify_left, rectify_samples, rectify_stereo

    h, w = scene.left.shape[:2]
    camera = np.array([[float(w), 0.0, (w - 1) / 2.0], [0.0, float(w), (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    calibration = StereoCalibration(M1=camera, D1=np.array([0.05, 0.0, 0.0, 0.0, 0.0]), M2=camera.copy(),
                                    D2=np.zeros(5), R=cv2.Rodrigues(np.radians([0.3, -0.2, 0.4]))[0],
                                    T=np.array([-1.0, 0.0, 0.0]), image_size=(w, h), source="warm")
    rectification = rectify_stereo(calibration, w, h)
    return rectify_left(scene.left, rectification), rectify_samples(samples, rectification)


def _warm_process(args, **popen):
    """``python -m stereobudget.warm ARGS`` in a process of its own.

    It runs beside this package's folder, so that it imports this copy of the package (not
    one that its working directory would shadow it with) and fills its cache.
    """
    home = Path(__file__).resolve().parents[1]
    return subprocess.Popen([sys.executable, "-m", "stereobudget.warm", *args], cwd=home, **popen)


def warm_method(method: str, *, kinds=KINDS) -> float:
    """Run every kernel ``sb-decode --method METHOD`` runs, on tiny pairs (and, for
    :data:`PLACED_METHODS`, on the same pairs rectified at the host); returns the seconds taken."""
    from .decoding import Decoder
    from .decoding._checks import psnr_at_samples
    from .decoding._disprange import resolve_range
    from .sampling._patterns import SamplingPattern
    from .pipeline._jobs import recover_right_image

    start = time.perf_counter()
    pattern = {"full": SamplingPattern("grid", 1, 1), "downsample": SamplingPattern("downsample", 4, 4)}.get(
        method, SamplingPattern("grid", 5, 5))
    for kind in kinds:
        scene, samples = _tiny_pair(kind, pattern)
        pairs = [(scene.left, samples)]
        if method in PLACED_METHODS:
            pairs.append(_placed_pair(scene, samples))
        for left, given in pairs:
            min_disp, max_disp, _ = resolve_range(left, given, max_disp=8)
            with Decoder(keep_freed_memory=False) as decoder:
                result = decoder.decode(left, given, max_disp=max_disp, min_disp=min_disp, method=method)
            psnr_at_samples(left, result.disparity, given)
            recover_right_image(left, result.disparity, given)
    return time.perf_counter() - start


def warm_hybrid_tail(*, kinds=KINDS) -> float:
    """Compile the kernels a default Hybrid decode runs after its splat; returns the seconds taken.

    First the grid blur, which the decode reaches right after its splat; then the census
    mixed into the fill, the semi-global paths, the checks and the row fill, on tiny pairs
    whose fill is random; last the check against the samples and the recovered right
    image.  Run in a second process beside a first decode, which meanwhile compiles the
    range estimate, the low-pass, the splat and the fill's slice, it has the rest in the
    cache by the time that decode reaches it.  The slice (7 s of compiling) is left to
    the decode: compiled here first, it was not ready in time, and the decode compiled it
    as well.
    """
    import numpy as np

    from .cost._cost import float_and_gray
    from .decoding._checks import psnr_at_samples
    from .decoding._hybrid import census_semiglobal_tail, hybrid_weight
    from .decoding._params import DecoderParams, StageTimer
    from .fill._geometry import grid_geometry
    from .fill._grid import _blur_grid
    from .sampling._patterns import SamplingPattern
    from .pipeline._jobs import recover_right_image

    start = time.perf_counter()
    rng = np.random.default_rng(0)
    _blur_grid(np.zeros((4, 4, 4, 3), np.float32), grid_geometry(8, 8, 255.0, sigma_s=2.0, sigma_r=10.0))
    pairs = [_tiny_pair(kind, SamplingPattern("grid", 5, 5)) for kind in kinds]
    for scene, samples in pairs:
        left_f, guide = float_and_gray(scene.left)
        fill = rng.random((*guide.shape, 9), dtype=np.float32)
        # I1 stands in for both low-passed images: only their types matter here.
        census_semiglobal_tail(fill, guide, samples, left_f, left_f.copy(), min_disp=0, params=DecoderParams(),
                               timer=StageTimer(), weight=hybrid_weight(5), image=left_f)
    for scene, samples in pairs:
        psnr_at_samples(scene.left, scene.disparity, samples)
        recover_right_image(scene.left, scene.disparity, samples)
    return time.perf_counter() - start


def start_hybrid_tail(kind: str):
    """Start :func:`warm_hybrid_tail` for ``kind`` input (``"rgb"`` or ``"gray"``) in a second process.

    For a first decode on a cold cache: numba compiles on one thread, so the second core
    compiles the decode's later kernels while the first compiles its fill.  Whatever it
    has not finished when this process exits, this process needed no more: it is stopped
    then (what it has saved stays in the cache).  Returns the process, or None when it
    could not start (the decode then compiles everything itself, as before).
    """
    import atexit
    try:
        child = _warm_process(["--hybrid-tail", "--kinds", kind], stdin=subprocess.DEVNULL,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except (OSError, ValueError, TypeError):   # no interpreter to start (embedded), no processes left
        return None

    def finish():
        if child.poll() is None:
            child.terminate()
        try:
            child.wait(timeout=10)
        except subprocess.TimeoutExpired:
            child.kill()
    atexit.register(finish)
    return child


def warm(methods=METHODS, *, jobs: int = 2, kinds=KINDS, report=print) -> float:
    """Compile the kernels of ``methods`` (``jobs`` processes); returns the wall seconds taken."""
    methods = [m for m in METHODS if m in methods]
    start = time.perf_counter()
    if jobs <= 1 or len(methods) < 2:
        for method in methods:
            report(f"{method}: {warm_method(method, kinds=kinds):.1f} s")
        return time.perf_counter() - start
    groups = [[m for m in group if m in methods] for group in GROUPS]
    groups = [g for g in groups if g]
    other = [m for m in methods if not any(m in g for g in groups)]
    if other:
        groups[-1].extend(other)
    children = [_warm_process(["--jobs", "1", "--methods", ",".join(group), "--kinds", ",".join(kinds)])
                for group in groups[1:]]
    for method in groups[0]:
        report(f"{method}: {warm_method(method, kinds=kinds):.1f} s")
    failed = [child.args for child in children if child.wait() != 0]
    if failed:
        raise RuntimeError(f"warming failed in {failed}")
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m stereobudget.warm", description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated (default: all)")
    parser.add_argument("--kinds", default=",".join(KINDS), help="input kinds: rgb, gray (default: both)")
    parser.add_argument("--jobs", type=int, default=2, help="processes compiling side by side (default 2)")
    parser.add_argument("--hybrid-tail", action="store_true",
                        help="only what the default hybrid runs after its fill (beside a first decode)")
    args = parser.parse_args(argv)
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    if args.hybrid_tail:
        warm_hybrid_tail(kinds=kinds)
        return 0
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        parser.error(f"unknown method(s) {', '.join(unknown)}; expected {', '.join(METHODS)}")
    logging.basicConfig(format="%(message)s", stream=sys.stderr)
    print(f"compiling the kernels of {', '.join(methods)} unless cached (about 35 s once after an install, "
          f"{max(1, args.jobs)} process(es))", file=sys.stderr, flush=True)
    seconds = warm(methods, jobs=args.jobs, kinds=kinds,
                   report=lambda text: print(text, file=sys.stderr, flush=True))
    print(f"kernels of {', '.join(methods)} compiled or loaded in {seconds:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    from ._kernels._stack import call_with_stack_room
    sys.exit(call_with_stack_room(main))
