"""Census matching cost: the Hamming distance between 5x5 census signatures.

Real camera pairs differ in exposure, gain and noise.  An absolute difference of
intensities reads such a difference as a mismatch everywhere; the census transform keeps
only the order of each pixel against its neighbours, which a monotonic change of
brightness leaves alone (Zabih & Woodfill).  Each pixel's signature is a 24-bit word (one
bit per neighbour of the 5x5 window: neighbour darker than the centre), and the cost of a
match is the number of differing bits.
"""

import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL
from .._kernels._parallel import run_parts

#: Window radius of the census transform (5 x 5 window, 24 bits).
CENSUS_RADIUS = 2
#: Bits in a signature: the most a census cost can be.
CENSUS_BITS = (2 * CENSUS_RADIUS + 1) ** 2 - 1


@njit(cache=True, **RANGE_KERNEL)
def _census_rows(gray, radius, out, first, stop):
    h, w = gray.shape
    for y in range(first, stop):
        for x in range(w):
            centre = gray[y, x]
            bits = np.uint32(0)
            for dy in range(-radius, radius + 1):
                yy = min(max(y + dy, 0), h - 1)
                for dx in range(-radius, radius + 1):
                    if dy == 0 and dx == 0:
                        continue
                    xx = min(max(x + dx, 0), w - 1)
                    bits = (bits << np.uint32(1)) | np.uint32(gray[yy, xx] < centre)
            out[y, x] = bits


def census_transform(gray: np.ndarray, *, radius: int = CENSUS_RADIUS) -> np.ndarray:
    """Census signature of every pixel: bit k set where the k-th neighbour is darker.

    Parameters
    ----------
    gray : ndarray, (H, W), any real dtype
        The image (gray levels).
    radius : int
        Window radius; the window has ``(2 radius + 1)^2 - 1 <= 32`` neighbours.
        Neighbours outside the image repeat the border pixel.

    Returns
    -------
    ndarray, uint32 (H, W)
        Neighbours in row-major window order, the first in the highest bit.
    """
    if (2 * radius + 1) ** 2 - 1 > 32:
        raise ValueError(f"a census window of radius {radius} needs more than 32 bits")
    gray = np.ascontiguousarray(gray, np.float32)
    out = np.zeros(gray.shape, np.uint32)
    run_parts(_census_rows, gray.shape[0], gray, int(radius), out)
    return out


@njit(cache=True, inline="always")
def popcount32(value):
    """Number of set bits of a 32-bit word (SWAR: no table, no branch)."""
    v = np.uint64(value)
    v = v - ((v >> np.uint64(1)) & np.uint64(0x55555555))
    v = (v & np.uint64(0x33333333)) + ((v >> np.uint64(2)) & np.uint64(0x33333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F)
    return np.int64(((v * np.uint64(0x01010101)) & np.uint64(0xFFFFFFFF)) >> np.uint64(24))


@njit(cache=True, **RANGE_KERNEL)
def _census_volume_rows(left_bits, right_bits, min_disp, num_disp, out, first, stop):
    w = left_bits.shape[1]
    for y in range(first, stop):
        for x in range(w):
            total = 0
            count = 0
            for k in range(num_disp):
                xr = x - (min_disp + k)
                if 0 <= xr < w:
                    c = popcount32(left_bits[y, x] ^ right_bits[y, xr])
                    out[y, x, k] = c
                    total += c
                    count += 1
            # Where x - d leaves the right image there is nothing to match: those layers
            # get the pixel's mean cost, neither favoured nor ruled out, so the
            # aggregation's smoothness decides them.
            neutral = np.uint8((total + count // 2) // count) if count else np.uint8(0)
            for k in range(num_disp):
                xr = x - (min_disp + k)
                if xr < 0 or xr >= w:
                    out[y, x, k] = neutral


def census_cost_volume(left_gray: np.ndarray, right_gray: np.ndarray, *, min_disp: int,
                       num_disp: int) -> np.ndarray:
    """Census cost of every left pixel at every disparity (the left view's DSI).

    Parameters
    ----------
    left_gray, right_gray : ndarray, (H, W)
        Gray images of the rectified pair.  Left pixel (x, y) matches right (x - d, y).
    min_disp, num_disp : int
        Disparities ``min_disp ... min_disp + num_disp - 1``.

    Returns
    -------
    ndarray, uint8 (H, W, num_disp)
        Hamming distances, 0 ... :data:`CENSUS_BITS`.  Layers whose match falls outside
        the right image hold the mean of the pixel's other layers.
    """
    left_bits = census_transform(left_gray)
    h, w = left_bits.shape
    out = np.empty((h, w, num_disp), np.uint8)
    run_parts(_census_volume_rows, h, left_bits, census_transform(right_gray), int(min_disp), int(num_disp), out)
    return out


def census_cost_volume_reference(left_gray, right_gray, *, min_disp, num_disp):
    """:func:`census_cost_volume` in plain numpy (the tests hold the kernel to it)."""
    def signature(gray):
        gray = np.asarray(gray, np.float32)
        h, w = gray.shape
        r = CENSUS_RADIUS
        padded = np.pad(gray, r, mode="edge")
        bits = np.zeros((h, w), np.uint64)
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                if dy or dx:
                    neighbour = padded[r + dy:r + dy + h, r + dx:r + dx + w]
                    bits = (bits << np.uint64(1)) | (neighbour < gray).astype(np.uint64)
        return bits

    lb, rb = signature(left_gray), signature(right_gray)
    h, w = lb.shape
    out = np.zeros((h, w, num_disp), np.int64)
    inside = np.zeros((h, w, num_disp), bool)
    for k in range(num_disp):
        d = min_disp + k
        xs = np.arange(w) - d
        ok = (xs >= 0) & (xs < w)
        diff = lb[:, ok] ^ rb[:, xs[ok]]
        out[:, ok, k] = np.array([bin(int(v)).count("1") for v in diff.ravel()]).reshape(diff.shape)
        inside[:, ok, k] = True
    count = inside.sum(axis=2)
    neutral = (np.where(inside, out, 0).sum(axis=2) + count // 2) // np.maximum(count, 1)
    out = np.where(inside, out, neutral[:, :, None])
    return out.astype(np.uint8)


@njit(cache=True, **RANGE_KERNEL)
def _spaced_census_rows(gray, spacing_x, spacing_y, out, first, stop):
    h, w = gray.shape
    for y in range(first, stop):
        for x in range(w):
            centre = gray[y, x]
            bits = 0
            for dy in (-1, 0, 1):
                yy = min(max(y + dy * spacing_y, 0), h - 1)
                for dx in (-1, 0, 1):
                    if dy == 0 and dx == 0:
                        continue
                    xx = min(max(x + dx * spacing_x, 0), w - 1)
                    bits = (bits << 1) | (1 if gray[yy, xx] < centre else 0)
            out[y, x] = bits


def spaced_census(gray: np.ndarray, *, spacing_x: int, spacing_y: int) -> np.ndarray:
    """Census of every pixel against its 8 neighbours ``spacing`` pixels away.

    With the spacing of a sample grid this is, at each pixel of I1, what
    :func:`lattice_census` is at each sample of I2: the two can be compared for every
    (sample, disparity) pair of the sparse DSI.

    Parameters
    ----------
    gray : ndarray, (H, W)
    spacing_x, spacing_y : int
        Neighbour offsets; neighbours outside the image repeat the border.

    Returns
    -------
    ndarray, uint8 (H, W)
        Neighbours in row-major order, the first in the highest bit.
    """
    gray = np.ascontiguousarray(gray, np.float32)
    out = np.zeros(gray.shape, np.uint8)
    run_parts(_spaced_census_rows, gray.shape[0], gray, int(spacing_x), int(spacing_y), out)
    return out


def lattice_census(lattice_gray: np.ndarray) -> np.ndarray:
    """Census of every sample of a grid against its 8 grid neighbours.

    Parameters
    ----------
    lattice_gray : ndarray, (rows, cols)
        The samples' gray values on their grid (``I2[oy::sy, ox::sx]``).

    Returns
    -------
    ndarray, int64 (rows * cols,)
        8-bit codes in the bit order of :func:`spaced_census`, row-major over the grid.
    """
    return spaced_census(lattice_gray, spacing_x=1, spacing_y=1).astype(np.int64).ravel()


@njit(cache=True, **RANGE_KERNEL)
def _mix_census_rows(volume, left_codes, right_codes, min_disp, weight, scale, backwards, first, stop):
    """Rows ``[first, stop)`` of :func:`mix_spaced_census`.

    ``backwards`` (W - 1 + max(0, min_disp) + D,) uint8 is the range's scratch: row y's
    right codes read backwards and clamped to the row, so that the codes pixel x meets at
    layers 0, 1, 2, ... lie side by side and the layer loop vectorises.  Read in place
    (backwards, each index clamped) the mix took 2.6 times as long.
    """
    w, nd = volume.shape[1], volume.shape[2]
    start = w - 1 - min(0, min_disp)     # backwards[s] is column start - s
    for y in range(first, stop):
        for s in range(backwards.shape[0]):
            backwards[s] = right_codes[y, min(max(start - s, 0), w - 1)]
        for x in range(w):
            first_code = start - x + min_disp   # column x - min_disp: layer 0
            codes = backwards[first_code:first_code + nd]
            code = np.uint32(left_codes[y, x])
            layers = volume[y, x]
            for k in range(nd):
                layers[k] = layers[k] * scale + weight * np.float32(popcount32(code ^ np.uint32(codes[k])))


def mix_spaced_census(volume: np.ndarray, left_codes: np.ndarray, right_codes: np.ndarray, *, min_disp: int,
                      volume_scale: float, census_weight: float) -> np.ndarray:
    """``volume * volume_scale + census_weight * bits`` in place, ``bits`` the differing bits
    of two code images (:func:`spaced_census`) at each disparity.

    Parameters
    ----------
    volume : ndarray, float32 (H, W, D), C-contiguous
        Left-view cost; layer ``k`` is disparity ``min_disp + k``.
    left_codes, right_codes : ndarray, uint8 (H, W)
        Codes of the two views; right columns past the border repeat the border.
    min_disp : int
    volume_scale, census_weight : float

    Returns
    -------
    ndarray
        ``volume``.
    """
    h, w, nd = volume.shape
    run_parts(_mix_census_rows, h, volume, left_codes, right_codes, int(min_disp), np.float32(census_weight),
              np.float32(volume_scale), scratch=lambda: (np.empty(w - 1 + max(0, int(min_disp)) + nd, np.uint8),))
    return volume
