"""The memory estimate of a decode, from the same :class:`DecoderParams` the decoder runs with.

:func:`stereobudget.io.estimate_decode_memory` is the formula (kept beside the limits, which
the camera side reads without the decoder); here it is fed from the sample set and the
parameters, so the check before a decode and the tiling's band search cannot drift apart
from each other or from what the decoder allocates.
"""

from __future__ import annotations

from ..io._limits import check_decode_memory, estimate_decode_memory
from ._params import DecoderParams


def _memory_arguments(samples, params: DecoderParams) -> dict:
    """Keywords of :func:`stereobudget.io.estimate_decode_memory` that the samples and params set."""
    p = samples.pattern
    return dict(stride_x=p.stride_x, stride_y=p.stride_y, sigma_s_per_stride=params.sigma_s_per_stride,
                sigma_r=params.sigma_r, cells_per_sigma_s=params.grid_cells_per_sigma_s,
                cells_per_sigma_r=params.grid_cells_per_sigma_r)


def decode_memory(samples, *, num_disp: int, method: str, params: DecoderParams | None = None,
                  rows: int | None = None) -> int:
    """Estimated peak bytes of decoding ``samples`` (or a band of ``rows`` of it).

    Parameters
    ----------
    samples : SampleSet
    num_disp : int
        Disparities searched.
    method : str
        The method that will run (``"downsample"`` for a downsample sample file).
    params : DecoderParams, optional
        Those the decoder runs with (default: the defaults).
    rows : int, optional
        Height of the band decoded (default: the whole frame).

    Returns
    -------
    int
    """
    params = params or DecoderParams()
    return estimate_decode_memory(samples.height if rows is None else int(rows), samples.width, int(num_disp),
                                  method, **_memory_arguments(samples, params))


def check_memory(samples, *, num_disp: int, method: str, params: DecoderParams | None = None,
                 max_memory: int | None = None) -> int:
    """:func:`stereobudget.io.check_decode_memory` of this decode: raises
    :class:`~stereobudget.errors.MemoryLimitError` over the limit, else returns the estimate."""
    params = params or DecoderParams()
    return check_decode_memory(samples.height, samples.width, int(num_disp), method, max_memory=max_memory,
                               **_memory_arguments(samples, params))
