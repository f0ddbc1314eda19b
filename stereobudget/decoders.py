"""Decoders: left image + sample set -> dense disparity of the left view.

``decode`` is the library entry point behind ``sb-decode``.  Each method is a short
pipeline of pure functions from the other modules:

* ``sparse`` (paper Fig. 2(b)): Eq. (2) sparse DSI -> Eq. (3) normalised joint bilateral
  fill guided by I1 -> Yang's non-local aggregation on I1's MST -> winner-take-all with
  parabolic sub-pixel refinement -> 3x3 median.
* ``full`` (``stride 1``): the same aggregation on the full DSI of Eq. (1) with Yang's
  left-right check and non-local refinement; the "100 % of I2" reference.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, asdict

import numpy as np
from numba import njit, prange

from .container import SampleSet
from .cost import DEFAULT_TRUNCATION, full_dsi, to_float_image, to_gray
from .bilateral import filled_sparse_dsi
from .errors import MismatchError, OptionError
from . import tree as _tree

log = logging.getLogger("stereobudget")

METHODS = ("sparse", "full")


@dataclass(frozen=True)
class DecoderParams:
    """Parameters of the decoders (defaults: the paper's values, see docs/results.md).

    Attributes
    ----------
    sigma_r : float
        Range sigma of the joint bilateral fill, 8-bit units (paper: 20).
    sigma_s_per_stride : float
        Spatial sigma of the fill in units of the sampling stride (paper: 3).
    truncation : float
        Truncation of the absolute colour difference (8-bit units).
    tree_sigma : float
        Similarity falloff of the MST aggregation (Yang: 0.1 * 255).
    tree_median : int
        Median filter applied to I1 before building the tree (0 = off).
    grad_weight : float
        Weight of the gradient term of the full DSI (Yang: 0.11).
    median_size : int
        Median filter on the final disparity (0 = off).
    """

    sigma_r: float = 20.0
    sigma_s_per_stride: float = 3.0
    truncation: float = DEFAULT_TRUNCATION
    tree_sigma: float = 0.1 * 255
    tree_median: int = 3
    grad_weight: float = 0.11
    median_size: int = 3


@dataclass
class DecodeResult:
    """Output of :func:`decode`.

    Attributes
    ----------
    disparity : ndarray, float32 (H, W)
        Disparity of the left view in pixels; NaN where invalid.
    method : str
    min_disp, max_disp : int
    timings : dict
        Seconds per stage.
    """

    disparity: np.ndarray
    method: str
    min_disp: int
    max_disp: int
    timings: dict = field(default_factory=dict)
    params: DecoderParams = field(default_factory=DecoderParams)

    def summary(self) -> dict:
        return {"method": self.method, "min_disp": self.min_disp, "max_disp": self.max_disp,
                "timings": {k: round(v, 4) for k, v in self.timings.items()}, "params": asdict(self.params)}


class _Timer:
    def __init__(self):
        self.timings = {}

    def __call__(self, name):
        timer = self

        class _Ctx:
            def __enter__(self):
                self.t0 = time.perf_counter()

            def __exit__(self, *exc):
                timer.timings[name] = timer.timings.get(name, 0.0) + time.perf_counter() - self.t0
        return _Ctx()


@njit(cache=True, parallel=True)
def winner_take_all(cost, min_disp):
    """Per-pixel argmin over disparity with a parabola fit through the minimum and its neighbours.

    Parameters
    ----------
    cost : ndarray, float32 (H, W, D)
    min_disp : int

    Returns
    -------
    ndarray, float32 (H, W)
    """
    h, w, nd = cost.shape
    out = np.empty((h, w), dtype=np.float32)
    for y in prange(h):
        for x in range(w):
            c = cost[y, x]
            best = 0
            bv = c[0]
            for i in range(1, nd):
                if c[i] < bv:
                    bv = c[i]
                    best = i
            sub = np.float32(0.0)
            if 0 < best < nd - 1:
                cm = c[best - 1]
                cp = c[best + 1]
                denom = cm - 2 * bv + cp
                if denom > 1e-12:
                    sub = np.float32(0.5) * (cm - cp) / denom
                    if sub > 0.5:
                        sub = np.float32(0.5)
                    elif sub < -0.5:
                        sub = np.float32(-0.5)
            out[y, x] = min_disp + best + sub
    return out


def median_filter_disparity(disparity: np.ndarray, size: int) -> np.ndarray:
    """Median filter (OpenCV; float32 supports sizes 3 and 5)."""
    if size <= 1:
        return disparity
    import cv2
    return cv2.medianBlur(np.ascontiguousarray(disparity, np.float32), int(size))


def check_inputs(left: np.ndarray, samples: SampleSet, *, min_disp: int, max_disp: int) -> None:
    """Raise :class:`MismatchError` / :class:`OptionError` when left image, samples and range disagree."""
    h, w = left.shape[:2]
    c = 1 if left.ndim == 2 else left.shape[2]
    if (h, w) != (samples.height, samples.width):
        raise MismatchError(f"left image is {w}x{h} but the samples are of a {samples.width}x{samples.height} image")
    if c != samples.channels:
        raise MismatchError(f"left image has {c} channel(s) but the samples have {samples.channels}")
    if left.dtype != samples.dtype:
        raise MismatchError(f"left image is {left.dtype} but the samples are {samples.dtype}")
    if max_disp <= min_disp:
        raise OptionError(f"--max-disp ({max_disp}) must be greater than --min-disp ({min_disp})")
    if max_disp - min_disp >= w or abs(min_disp) >= w:
        raise OptionError(f"disparity range [{min_disp}, {max_disp}] does not fit an image {w} pixels wide")


def _is_full_grid(samples: SampleSet) -> bool:
    p = samples.pattern
    return p.kind == "grid" and p.stride_x == 1 and p.stride_y == 1


def decode(left: np.ndarray, samples: SampleSet, *, max_disp: int, min_disp: int = 0,
           method: str = "sparse", params: DecoderParams | None = None) -> DecodeResult:
    """Dense disparity of the left view from I1 and the right camera's samples.

    Parameters
    ----------
    left : ndarray, (H, W) or (H, W, 3), uint8 or uint16
        The left image I1, RGB.
    samples : SampleSet
        What the right camera sent.
    max_disp, min_disp : int
        Disparity search range, inclusive.
    method : {"sparse", "full"}
        Decoder.  A sample set with stride 1 is always decoded as ``full``.
    params : DecoderParams, optional

    Returns
    -------
    DecodeResult
    """
    params = params or DecoderParams()
    if method not in METHODS:
        raise OptionError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    check_inputs(left, samples, min_disp=min_disp, max_disp=max_disp)
    if _is_full_grid(samples):
        method = "full"
    timer = _Timer()
    num_disp = int(max_disp - min_disp + 1)
    with timer("prepare"):
        left_f = to_float_image(left)
        guide = to_gray(left_f)
    with timer("tree"):
        tree = _tree.build_tree(left_f, sigma=params.tree_sigma, median_size=params.tree_median)
    if method == "sparse":
        with timer("jbf_fill"):
            rows, cols = samples.positions()
            right_values = to_float_image(samples.values_rgb()[:, None, :])[:, 0, :]
            stride = float(np.sqrt(samples.pattern.stride_x * samples.pattern.stride_y))
            cost = filled_sparse_dsi(left_f, guide, rows, cols, right_values, min_disp=min_disp,
                                     num_disp=num_disp, sigma_s=params.sigma_s_per_stride * stride,
                                     sigma_r=params.sigma_r, truncation=params.truncation)
        with timer("aggregate"):
            cost = _tree.aggregate(cost, tree)
        with timer("wta"):
            disp = winner_take_all(cost, int(min_disp))
            disp = median_filter_disparity(disp, params.median_size)
    else:
        from .refine import full_pair_disparity
        right_full = samples.grid_values()[:, :, :]
        right_f = to_float_image(right_full if samples.channel_order != "bgr" else right_full[:, :, ::-1])
        disp = full_pair_disparity(left_f, right_f, tree=tree, min_disp=min_disp, num_disp=num_disp,
                                   params=params, timer=timer)
    return DecodeResult(disparity=disp, method=method, min_disp=int(min_disp), max_disp=int(max_disp),
                        timings=timer.timings, params=params)
