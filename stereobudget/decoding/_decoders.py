"""Decoders: left image + sample set -> dense disparity of the left view.

:func:`decode` is the library entry point behind ``sb-decode``; :class:`Decoder` runs a
sequence of decodes that hand memory to each other (an opt-in: it holds memory between
calls and tunes the C allocator).  Each method is a short pipeline of pure functions from
the other subpackages, in its own module:

* ``sparse`` (paper Fig. 2(b)): :mod:`stereobudget.decoding._sparse`.
* ``hybrid`` (paper Fig. 2(c)): :mod:`stereobudget.decoding._hybrid`.
* ``downsample`` (paper Fig. 2(a)): :mod:`stereobudget.decoding._downsample`.
* ``full`` (``stride 1``): :mod:`stereobudget.decoding._full`.

What they share: parameters, result, input checks (:mod:`._params`), the memory estimate
(:mod:`._memory`), a frame decoded in one piece (:mod:`._frame`) and in bands
(:mod:`._tiling`).
"""

from __future__ import annotations

import threading

import numpy as np

from ..io._samples import SampleSet
from .._kernels import _scratch as scratch
from .._kernels._first_run import compile_notice
from ._methods import DEFAULT_METHOD
from ._frame import decode_frame
from ._params import DecodeResult, DecoderParams, check_inputs, resolve_method  # noqa: F401  (check_inputs: batch)
from ._tiling import DEFAULT_TILE_OVERLAP, auto_tile_rows, decode_tiled


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
        The estimate (:func:`stereobudget.decoding.estimate_decode_memory`) exceeds
        ``max_memory``; checked before any volume is allocated.

    Notes
    -----
    A plain call leaves the process as it found it: the volumes it allocates are reused
    within the call (:mod:`stereobudget._kernels._scratch`) and all given back when it
    returns, and the C allocator keeps its settings.  A sequence of decodes is faster when
    each takes over the previous one's memory; :class:`Decoder` opts in to that.
    """
    with scratch.in_use(), compile_notice(method or DEFAULT_METHOD):
        # The noise adaptation waits for I1's gray image (made in decode_frame anyway); a
        # tiled decode adapts on the whole frame in decode_tiled.
        method, params = resolve_method(left, samples, method=method, params=params,
                                        min_disp=min_disp, max_disp=max_disp, adapt=False)
        overlap = DEFAULT_TILE_OVERLAP if tile_overlap is None else int(tile_overlap)
        if tile_rows is None:
            tile_rows = auto_tile_rows(samples, num_disp=int(max_disp - min_disp + 1), method=method,
                                       params=params, max_memory=max_memory, overlap=overlap)
        if tile_rows and tile_rows < samples.height:
            return decode_tiled(left, samples, max_disp=max_disp, min_disp=min_disp, method=method, params=params,
                                max_memory=max_memory, tile_rows=tile_rows, overlap=overlap)
        return decode_frame(left, samples, max_disp=max_disp, min_disp=min_disp, method=method,
                            params=params, max_memory=max_memory)


class Decoder:
    """A sequence of decodes in one process that hand memory to each other (opt-in).

    Between plain :func:`decode` calls nothing is kept.  While a Decoder is open, each
    decode's dead cost volumes are kept for the next one (up to
    :data:`stereobudget._kernels.SPARE_BYTES` of volumes of up to
    :data:`stereobudget._kernels.LARGE_BYTES`, and all larger ones of the frame decoded last,
    dropped when a decode of another frame size begins; the memory limit counts them as
    available), and glibc is let keep freed blocks mapped, so the next decode's arrays do
    not page-fault afresh.  On the benchmark machine this spares 1-4 MP decodes 9-35 % of
    their CPU time (``scripts/bench.py --sections reuse``).  ``sb-decode`` and the batch
    runners decode this way (:func:`shared_decoder`).

    Parameters
    ----------
    keep_freed_memory : bool
        Also tune the C allocator (:func:`stereobudget._kernels.keep_freed_memory`).  That
        is a process-wide setting which stays after :meth:`close` (glibc cannot restore its
        adaptive threshold); ``False`` keeps only the volumes.
        ``STEREOBUDGET_KEEP_FREED_MEMORY=0`` turns it and the large volumes off either way.
    temporal : bool or TemporalParams
        The decodes are the frames of one stream, in order: each searches only a band of
        disparities around the previous frame's, and the whole ``min_disp..max_disp`` on the
        first frame, after a scene cut, and where the band's winners sit at its edge
        (:class:`stereobudget.decoding.TemporalSearch`; :meth:`reset` starts a new stream).
        A frame of another size than the first is an error.  ``TemporalParams`` tunes it.

    Notes
    -----
    The pools are the process's: while any Decoder is open, every decode in the process
    (in any thread, through :func:`decode` too) shares them.  :meth:`close` of the last
    open one gives the spare volumes back (and, the allocator tuned, trims its free
    memory).  Used without ``with``, :meth:`decode` opens the Decoder and :meth:`close`
    must end it.

    Examples
    --------
    >>> with Decoder() as decoder:                                  # doctest: +SKIP
    ...     for left, samples in frames:
    ...         disparity = decoder.decode(left, samples, max_disp=64).disparity
    """

    def __init__(self, *, keep_freed_memory: bool = True, temporal=False):
        self.keep_freed_memory = bool(keep_freed_memory)
        self._open = False
        self._lock = threading.Lock()
        self._temporal = None
        if temporal:
            from ._temporal import TemporalParams, TemporalSearch
            self._temporal = TemporalSearch(temporal if isinstance(temporal, TemporalParams) else None)

    def reset(self) -> None:
        """A temporal Decoder: the next decode is the first frame of a new stream (any size)."""
        if self._temporal is not None:
            self._temporal.reset()
            self._temporal.shape = None
            self._temporal.frame = -1

    @property
    def is_open(self) -> bool:
        """Whether this Decoder keeps the pools now."""
        return self._open

    def open(self) -> "Decoder":
        """Start keeping memory between decodes (again, after a :meth:`close`); returns self."""
        with self._lock:
            if not self._open:
                scratch.begin_keeping()
                self._open = True
        if self.keep_freed_memory:
            scratch.keep_freed_memory()
        return self

    def close(self) -> None:
        """Stop keeping memory; the last open Decoder of the process gives it all back."""
        with self._lock:
            if not self._open:
                return
            self._open = False
        scratch.end_keeping()

    def __enter__(self) -> "Decoder":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def decode(self, left: np.ndarray, samples: SampleSet, **options) -> DecodeResult:
        """:func:`decode` (same arguments and result) on the memory of this Decoder's earlier decodes.

        A temporal Decoder needs ``max_disp`` (an integer) and fills the result's ``stream``.
        """
        self.open()
        if self._temporal is not None:
            return self._temporal.decode(decode, left, samples, **options)
        return decode(left, samples, **options)


_shared: list = []
_shared_lock = threading.Lock()


def shared_decoder() -> Decoder:
    """The process's own open :class:`Decoder`, made on first call and never closed.

    For programs that decode from start to end of their process: ``sb-decode`` and the
    workers of the batch runners (:func:`stereobudget.pipeline.decode_file`).  A library that
    only sometimes decodes should use a ``with Decoder():`` block instead, which gives the
    memory back at its end.
    """
    with _shared_lock:
        if not _shared:
            _shared.append(Decoder().open())
        return _shared[0]
