"""Semi-global aggregation (Hirschmüller): costs summed along 4 or 8 straight paths.

Along each path r the cost to a pixel p at disparity d is

    L_r(p, d) = C(p, d) + min(L_r(p - r, d),
                              L_r(p - r, d +- 1) + P1,
                              min_k L_r(p - r, k) + P2(p, r)) - min_k L_r(p - r, k)

and the aggregated cost is S(p, d) = sum_r L_r(p, d).  P1 charges a one-level step (a
slanted surface), P2 any larger jump (a depth edge).  P2 is lowered where I1 has an edge
between p - r and p, P2(p, r) = max(P1, P2 / (1 + |I1(p) - I1(p - r)| / edge_scale)),
so depth edges are cheap where colour edges are.  Unlike the tree filter, the paths
keep a slanted plane's gradual change of disparity: only the steps are charged.

Volumes: the cost is uint8 (H, W, D); the sum is float32 (H, W, D), with a second one
while the paths from below are summed apart (9 bytes per pixel and disparity at the
peak); the paths keep two rows of float32 (W, D) per direction.
"""

import numpy as np
from numba import njit, prange

from ._winner import refined_winner


@njit(cache=True, inline="always")
def _path_step(cost, prev, prev_min, p1, p2, out):
    """One step of a path: ``out`` from the predecessor's ``prev``; returns min of ``out``."""
    nd = cost.shape[0]
    jump = prev_min + p2
    best = np.float32(np.inf)
    for d in range(nd):
        v = prev[d]
        if d > 0:
            v = min(v, prev[d - 1] + p1)
        if d < nd - 1:
            v = min(v, prev[d + 1] + p1)
        v = min(v, jump)
        value = np.float32(cost[d]) + v - prev_min
        out[d] = value
        best = min(best, value)
    return best


@njit(cache=True, inline="always")
def _path_start(cost, out):
    nd = cost.shape[0]
    best = np.float32(np.inf)
    for d in range(nd):
        out[d] = np.float32(cost[d])
        best = min(best, out[d])
    return best


@njit(cache=True, inline="always")
def _edge_p2(a, b, p1, p2, edge_scale):
    return max(p1, p2 / (np.float32(1.0) + abs(a - b) / edge_scale))


@njit(cache=True, parallel=True)
def _horizontal_paths(cost, guide, p1, p2, edge_scale, total):
    """Left-to-right and right-to-left paths of every row (rows are independent)."""
    h, w, nd = cost.shape
    for y in prange(h):
        prev = np.empty(nd, np.float32)
        cur = np.empty(nd, np.float32)
        for direction in (1, -1):
            start = 0 if direction == 1 else w - 1
            prev_min = _path_start(cost[y, start], prev)
            for d in range(nd):
                total[y, start, d] += prev[d]
            for i in range(1, w):
                x = start + direction * i
                p2e = _edge_p2(guide[y, x], guide[y, x - direction], p1, p2, edge_scale)
                prev_min = _path_step(cost[y, x], prev, prev_min, p1, p2e, cur)
                for d in range(nd):
                    total[y, x, d] += cur[d]
                prev, cur = cur, prev


@njit(cache=True)
def _vertical_pass(cost, guide, direction, steps, p1, p2, edge_scale, total):
    """The paths that come from the row before (``direction`` 1: from above, -1: from below)."""
    h, w, nd = cost.shape
    npaths = steps.shape[0]
    # Two row buffers per path, used in turn for the previous and the current row.
    rows = np.empty((2, npaths, w, nd), np.float32)
    mins = np.empty((2, npaths, w), np.float32)
    for i in range(h):
        y = i if direction == 1 else h - 1 - i
        cur, prev = rows[i % 2], rows[1 - i % 2]
        cur_min, prev_min = mins[i % 2], mins[1 - i % 2]
        for x in range(w):
            for k in range(npaths):
                # The predecessor is one row back and ``steps[k]`` columns back.
                xp = x - steps[k] * direction
                if i == 0 or xp < 0 or xp >= w:
                    cur_min[k, x] = _path_start(cost[y, x], cur[k, x])
                else:
                    p2e = _edge_p2(guide[y, x], guide[y - direction, xp], p1, p2, edge_scale)
                    cur_min[k, x] = _path_step(cost[y, x], prev[k, xp], prev_min[k, xp], p1, p2e, cur[k, x])
                for d in range(nd):
                    total[y, x, d] += cur[k, x, d]


@njit(cache=True, parallel=True)
def _vertical_paths(cost, guide, p1, p2, edge_scale, diagonals, down, up):
    """Both vertical passes at once, each on its own thread and into its own sum: a pass
    is sequential over rows, and splitting a row between threads would make every row
    wait for the slower one (badly so on a busy machine)."""
    steps = np.array([0, 1, -1]) if diagonals else np.array([0])
    for j in prange(2):
        if j == 0:
            _vertical_pass(cost, guide, 1, steps, p1, p2, edge_scale, down)
        else:
            _vertical_pass(cost, guide, -1, steps, p1, p2, edge_scale, up)


@njit(cache=True, parallel=True)
def _add_into(total, other):
    h = total.shape[0]
    for y in prange(h):
        total[y] += other[y]


def semiglobal_aggregate(cost: np.ndarray, guide: np.ndarray, *, p1: float, p2: float,
                         edge_scale: float = 8.0, paths: int = 8) -> np.ndarray:
    """Sum of the path costs L_r over 4 or 8 directions (see the module docstring).

    Parameters
    ----------
    cost : ndarray, uint8 or float32 (H, W, D)
        Matching cost volume of the left view.
    guide : ndarray, float32 (H, W)
        I1's gray image, whose edges lower P2.
    p1, p2 : float
        Penalties of a one-level disparity change and of a larger one (cost units).
    edge_scale : float
        Gray-level difference that halves P2.
    paths : {4, 8}
        Horizontal and vertical paths, plus the four diagonals for 8.

    Returns
    -------
    ndarray, float32 (H, W, D)
    """
    if paths not in (4, 8):
        raise ValueError(f"semi-global aggregation takes 4 or 8 paths, not {paths}")
    if cost.dtype != np.uint8:
        cost = np.ascontiguousarray(cost, np.float32)
    cost = np.ascontiguousarray(cost)
    guide = np.ascontiguousarray(guide, np.float32)
    total = np.zeros(cost.shape, np.float32)
    from_below = np.zeros(cost.shape, np.float32)
    p1, p2, scale = np.float32(p1), np.float32(max(p1, p2)), np.float32(edge_scale)
    _vertical_paths(cost, guide, p1, p2, scale, paths == 8, total, from_below)
    _horizontal_paths(cost, guide, p1, p2, scale, total)
    _add_into(total, from_below)
    return total


def semiglobal_aggregate_reference(cost, guide, *, p1, p2, edge_scale=8.0, paths=8):
    """:func:`semiglobal_aggregate` path by path in plain numpy (for the tests)."""
    cost = np.asarray(cost, np.float64)
    guide = np.asarray(guide, np.float64)
    h, w, nd = cost.shape
    p2 = max(p1, p2)
    directions = [(0, 1), (0, -1), (1, 0), (-1, 0)]
    if paths == 8:
        directions += [(1, 1), (1, -1), (-1, -1), (-1, 1)]
    total = np.zeros_like(cost)
    for dy, dx in directions:
        lr = np.zeros_like(cost)
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        xs = list(range(w)) if dx >= 0 else list(range(w - 1, -1, -1))
        for y in ys:
            for x in xs:
                py, px = y - dy, x - dx
                if not (0 <= py < h and 0 <= px < w):
                    lr[y, x] = cost[y, x]
                    continue
                prev = lr[py, px]
                low = prev.min()
                jump = max(p1, p2 / (1 + abs(guide[y, x] - guide[py, px]) / edge_scale))
                up = np.concatenate([[np.inf], prev[:-1]]) + p1
                down = np.concatenate([prev[1:], [np.inf]]) + p1
                lr[y, x] = cost[y, x] + np.minimum.reduce([prev, up, down, np.full(nd, low + jump)]) - low
        total += lr
    return total


@njit(cache=True, parallel=True)
def semiglobal_winners(total, min_disp):
    """Left and right disparities from the aggregated cost.

    The left view's winner is refined to sub-pixel by a parabola; the right view's is
    searched along the diagonal ``total[y, xr + d, d]`` (Hirschmüller's right view from
    the left volume, no second aggregation).

    Parameters
    ----------
    total : ndarray, float32 (H, W, D)
    min_disp : int

    Returns
    -------
    left, right : ndarray, float32 (H, W)
        Right pixels with no match in I1 are NaN.
    """
    h, w, nd = total.shape
    left = np.empty((h, w), np.float32)
    right = np.empty((h, w), np.float32)
    for y in prange(h):
        for x in range(w):
            row = total[y, x]
            best = 0
            for d in range(1, nd):
                if row[d] < row[best]:
                    best = d
            left[y, x] = refined_winner(row, best, min_disp)
            best_r = -1
            best_v = np.float32(np.inf)
            for k in range(nd):
                xl = x + min_disp + k
                if 0 <= xl < w and total[y, xl, k] < best_v:
                    best_v = total[y, xl, k]
                    best_r = k
            right[y, x] = np.float32(min_disp + best_r) if best_r >= 0 else np.float32(np.nan)
    return left, right
