"""Decoders: left image + sample set -> dense disparity of the left view.

``decode`` is the library entry point behind ``sb-decode``.  Each method is a short
pipeline of pure functions from the other modules:

* ``sparse`` (paper Fig. 2(b)): Eq. (2) sparse DSI -> Eq. (3) normalised joint bilateral
  fill guided by I1 -> Yang's non-local aggregation on I1's MST -> winner-take-all with
  parabolic sub-pixel refinement -> 3x3 median.
* ``hybrid`` (paper Fig. 2(c)): a weighted mean of the Sparse filled DSI and a full DSI
  between the low-passed interpolation of the samples and an equally low-passed I1.  By
  default the full DSI is a census at the grid's spacing, summed along semi-global paths
  with a diagonal left-right check and a row fill (robust to the exposure differences
  and slanted surfaces of real pairs); ``hybrid_aggregation="tree"`` is the paper's:
  absolute differences, Yang's tree, left-right check against the interpolated right
  image, non-local refinement.
* ``downsample`` (paper Fig. 2(a)): the camera sent block means; they are upsampled, I1
  is passed through the same down/up operator so both have the same spectrum, and the
  pair is matched like a full pair (LR check + refinement).
* ``full`` (``stride 1``): census cost, semi-global aggregation, left-right check and
  non-local refinement (:mod:`stereobudget.decoding._full`); ``full_cost="ad"`` keeps
  the paper's reference, the tree aggregation of the Eq. (1) DSI with Yang's check.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, asdict, replace

import numpy as np
from ..io._samples import SampleSet
from ..cost._cost import (DEFAULT_TRUNCATION, float_and_gray, noise_level, noise_level_of_gray, sample_row_steps,
                   to_float_image, to_gray)
from ..sampling._patterns import grid_shape
from ..fill._bilateral import filled_sparse_dsi, release_grids, sparse_dsi_grids
from ..io._limits import volume_layers
from ..fill._lowpass import (_sample_values_f32, block_lowpass, gaussian_lowpass,  # noqa: F401  (re-exported)
                      lowpass_interpolation, upsample_block_means)
from ..aggregate._refine import median_filter_disparity  # noqa: F401  (re-exported)
from ..aggregate._winner import subpixel_winner, winner_take_all  # noqa: F401  (re-exported for callers of decoders)
from ..errors import MismatchError, OptionError
from .._kernels import _scratch as scratch
from ..aggregate import _tree as _tree
from ._methods import DEFAULT_METHOD, METHODS  # noqa: F401  (re-exported)

log = logging.getLogger("stereobudget")



@dataclass(frozen=True)
class DecoderParams:
    """Parameters of the decoders (defaults: the paper's values, see docs/results.md).

    Attributes
    ----------
    sigma_r : float
        Range sigma of the joint bilateral fill, 8-bit units (paper: 20; 15 measured
        slightly better on Middlebury and neutral on the synthetic scenes).
    sigma_s_per_stride : float
        Spatial sigma of the fill in units of the sampling stride (paper: 3; 2 is better
        on every Middlebury scene group and on 9 of 10 synthetic scenes: a narrower
        window mixes fewer costs from occluded pixels into their visible neighbours).
    truncation : float
        Truncation of the sparse (Eq. 2) absolute colour difference, 8-bit units.  With
        only samples there is no gradient term, so the colour term carries the match and
        a wider truncation than the full-pair cost keeps it discriminative.
    full_truncation, grad_truncation : float
        Truncations of the colour and x-gradient terms of a dense DSI (full pair,
        Downsample, Hybrid's interpolated DSI): Yang / Rhemann et al.'s 7 and 2.
    tree_sigma : float
        Similarity falloff of the MST aggregation (Yang: 0.1 * 255).
    tree_median : int
        Median filter applied to I1 before building the tree (0 = off).
    grad_weight : float
        Weight of the gradient term of a dense DSI (Yang / Rhemann et al.: 0.89, colour
        gets 0.11).
    median_size : int
        Median filter on the final disparity (0 = off).
    lowpass_per_stride : float
        Hybrid: sigma of the Gaussian that interpolates the samples and low-passes I1, in
        units of the stride.  0.5 puts the Gaussian's response at the samples' Nyquist
        frequency 1/(2 s) at exp(-pi^2 / 8) = 29 % (0.7 -> 9 % suppresses aliases better
        but blurs away the detail the dense DSI is for; docs/results.md has the sweep).
    step_weight, step_truncation : float
        Sparse DSI: weight and truncation (gray levels) of the difference between row
        neighbours of the sample grid compared with I1's difference over the same spacing
        (:func:`stereobudget.cost.sparse_pair_cost`); the sweep in docs/results.md.
    sparse_census_weight : float
        Weight of the lattice census in the Sparse DSI (:func:`stereobudget.cost.sparse_pair_cost`):
        each sample's order against its 8 grid neighbours, compared with I1's at the same
        spacing, survives the exposure differences of real camera pairs.
    noise_reference : float or None
        Every cost truncation is at least this many times the difference that the left
        image's noise alone produces (see :func:`adapt_to_noise`).  None: off.
    hybrid_sparse_weight : float or None
        Hybrid: weight of the Sparse DSI in the mean (the interpolated DSI gets 1 - w).
        ``None``: chosen from the stride by :func:`hybrid_weight`.
    grid_cells_per_sigma_s, grid_cells_per_sigma_r : float
        Resolution of the bilateral grid of the Sparse fill: grid cells per spatial and
        per range sigma (:func:`stereobudget.fill.grid_geometry`).  One cell per
        sigma is Paris & Durand's sampling rate; the grid blur is narrowed so the
        effective kernel keeps its sigma, and the sweep recorded in the commit history
        (``benchmarks/sweep.py``) finds every scene within 0.2 pp of 2 cells per
        sigma at strides 3, 5 and 8, for 1/8 of the grid cells.
    hybrid_aggregation : {"semiglobal_census", "semiglobal", "tree"}
        How Hybrid matches and aggregates.  ``"semiglobal_census"``: the Sparse fill
        (weight ``hybrid_sparse_weight``) mixed with the census, at the grid's spacing, of
        the low-passed I1 and the low-passed interpolation of the samples, summed along
        the semi-global paths (P2 = ``hybrid_sgm_p2``), checked left against right on the
        diagonal, rejected pixels filled from their row.  On the 23 real pairs
        (``benchmarks/evaluate_real.py``) 26.6 % bad pixels at stride 5 and 19.9 % at
        stride 3, against 31.5 % and 28.6 % for ``"tree"`` (the paper's route: the Sparse
        fill mixed with absolute differences of the low-passed pair, Yang's tree, check
        and refinement), which stays better on the four paper scenes (6.6 % against 8.0 %
        at stride 5).  ``"semiglobal"``: the paper's mixed cost on the semi-global paths
        (28.3 % / 8.4 %).
    full_cost : {"census", "ad"}
        Cost and aggregation of the full pair.  ``"census"``: 5x5 census, semi-global
        aggregation (:mod:`stereobudget.decoding._full`); on the 23 real pairs of the
        development set 16.8 % bad pixels against OpenCV SGBM's 20.8 % and the tree on
        absolute differences' 26 % (``benchmarks/evaluate_real.py``; docs/results.md).
        ``"ad"``: the paper's Eq. (1) cost on the tree (Yang), which assumes equal
        exposure in both cameras.
    sgm_p1, sgm_p2 : float
        Semi-global penalties of a one-level and of a larger disparity change, as
        multiples of the cost volume's typical margin (the data term's own scale, so the
        same multiples serve every scene, size and cost); the sweep is in docs/results.md
        (``benchmarks/evaluate_real.py --param sgm_p2=4``).
    hybrid_sgm_p2 : float
        P2 of Hybrid's semi-global aggregation.  A sample grid's filled cost separates
        disparities less sharply than a full pair's census, so its margin calls for a
        stronger smoothness term: on 8 scenes (6 real, 2 Middlebury) at stride 5 P2 = 4,
        8, 16, 32 gave 24.65, 24.03, 23.48, 23.13 % mean bad pixels, the last two losing
        on Middlebury (Tsukuba 7.8 -> 8.4 -> 8.8); 16 is the compromise.
    sgm_edge_scale : float
        Gray-level difference across which P2 halves (depth edges follow colour edges).
    sgm_paths : {4, 8}
        Semi-global paths: horizontal and vertical, plus the diagonals for 8.
    right_check : {"tree", "diagonal"}
        Where the left-right check of Hybrid, Downsample and the full pair gets the right
        view's disparity: ``"tree"`` aggregates the right view's costs on the right
        image's own tree (Yang); ``"diagonal"`` reads it off the left view's aggregated
        costs, normalised by each pixel's tree support (Hirschmüller's search), which
        saves a tree and an aggregation but lets more errors pass the check: measured
        0.3-0.5 pp worse on the 9-scene mean, up to 2.5 pp on Teddy (benchmarks/bench.py).
    """

    sigma_r: float = 15.0
    sigma_s_per_stride: float = 2.0
    truncation: float = DEFAULT_TRUNCATION
    full_truncation: float = 7.0
    grad_truncation: float = 2.0
    tree_sigma: float = 0.1 * 255
    tree_median: int = 3
    grad_weight: float = 0.89
    median_size: int = 3
    lowpass_per_stride: float = 0.5
    step_weight: float = 0.4
    step_truncation: float = 5.0
    sparse_census_weight: float = 0.5
    noise_reference: float | None = 2.5
    hybrid_sparse_weight: float | None = None
    grid_cells_per_sigma_s: float = 1.0
    grid_cells_per_sigma_r: float = 1.0
    hybrid_aggregation: str = "semiglobal_census"
    full_cost: str = "census"
    sgm_p1: float = 1.0
    sgm_p2: float = 8.0
    hybrid_sgm_p2: float = 16.0
    sgm_edge_scale: float = 8.0
    sgm_paths: int = 8
    right_check: str = "tree"


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
    """``with timer(stage):`` adds the block's wall time to ``timings[stage]``."""

    def __init__(self):
        self.timings = {}

    def __call__(self, name):
        return _Stage(self.timings, name)


class _Stage:
    # A plain class made once (a class made per stage cost ~0.3 ms per decode).
    __slots__ = ("timings", "name", "start")

    def __init__(self, timings, name):
        self.timings, self.name = timings, name

    def __enter__(self):
        self.start = time.perf_counter()

    def __exit__(self, *exc):
        self.timings[self.name] = self.timings.get(self.name, 0.0) + time.perf_counter() - self.start


def check_inputs(left: np.ndarray, samples: SampleSet, *, min_disp: int, max_disp: int) -> None:
    """Raise :class:`MismatchError` / :class:`OptionError` when left image, samples and range disagree."""
    h, w = left.shape[:2]
    c = 1 if left.ndim == 2 else left.shape[2]
    if (h, w) != (samples.height, samples.width):
        raise MismatchError(f"left image is {w}x{h} but the samples are of a {samples.width}x{samples.height} image")
    expected = getattr(samples, "colour_channels", samples.channels)   # 3 for a raw mosaic
    if c != expected:
        raise MismatchError(f"left image has {c} channel(s) but the samples have {samples.channels}"
                            + (f" ({samples.channel_order}: compared with an RGB left image)"
                               if expected != samples.channels else ""))
    if left.dtype != samples.dtype:
        raise MismatchError(f"left image is {left.dtype} but the samples are {samples.dtype}")
    if max_disp <= min_disp:
        raise OptionError(f"--max-disp ({max_disp}) must be greater than --min-disp ({min_disp})")
    if max_disp - min_disp >= w or abs(min_disp) >= w or abs(max_disp) >= w:
        raise OptionError(f"disparity range [{min_disp}, {max_disp}] does not fit an image {w} pixels wide")


def _is_full_grid(samples: SampleSet) -> bool:
    p = samples.pattern
    return p.kind == "grid" and p.stride_x == 1 and p.stride_y == 1


def adapt_to_noise(params: DecoderParams, left: np.ndarray, *, method: str,
                   gray: np.ndarray | None = None) -> DecoderParams:
    """Raise the cost truncations above what the left image's noise alone produces.

    With gray-level noise sigma (:func:`stereobudget.cost.noise_level`), two matching
    pixels differ by about ``2 sigma`` in colour, ``sigma`` in x-gradient and ``2 sigma``
    in a grid step; a truncation below a few times that saturates on noise and the cost
    stops discriminating.  Each truncation of a cost computed on full-resolution pixels
    (the Sparse DSI of ``sparse``/``hybrid``, the dense DSI of ``full``) is therefore at
    least ``noise_reference`` times its noise scale.  Hybrid's interpolated DSI and
    Downsample work on low-passed images whose noise is already averaged away, so they
    keep their truncations.  On Middlebury (sigma 0.7-2.05) this only touches Cones.
    ``gray``: I1 as :func:`stereobudget.cost.to_gray` of its float image, when the caller
    has it already (the noise is measured on it).
    """
    if params.noise_reference is None:
        return params
    sigma = noise_level_of_gray(gray) if gray is not None else noise_level(to_float_image(left))
    k = params.noise_reference
    changes = {"noise_reference": None}
    if method in ("sparse", "hybrid"):
        changes.update(truncation=max(params.truncation, 2 * k * sigma),
                       step_truncation=max(params.step_truncation, 2 * k * sigma))
    elif method == "full":
        changes.update(full_truncation=max(params.full_truncation, 2 * k * sigma),
                       grad_truncation=max(params.grad_truncation, k * sigma))
    return replace(params, **changes)


def _stride(samples: SampleSet) -> float:
    return float(np.sqrt(samples.pattern.stride_x * samples.pattern.stride_y))


def hybrid_weight(stride: float) -> float:
    """Weight of the Sparse DSI in Hybrid's mean, from the sampling stride.

    The sweep in docs/results.md (strides 3 and 5, weights 0.3-0.9) has its optimum at
    0.7 for both: the interpolated DSI is blurred in proportion to the stride, but so is
    the Sparse fill (sigma_s = 3 stride), so their relative reliability does not move
    with the sampling rate and one weight serves all strides.
    """
    return 0.7


def _sparse_fill_arguments(left_f, guide, samples, params):
    """Positional and keyword arguments of the Sparse fill (Eq. 2 + Eq. 3) for these samples."""
    rows, cols = samples.positions()
    values = _sample_values_f32(samples)
    steps = None
    if samples.pattern.is_regular_grid and params.step_weight > 0:
        # Row neighbours of a grid are stride_x pixels apart: their difference is exact data.
        lattice = to_gray(values.reshape(grid_shape(samples.pattern, samples.height, samples.width) + (-1,)))
        steps = sample_row_steps(lattice).ravel()
    return (left_f, guide, rows, cols, values), dict(
        sigma_s=params.sigma_s_per_stride * _stride(samples), sigma_r=params.sigma_r,
        truncation=params.truncation, right_steps=steps, step_spacing=samples.pattern.stride_x,
        step_weight=params.step_weight, step_truncation=params.step_truncation,
        census_spacing=(samples.pattern.stride_x, samples.pattern.stride_y) if samples.pattern.is_regular_grid else None,
        census_weight=params.sparse_census_weight,
        cells_per_sigma_s=params.grid_cells_per_sigma_s, cells_per_sigma_r=params.grid_cells_per_sigma_r)


def _sparse_filled_cost(left_f, guide, samples, *, min_disp, num_disp, params, layout=None):
    args, kwargs = _sparse_fill_arguments(left_f, guide, samples, params)
    return filled_sparse_dsi(*args, min_disp=min_disp, num_disp=num_disp, **kwargs,
                             pixel_of_row=None if layout is None else layout.pixel_of_row)


def _decode_hybrid(left_f, guide, samples, tree_guide, *, min_disp, num_disp, params, timer):
    from ..aggregate._refine import left_right_refined_rows, pair_trees
    from ..aggregate._pair_volumes import pair_cost_rows
    layers = volume_layers(num_disp)
    stride = _stride(samples)
    weight = params.hybrid_sparse_weight if params.hybrid_sparse_weight is not None else hybrid_weight(stride)
    if params.hybrid_aggregation == "semiglobal_census":
        with timer("interpolate"):
            sigma = params.lowpass_per_stride * stride
            right_lp = lowpass_interpolation(samples, sigma=sigma)
            left_lp = gaussian_lowpass(left_f, sigma=sigma)
        return _hybrid_census_semiglobal(left_f, guide, samples, left_lp, right_lp, min_disp=min_disp,
                                         num_disp=num_disp, params=params, timer=timer, weight=weight)
    with timer("jbf_fill"):
        # Splat and blur only: the grids are sliced pixel by pixel in the cost kernel below.
        args, kwargs = _sparse_fill_arguments(left_f, guide, samples, params)
        grids = sparse_dsi_grids(*args, min_disp=min_disp, num_disp=layers, **kwargs)
    with timer("interpolate"):
        sigma = params.lowpass_per_stride * stride
        right_lp = lowpass_interpolation(samples, sigma=sigma)
        left_lp = gaussian_lowpass(left_f, sigma=sigma)
    if params.hybrid_aggregation == "semiglobal":
        return _hybrid_semiglobal(left_lp, right_lp, grids, guide, min_disp=min_disp, num_disp=num_disp,
                                  params=params, timer=timer, mix_weights=_hybrid_mix(params, weight))
    with timer("tree"):
        tree, left_layout, right_layout = pair_trees(tree_guide, right_lp, params=params)
    with timer("cost"):
        # The fill and the dense DSI of the low-passed pair, both brought to [0, 1] by their
        # largest possible value and mixed per pixel; the right view's volume is gathered
        # from the same rows (volumes.pair_cost_rows).
        left_rows, right_rows = pair_cost_rows(
            left_lp, right_lp, min_disp=min_disp, num_disp=layers, truncation=params.full_truncation,
            grad_weight=params.grad_weight, grad_truncation=params.grad_truncation, left_layout=left_layout,
            right_layout=right_layout, grids=grids, guide=guide, mix_weights=_hybrid_mix(params, weight))
    release_grids(grids)
    del grids
    disp, _ = left_right_refined_rows(left_rows, right_rows, left_layout=left_layout, right_layout=right_layout,
                                      left_tree=tree, min_disp=min_disp, params=params, timer=timer,
                                      num_disp=num_disp)
    scratch.recycle(left_rows, right_rows)
    return disp


def _hybrid_mix(params, weight):
    """Weights of the fill and of the dense DSI in Hybrid's mean, each brought to [0, 1]
    by its largest possible value."""
    dense_max = (1 - params.grad_weight) * params.full_truncation + params.grad_weight * params.grad_truncation
    return weight / params.truncation, (1.0 - weight) / dense_max


def _hybrid_semiglobal(left_lp, right_lp, grids, guide, *, min_disp, num_disp, params, timer, mix_weights):
    """Hybrid's mixed DSI aggregated along semi-global paths, LR-checked on the diagonal,
    rejected pixels filled from their row (as the full pair, :mod:`stereobudget.decoding._full`)."""
    from types import SimpleNamespace

    from ..aggregate._pair_volumes import pair_cost_rows
    from ._full import semiglobal_disparity, typical_margin
    h, w = guide.shape
    layers = volume_layers(num_disp)
    with timer("cost"):
        pixel_order = SimpleNamespace(row_of_pixel=np.arange(h * w, dtype=np.int32))
        rows, _ = pair_cost_rows(left_lp, right_lp, min_disp=min_disp, num_disp=layers,
                                 truncation=params.full_truncation, grad_weight=params.grad_weight,
                                 grad_truncation=params.grad_truncation, left_layout=pixel_order, grids=grids,
                                 guide=guide, mix_weights=mix_weights)
        release_grids(grids)
        cost = np.ascontiguousarray(rows.reshape(h, w, layers)[:, :, :num_disp])  # float32
        scratch.recycle(rows)
        margin = typical_margin(cost, floor=0.0)
    return semiglobal_disparity(cost, guide, min_disp=min_disp, p1=params.sgm_p1 * margin,
                                p2=params.hybrid_sgm_p2 * margin, params=params, timer=timer)


def _hybrid_census_semiglobal(left_f, guide, samples, left_lp, right_lp, *, min_disp, num_disp, params, timer,
                              weight):
    """Hybrid with a radiometrically robust dense term: the Sparse fill mixed with the census
    of the low-passed pair at the grid's spacing, aggregated on semi-global paths."""
    from ..cost._census import mix_spaced_census, spaced_census
    from ._full import semiglobal_disparity, typical_margin
    p = samples.pattern
    with timer("jbf_fill"):
        cost = _sparse_filled_cost(left_f, guide, samples, min_disp=min_disp, num_disp=num_disp, params=params)
    with timer("cost"):
        cost = np.ascontiguousarray(cost, np.float32)
        left_codes = spaced_census(to_gray(left_lp), spacing_x=p.stride_x, spacing_y=p.stride_y)
        right_codes = spaced_census(to_gray(right_lp), spacing_x=p.stride_x, spacing_y=p.stride_y)
        mix_spaced_census(cost, left_codes, right_codes, min_disp=int(min_disp),
                          volume_scale=weight / params.truncation, census_weight=(1.0 - weight) / 8.0)
        margin = typical_margin(cost, floor=0.0)
    return semiglobal_disparity(cost, guide, min_disp=min_disp, p1=params.sgm_p1 * margin,
                                p2=params.hybrid_sgm_p2 * margin, params=params, timer=timer)


def _decode_downsample(left_f, samples, tree_guide, *, min_disp, num_disp, params, timer):
    from ..aggregate._refine import full_pair_disparity
    p = samples.pattern
    h, w = samples.height, samples.width
    rows, cols = -(-h // p.stride_y), -(-w // p.stride_x)
    with timer("interpolate"):
        low = _sample_values_f32(samples).reshape(rows, cols, samples.channels)
        right_up = upsample_block_means(low, p.stride_x, p.stride_y, h, w)
        left_up = block_lowpass(left_f, p.stride_x, p.stride_y)
    # From here on the upsampled pair is matched like any full pair (the tree stays I1's own).
    return full_pair_disparity(left_up, right_up, tree_guide=tree_guide, min_disp=min_disp, num_disp=num_disp,
                               params=params, timer=timer)


def _resolve_method(left, samples, *, method, params, min_disp, max_disp, adapt=True):
    """Validate the inputs, pick the method a sample set implies, and (``adapt``) adapt the
    params to I1's noise."""
    params = params or DecoderParams()
    method = method or DEFAULT_METHOD
    if method not in METHODS:
        raise OptionError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if params.hybrid_aggregation not in ("tree", "semiglobal", "semiglobal_census"):
        raise OptionError(f"unknown hybrid_aggregation {params.hybrid_aggregation!r}; expected 'tree' or 'semiglobal'")
    if params.full_cost not in ("census", "ad"):
        raise OptionError(f"unknown full_cost {params.full_cost!r}; expected 'census' or 'ad'")
    if params.right_check not in ("tree", "diagonal"):
        raise OptionError(f"unknown right_check {params.right_check!r}; expected 'tree' or 'diagonal'")
    check_inputs(left, samples, min_disp=min_disp, max_disp=max_disp)
    from ._mosaic import mosaic_decoding
    method, params = mosaic_decoding(samples, method=method, params=params)
    if _is_full_grid(samples):
        method = "full"
    elif method == "full":
        raise OptionError(f"--method full needs every pixel of I2 (a sample file written with --stride 1); "
                          f"this one holds {samples.pattern.kind} samples at stride "
                          f"{samples.pattern.stride_x}x{samples.pattern.stride_y}")
    return method, (adapt_to_noise(params, left, method=method) if adapt else params)


def decode(left: np.ndarray, samples: SampleSet, *, max_disp: int, min_disp: int = 0,
           method: str | None = None, params: DecoderParams | None = None,
           max_memory: int | None = None, tile_rows: int | None = None,
           tile_overlap: int | None = None) -> DecodeResult:
    """Dense disparity of the left view from I1 and the right camera's samples.

    Parameters
    ----------
    left : ndarray, (H, W) or (H, W, 3), uint8 or uint16
        The left image I1, RGB.
    samples : SampleSet
        What the right camera sent.
    max_disp, min_disp : int
        Disparity search range, inclusive.
    method : {"hybrid", "sparse", "downsample", "full"}
        Decoder.  A sample set with stride 1 is always decoded as ``full``; a
        ``downsample`` sample file only as ``downsample``.
    params : DecoderParams, optional
    max_memory : int, optional
        Largest estimated peak memory allowed, in bytes (default:
        :func:`stereobudget.io.default_memory_limit`, 75 % of the available memory).
    tile_rows : int, optional
        Decode in horizontal bands of this many rows (see :func:`decode_tiled`); ``0``
        never tiles.  Default: tile only when the whole frame's memory estimate exceeds
        the limit, with the tallest bands that fit (Sparse, Hybrid and full only).
    tile_overlap : int, optional
        Extra rows decoded above and below each band and then dropped
        (default :data:`DEFAULT_TILE_OVERLAP`).

    Returns
    -------
    DecodeResult

    Raises
    ------
    MismatchError, OptionError
        Left image and samples disagree, or the disparity range does not fit.
    MemoryLimitError
        The estimate (:func:`stereobudget.io.estimate_decode_memory`) exceeds
        ``max_memory``; checked before any volume is allocated.

    Notes
    -----
    Decodes in one process hand memory to each other: dead cost volumes are kept for
    the next decode (:mod:`stereobudget._kernels._scratch`: up to 256 MiB of volumes of up to 64 MiB,
    and all larger ones of the frame decoded last, dropped when a decode of another frame
    begins; the memory limit counts them as available), and the first call lets glibc
    keep freed blocks mapped (:func:`stereobudget._kernels.keep_freed_memory`).
    ``STEREOBUDGET_KEEP_FREED_MEMORY=0`` opts out of both but the 256 MiB;
    :func:`stereobudget._kernels.release` gives everything back.
    """
    # Each decode's temporaries are the next one's: keep them mapped (no page faults).
    scratch.keep_freed_memory()
    # The noise adaptation waits for I1's gray image (made below anyway); a tiled decode
    # adapts on the whole frame in decode_tiled.
    method, params = _resolve_method(left, samples, method=method, params=params,
                                     min_disp=min_disp, max_disp=max_disp, adapt=False)
    overlap = DEFAULT_TILE_OVERLAP if tile_overlap is None else int(tile_overlap)
    if tile_rows is None:
        tile_rows = auto_tile_rows(samples, num_disp=int(max_disp - min_disp + 1), method=method,
                                   params=params, max_memory=max_memory, overlap=overlap)
    if tile_rows and tile_rows < samples.height:
        return decode_tiled(left, samples, max_disp=max_disp, min_disp=min_disp, method=method, params=params,
                            max_memory=max_memory, tile_rows=tile_rows, overlap=overlap)
    # Another frame size than the last decode's: the large spare volumes of that one are
    # dropped (scratch.frame; of the same size, those this decode does not take go after it).
    with scratch.frame((samples.height, samples.width, int(max_disp - min_disp + 1), method)):
        return _decode_whole_frame(left, samples, max_disp=max_disp, min_disp=min_disp, method=method,
                                   params=params, max_memory=max_memory)


def _decode_whole_frame(left, samples, *, max_disp, min_disp, method, params, max_memory):
    """:func:`decode` of a frame (or band) in one piece, after its checks and the tiling decision."""
    from ..io._limits import check_decode_memory
    check_decode_memory(samples.height, samples.width, int(max_disp - min_disp + 1),
                        "downsample" if samples.pattern.kind == "downsample" else method,
                        max_memory=max_memory, stride_x=samples.pattern.stride_x,
                        stride_y=samples.pattern.stride_y, sigma_s_per_stride=params.sigma_s_per_stride,
                        sigma_r=params.sigma_r)
    timer = _Timer()
    num_disp = int(max_disp - min_disp + 1)
    with timer("prepare"):
        left_f, guide = float_and_gray(left)
        params = adapt_to_noise(params, left, method=method, gray=guide)
    # I1's tree is built by each method, with the right image's when it has one (concurrently).
    # An 8-bit I1 gives the same tree as its float copy, by a counting sort over 256 keys
    # instead of 65536 (~30 % faster).
    tree_guide = left if left.dtype == np.uint8 else left_f
    if samples.pattern.kind == "downsample" and method not in ("downsample",):
        if method != "hybrid":
            raise OptionError(f"a downsample sample file can only be decoded with --method downsample, not {method}")
        method = "downsample"
    elif method == "downsample" and samples.pattern.kind != "downsample":
        raise OptionError(f"--method downsample needs a sample file written with --pattern downsample "
                          f"(this one is {samples.pattern.kind})")
    if method == "sparse":
        with timer("tree"):
            tree, = _tree.build_trees([tree_guide], sigma=params.tree_sigma, median_size=params.tree_median)
        with timer("jbf_fill"):
            # The fill writes its volume in the tree's depth-first row order, so the
            # aggregation walk streams through it (half the time of a pixel-order walk).
            layout = _tree.tree_layout(tree)
            cost = _sparse_filled_cost(left_f, guide, samples, min_disp=min_disp, num_disp=volume_layers(num_disp),
                                       params=params, layout=layout)
        with timer("aggregate"):  # the winners are taken during the aggregation's walk
            disp = _tree.aggregate_rows_winners(cost, layout, min_disp=int(min_disp), num_disp=num_disp)
        scratch.recycle(cost)
        with timer("median"):
            disp = median_filter_disparity(disp, params.median_size)
    elif method == "hybrid":
        disp = _decode_hybrid(left_f, guide, samples, tree_guide, min_disp=min_disp, num_disp=num_disp,
                              params=params, timer=timer)
    elif method == "downsample":
        disp = _decode_downsample(left_f, samples, tree_guide, min_disp=min_disp, num_disp=num_disp,
                                  params=params, timer=timer)
    else:
        with timer("prepare"):
            right_f = _sample_values_f32(samples).reshape(samples.height, samples.width, samples.channels)
        if params.full_cost == "census":
            from ._full import census_semiglobal_disparity as full_pair_disparity
        else:
            from ..aggregate._refine import full_pair_disparity
        disp = full_pair_disparity(left_f, right_f, tree_guide=tree_guide, min_disp=min_disp, num_disp=num_disp,
                                   params=params, timer=timer)
    return DecodeResult(disparity=disp, method=method, min_disp=int(min_disp), max_disp=int(max_disp),
                        timings=timer.timings, params=params)


# --------------------------------------------------------------------------------------
# Tiling: frames whose volumes do not fit in memory are decoded in overlapping bands.

#: Rows decoded above and below each band and then dropped.  The sparse fill reaches
#: ~4 sigma_s (40 px at stride 5), but the tree aggregation and, above all, Hybrid's
#: left-right refinement are global: unstable pixels take disparities from far along
#: the tree.  benchmarks/tile_overlap.py measures the seams against the overlap (Teddy, Cones,
#: 1x and 2x, bands of 96 / 192 rows): 64 rows suffice for Sparse but cost Hybrid up to
#: 0.7 pp; with 128 the bad-pixel rate stays within 0.05 pp of untiled in all 8 cases.
DEFAULT_TILE_OVERLAP = 128
#: Bands are never made shorter than this (below it the overlap dominates the work).
MIN_TILE_ROWS = 64
TILED_METHODS = ("sparse", "hybrid", "full")


def _band_samples(samples: SampleSet, top: int, bottom: int):
    """The samples of rows ``[top, bottom)`` as a sample set of that band.

    A regular grid stays a real :class:`SampleSet` (the lattice rows inside the band,
    the row offset moved to the band's origin), so every grid-only decoder path still
    applies; other point patterns get a :class:`_BandSamples` view.
    """
    p = samples.pattern
    if not p.is_regular_grid:
        return _BandSamples(samples, top, bottom)
    from dataclasses import replace as _replace
    first = max(0, -(-(top - p.offset_y) // p.stride_y))
    last = max(first, -(-(bottom - p.offset_y) // p.stride_y))
    pattern = _replace(p, offset_y=p.offset_y + first * p.stride_y - top)
    values = samples.grid_values()[first:last].reshape(-1, samples.channels)
    from ..io._mosaic import shifted_order  # a mosaic band starting on an odd row: the next tile row's pattern
    return SampleSet(height=int(bottom - top), width=samples.width,
                     channel_order=shifted_order(samples.channel_order, rows=top), pattern=pattern, values=np.ascontiguousarray(values), codec=samples.codec,
                     value_bits=samples.value_bits, quality=samples.quality)


class _BandSamples:
    """The samples of rows ``[top, bottom)`` of a non-grid sample set, as a sample set of that band.

    Offers what the decoders read from a :class:`SampleSet` (size, channels, dtype,
    pattern strides, positions in transmission order, RGB values), with positions
    relative to the band.  The pattern is that of the whole frame: only its kind and
    strides are used, which a band shares.
    """

    def __init__(self, samples: SampleSet, top: int, bottom: int):
        rows, cols = samples.positions()
        keep = (rows >= top) & (rows < bottom)
        self._rows = (np.asarray(rows)[keep] - top).astype(np.int64)
        self._cols = np.asarray(cols)[keep].astype(np.int64)
        self._values = samples.values_rgb()[keep]
        self.mosaic = getattr(samples, "mosaic", None)
        self._colours = samples.sample_colours()[keep] if self.mosaic else None
        self.colour_channels = getattr(samples, "colour_channels", samples.channels)
        self.height = int(bottom - top)
        self.width = samples.width
        self.channels = samples.channels
        self.dtype = samples.dtype
        self.pattern = samples.pattern

    @property
    def epsilon(self) -> float:
        return self._values.shape[0] / float(self.height * self.width)

    def positions(self):
        return self._rows, self._cols

    def values_rgb(self) -> np.ndarray:
        return self._values

    def sample_colours(self) -> np.ndarray:
        return self._colours


def auto_tile_rows(samples: SampleSet, *, num_disp: int, method: str, params: DecoderParams | None = None,
                   max_memory: int | None = None, overlap: int = DEFAULT_TILE_OVERLAP) -> int:
    """Band height for :func:`decode` when the whole frame would exceed the memory limit, else 0.

    Returns 0 (decode the frame at once) when the estimate of the whole frame fits the
    limit, when the method or pattern cannot be tiled, or when not even a band of
    :data:`MIN_TILE_ROWS` rows plus its overlap fits (the caller's memory check then
    refuses the frame with its usual message).
    """
    from ..io._limits import default_memory_limit, estimate_decode_memory
    params = params or DecoderParams()
    if method not in TILED_METHODS or samples.pattern.kind == "downsample":
        return 0
    h, w = samples.height, samples.width
    p = samples.pattern

    def estimate(rows: int) -> int:
        return estimate_decode_memory(rows, w, num_disp, method, stride_x=p.stride_x, stride_y=p.stride_y,
                                      sigma_s_per_stride=params.sigma_s_per_stride, sigma_r=params.sigma_r,
                                      cells_per_sigma_s=params.grid_cells_per_sigma_s,
                                      cells_per_sigma_r=params.grid_cells_per_sigma_r)

    try:
        limit = default_memory_limit() if max_memory is None else int(max_memory)
    except ValueError:
        return 0  # a malformed $STEREOBUDGET_MAX_MEMORY is reported by the memory check
    if limit is None or estimate(h) <= limit:
        return 0
    # Whole-frame arrays kept besides the bands: float32 I1, guide and disparity.
    limit -= 24 * h * w
    lo, hi = 0, h  # largest core height whose band (core + 2 overlaps) fits: binary search
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if estimate(min(mid + 2 * overlap, h)) <= limit:
            lo = mid
        else:
            hi = mid - 1
    return lo if lo >= MIN_TILE_ROWS else 0


def decode_tiled(left: np.ndarray, samples: SampleSet, *, max_disp: int, min_disp: int = 0,
                 method: str | None = None, params: DecoderParams | None = None, tile_rows: int,
                 overlap: int = DEFAULT_TILE_OVERLAP, max_memory: int | None = None) -> DecodeResult:
    """Decode a frame as horizontal bands of ``tile_rows`` rows and stitch them.

    Each band is decoded together with ``overlap`` rows above and below it (fewer at the
    frame's top and bottom) and only its own rows are kept, so peak memory is that of
    one band of ``tile_rows + 2 overlap`` rows.  The fill, the trees and the
    refinement are computed per band: a pixel within ``overlap`` rows of a seam loses
    the support of pixels beyond the band, which a large enough overlap makes
    negligible (see :data:`DEFAULT_TILE_OVERLAP`).

    Parameters
    ----------
    left, samples, max_disp, min_disp, method, params, max_memory
        As :func:`decode`.
    tile_rows : int
        Rows kept from each band (>= 1).
    overlap : int
        Extra rows decoded on each side of a band (>= 0).

    Returns
    -------
    DecodeResult
        ``timings`` are summed over the bands.
    """
    method, params = _resolve_method(left, samples, method=method, params=params,
                                     min_disp=min_disp, max_disp=max_disp)
    if method not in TILED_METHODS or samples.pattern.kind == "downsample":
        raise OptionError(f"tiled decoding supports {', '.join(TILED_METHODS)} on point samples, not "
                          f"{method} on a {samples.pattern.kind} sample file")
    tile_rows, overlap = int(tile_rows), int(overlap)
    if tile_rows < 1 or overlap < 0:
        raise OptionError(f"tile rows must be >= 1 and the overlap >= 0 (got {tile_rows}, {overlap})")
    h = samples.height
    disparity = np.empty((h, samples.width), np.float32)
    timings: dict = {}
    tiles = 0
    for top in range(0, h, tile_rows):
        bottom = min(top + tile_rows, h)
        band_top, band_bottom = max(top - overlap, 0), min(bottom + overlap, h)
        # The bands are sized to the memory limit: no room for spare volumes beside them.
        with scratch.holding_no_large_spares():
            band = decode(left[band_top:band_bottom], _band_samples(samples, band_top, band_bottom),
                          max_disp=max_disp, min_disp=min_disp, method=method, params=params,
                          max_memory=max_memory, tile_rows=0)
        disparity[top:bottom] = band.disparity[top - band_top:bottom - band_top]
        for stage, seconds in band.timings.items():
            timings[stage] = timings.get(stage, 0.0) + seconds
        tiles += 1
        del band
    log.debug("decoded %d bands of %d rows (+%d overlap)", tiles, tile_rows, overlap)
    return DecodeResult(disparity=disparity, method=method, min_disp=int(min_disp), max_disp=int(max_disp),
                        timings=timings, params=params)
