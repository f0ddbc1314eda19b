"""What every decoder shares: :class:`DecoderParams`, :class:`DecodeResult`, the input
checks, the noise adaptation of the cost truncations and the choice of the method a
sample set implies."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from ..cost._cost import DEFAULT_TRUNCATION, noise_level, noise_level_of_gray, to_float_image
from ..errors import MismatchError, OptionError
from ..io._samples import SampleSet
from ._methods import DEFAULT_METHOD, METHOD_RECORDS, METHODS

#: The routes a :class:`DecoderParams` may choose, each with what it does (checked on construction).
HYBRID_AGGREGATIONS = {
    "semiglobal_census": "the Sparse fill mixed with the census of the low-passed pair, semi-global paths",
    "semiglobal": "the paper's mixed cost on the semi-global paths",
    "tree": "the paper's mixed cost on Yang's tree, left-right check and refinement",
}
FULL_COSTS = {
    "census": "5x5 census of the pair, semi-global paths",
    "ad": "Eq. 1 (colour and gradient differences) on Yang's tree",
}
RIGHT_CHECKS = {
    "tree": "the right view's costs aggregated on the right image's own tree",
    "diagonal": "the right view's disparity read off the left view's aggregated costs",
}
ROW_FILLS = {
    "nearest": "a rejected pixel takes the disparity of the nearest kept pixel of its row",
    "background": "a rejected pixel takes the smaller disparity of the kept pixels on either side",
}


@dataclass(frozen=True)
class DecoderParams:
    """Parameters of the decoders (defaults: the paper's values, see docs/results.md).

    Attributes
    ----------
    sigma_r : float
        Range sigma of the joint bilateral fill, 8-bit units (paper: 20; 15 measured
        slightly better on Middlebury and neutral on the synthetic scenes).
    sigma_s_per_stride : float
        Spatial sigma of the fill in units of the sampling stride (paper: 3).  A narrower
        window mixes fewer costs from occluded pixels into their visible neighbours, and
        fewer disparities of a slanted surface into one pixel; the semi-global paths that
        follow the fill do the smoothing the paper asked of a wide window.  Stride 5, mean
        bad > 1 px over 23 real pairs / the paper's 4 scenes (docs/results.md): Hybrid
        2 -> 26.60 / 7.98, 1.5 -> 25.83 / 7.86, 1 -> 25.29 / 8.02; Sparse 2 -> 29.57 /
        6.74, 1.5 -> 29.24 / 6.68, 1 -> 29.40 / 7.27.  1.5 is better on both sets for both
        methods; 1 loses on the fronto-parallel 2001 scenes and costs 37 % more time
        (a grid four times finer).
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
    median_size, median_passes : int
        Median filter on the final disparity: its window side (0 = off; 3 or 5, the sizes
        OpenCV filters float32 maps at) and how many times it runs
        (:func:`stereobudget.aggregate.median_filter_disparity`).  Two passes of 5 x 5 act
        about as one 7 x 7.  Swept on both sets, every route at once (``scripts/evaluate_real.py
        --param median_passes=...``, mean bad > 1 px, realdev / Middlebury's four; Hybrid at
        stride 5, ``--epsilon 0.04``, stride 3, then the full pair):

        - one 3 x 3: 24.96 / 20.27 / 18.76 / 16.83 and 7.73 / 7.02 / 5.56 / 3.80;
        - one 5 x 5: 24.82 / 20.07 / 18.61 / 16.30 and 7.57 / 6.83 / 5.43 / 3.55;
        - two: 24.77 / 19.98 / 18.55 / 16.11 and 7.55 / 6.70 / 5.36 / 3.50;
        - three: 24.76 / 19.95 / 18.54 / 16.07 and 7.54 / 6.63 / 5.34 / 3.52;
        - one true 7 x 7: 24.75 / 19.95 / 18.53 / 16.07 and 7.54 / 6.71 / 5.36 / 3.54;
        - one true 13 x 13: 24.84 / 20.02 / 18.69 / 16.40 and 7.66 / 6.54 / 5.47 / 3.99.

        The disparity map's outliers are streaks and specks a few pixels across (row
        fills, unsampled structure at the grid's spacing), which a wider median removes
        until it starts to erase thin structures; two passes take most of the gain for
        1.5 ms a 640 x 480 frame.
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
        ``None``: chosen from the stride by :func:`stereobudget.decoding.hybrid_weight`.
    grid_cells_per_sigma_s, grid_cells_per_sigma_r : float
        Resolution of the bilateral grid of the Sparse fill: grid cells per spatial and
        per range sigma (:func:`stereobudget.fill.grid_geometry`).  One cell per
        sigma is Paris & Durand's sampling rate; the grid blur is narrowed so the
        effective kernel keeps its sigma, and the sweep in docs/results.md
        (``scripts/sweep.py``) finds every scene within 0.2 pp of 2 cells per
        sigma at strides 3, 5 and 8, for 1/8 of the grid cells.
    hybrid_aggregation : {"semiglobal_census", "semiglobal", "tree"}
        How Hybrid matches and aggregates.  ``"semiglobal_census"``: the Sparse fill
        (weight ``hybrid_sparse_weight``) mixed with the census, at the grid's spacing, of
        the low-passed I1 and the low-passed interpolation of the samples, summed along
        the semi-global paths (P2 = ``hybrid_sgm_p2``), checked left against right on the
        diagonal, rejected pixels filled from their row.  On the 23 real pairs
        (``scripts/evaluate_real.py``) 25.8 % bad pixels at stride 5 and 19.6 % at
        stride 3, against 31.2 % at stride 5 for ``"tree"`` (the paper's route: the Sparse
        fill mixed with absolute differences of the low-passed pair, Yang's tree, check
        and refinement), which stays better on the four paper scenes (6.1 % against 7.9 %
        at stride 5).  ``"semiglobal"``: the paper's mixed cost on the semi-global paths
        (28.3 % / 8.4 %).
    full_cost : {"census", "ad"}
        Cost and aggregation of the full pair.  ``"census"``: 5x5 census, semi-global
        aggregation (:mod:`stereobudget.decoding._full`); on the 23 real pairs of the
        development set 16.8 % bad pixels against OpenCV SGBM's 20.8 % and the tree on
        absolute differences' 26 % (``scripts/evaluate_real.py``; docs/results.md).
        ``"ad"``: the paper's Eq. (1) cost on the tree (Yang), which assumes equal
        exposure in both cameras.
    sgm_p1, sgm_p2 : float
        Semi-global penalties of a one-level and of a larger disparity change, as
        multiples of the cost volume's typical margin (the data term's own scale, so the
        same multiples serve every scene, size and cost); the sweep is in docs/results.md
        (``scripts/evaluate_real.py --param sgm_p2=4``).
    hybrid_sgm_p2 : float
        P2 of Hybrid's semi-global aggregation.  A sample grid's filled cost separates
        disparities less sharply than a full pair's census, so its margin calls for a
        stronger smoothness term: on 8 scenes (6 real, 2 Middlebury) at stride 5 P2 = 4,
        8, 16, 32 gave 24.65, 24.03, 23.48, 23.13 % mean bad pixels, the last two losing
        on Middlebury (Tsukuba 7.8 -> 8.4 -> 8.8); 16 is the compromise.
    sgm_edge_scale : float
        Gray-level difference across which P2 halves (depth edges follow colour edges).
    sgm_paths : {4, 8}
        Semi-global paths of the full pair: horizontal and vertical, plus the diagonals for 8.
    hybrid_sgm_paths : {4, 8}
        Semi-global paths of Hybrid's routes.  Four (no diagonals) measured better than eight
        on realdev at every sampling rate and within 0.2 pp on Middlebury's four, and take 18 % less
        time at 640x480 (``python scripts/evaluate_real.py --param hybrid_sgm_paths=8`` against
        the default; docs/results.md): realdev 25.83 -> 25.28 (stride 5), 20.96 -> 20.59
        (``--epsilon 0.04``), 19.56 -> 19.06 (stride 3); Middlebury 7.86 -> 7.86, 7.06 -> 7.23,
        5.72 -> 5.78.  The diagonals smooth the samples' coarse DSI along slants that are not
        there (KITTI's road: 2-4 pp better without them).  The full pair keeps eight, which
        measured better there (16.83 against 17.12 on realdev, 3.80 against 4.00).
    row_fill, hybrid_row_fill : {"nearest", "background"}
        What the pixels the semi-global routes' left-right check rejects take
        (:func:`stereobudget.aggregate.fill_from_row`): the nearest kept pixel of the row
        (``row_fill``, the full pair), or the smaller disparity of the kept pixels on either
        side (``hybrid_row_fill``, Hybrid): Hirschmüller's treatment of occlusions.  On both
        sets and every sampling rate Hybrid measured better with the background
        (``scripts/evaluate_real.py --param hybrid_row_fill=nearest`` against the default):
        realdev 25.28 -> 24.96 (stride 5), 20.59 -> 20.27 (``--epsilon 0.04``), 19.06 -> 18.76
        (stride 3); Middlebury's four 7.86 -> 7.73, 7.23 -> 7.02, 5.78 -> 5.56.  The full pair
        measured worse with it (16.83 -> 16.96, 3.80 -> 3.86): its rejected pixels are fewer and
        less often beside an occluding edge, so it keeps the nearest.
    rejected_median : bool
        After the row fill of the semi-global routes (the full pair and Hybrid's), give each
        pixel the left-right check rejected the weighted median of the filled map around it,
        weighted by nearness and likeness in I1's colours
        (:func:`stereobudget.aggregate.weighted_median_fill`; Rhemann et al. 2011, Hosni et
        al. 2013: radius 9, sigma_s 9, every third pixel; sigma_c 10 levels of the largest
        channel difference): the row fill's streaks take the disparity of the surface the
        pixel belongs to.  Measured with ``scripts/evaluate_real.py
        --param rejected_median=False`` against the default (mean bad > 1 px, Hybrid at stride
        5 / ``--epsilon 0.04`` / stride 3, then the full pair): see docs/results.md, "The
        rejected pixels' weighted median".
    right_check : {"tree", "diagonal"}
        Where the left-right check of Hybrid, Downsample and the full pair gets the right
        view's disparity: ``"tree"`` aggregates the right view's costs on the right
        image's own tree (Yang); ``"diagonal"`` reads it off the left view's aggregated
        costs, normalised by each pixel's tree support (Hirschmüller's search), which
        saves a tree and an aggregation but lets more errors pass the check: measured
        0.3-0.5 pp worse on the 9-scene mean, up to 2.5 pp on Teddy (scripts/bench.py).
    plane_refinement : bool
        After the semi-global routes' left-right check and row fill, fit a robust plane
        to the confident pixels of each segment of I1 and let it replace the rejected
        pixels and the terraces it explains, a grid's samples arbitrating
        (:func:`stereobudget.aggregate.plane_refinement`).  Off: Hybrid, mean bad > 1 px
        on the 23 real pairs / the paper's 4 (``scripts/evaluate_real.py --param
        plane_refinement=True``), raw stride 5 25.83 -> 25.71 / 7.86 -> 7.85,
        ``--epsilon 0.04`` 20.96 -> 20.81 / 7.06 -> 7.04, stride 3 19.56 -> 19.42 / 5.72 ->
        5.78 (Venus 1.47 -> 1.63): small gains on the real pairs (KITTI, Vintage,
        Playtable), a loss on the paper's scenes at stride 3, for 9-18 % of the decode time.
    plane_segment_size : int
        Spacing in pixels of the segments' seeds (segments of about its square).
    """

    sigma_r: float = 15.0
    sigma_s_per_stride: float = 1.5
    truncation: float = DEFAULT_TRUNCATION
    full_truncation: float = 7.0
    grad_truncation: float = 2.0
    tree_sigma: float = 0.1 * 255
    tree_median: int = 3
    grad_weight: float = 0.89
    median_size: int = 5
    median_passes: int = 2
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
    hybrid_sgm_paths: int = 4
    right_check: str = "tree"
    row_fill: str = "nearest"
    hybrid_row_fill: str = "background"
    rejected_median: bool = True
    plane_refinement: bool = False
    plane_segment_size: int = 12

    def __post_init__(self):
        for name, table in (("hybrid_aggregation", HYBRID_AGGREGATIONS), ("full_cost", FULL_COSTS),
                            ("right_check", RIGHT_CHECKS), ("row_fill", ROW_FILLS),
                            ("hybrid_row_fill", ROW_FILLS)):
            value = getattr(self, name)
            if value not in table:
                raise OptionError(f"unknown {name} {value!r}; expected one of {', '.join(map(repr, table))}")
        if self.median_size not in (0, 1, 3, 5):
            raise OptionError(f"median_size must be 0, 1, 3 or 5, got {self.median_size!r}")
        if not isinstance(self.median_passes, (int, np.integer)) or self.median_passes < 0:
            raise OptionError(f"median_passes must be a whole number >= 0, got {self.median_passes!r}")


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
    params : DecoderParams
        The parameters used (after the noise adaptation).
    stream : dict
        Empty, except from a ``Decoder(temporal=True)``: the frame's number from 0
        (``frame``), the disparities it searched (``searched``, a pair) and why
        (``reason``, see :class:`stereobudget.decoding.TemporalSearch`).
    """

    disparity: np.ndarray
    method: str
    min_disp: int
    max_disp: int
    timings: dict = field(default_factory=dict)
    params: DecoderParams = field(default_factory=DecoderParams)
    stream: dict = field(default_factory=dict)

    def summary(self) -> dict:
        return {"method": self.method, "min_disp": self.min_disp, "max_disp": self.max_disp,
                "timings": {k: round(v, 4) for k, v in self.timings.items()}, "params": asdict(self.params)}


class StageTimer:
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
    if w < 2:
        raise OptionError(f"the images are {w} pixel wide: a disparity needs at least two columns")
    if max_disp - min_disp >= w or abs(min_disp) >= w or abs(max_disp) >= w:
        raise OptionError(f"disparity range [{min_disp}, {max_disp}] does not fit an image {w} pixels wide")


def is_full_grid(samples: SampleSet) -> bool:
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
    noise = METHOD_RECORDS[method].noise
    if noise == "sparse":
        changes.update(truncation=max(params.truncation, 2 * k * sigma),
                       step_truncation=max(params.step_truncation, 2 * k * sigma))
    elif noise == "dense":
        changes.update(full_truncation=max(params.full_truncation, 2 * k * sigma),
                       grad_truncation=max(params.grad_truncation, k * sigma))
    return replace(params, **changes)



def sampling_stride(samples: SampleSet) -> float:
    """The geometric mean of the pattern's strides: the scale of the fill and the low-pass."""
    return float(np.sqrt(samples.pattern.stride_x * samples.pattern.stride_y))


def method_for(samples: SampleSet, requested: str | None) -> str:
    """The method that decodes ``samples`` when ``requested`` is asked for: the one place it is decided.

    A stride-1 file is decoded as the full pair whatever was asked; a file of block means by
    Downsample (when the default was asked); any other method must accept the file's samples
    (its record's ``patterns``).
    """
    requested = requested or DEFAULT_METHOD
    if requested not in METHODS:
        raise OptionError(f"unknown method {requested!r}; expected one of {', '.join(METHODS)}")
    p = samples.pattern
    if p.kind == "downsample":
        if requested not in ("downsample", DEFAULT_METHOD):
            raise OptionError(f"a downsample sample file can only be decoded with --method downsample, "
                              f"not {requested}")
        return "downsample"
    if is_full_grid(samples):
        return "full"
    takes = METHOD_RECORDS[requested].patterns
    if takes == "blocks":
        raise OptionError(f"--method downsample needs a sample file written with --pattern downsample "
                          f"(this one is {p.kind})")
    if takes == "full":
        raise OptionError(f"--method full needs every pixel of I2 (a sample file written with --stride 1); "
                          f"this one holds {p.kind} samples at stride {p.stride_x}x{p.stride_y}")
    return requested


def resolve_method(left, samples, *, method, params, min_disp, max_disp, adapt=True):
    """Validate the inputs, pick the method a sample set implies (:func:`method_for`), adapt the
    params to mosaic samples and (``adapt``) to I1's noise."""
    params = params or DecoderParams()
    if (method or DEFAULT_METHOD) not in METHODS:
        raise OptionError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    check_inputs(left, samples, min_disp=min_disp, max_disp=max_disp)
    from ._mosaic import mosaic_decoding
    params = mosaic_decoding(samples, method=method or DEFAULT_METHOD, params=params)
    method = method_for(samples, method)
    return method, (adapt_to_noise(params, left, method=method) if adapt else params)
