"""Downsample (paper Fig. 2(a)): the camera sent block means; they are upsampled, I1 is passed
through the same down/up operator so both have the same spectrum, and the pair is matched
like a full pair (LR check + refinement)."""

from __future__ import annotations

from ..aggregate._refine import full_pair_disparity
from ..fill._lowpass import _sample_values_f32, block_lowpass, upsample_block_means


def decode_downsample(left_f, guide, samples, tree_guide, *, min_disp, num_disp, params, timer):
    """Left disparity by the Downsample decoder (module docstring); arguments as
    :func:`stereobudget.decoding._sparse.decode_sparse` (``samples`` a downsample sample set;
    ``guide`` unused, every pipeline has one signature)."""
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
