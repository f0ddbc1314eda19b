"""The memory model of a decode: its peak from the image size, the range, the method's record and
the same :class:`DecoderParams` the decoder runs with.

:func:`estimate_decode_memory` is the formula, each method's part of it in its record
(:data:`stereobudget.decoding.METHOD_RECORDS`) and the fill's grids sized by the fill's own
:func:`stereobudget.fill.grid_geometry`; :func:`decode_memory` / :func:`check_memory` feed it
from a sample set and the parameters, so the check before a decode and the tiling's band
search cannot drift apart from each other or from what the decoder allocates.  Free of
numba, like the records.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING

from ..cost._layers import volume_layers
from ..fill._geometry import grid_geometry
from ._methods import method_record

if TYPE_CHECKING:
    from ._params import DecoderParams

_FLOAT32 = 4
#: Bytes per pixel the decoders hold besides the cost volumes and bilateral grids:
#: float32 copies of I1 (and of the interpolated right image), the gray guide, the
#: x-gradients, the two trees while they are built (edge keys, sorted edges, order,
#: parent, weight), the low-pass grids of Hybrid and the disparity maps.  Measured
#: peaks stay below this (see tests/cli/test_robustness.py and docs/errors.md).
_PER_PIXEL_OVERHEAD = 192
#: Safety margin on the volume terms (allocator slack, numba thread-local buffers).
_VOLUME_MARGIN = 1.10
#: Fixed allowance for small arrays (kernels, LUTs) independent of the image size.
_FIXED_OVERHEAD = 16 * 2 ** 20



def estimate_decode_memory(height: int, width: int, num_disp: int, method: str, *,
                           stride_x: int = 5, stride_y: int = 5, sigma_s_per_stride: float = 1.5,
                           sigma_r: float = 15.0, cells_per_sigma_s: float = 1.0,
                           cells_per_sigma_r: float = 1.0) -> int:
    """Conservative estimate of the peak memory of :func:`stereobudget.decoding.decode`, in bytes.

    The decoders are dominated by float32 ``(H, W, D)`` cost volumes (``V`` bytes each)
    and, for the Sparse fill, two float32 bilateral grids ``(GY, GX, GZ, D)`` (``G``
    bytes each) of which a separable blur keeps a third copy:

    ================  ================================
    method            at most alive at once
    ================  ================================
    ``sparse``        ``max(3 G, 2 G + V)``
    ``hybrid``        ``max(3 G, 2 G + 2 V)``
    ``full``          ``V + V / 4``
    ``downsample``    ``2 V``
    ================  ================================

    (each method's ``peak`` in :data:`stereobudget.decoding.METHOD_RECORDS` says where).

    A margin of 10 % on the volume terms, 192 bytes per pixel for images, trees and
    disparity maps, and 16 MiB of fixed allowance are added.  Measured peaks
    (``scripts/measure_decode_memory.py``: peak RSS above the resting RSS after JIT
    warm-up) are 55-99 % of the estimate at 450x375 and 1152x900, except a Sparse decode
    of an fps pattern at stride 3 (113 %: its grids outgrow the model); the grid terms are
    those of the general fill (jitter, fps), looser for regular grids (docs/errors.md).

    Parameters
    ----------
    height, width : int
        Image size in pixels.
    num_disp : int
        Number of disparities searched (``max_disp - min_disp + 1``).
    method : {"sparse", "hybrid", "full", "downsample"}
        The decoder that will actually run (a stride-1 file runs ``full``).
    stride_x, stride_y : int
        Sampling strides (the Sparse fill's grid cell is proportional to the stride).
    sigma_s_per_stride, sigma_r : float
        Fill sigmas (:class:`stereobudget.decoding.DecoderParams`).
    cells_per_sigma_s, cells_per_sigma_r : float
        Resolution of the fill's bilateral grid (``DecoderParams.grid_cells_per_sigma_*``).

    Returns
    -------
    int
        Bytes.
    """
    if height < 1 or width < 1 or num_disp < 1:
        raise ValueError(f"size {width}x{height} with {num_disp} disparities is empty")
    record = method_record(method)
    pixels = int(height) * int(width)
    num_disp = volume_layers(num_disp)
    volume = pixels * num_disp * _FLOAT32
    grid = 0
    if record.fill_grids:
        # The fill's own geometry, with the largest guide value (255: every guide is in 8-bit
        # units), so the estimate never falls below what the fill allocates.
        stride = math.sqrt(max(int(stride_x), 1) * max(int(stride_y), 1))
        gy, gx, gz = grid_geometry(height, width, 255.0, sigma_s=sigma_s_per_stride * stride, sigma_r=sigma_r,
                                   cells_per_sigma_s=cells_per_sigma_s, cells_per_sigma_r=cells_per_sigma_r).shape
        grid = gy * gx * gz * num_disp * _FLOAT32
    return int(record.peak(volume, grid) * _VOLUME_MARGIN) + _PER_PIXEL_OVERHEAD * pixels + _FIXED_OVERHEAD




def check_decode_memory(height: int, width: int, num_disp: int, method: str, *,
                        max_memory: int | None = None, stride_x: int = 5, stride_y: int = 5,
                        sigma_s_per_stride: float = 1.5, sigma_r: float = 15.0,
                        cells_per_sigma_s: float = 1.0, cells_per_sigma_r: float = 1.0) -> int:
    """Raise :class:`~stereobudget.errors.MemoryLimitError` when a decode would exceed the limit.

    Parameters
    ----------
    height, width, num_disp, method, stride_x, stride_y, sigma_s_per_stride, sigma_r, cells_per_sigma_s, cells_per_sigma_r
        As :func:`estimate_decode_memory`.
    max_memory : int, optional
        Limit in bytes; default :func:`default_memory_limit`.

    Returns
    -------
    int
        The estimate, in bytes.
    """
    from ..errors import MemoryLimitError, OptionError
    from ..io._limits import DEFAULT_MEMORY_FRACTION, MEMORY_LIMIT_ENV, default_memory_limit, format_size

    needed = estimate_decode_memory(height, width, num_disp, method, stride_x=stride_x,
                                    stride_y=stride_y, sigma_s_per_stride=sigma_s_per_stride,
                                    sigma_r=sigma_r, cells_per_sigma_s=cells_per_sigma_s,
                                    cells_per_sigma_r=cells_per_sigma_r)
    if max_memory is None:
        try:
            limit = default_memory_limit()
        except ValueError as exc:
            raise OptionError(f"${MEMORY_LIMIT_ENV}: {exc}") from None
        source = f"{int(DEFAULT_MEMORY_FRACTION * 100)} % of the available memory"
        if os.environ.get(MEMORY_LIMIT_ENV):
            source = f"${MEMORY_LIMIT_ENV}"
    else:
        limit, source = int(max_memory), "--max-memory"
    if limit is not None and needed > limit:
        raise MemoryLimitError(
            f"decoding {width}x{height} with {num_disp} disparities ({method}) needs about "
            f"{format_size(needed)} but {format_size(limit)} is allowed ({source}); narrow the "
            f"--min-disp/--max-disp range, use a smaller image, or raise --max-memory")
    return needed



def _default_params():
    from ._params import DecoderParams
    return DecoderParams()


def _memory_arguments(samples, params: DecoderParams) -> dict:
    """Keywords of :func:`estimate_decode_memory` that the samples and params set."""
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
    params = params or _default_params()
    return estimate_decode_memory(samples.height if rows is None else int(rows), samples.width, int(num_disp),
                                  method, **_memory_arguments(samples, params))


def check_memory(samples, *, num_disp: int, method: str, params: DecoderParams | None = None,
                 max_memory: int | None = None) -> int:
    """:func:`check_decode_memory` of this decode: raises
    :class:`~stereobudget.errors.MemoryLimitError` over the limit, else returns the estimate."""
    params = params or _default_params()
    return check_decode_memory(samples.height, samples.width, int(num_disp), method, max_memory=max_memory,
                               **_memory_arguments(samples, params))


__all__ = ["estimate_decode_memory", "check_decode_memory", "decode_memory", "check_memory"]
