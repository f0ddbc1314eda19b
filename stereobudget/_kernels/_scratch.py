"""Volume memory handed from one decode to the next in the same process, on request.

The first write to a fresh float32 volume page-faults: the kernel maps and zeroes every
4 KiB page, ~8-10 ms for one of Teddy's 41 MB volumes on the benchmark machine, and a
Hybrid decode writes two (plus ~20 MB of bilateral grids).  Decodes that follow each other
in one process (a batch of frames, a dask worker, an embedding application) can give their
cost volumes back here when they are done, and the next decode of the same size takes
them instead of new memory.  That holds memory between calls, so it is the caller's
choice: volumes are kept between decodes only while one :func:`begin_keeping` is open
(:class:`stereobudget.decoding.Decoder` opens one).  Otherwise a decode's volumes are
reused only within it (:func:`in_use`) and all are dropped when it returns.

Volumes of up to :data:`LARGE_BYTES` each are kept up to :data:`SPARE_BYTES` in all (the
largest first when they do not all fit); larger ones (the cost volumes of frames from
~0.25 MP up, the bands of a tiled decode) are all kept, until a decode of another frame
size begins (:func:`frame`: they are dropped before its volumes are allocated, so stale
volumes are never held beside new ones).  New memory costs
the most there: 1-4 MP decodes took 9-35 % less CPU time on reused volumes
(measured with scripts/bench.py --sections reuse).  :func:`spare_bytes` tells the memory check what
is held; :func:`release` drops everything.

The smaller temporaries (trees, grids, keys: ~2000 pages a Hybrid decode of Teddy) can be
kept mapped by the C allocator instead (:func:`keep_freed_memory`, a process-wide setting
that only an opt-in calls).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import threading

import numpy as np

from ._parallel import fill_zero

#: Small spare volumes (each at most :data:`LARGE_BYTES`) are kept between decodes up to
#: this total, the largest first (:func:`_fitting_spares`).
SPARE_BYTES = 256 * 2 ** 20
#: Volumes over this many bytes are a frame's own (its cost volumes, its largest grids):
#: "large" spares, all kept for the next decode of the same frame (:func:`frame`) outside
#: the :data:`SPARE_BYTES` budget.  In the budget, a 0.25 MP x 256 Sparse decode's 244 MiB
#: volume left no room for its four 32-48 MB grids, allocated anew by every decode.
LARGE_BYTES = 64 * 2 ** 20

_lock = threading.Lock()
_spare: list = []       # (_frames.begun when given back, volume) of up to LARGE_BYTES each,
                        # at most SPARE_BYTES in all, in the order given back
_large: list = []       # larger volumes, of the frame decoded last


class _Frames:
    """The decodes :func:`frame` has seen (module state, changed with the lock held)."""
    key = None      # the last frame's key
    running = 0     # decodes inside frame() now
    begun = 0       # frames begun: keys that differed from the one before
    holding_none = 0   # inside holding_no_large_spares(): large volumes given back are freed
    in_use = 0      # calls inside in_use(): volumes given back are kept for them
    keepers = 0     # begin_keeping() calls not yet ended: volumes are kept between calls


_frames = _Frames()
_malloc_tuned: list = []

# glibc's mallopt parameters (malloc.h) and the largest mmap threshold it accepts on 64-bit.
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD_MAX = 32 * 2 ** 20


def _keeping_memory() -> bool:
    """False when ``STEREOBUDGET_KEEP_FREED_MEMORY=0`` opts out of keeping memory between decodes."""
    return os.environ.get("STEREOBUDGET_KEEP_FREED_MEMORY", "1") != "0"


def keep_freed_memory() -> bool:
    """Let the C allocator keep freed blocks of up to 32 MiB mapped, for the next decode.

    glibc returns large freed blocks to the system, so the next decode's arrays are
    fresh pages that fault on first touch (~2000 faults and 5-15 ms per Hybrid decode of
    Teddy on the benchmark machine, scripts/bench.py).  This raises glibc's mmap
    threshold to its maximum and its trim threshold to :data:`SPARE_BYTES`, so blocks are
    reused instead; the process keeps up to that much freed memory.  The setting lasts
    for the rest of the process (glibc cannot restore its adaptive threshold), so only an
    explicit opt-in calls it (:class:`stereobudget.decoding.Decoder`), never a plain
    :func:`stereobudget.decode`; ``STEREOBUDGET_KEEP_FREED_MEMORY=0`` leaves the allocator
    alone even then.  Elsewhere than Linux it does nothing.

    Returns
    -------
    bool
        Whether the allocator was tuned (by this call or an earlier one).
    """
    if _malloc_tuned:
        return _malloc_tuned[0]
    with _lock:
        if not _malloc_tuned:
            tuned = False
            if sys.platform.startswith("linux") and _keeping_memory():
                try:
                    mallopt = ctypes.CDLL(None).mallopt
                    # Both or neither: a trim threshold alone turns off glibc's adaptive mmap
                    # threshold, and every block is then mapped afresh (7x the faults).
                    tuned = bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX)) and bool(
                        mallopt(_M_TRIM_THRESHOLD, SPARE_BYTES))
                except (OSError, AttributeError):
                    tuned = False
            _malloc_tuned.append(tuned)
    return _malloc_tuned[0]


def avoid_huge_pages() -> bool:
    """Stop numpy from asking the kernel for huge pages for its large arrays, for the rest of the process.

    numpy advises transparent huge pages (``MADV_HUGEPAGE``) for every array of 4 MiB or
    more.  Where the kernel honours that advice on demand (``defrag`` = ``madvise``, the
    common default), the first touch of such an array may wait while the kernel compacts
    memory to free a 2 MiB page.  A process that decodes one pair touches all its volumes
    once, and paid that wait in some runs: a warm single ``sb-decode`` of a 0.36 MP pair
    (plain install, 2-core Intel machine, 12 runs alternating) took a median of 0.75 s
    (0.60-0.95) with the advice and 0.65 s (0.63-0.68) without.  A stream or a batch
    reuses its volumes, where huge pages pay (frames ~3 % faster), so only a command that
    decodes one pair calls this; the setting is process-wide, so no decode of the library
    does.  ``NUMPY_MADVISE_HUGEPAGE=1`` in the environment keeps numpy's advice.

    Returns
    -------
    bool
        Whether numpy's advice is off now.
    """
    if os.environ.get("NUMPY_MADVISE_HUGEPAGE") == "1":
        return False
    try:
        from numpy._core import multiarray
    except ImportError:        # numpy 1.x
        from numpy.core import multiarray
    setter = getattr(multiarray, "_set_madvise_hugepage", None)
    if setter is None:
        return False
    setter(False)
    return True


def empty_volume(shape) -> np.ndarray:
    """An uninitialised C-contiguous float32 array of ``shape``, reusing a spare one of that size.

    Parameters
    ----------
    shape : tuple of int

    Returns
    -------
    numpy.ndarray
        float32, contents undefined; a new one starts on a 64-byte cache line.
    """
    size = int(np.prod(shape, dtype=np.int64))
    with _lock:
        spare = _take_spare(size)
    return (_line_aligned_empty(size) if spare is None else spare).reshape(shape)


#: Bytes of a cache line.
_LINE_BYTES = 64


def _line_aligned_empty(size: int) -> np.ndarray:
    """An uninitialised float32 (size,) array whose first element starts a cache line.

    Rows of 16k floats then start lines too, so a row's software prefetch asks for
    exactly its lines (:func:`stereobudget._kernels.prefetch_row`); numpy's own
    allocations are 16-byte aligned.
    """
    per_line = _LINE_BYTES // 4
    raw = np.empty(size + per_line, np.float32)
    skip = (-(raw.ctypes.data // 4)) % per_line
    return raw[skip:skip + size]


def _take_spare(size: int):
    """The spare volume of ``size`` float32 values, or None; call with the lock held.

    Outside a decode (:func:`frame`), a large request that no spare matches is taken to
    come from another frame size: the large spares are dropped before the new volume is
    allocated.  Within one, the frame is known to be the spares' own, and a miss only
    means the decode needs more volumes of a size than were given back.
    """
    for i, (_, spare) in enumerate(_spare):
        if spare.size == size:
            return _spare.pop(i)[1]
    for i, spare in enumerate(_large):
        if spare.size == size:
            return _large.pop(i)
    if 4 * size > LARGE_BYTES and not _frames.running:
        _large.clear()
    return None


@contextlib.contextmanager
def frame(key):
    """Mark a decode of the frame ``key`` (anything comparable that fixes its volumes' sizes).

    A key other than the previous decode's drops the large spares first: they are of
    another frame size, and must not be held beside its new volumes.  Within the block a
    large miss drops nothing; at its end, the large spares it did not take go.  (Guessing
    the frame from the misses alone failed when a decode asks for two large volumes of one
    size and one is spare: a 4 MP x 128 Sparse decode asks for two 374 MiB grids, and the
    second request dropped the 1.9 GiB cost volume, allocated anew by every decode of the
    batch.)
    """
    with _lock:
        if _frames.key != key:
            _large.clear()
            _frames.begun += 1
        _frames.key = key
        _frames.running += 1
        offered = list(_large)
    try:
        yield
    finally:
        with _lock:
            _frames.running -= 1
            # Large spares the decode did not take are of sizes its frame no longer asks for
            # (grids follow the image's content): dropped, so a batch cannot pile them up.
            _large[:] = [spare for spare in _large if not any(spare is old for old in offered)]


@contextlib.contextmanager
def holding_no_large_spares():
    """Decodes inside give their large volumes back to the system instead of holding them
    for a next decode.  A tiled decode's bands run so: held to the end of a band, its
    finished large temporaries would sit beside the band's own volumes, over the band's
    memory estimate (12 MP Hybrid bands: 11.90 GiB peak against 11.73 GiB estimated)."""
    with _lock:
        _frames.holding_none += 1
    try:
        yield
    finally:
        with _lock:
            _frames.holding_none -= 1


def zeroed_volume(shape) -> np.ndarray:
    """:func:`empty_volume` filled with zeros (a spare one is cleared, a new one comes zeroed)."""
    size = int(np.prod(shape, dtype=np.int64))
    with _lock:
        volume = _take_spare(size)
    if volume is None:
        return np.zeros(shape, np.float32)
    fill_zero(volume.reshape(-1))
    return volume.reshape(shape)


def recycle(*volumes) -> None:
    """Give volumes back for later use; the caller must not touch them afterwards.

    ``None`` entries are ignored.  Kept only inside :func:`in_use` or while a
    :func:`begin_keeping` is open (otherwise dropped at once, as if freed): volumes of up to
    :data:`LARGE_BYTES` within :data:`SPARE_BYTES` in all (the largest first), larger ones
    unless ``STEREOBUDGET_KEEP_FREED_MEMORY=0``.
    """
    keep_large = _keeping_memory()
    with _lock:
        if not (_frames.in_use or _frames.keepers):
            return
        for volume in volumes:
            if (volume is None or volume.size == 0 or volume.dtype != np.float32
                    or not volume.flags.c_contiguous):
                continue
            if volume.nbytes <= LARGE_BYTES:
                _spare.append((_frames.begun, volume.reshape(-1)))
            elif keep_large and not _frames.holding_none:
                _large.append(volume.reshape(-1))
        if sum(spare.nbytes for _, spare in _spare) > SPARE_BYTES:
            _spare[:] = _fitting_spares(_spare)


def _fitting_spares(spares: list) -> list:
    """The (frame, volume) ``spares`` kept within :data:`SPARE_BYTES`, in their order: the
    latest frame's first, the largest first, then whatever still fits.

    New memory costs per byte, so the budget keeps as many bytes as it can, and a
    decode's largest volumes, which the next decode of the frame asks for again, never
    make room for its temporaries (oldest first, a 1 MP x 64 Sparse decode recycled its
    44 MB blur grid after taking its 244 MB volume back, which dropped that volume; every
    later decode allocated it anew).  Spares of earlier frames go before the current
    frame's, so a stale large one cannot hold its place; of equal sizes the newest stay.
    """
    kept, total = set(), 0
    for i in sorted(range(len(spares)), key=lambda i: (-spares[i][0], -spares[i][1].nbytes, -i)):
        if total + spares[i][1].nbytes <= SPARE_BYTES:
            kept.add(i)
            total += spares[i][1].nbytes
    return [spare for i, spare in enumerate(spares) if i in kept]


@contextlib.contextmanager
def in_use():
    """Volumes given back inside the block are kept for reuse inside it (one decode hands its
    grids to its own later volumes); when the last such block ends and no
    :func:`begin_keeping` is open, every spare volume is dropped, so a plain decode leaves
    nothing held."""
    with _lock:
        _frames.in_use += 1
    try:
        yield
    finally:
        with _lock:
            _frames.in_use -= 1
            if not (_frames.in_use or _frames.keepers):
                _drop_spares()


def begin_keeping() -> None:
    """Keep spare volumes between calls until the matching :func:`end_keeping`.

    Calls nest (a count): the pools are process-wide, and while any caller keeps them every
    decode of the process shares them.
    """
    with _lock:
        _frames.keepers += 1


def end_keeping() -> None:
    """End one :func:`begin_keeping`; the last one gives back everything held (:func:`release`)."""
    with _lock:
        if _frames.keepers <= 0:
            raise RuntimeError("end_keeping() without begin_keeping()")
        _frames.keepers -= 1
        last = not (_frames.keepers or _frames.in_use)
    if last:
        release()


def keeping() -> bool:
    """Whether spare volumes are kept between calls now (a :func:`begin_keeping` is open)."""
    return _frames.keepers > 0


def _drop_spares() -> None:
    """Forget every spare volume and the last frame; call with the lock held."""
    _spare.clear()
    _large.clear()
    _frames.key = None


def spare_bytes() -> int:
    """Bytes held in spare volumes (a decode takes them or drops them before allocating)."""
    with _lock:
        return sum(spare.nbytes for _, spare in _spare) + sum(spare.nbytes for spare in _large)


def release() -> None:
    """Drop every spare volume; with :func:`keep_freed_memory` in force, also hand the
    allocator's free memory back to the system."""
    with _lock:
        _drop_spares()
    if _malloc_tuned and _malloc_tuned[0]:
        try:
            ctypes.CDLL(None).malloc_trim(0)
        except (OSError, AttributeError):
            pass
