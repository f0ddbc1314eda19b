"""Volume memory handed from one decode to the next in the same process.

The first write to a fresh float32 volume page-faults: the kernel maps and zeroes every
4 KiB page, ~8-10 ms for one of Teddy's 41 MB volumes on the benchmark machine, and a
Hybrid decode writes two (plus ~20 MB of bilateral grids).  Decodes that follow each other in one process (a batch of
frames, a dask worker, an embedding application) give their cost volumes back here when
they are done, and the next decode of the same size takes them instead of new memory.
At most :data:`SPARE_BYTES` are kept; :func:`release` drops them.  A single decode in a
fresh process (one ``sb-decode`` call) gains nothing and loses nothing.
"""

from __future__ import annotations

import threading

import numpy as np

#: Most bytes of volume memory kept between decodes (the oldest go first).
SPARE_BYTES = 256 * 2 ** 20

_lock = threading.Lock()
_spare: list = []


def empty_volume(shape) -> np.ndarray:
    """An uninitialised C-contiguous float32 array of ``shape``, reusing a spare one of that size.

    Parameters
    ----------
    shape : tuple of int

    Returns
    -------
    numpy.ndarray
        float32, contents undefined.
    """
    size = int(np.prod(shape, dtype=np.int64))
    with _lock:
        for i, spare in enumerate(_spare):
            if spare.size == size:
                return _spare.pop(i).reshape(shape)
    return np.empty(shape, np.float32)


def zeroed_volume(shape) -> np.ndarray:
    """:func:`empty_volume` filled with zeros (a spare one is cleared, a new one comes zeroed)."""
    size = int(np.prod(shape, dtype=np.int64))
    with _lock:
        for i, spare in enumerate(_spare):
            if spare.size == size:
                volume = _spare.pop(i)
                break
        else:
            return np.zeros(shape, np.float32)
    volume.fill(0.0)
    return volume.reshape(shape)


def recycle(*volumes) -> None:
    """Give volumes back for later decodes; the caller must not touch them afterwards.

    ``None`` entries are ignored, and so are volumes larger than :data:`SPARE_BYTES`.
    """
    with _lock:
        for volume in volumes:
            if (volume is None or volume.size == 0 or volume.dtype != np.float32
                    or not volume.flags.c_contiguous):
                continue
            if volume.nbytes <= SPARE_BYTES:
                _spare.append(volume.reshape(-1))
        while sum(spare.nbytes for spare in _spare) > SPARE_BYTES:
            _spare.pop(0)


def release() -> None:
    """Drop every spare volume (their memory returns to the allocator)."""
    with _lock:
        _spare.clear()
