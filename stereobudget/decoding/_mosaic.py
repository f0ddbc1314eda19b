"""How the decoders use raw-mosaic samples (``sb-encode --pix-fmt bayer_*``).

Every sample is compared with the channel of I1 its colour names (the colour of its pixel
in the right camera's mosaic): the samples reach the cost kernels as RGB values with NaN
in the two channels they lack (:func:`stereobudget.fill._lowpass._sample_values_f32`),
which :func:`stereobudget.cost.pixel_cost` skips.  So:

* ``sparse``: Eq. (2) on the sampled channel only.  The row-step and lattice-census terms
  are off: at an odd stride a sample's grid neighbours have other colours, so neither
  their difference nor their order says anything about I2's structure.
* ``hybrid``: the same Sparse fill, and the dense term on an interpolation of the samples
  that normalises every channel by its own samples (R and B from a quarter of them at an
  odd stride, G from half).  A lattice missing a colour (an even stride samples one or two
  colours only) gives no such image: there Hybrid keeps only its Sparse fill.
* ``full`` (stride 1) would need a demosaiced frame, and ``downsample`` cannot apply
  (block means would mix the colours; such files are refused when written and read).
"""

from __future__ import annotations

from dataclasses import replace

from ..errors import OptionError


def mosaic_decoding(samples, *, method: str, params):
    """The ``params`` for decoding mosaic samples with ``method``; unchanged for any other sample set.

    Raises
    ------
    OptionError
        A stride-1 mosaic (``full``): the decoders compare samples, not a demosaiced frame.
    """
    if not getattr(samples, "mosaic", None):
        return params
    p = samples.pattern
    if p.kind == "grid" and p.stride_x == 1 and p.stride_y == 1:
        raise OptionError(f"a {samples.channel_order} mosaic at stride 1 is a whole raw frame: the full-pair "
                          "decoder needs it demosaiced (encode the demosaiced RGB frame); Sparse and Hybrid "
                          "decode mosaic samples at stride >= 2")
    changes = {"sparse_census_weight": 0.0, "step_weight": 0.0}
    if method == "hybrid":
        from ..io._mosaic import colours_present
        if not all(colours_present(samples)):
            changes["hybrid_sparse_weight"] = 1.0
    return replace(params, **changes)
