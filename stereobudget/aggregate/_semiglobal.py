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

Volumes: the cost is uint8 or float32 (H, W, D).  The paths from above and those from
below are summed into two float32 (H, W, D) volumes, each pass on its own thread (8 bytes
per pixel and disparity at the peak); the horizontal paths and the sum of the two are
taken row by row in a (W, D) float32 buffer, where the winners are searched too, so the
sum is never written out unless asked for (:func:`semiglobal_aggregate`); the right view's
winners read a transposed copy of the row, float32 (D, W).  The paths keep two rows of
float32 (W, D) per direction.

Every sum is formed in one fixed order (paths from above, left to right, right to left,
paths from below), so the fused route (:func:`semiglobal_disparities`) and the volume
(:func:`semiglobal_aggregate`) followed by :func:`semiglobal_winners` agree bit for bit.
"""

import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL, RANGE_KERNEL_COUNTED
from .._kernels._parallel import run_parts

from ._winner import refined_winner, subpixel_winner


@njit(cache=True, inline="always")
def _smallest(values):
    """The smallest of ``values`` (float32, no NaN), in eight interleaved running minima.

    One running minimum is a chain of compare-and-selects that LLVM will not reorder (it
    could for floats only under fast-math flags), so it stays scalar; eight independent
    ones become one vector minimum per eight layers.  The minimum of finite values does
    not depend on the order it is taken in, so this is bit for bit a plain loop's.
    """
    n = values.shape[0]
    m0 = m1 = m2 = m3 = m4 = m5 = m6 = m7 = np.float32(np.inf)
    d = 0
    while d + 8 <= n:
        m0 = min(m0, values[d])
        m1 = min(m1, values[d + 1])
        m2 = min(m2, values[d + 2])
        m3 = min(m3, values[d + 3])
        m4 = min(m4, values[d + 4])
        m5 = min(m5, values[d + 5])
        m6 = min(m6, values[d + 6])
        m7 = min(m7, values[d + 7])
        d += 8
    best = min(min(min(m0, m1), min(m2, m3)), min(min(m4, m5), min(m6, m7)))
    for k in range(d, n):
        best = min(best, values[k])
    return best


@njit(cache=True, inline="always")
def _path_step(cost, prev, prev_min, p1, p2, out):
    """One step of a path: ``out`` from the predecessor's ``prev``; returns min of ``out``.

    The first and last layers, which have one neighbour, are taken apart so that the
    loop over the others has no branch and vectorises.  min(a + P1, b + P1) is
    min(a, b) + P1 exactly (rounding is monotonic), so one addition serves both
    neighbours.
    """
    nd = cost.shape[0]
    jump = prev_min + p2
    if nd == 1:
        out[0] = np.float32(cost[0]) + min(prev[0], jump) - prev_min
        return out[0]
    out[0] = np.float32(cost[0]) + min(min(prev[0], prev[1] + p1), jump) - prev_min
    for d in range(1, nd - 1):
        out[d] = np.float32(cost[d]) + min(min(prev[d], min(prev[d - 1], prev[d + 1]) + p1), jump) - prev_min
    last = nd - 1
    out[last] = np.float32(cost[last]) + min(min(prev[last], prev[last - 1] + p1), jump) - prev_min
    return _smallest(out)


@njit(cache=True, inline="always")
def _path_start(cost, out):
    nd = cost.shape[0]
    for d in range(nd):
        out[d] = np.float32(cost[d])
    return _smallest(out)


@njit(cache=True, inline="always")
def _edge_p2(a, b, p1, p2, edge_scale):
    return max(p1, p2 / (np.float32(1.0) + abs(a - b) / edge_scale))


@njit(cache=True)
def _vertical_pass(cost, guide, direction, steps, p1, p2, edge_scale, total):
    """The paths that come from the row before (``direction`` 1: from above, -1: from below),
    summed into ``total`` (overwritten)."""
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
                total[y, x, d] = cur[0, x, d]
            for k in range(1, npaths):
                for d in range(nd):
                    total[y, x, d] += cur[k, x, d]


@njit(cache=True, **RANGE_KERNEL_COUNTED)
def _vertical_paths(cost, guide, p1, p2, edge_scale, steps, down, up, first, stop):
    """Passes ``[first, stop)`` of the two vertical ones (0: down, 1: up), each into its own sum.

    Both run at once, each on its own thread: a pass is sequential over rows, and
    splitting a row between threads would make every row wait for the slower one (badly
    so on a busy machine).  ``steps``: the x steps of the paths, [0, 1, -1] with the diagonals."""
    for j in range(first, stop):
        if j == 0:
            _vertical_pass(cost, guide, 1, steps, p1, p2, edge_scale, down)
        else:
            _vertical_pass(cost, guide, -1, steps, p1, p2, edge_scale, up)


@njit(cache=True, inline="always")
def _row_total(cost, guide, p1, p2, edge_scale, down, up, y, row, path):
    """``row`` (W, D) = the paths from above at row ``y`` + left to right + right to left +
    the paths from below.  ``row`` may be ``down[y]`` itself."""
    w, nd = cost.shape[1], cost.shape[2]
    for direction in (1, -1):
        start = 0 if direction == 1 else w - 1
        prev, cur = path[0], path[1]
        prev_min = _path_start(cost[y, start], prev)
        for i in range(w):
            x = start + direction * i
            if i > 0:
                p2e = _edge_p2(guide[y, x], guide[y, x - direction], p1, p2, edge_scale)
                prev_min = _path_step(cost[y, x], prev, prev_min, p1, p2e, cur)
                prev, cur = cur, prev
            if direction == 1:
                for d in range(nd):
                    row[x, d] = down[y, x, d] + prev[d]
            else:
                for d in range(nd):
                    row[x, d] += prev[d]
    for x in range(w):
        for d in range(nd):
            row[x, d] += up[y, x, d]


@njit(cache=True)
def _row_winners(row, min_disp, y, left, right, layers, best_v, best_k):
    """Left and right winners of row ``y`` from its aggregated cost ``row`` (W, D).

    The right view's winner at ``xr`` is the first smallest ``row[xr + min_disp + k, k]``
    over ``k`` (:func:`semiglobal_winners` walks that diagonal, one cache line per layer).
    Here the row is transposed once into ``layers`` (D, W) and each layer is compared with
    the best so far for every right pixel at once, in increasing ``k`` with a strict
    ``<``: the same winners bit for bit, in vector instructions.  ``best_v`` (W,) float32
    and ``best_k`` (W,) int32 are scratch.
    """
    w, nd = row.shape
    for x in range(w):
        left[y, x] = subpixel_winner(row[x], min_disp)
        for k in range(nd):
            layers[k, x] = row[x, k]
    best_v[:] = np.inf
    best_k[:] = -1
    for k in range(nd):
        # Right pixel xr meets layer k of left pixel xr + min_disp + k, when that is in the row.
        lo = max(0, -min_disp - k)
        hi = min(w, w - min_disp - k)
        if hi <= lo:
            continue
        # Slices, so that the loop index is a plain count from 0 (no negative-index
        # handling in the way of vectorising).
        offered = layers[k, lo + min_disp + k:hi + min_disp + k]
        values = best_v[lo:hi]
        winners = best_k[lo:hi]
        layer = np.int32(k)
        for i in range(hi - lo):
            v = offered[i]
            b = values[i]
            winners[i] = layer if v < b else winners[i]
            values[i] = v if v < b else b
    for x in range(w):
        right[y, x] = np.float32(min_disp + best_k[x]) if best_k[x] >= 0 else np.float32(np.nan)


@njit(cache=True, **RANGE_KERNEL)
def _horizontal_paths_into(cost, guide, p1, p2, edge_scale, down, up, path, first, stop):
    """Rows ``[first, stop)`` of ``down`` += the horizontal paths and ``up`` (the aggregated volume);
    ``path`` (2, D) float32 is the range's scratch."""
    for y in range(first, stop):
        _row_total(cost, guide, p1, p2, edge_scale, down, up, y, down[y], path)


@njit(cache=True, **RANGE_KERNEL)
def _horizontal_paths_winners_rows(cost, guide, p1, p2, edge_scale, down, up, min_disp, left, right, path, row,
                                   layers, best_v, best_k, first, stop):
    """Rows ``[first, stop)`` of :func:`_horizontal_paths_winners`, on the range's scratch
    (:func:`_row_scratch`)."""
    for y in range(first, stop):
        _row_total(cost, guide, p1, p2, edge_scale, down, up, y, row, path)
        _row_winners(row, min_disp, y, left, right, layers, best_v, best_k)


def _row_scratch(w, nd):
    """Scratch of one range of rows: the path pair (2, D), the row's sum (W, D), its layers
    (D, W), and the right view's best value and layer (W,) float32 / int32."""
    return (np.empty((2, nd), np.float32), np.empty((w, nd), np.float32), np.empty((nd, w), np.float32),
            np.empty(w, np.float32), np.empty(w, np.int32))


def _horizontal_paths_winners(cost, guide, p1, p2, edge_scale, down, up, min_disp):
    """The winners of every row of the aggregated volume, each row summed in a buffer."""
    h, w = cost.shape[:2]
    left = np.empty((h, w), np.float32)
    right = np.empty((h, w), np.float32)
    run_parts(_horizontal_paths_winners_rows, h, cost, guide, p1, p2, edge_scale, down, up, min_disp, left, right,
              scratch=lambda: _row_scratch(w, cost.shape[2]))
    return left, right


def _vertical_sums(cost, guide, p1, p2, edge_scale, paths):
    if paths not in (4, 8):
        raise ValueError(f"semi-global aggregation takes 4 or 8 paths, not {paths}")
    if cost.dtype != np.uint8:
        cost = np.ascontiguousarray(cost, np.float32)
    cost = np.ascontiguousarray(cost)
    guide = np.ascontiguousarray(guide, np.float32)
    down = np.empty(cost.shape, np.float32)
    up = np.empty(cost.shape, np.float32)
    p1, p2, scale = np.float32(p1), np.float32(max(p1, p2)), np.float32(edge_scale)
    steps = np.array([0, 1, -1] if paths == 8 else [0], np.int64)
    run_parts(_vertical_paths, 2, cost, guide, p1, p2, scale, steps, down, up, parts=2)
    return cost, guide, p1, p2, scale, down, up


def semiglobal_aggregate(cost: np.ndarray, guide: np.ndarray, *, p1: float, p2: float,
                         edge_scale: float = 8.0, paths: int = 8) -> np.ndarray:
    """Sum of the path costs L_r over 4 or 8 directions (see the module docstring).

    Parameters
    ----------
    cost : ndarray, uint8 or float32 (H, W, D)
        Matching cost volume of the left view (non-negative, no NaN).
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
    cost, guide, p1, p2, scale, down, up = _vertical_sums(cost, guide, p1, p2, edge_scale, paths)
    run_parts(_horizontal_paths_into, cost.shape[0], cost, guide, p1, p2, scale, down, up,
              scratch=lambda: (np.empty((2, cost.shape[2]), np.float32),))
    return down


def semiglobal_disparities(cost: np.ndarray, guide: np.ndarray, *, min_disp: int, p1: float, p2: float,
                           edge_scale: float = 8.0, paths: int = 8):
    """:func:`semiglobal_winners` of :func:`semiglobal_aggregate`, without writing the sum out.

    The last pass (the horizontal paths) takes the winners of each row as soon as the
    row's sum is complete; the result is the two-step route's bit for bit.

    Parameters
    ----------
    cost, guide, p1, p2, edge_scale, paths
        As for :func:`semiglobal_aggregate`.
    min_disp : int

    Returns
    -------
    left, right : ndarray, float32 (H, W)
        As from :func:`semiglobal_winners`.
    """
    cost, guide, p1, p2, scale, down, up = _vertical_sums(cost, guide, p1, p2, edge_scale, paths)
    return _horizontal_paths_winners(cost, guide, p1, p2, scale, down, up, int(min_disp))


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
    h, w = total.shape[:2]
    left = np.empty((h, w), np.float32)
    right = np.empty((h, w), np.float32)
    run_parts(_winners_rows, h, total, int(min_disp), left, right)
    return left, right


@njit(cache=True, **RANGE_KERNEL)
def _winners_rows(total, min_disp, left, right, first, stop):
    """Rows ``[first, stop)`` of :func:`semiglobal_winners`."""
    w, nd = total.shape[1], total.shape[2]
    for y in range(first, stop):
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
