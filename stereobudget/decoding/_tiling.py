"""Tiling: frames whose volumes do not fit in memory are decoded in overlapping bands."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from ..errors import OptionError
from ..io._samples import SampleSet
from .._kernels import _scratch as scratch
from ._frame import decode_frame
from ..io._limits import default_memory_limit
from ._memory import decode_memory
from ._methods import TILED_METHODS
from ._params import DecodeResult, DecoderParams, resolve_method

log = logging.getLogger("stereobudget")

#: Rows decoded above and below each band and then dropped.  The sparse fill reaches
#: ~4 sigma_s (40 px at stride 5), but the tree aggregation and, above all, Hybrid's
#: left-right refinement are global: unstable pixels take disparities from far along
#: the tree.  scripts/tile_overlap.py measures the seams against the overlap (Teddy, Cones,
#: 1x and 2x, bands of 96 / 192 rows): 64 rows suffice for Sparse but cost Hybrid up to
#: 0.7 pp; with 128 the bad-pixel rate stays within 0.05 pp of untiled in all 8 cases.
DEFAULT_TILE_OVERLAP = 128
#: Bands are never made shorter than this (below it the overlap dominates the work).
MIN_TILE_ROWS = 64


def band_samples(samples: SampleSet, top: int, bottom: int):
    """The samples of rows ``[top, bottom)`` as a sample set of that band.

    Parameters
    ----------
    samples : SampleSet
        The samples of a whole frame.
    top, bottom : int
        The band's first row and the row after its last, in frame rows.

    Returns
    -------
    SampleSet or sample-set view
        A regular grid stays a real :class:`SampleSet` (the lattice rows inside the band,
        the row offset moved to the band's origin), so every grid-only decoder path still
        applies; other point patterns get a read-only view with the decoders' reading
        interface, positions relative to the band.  A Bayer mosaic band starting on an odd
        row carries the colour order of that row.
    """
    p = samples.pattern
    if not p.is_regular_grid:
        return _BandSamples(samples, top, bottom)
    first = max(0, -(-(top - p.offset_y) // p.stride_y))
    last = max(first, -(-(bottom - p.offset_y) // p.stride_y))
    pattern = replace(p, offset_y=p.offset_y + first * p.stride_y - top)
    values = samples.grid_values()[first:last].reshape(-1, samples.channels)
    from ..io._mosaic import shifted_order  # a mosaic band starting on an odd row: the next tile row's pattern
    return SampleSet(height=int(bottom - top), width=samples.width,
                     channel_order=shifted_order(samples.channel_order, rows=top),
                     pattern=pattern, values=np.ascontiguousarray(values), codec=samples.codec,
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
    params = params or DecoderParams()
    if method not in TILED_METHODS:      # a downsample file resolves to its own, untiled method
        return 0
    h, w = samples.height, samples.width

    def estimate(rows: int) -> int:
        return decode_memory(samples, num_disp=num_disp, method=method, params=params, rows=rows)

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
    with scratch.in_use():
        return _decode_bands(left, samples, max_disp=max_disp, min_disp=min_disp, method=method, params=params,
                             tile_rows=tile_rows, overlap=overlap, max_memory=max_memory)


def _decode_bands(left, samples, *, max_disp, min_disp, method, params, tile_rows, overlap, max_memory):
    """:func:`decode_tiled` with the spare volumes in use (each band's smaller temporaries
    serve the next band)."""
    method, params = resolve_method(left, samples, method=method, params=params,
                                    min_disp=min_disp, max_disp=max_disp)
    if method not in TILED_METHODS:
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
        band_left, band_right = left[band_top:band_bottom], band_samples(samples, band_top, band_bottom)
        # The whole frame's noise-adapted params hold for its bands.
        band_method, _ = resolve_method(band_left, band_right, method=method, params=params,
                                        min_disp=min_disp, max_disp=max_disp, adapt=False)
        # The bands are sized to the memory limit: no room for spare volumes beside them.
        with scratch.holding_no_large_spares():
            band = decode_frame(band_left, band_right, max_disp=max_disp, min_disp=min_disp,
                                method=band_method, params=params, max_memory=max_memory)
        disparity[top:bottom] = band.disparity[top - band_top:bottom - band_top]
        for stage, seconds in band.timings.items():
            timings[stage] = timings.get(stage, 0.0) + seconds
        tiles += 1
        del band
    log.debug("decoded %d bands of %d rows (+%d overlap)", tiles, tile_rows, overlap)
    return DecodeResult(disparity=disparity, method=method, min_disp=int(min_disp), max_disp=int(max_disp),
                        timings=timings, params=params)
