"""Inverse PNG row filters (RFC 2083, section 6) for the ``deflate`` payload codec.

A kernel of its own so that the camera side, which only filters (numpy, in
:mod:`stereobudget.io._codecs`), never imports numba: Average and Paeth depend on the
reconstructed left neighbour, so undoing them is a sequential loop.
"""

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def unfilter_rows(filtered, out, bpp):
    """Undo the row filters of ``filtered`` (rows x (1 + line) bytes) into ``out`` (rows x line).

    Returns
    -------
    int
        -1, or the first row whose filter type byte is not 0..4 (``out`` is then partial).
    """
    rows, line = out.shape
    for r in range(rows):
        base = r * (line + 1)
        kind = filtered[base]
        if kind > 4:
            return r
        for i in range(line):
            x = np.int32(filtered[base + 1 + i])
            a = np.int32(out[r, i - bpp]) if i >= bpp else np.int32(0)
            b = np.int32(out[r - 1, i]) if r > 0 else np.int32(0)
            if kind == 0:
                v = x
            elif kind == 1:
                v = x + a
            elif kind == 2:
                v = x + b
            elif kind == 3:
                v = x + (a + b) // 2
            else:
                c = np.int32(out[r - 1, i - bpp]) if (r > 0 and i >= bpp) else np.int32(0)
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                if pa <= pb and pa <= pc:
                    v = x + a
                elif pb <= pc:
                    v = x + b
                else:
                    v = x + c
            out[r, i] = v & 0xFF
    return -1
