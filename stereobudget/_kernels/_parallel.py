"""Parallel forms of the numpy one-liners that run between the decoders' kernels.

After each parallel kernel numba's worker thread keeps spinning for a while; a numpy
call that follows runs on the main thread alone while that spin occupies the other
vCPU (the two vCPUs of these machines share one core's units).  These kernels split the
same work between both threads.  Their results equal numpy's, bit for bit.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: Elements per work item of :func:`fill_zero` (256 KiB of float32).
_FILL_CHUNK = 1 << 16


@njit(cache=True, parallel=True)
def take(values, index):
    """``values[index]`` for a 1-D ``values`` and a 1-D integer ``index`` of valid positions."""
    out = np.empty(index.shape[0], dtype=values.dtype)
    for i in prange(index.shape[0]):
        out[i] = values[index[i]]
    return out


@njit(cache=True, parallel=True)
def fill_zero(flat):
    """Set every element of a 1-D float32 array to 0 (``flat.fill(0.0)``)."""
    n = flat.shape[0]
    for chunk in prange((n + _FILL_CHUNK - 1) // _FILL_CHUNK):
        flat[chunk * _FILL_CHUNK:min(n, (chunk + 1) * _FILL_CHUNK)] = 0.0
