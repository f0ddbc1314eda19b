"""A frame (or a band of one) decoded in one piece: the memory check, I1's float and gray
images, the noise adaptation, then the method's own pipeline."""

from __future__ import annotations

import numpy as np

from ..cost._cost import float_and_gray
from ..errors import OptionError
from .._kernels import _scratch as scratch
from ._downsample import decode_downsample
from ._full import decode_full
from ._hybrid import decode_hybrid
from ._memory import check_memory
from ._params import DecodeResult, StageTimer, adapt_to_noise
from ._sparse import decode_sparse


def run_pipeline(method, left_f, guide, samples, tree_guide, *, min_disp, num_disp, params, timer):
    """The float32 (H, W) disparity of ``method``'s own pipeline (every pipeline takes these arguments)."""
    if method == "sparse":
        pipeline = decode_sparse
    elif method == "hybrid":
        pipeline = decode_hybrid
    elif method == "downsample":
        pipeline = decode_downsample
    elif method == "full":
        pipeline = decode_full
    else:
        raise OptionError(f"unknown method {method!r}")
    return pipeline(left_f, guide, samples, tree_guide, min_disp=min_disp, num_disp=num_disp, params=params,
                    timer=timer)


def decode_frame(left, samples, *, max_disp, min_disp, method, params, max_memory):
    """:func:`stereobudget.decode` of a frame (or band) in one piece, after its checks and the
    tiling decision (``method`` and ``params`` as :func:`._params.resolve_method` left them,
    the noise adaptation still to come)."""
    num_disp = int(max_disp - min_disp + 1)
    # Another frame size than the last decode's: the large spare volumes of that one are
    # dropped (scratch.frame; of the same size, those this decode does not take go after it).
    with scratch.frame((samples.height, samples.width, num_disp, method)):
        check_memory(samples, num_disp=num_disp, method=method, params=params, max_memory=max_memory)
        timer = StageTimer()
        with timer("prepare"):
            left_f, guide = float_and_gray(left)
            params = adapt_to_noise(params, left, method=method, gray=guide)
        # I1's tree is built by each method, with the right image's when it has one (concurrently).
        # An 8-bit I1 gives the same tree as its float copy, by a counting sort over 256 keys
        # instead of 65536 (~30 % faster).
        tree_guide = left if left.dtype == np.uint8 else left_f
        disp = run_pipeline(method, left_f, guide, samples, tree_guide, min_disp=min_disp, num_disp=num_disp,
                            params=params, timer=timer)
    return DecodeResult(disparity=disp, method=method, min_disp=int(min_disp), max_disp=int(max_disp),
                        timings=timer.timings, params=params)
