"""One record per decoder: what it is, which samples it takes, whether it tiles, how it adapts to
noise, and its memory peak.

Kept free of numba and OpenCV so that the command line can list the methods and show the
default in ``--help``, and the memory estimate can run, without loading the decoder.  Every
place that depends on the method reads its record here: the method chosen for a sample set
(:func:`stereobudget.decoding._params.resolve_method`), the tiling, the memory estimate, and
the dispatch to the method's pipeline (:func:`stereobudget.decoding._frame.run_pipeline`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class MethodRecord:
    """What the rest of the package needs to know about one decoder.

    Attributes
    ----------
    name : str
        The name ``decode(method=...)`` and ``--method`` take.
    summary : str
        One line for documentation and ``--help``.
    patterns : str
        The sample files it decodes: ``"points"`` (samples of I2 at a pattern's positions,
        any stride > 1), ``"full"`` (every pixel of I2: a stride-1 grid) or ``"blocks"``
        (block means, ``--pattern downsample``).
    tiled : bool
        Whether a frame too large for memory may be decoded in bands of rows.
    fill_grids : bool
        Whether it runs the Sparse fill, whose bilateral grids the memory model counts.
    peak : callable
        ``peak(volume, grid) -> bytes``: the most of the float32 ``(H, W, D)`` cost volumes
        (``volume`` bytes each) and of the fill's ``(GY, GX, GZ, D)`` grids (``grid`` bytes
        each, 0 without the fill) alive at once (see
        :func:`stereobudget.decoding.estimate_decode_memory`).
    noise : str
        Which truncations the noise adaptation (:func:`stereobudget.decoding.adapt_to_noise`)
        raises: ``"sparse"`` (Eq. 2's colour and step truncations), ``"dense"`` (the dense
        DSI's colour and gradient truncations) or ``"none"`` (a cost on low-passed images,
        whose noise is already averaged away).
    """

    name: str
    summary: str
    patterns: str
    tiled: bool
    fill_grids: bool
    peak: Callable[[int, int], int]
    noise: str


METHOD_RECORDS = {record.name: record for record in (
    MethodRecord("hybrid", "the Sparse fill mixed with a dense cost of the low-passed pair (paper Fig. 2c)",
                 patterns="points", tiled=True, fill_grids=True, noise="sparse",
                 # grid blur; or the cost and the two uint16 semi-global sums (half a volume
                 # each) while the sliced grids wait in the spare pool for the next decode
                 # (the tree route needs as much: 2 G + 2 V)
                 peak=lambda volume, grid: max(3 * grid, 2 * grid + 2 * volume)),
    MethodRecord("sparse", "Eq. 2 at the samples, filled by the joint bilateral filter (paper Fig. 2b)",
                 patterns="points", tiled=True, fill_grids=True, noise="sparse",
                 # grid blur; or the grids and the sliced volume
                 peak=lambda volume, grid: max(3 * grid, 2 * grid + volume)),
    MethodRecord("downsample", "a dense cost against the block means of I2 (paper Fig. 2a)",
                 patterns="blocks", tiled=False, fill_grids=False, noise="none",
                 # left + right-view volume during the left-right check; left + refinement after it
                 peak=lambda volume, grid: 2 * volume),
    MethodRecord("full", "the whole right image: census and semi-global paths (or Eq. 1 on the tree)",
                 patterns="full", tiled=True, fill_grids=False, noise="dense",
                 # the uint8 census volume and the two uint16 sums of the semi-global paths
                 peak=lambda volume, grid: volume + volume // 4),
)}

#: The decoders :func:`stereobudget.decode` accepts (paper Fig. 2, plus the full pair).
METHODS = tuple(METHOD_RECORDS)
#: Method used when the caller does not choose one.
DEFAULT_METHOD = "hybrid"
#: Methods that may decode a frame in bands of rows (:func:`stereobudget.decoding.decode_tiled`).
TILED_METHODS = tuple(name for name, record in METHOD_RECORDS.items() if record.tiled)


def method_record(name: str) -> MethodRecord:
    """The record of method ``name``; ValueError names the methods when there is none."""
    try:
        return METHOD_RECORDS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; expected one of {', '.join(METHODS)}") from None


__all__ = ["MethodRecord", "METHOD_RECORDS", "METHODS", "DEFAULT_METHOD", "TILED_METHODS", "method_record"]
