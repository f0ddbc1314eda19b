"""Farthest point sampling (Eldar et al. 1997) on the pixel lattice, exact and incremental.

The sampler behind the ``fps`` and ``adaptive_fps`` patterns of
:mod:`stereobudget.sampling` (which defines *what* is sampled; ``docs/format.md`` gives
the normative definition).  This module makes it fast.

Definition (all integer arithmetic, so any implementation reproduces it bit for bit):
pixel ``q = y * W + x`` has the squared Euclidean distance ``d2(q)`` to the nearest point
chosen so far (+infinity before the first one), a weight ``w(q)`` (1 for plain FPS) and a
tie-break key ``t(q) = splitmix64(seed + (q + 1) * 0x9E3779B97F4A7C15)``.  The next point
is the pixel with the largest ``(d2(q) * w(q), t(q))``, compared lexicographically.  The
keys ``t(q)`` are all distinct, so the choice is unique.

Speed: a naive step costs O(H W).  Here a step costs O(window + blocks):

* the new point ``p`` can only lower ``d2`` of pixels closer to it than their current
  ``d2``, and ``d2 <= R2`` everywhere (``R2`` = the largest ``d2``, which is the chosen
  point's own ``d2`` in the unweighted phase), so only the square of half-side
  ``ceil(sqrt(R2))`` around ``p`` is visited;
* the maximum is kept per 8x8 block and per row of blocks.  Keys only decrease, so a
  block's maximum must be recomputed only when its arg-max pixel was lowered, and a
  block row only when one of its blocks changed; the global choice scans the block rows.

Teddy (450 x 375) at 4 % (6750 points) takes a few milliseconds.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Side of the square blocks that keep partial maxima.
BLOCK = 8
_INF = np.int64(1) << np.int64(62)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True, inline="always")
def _tie_key(seed, q):
    z = seed + np.uint64(q + 1) * np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, inline="always")
def _weight(tile_weights, tile_cols, tile_h, tile_w, y, x):
    return tile_weights[(y // tile_h) * tile_cols + (x // tile_w)]


@njit(cache=True)
def _best_of_block(d2, width, height, by, bx, tile_weights, tile_cols, tile_h, tile_w, seed):
    """Arg-max pixel and key of one block."""
    best_key = np.int64(-1)
    best_q = np.int64(-1)
    best_t = np.uint64(0)
    y1 = min(height, (by + 1) * BLOCK)
    x1 = min(width, (bx + 1) * BLOCK)
    for y in range(by * BLOCK, y1):
        for x in range(bx * BLOCK, x1):
            q = y * width + x
            k = d2[q] * _weight(tile_weights, tile_cols, tile_h, tile_w, y, x)
            if k > best_key:
                best_key = k
                best_q = q
                best_t = _tie_key(seed, q)
            elif k == best_key:
                t = _tie_key(seed, q)
                if t > best_t:
                    best_q = q
                    best_t = t
    return best_key, best_q


@njit(cache=True)
def _best_of_row(blk_key, blk_idx, by, blocks_x, seed):
    best_key = np.int64(-1)
    best_q = np.int64(-1)
    best_t = np.uint64(0)
    for bx in range(blocks_x):
        b = by * blocks_x + bx
        k = blk_key[b]
        if k > best_key:
            best_key = k
            best_q = blk_idx[b]
            best_t = _tie_key(seed, best_q)
        elif k == best_key:
            t = _tie_key(seed, blk_idx[b])
            if t > best_t:
                best_q = blk_idx[b]
                best_t = t
    return best_key, best_q


@njit(cache=True)
def _rebuild(d2, height, width, tile_weights, tile_cols, tile_h, tile_w, seed,
             blk_key, blk_idx, row_key, row_idx):
    """Recompute every block and block-row maximum (after a change of weights)."""
    blocks_y = row_key.shape[0]
    blocks_x = blk_key.shape[0] // blocks_y
    for by in range(blocks_y):
        for bx in range(blocks_x):
            k, q = _best_of_block(d2, width, height, by, bx, tile_weights, tile_cols, tile_h, tile_w, seed)
            blk_key[by * blocks_x + bx] = k
            blk_idx[by * blocks_x + bx] = q
        k, q = _best_of_row(blk_key, blk_idx, by, blocks_x, seed)
        row_key[by] = k
        row_idx[by] = q


@njit(cache=True)
def _first_point(height, width, seed):
    """Largest tie-break key over the image (every distance is still infinite)."""
    best_q = np.int64(0)
    best_t = _tie_key(seed, 0)
    for q in range(1, height * width):
        t = _tie_key(seed, q)
        if t > best_t:
            best_t = t
            best_q = q
    return best_q


@njit(cache=True)
def _extend(d2, height, width, tile_weights, tile_cols, tile_h, tile_w, seed,
            blk_key, blk_idx, row_key, row_idx, fixed_radius2, out_rows, out_cols):
    """Choose ``len(out_rows)`` further points, updating the state in place.

    ``fixed_radius2 < 0``: unweighted phase, the window radius is the chosen point's own
    ``d2`` (the global maximum).  Otherwise it is ``fixed_radius2``, an upper bound of
    every ``d2`` (used when weights make the chosen point's ``d2`` smaller than the max).
    """
    blocks_y = row_key.shape[0]
    blocks_x = blk_key.shape[0] // blocks_y
    dirty_row = np.zeros(blocks_y, dtype=np.bool_)
    for step in range(out_rows.shape[0]):
        # Global choice over block rows, same order as everywhere: (key, tie key).
        best_key = np.int64(-1)
        p = np.int64(-1)
        best_t = np.uint64(0)
        for by in range(blocks_y):
            k = row_key[by]
            if k > best_key:
                best_key = k
                p = row_idx[by]
                best_t = _tie_key(seed, p)
            elif k == best_key:
                t = _tie_key(seed, row_idx[by])
                if t > best_t:
                    p = row_idx[by]
                    best_t = t
        py = p // width
        px = p - py * width
        out_rows[step] = py
        out_cols[step] = px
        radius2 = d2[p] if fixed_radius2 < 0 else fixed_radius2
        if radius2 >= _INF:
            radius = max(height, width)
        else:
            radius = np.int64(math.sqrt(float(radius2))) + 1
        y0 = max(0, py - radius)
        y1 = min(height - 1, py + radius)
        x0 = max(0, px - radius)
        x1 = min(width - 1, px + radius)
        for y in range(y0, y1 + 1):
            dy = y - py
            dy2 = dy * dy
            base = y * width
            for x in range(x0, x1 + 1):
                dx = x - px
                nd = dy2 + dx * dx
                if nd < d2[base + x]:
                    d2[base + x] = nd
        # Keys only decrease: a block needs work only if its arg-max was lowered.
        for by in range(y0 // BLOCK, y1 // BLOCK + 1):
            for bx in range(x0 // BLOCK, x1 // BLOCK + 1):
                b = by * blocks_x + bx
                q = blk_idx[b]
                qy = q // width
                if d2[q] * _weight(tile_weights, tile_cols, tile_h, tile_w, qy, q - qy * width) != blk_key[b]:
                    k, q2 = _best_of_block(d2, width, height, by, bx, tile_weights, tile_cols,
                                           tile_h, tile_w, seed)
                    blk_key[b] = k
                    blk_idx[b] = q2
                    dirty_row[by] = True
        for by in range(y0 // BLOCK, y1 // BLOCK + 1):
            if dirty_row[by]:
                k, q = _best_of_row(blk_key, blk_idx, by, blocks_x, seed)
                row_key[by] = k
                row_idx[by] = q
                dirty_row[by] = False


class FarthestPointSampler:
    """Incremental farthest point sampling of an ``height x width`` lattice.

    Parameters
    ----------
    height, width : int
        Lattice size.
    seed : int
        Seed of the tie-break keys (0 .. 2**64 - 1); it also fixes the first point.

    Notes
    -----
    State: ``d2`` (int64, H*W) squared distance of every pixel to the nearest chosen
    point; per-block and per-block-row maxima of the weighted key.  Weights are constant
    over tiles (see :meth:`set_tile_weights`); initially 1 everywhere.
    """

    def __init__(self, height: int, width: int, seed: int):
        if height < 1 or width < 1:
            raise ValueError(f"lattice must be at least 1x1, got {width}x{height}")
        self.height = int(height)
        self.width = int(width)
        self.seed = np.uint64(int(seed) & 0xFFFFFFFFFFFFFFFF)
        self.d2 = np.full(self.height * self.width, _INF, dtype=np.int64)
        self.count = 0
        blocks_y = -(-self.height // BLOCK)
        blocks_x = -(-self.width // BLOCK)
        self._blk_key = np.empty(blocks_y * blocks_x, dtype=np.int64)
        self._blk_idx = np.empty(blocks_y * blocks_x, dtype=np.int64)
        self._row_key = np.empty(blocks_y, dtype=np.int64)
        self._row_idx = np.empty(blocks_y, dtype=np.int64)
        self._tiles = (np.ones(1, dtype=np.int64), 1, self.height, self.width)
        self._fixed_radius2 = -1
        self._rebuild()

    def _rebuild(self):
        weights, cols, tile_h, tile_w = self._tiles
        _rebuild(self.d2, self.height, self.width, weights, cols, tile_h, tile_w, self.seed,
                 self._blk_key, self._blk_idx, self._row_key, self._row_idx)

    def set_tile_weights(self, weights: np.ndarray, *, tile_h: int, tile_w: int) -> None:
        """Weight every pixel of tile ``(y // tile_h, x // tile_w)`` by ``weights[ty, tx]`` (int >= 1).

        From now on the next point maximises ``d2 * weight``.
        """
        weights = np.ascontiguousarray(weights, dtype=np.int64)
        if weights.ndim != 2 or weights.shape != (-(-self.height // tile_h), -(-self.width // tile_w)):
            raise ValueError(f"tile weights of shape {weights.shape} do not tile a {self.width}x{self.height} "
                             f"lattice with {tile_w}x{tile_h} tiles")
        if weights.size and weights.min() < 1:
            raise ValueError("tile weights must be >= 1")
        if self.count == 0:
            raise ValueError("weights apply after the first point")
        self._tiles = (weights.ravel(), weights.shape[1], int(tile_h), int(tile_w))
        # Every d2 is at most today's maximum and never grows: a valid window bound from now on.
        self._fixed_radius2 = int(self.d2.max())
        self._rebuild()

    def extend(self, count: int):
        """Choose ``count`` more points; return their rows and columns (int64) in order."""
        total = self.height * self.width
        if count < 0 or self.count + count > total:
            raise ValueError(f"cannot choose {count} more of {total - self.count} remaining pixels")
        rows = np.empty(count, dtype=np.int64)
        cols = np.empty(count, dtype=np.int64)
        if count == 0:
            return rows, cols
        start = 0
        if self.count == 0:
            # Every distance is infinite: the first point is the largest tie-break key.
            first = int(_first_point(self.height, self.width, self.seed))
            rows[0], cols[0] = divmod(first, self.width)
            yy, xx = np.divmod(np.arange(total, dtype=np.int64), self.width)
            self.d2[:] = (yy - rows[0]) ** 2 + (xx - cols[0]) ** 2
            self._rebuild()
            start = 1
        weights, tile_cols, tile_h, tile_w = self._tiles
        _extend(self.d2, self.height, self.width, weights, tile_cols, tile_h, tile_w, self.seed,
                self._blk_key, self._blk_idx, self._row_key, self._row_idx,
                np.int64(self._fixed_radius2), rows[start:], cols[start:])
        self.count += count
        return rows, cols
