"""stereobudget: depth and the right image from a full left image plus sparse right-image samples.

The library is grouped by topic; each subpackage re-exports its public names:

- :mod:`stereobudget.io` — the sample file, raw sample grids, images, disparity files,
  atomic writes, size and memory limits.
- :mod:`stereobudget.sampling` — where the right camera samples (grid, random, adaptive,
  farthest-point), and the block means Downsample sends.
- :mod:`stereobudget.encoding` — the camera's job: select the samples
  (:func:`stereobudget.encoding.encode_image`), fit a byte budget
  (:func:`stereobudget.encoding.fit_budget`), write the file
  (:func:`stereobudget.encoding.encode_file`).
- :mod:`stereobudget.cost` — matching costs.  **Eq. 1**, the DSI of a full pair
  (:func:`stereobudget.cost.full_dsi`); **Eq. 2**, the sparse DSI (the cost of each left pixel
  against the right samples): :func:`stereobudget.cost.sparse_pair_cost`, with its step and
  lattice census terms, evaluated at a sample by :func:`stereobudget.cost.sample_cost` (its
  terms in one record, :class:`stereobudget.cost.SparseCostTerms`); the census of a full pair
  and of a grid's spacing (:func:`stereobudget.cost.census_cost_volume`,
  :func:`stereobudget.cost.spaced_census`).
- :mod:`stereobudget.fill` — **Eq. 3** with the filter of **Eq. 4**, the normalised joint
  bilateral fill of the sparse DSI: :func:`stereobudget.fill.filled_sparse_dsi` (the grids of
  :func:`stereobudget.fill.sparse_dsi_grids`; its terms and scales in
  :class:`stereobudget.cost.SparseCostTerms` and :class:`stereobudget.fill.FillScale`); the
  low-passed pair Hybrid and Downsample use (:func:`stereobudget.fill.gaussian_lowpass`,
  :func:`stereobudget.fill.block_lowpass`).
- :mod:`stereobudget.aggregate` — Yang's aggregation on the minimum spanning tree (the paper's
  cited matcher): :func:`stereobudget.aggregate.aggregate`; the cost volumes of both views
  (:func:`stereobudget.aggregate.pair_cost_rows`, where **Hybrid's mix** of the Sparse fill
  and the dense DSI of the low-passed pair is taken per pixel), winner-take-all and the
  left-right check with refinement; the semi-global paths the default full-pair and Hybrid
  routes aggregate on (:func:`stereobudget.aggregate.semiglobal_aggregate`).
- :mod:`stereobudget.decoding` — the decoders of paper Fig. 2 (Sparse, Hybrid, Downsample,
  and the full pair), their parameters (Hybrid's weight: :func:`stereobudget.decoding.hybrid_weight`),
  tiling and the memory estimate.  :func:`decode` is the entry point; :class:`Decoder` runs a
  sequence of decodes on each other's memory (an opt-in: it holds memory between calls).
- :mod:`stereobudget.synthesis` — the right image recovered from I1 and the disparity:
  **the warp for Î2** (:func:`stereobudget.synthesis.warp_left_to_right`), then the samples
  fill the holes (:func:`stereobudget.synthesis.recover_right`).
- :mod:`stereobudget.pipeline` — one pair, one file, one frame: the encode and decode paths
  (outputs checked, inputs read, decode, Î2, checks, atomic writes) that the commands, the
  batch items and the frame streams all call.
- :mod:`stereobudget.geometry` — real camera pairs: calibration files, rectification at the
  host (the samples placed where they land), depth in metres and PLY point clouds.
- :mod:`stereobudget.batch` — many inputs in one run; :mod:`stereobudget.cli` — the
  ``sb-encode`` / ``sb-decode`` commands (the repository's ``cli/`` folder);
  :mod:`stereobudget.scenes` — synthetic scenes with exact ground truth.

Plain references, for tests and for reading, sit beside the fast paths and are named for them:
:func:`stereobudget.cost.full_dsi_reference` (Eq. 1 layer by layer),
:func:`stereobudget.cost.census_cost_volume_reference`,
:func:`stereobudget.fill.sparse_joint_bilateral_reference` and
:func:`stereobudget.fill.filled_sparse_dsi_reference` (Eqs. 2-4 summed directly),
:func:`stereobudget.aggregate.aggregate_reference` (Yang's serial two-pass walk),
:func:`stereobudget.aggregate.left_right_refinement_reference` (his left-right check and
refinement), :func:`stereobudget.aggregate.semiglobal_aggregate_reference` and
:func:`stereobudget.synthesis.warp_reference` (the warp for Î2, gathered pixel by pixel).
Hybrid's mix is held to the weighted mean of the Sparse fill and :func:`~stereobudget.cost.full_dsi`.

The camera side (:mod:`stereobudget.encoding`, :mod:`stereobudget.io`, :mod:`stereobudget.sampling`)
imports neither numba nor OpenCV; the decoder is loaded on first use of :func:`decode`.
"""

from ._version import __version__

__all__ = ["__version__", "decode", "Decoder", "DecoderParams", "DecodeResult"]


def __getattr__(name):
    # Lazy: importing the decoder compiles/loads numba kernels, which the camera side never needs.
    if name in ("decode", "Decoder", "DecoderParams", "DecodeResult"):
        from . import decoding
        return getattr(decoding, name)
    raise AttributeError(f"module 'stereobudget' has no attribute {name!r}")
