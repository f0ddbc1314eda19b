"""Running a kernel's work on threads, and parallel forms of numpy one-liners.

:func:`run_parts` is how the hot kernels run on every core.  A kernel takes a range
``[first, stop)`` of its work items and releases the GIL (``nogil=True``); ``run_parts``
splits the items into :func:`numba.get_num_threads` contiguous ranges, numba's own
static schedule, and runs them at once on a small pool of threads, the calling thread
taking the first.  numba's ``parallel=True`` does the same in compiled code, but its
parfor passes doubled the compiling of a default decode: one process compiled the
decode and its recovered right image in 36.6-41.8 s with them and in 20.4-23.9 s
without.  The kernels' results do not depend on the split.

:func:`fill_zero` and :func:`take` are numpy one-liners that run between the decoders'
kernels, split the same way (numpy runs them on one thread).  Their results equal
numpy's, bit for bit.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit

from ._jit import RANGE_KERNEL

_pool_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None
_pool_size = 0
_pool_pid = 0


def _workers(count: int) -> ThreadPoolExecutor:
    """The process's pool of at least ``count`` threads (made again in a forked child,
    whose copy of the pool has no threads behind it)."""
    global _pool, _pool_size, _pool_pid
    with _pool_lock:
        if _pool is None or _pool_pid != os.getpid() or _pool_size < count:
            if _pool is not None and _pool_pid == os.getpid():
                _pool.shutdown(wait=False)
            _pool = ThreadPoolExecutor(max_workers=count, thread_name_prefix="stereobudget")
            _pool_size, _pool_pid = count, os.getpid()
        return _pool


def stop_workers() -> None:
    """Stop the pool's threads (idle between calls) and forget the pool; the next
    :func:`run_parts` starts another.  For a command about to exit: with no thread left
    but its own it can skip the interpreter's teardown."""
    global _pool
    with _pool_lock:
        pool, _pool = _pool, None
    if pool is not None and _pool_pid == os.getpid():
        pool.shutdown(wait=True)


def part_bounds(count: int, parts: int) -> list:
    """The ``parts + 1`` bounds of ``count`` items split into contiguous ranges as evenly as
    possible (numba's static schedule): part ``t`` is ``[bounds[t], bounds[t + 1])``."""
    return [count * t // parts for t in range(parts + 1)]


def run_parts(kernel, count: int, *args, parts: int | None = None, scratch=None) -> None:
    """Call ``kernel(*args, first, stop)`` over contiguous ranges covering ``[0, count)``, at once.

    Parameters
    ----------
    kernel : numba dispatcher compiled with ``nogil=True``
        Does items ``[first, stop)``; parts must not write the same memory.
    count : int
        Work items.
    parts : int, optional
        Ranges to split into; default :func:`numba.get_num_threads` (which
        ``numba.set_num_threads`` lowers, as it does for numba's parallel loops).
        Never more than ``count``; at most one range when the caller has one thread.
    scratch : callable, optional
        Returns a tuple of scratch arrays for one range, passed to the kernel after
        ``args`` (``kernel(*args, *scratch(), first, stop)``): each range gets its own.

    The calling thread runs the first range and the pool the others; an exception in any
    range is raised here once all have finished.
    """
    def own(*bounds):
        return (*args, *scratch(), *bounds) if scratch is not None else (*args, *bounds)

    threads = numba.get_num_threads()
    parts = min(count, threads if parts is None else parts)
    if parts <= 1 or threads <= 1:
        kernel(*own(0, count))
        return
    bounds = part_bounds(count, parts)
    pool = _workers(parts - 1)
    futures = [pool.submit(kernel, *own(bounds[t], bounds[t + 1])) for t in range(1, parts)]
    try:
        kernel(*own(bounds[0], bounds[1]))
    finally:
        for future in futures:
            future.exception()   # wait for every range before anything is raised
    for future in futures:
        future.result()


def take(values, index):
    """``values[index]`` for a 1-D ``values`` and a 1-D integer ``index`` of valid positions."""
    out = np.empty(index.shape[0], dtype=values.dtype)
    run_parts(_take_part, out.shape[0], values, index, out)
    return out


@njit(cache=True, **RANGE_KERNEL)
def _take_part(values, index, out, first, stop):
    for i in range(first, stop):
        out[i] = values[index[i]]


def fill_zero(flat):
    """Set every element of a 1-D float32 array to 0 (``flat.fill(0.0)``)."""
    run_parts(_zero_part, flat.shape[0], flat)


@njit(cache=True, **RANGE_KERNEL)
def _zero_part(flat, first, stop):
    flat[first:stop] = 0.0
