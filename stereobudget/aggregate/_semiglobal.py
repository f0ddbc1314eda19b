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

Fixed point: the paths count in 16-bit integers, as OpenCV's do.  Costs and penalties
are scaled by a power of two ``q`` (:func:`fixed_point_scale`, from a bound on the costs
and P2) and rounded as they are read, so that a path's cost stays below 8191 and eight
paths' sum below 2**16.  A vector then holds sixteen layers, twice float32's, and the
sums take half the memory; on the default decode's costs (at most 1, P2 about 7) one step
of ``q`` is 1/512 of a cost unit, and the realdev and Middlebury scores moved by at most
0.03 pp on any scene.  Integer costs stay exact.

Volumes: the cost is uint8 or float32 (H, W, D).  The paths from above and those from
below are summed into two uint16 (H, W, D) volumes, each pass on its own thread (4 bytes
per pixel and disparity at the peak); the horizontal paths and the sum of the two are
taken row by row in a (W, D) uint16 buffer and turned into a float32 row (whole numbers),
where the winners are searched too, so the sum is never written out unless asked for
(:func:`semiglobal_aggregate`, which divides it by ``q``: exact for a power of two); the
right view's winners read a transposed copy of the row, float32 (D, W).  The paths keep
two rows of uint16 (W, D) per direction.

Every sum is formed in one fixed order (paths from above, left to right, right to left,
paths from below), so the fused route (:func:`semiglobal_disparities`) and the volume
(:func:`semiglobal_aggregate`) followed by :func:`semiglobal_winners` agree bit for bit.
"""

import math

import numpy as np
from numba import njit

from .._kernels import _scratch as scratch
from .._kernels._jit import NO_REFCOUNTS, RANGE_KERNEL
from .._kernels._parallel import run_parts
from .._kernels._simd import FIXED_LANES, fixed_path_step

from ._winner import refined_winner, subpixel_winner


#: Largest cost plus P2 in fixed point: a path's cost stays within it, so eight paths'
#: sum fits 16 bits (8 * 8191 < 2**16) and no sum on the way wraps.
FIXED_LIMIT = 8190


def fixed_point_scale(cost_max: float, p2: float) -> float:
    """The power of two ``q`` that the path sums count in: ``q * (cost_max + p2) <= FIXED_LIMIT``.

    A power of two, so the costs of an integer volume stay exact (``q >= 1`` for any sum up
    to :data:`FIXED_LIMIT`) and dividing a sum by ``q`` is exact in float32.
    """
    span = float(cost_max) + float(p2)
    if not span > 0:
        return 1.0
    return 2.0 ** math.floor(math.log2(FIXED_LIMIT / span))


@njit(cache=True, inline="always")
def _fixed(value, scale):
    """A cost or penalty in fixed point: ``uint16(value * scale + 0.5)``, float32 arithmetic."""
    return np.uint16(np.float32(value) * scale + np.float32(0.5))


@njit(cache=True, inline="always")
def _path_step(cost, scale, prev, prev_min, p1, p2, out):
    """One step of a path: ``out`` (uint16) from the predecessor's ``prev``; returns min of ``out``.

    ``p1`` and ``p2`` are in fixed point; ``cost`` is quantised as it is read.  The inner
    layers go sixteen at a time (:func:`fixed_path_step`); the first and last, which have
    one neighbour, are taken here.
    """
    nd = cost.shape[0]
    if nd < FIXED_LANES + 2:
        return _short_path_step(cost, scale, prev, prev_min, p1, p2, out)
    jump = np.uint16(prev_min + p2)
    out[0] = _fixed(cost[0], scale) + min(min(prev[0], prev[1] + p1), jump) - prev_min
    last = nd - 1
    out[last] = _fixed(cost[last], scale) + min(min(prev[last], prev[last - 1] + p1), jump) - prev_min
    return min(min(out[0], out[last]), fixed_path_step(cost, scale, prev, out, prev_min, p1, jump))


@njit(cache=True, **NO_REFCOUNTS)
def _short_path_step(cost, scale, prev, prev_min, p1, p2, out):
    """:func:`_path_step` of fewer layers than a vector's inner span, element by element.

    A function of its own: with this loop inlined beside the vector call, LLVM made the
    vector path three times slower, though the loop never ran there."""
    nd = cost.shape[0]
    jump = np.uint16(prev_min + p2)
    if nd == 1:
        out[0] = _fixed(cost[0], scale) + min(prev[0], jump) - prev_min
        return out[0]
    smallest = np.uint16(0xFFFF)
    for d in range(nd):
        neighbours = min(prev[d - 1] if d > 0 else np.uint16(0xFFFF), prev[d + 1] if d < nd - 1 else np.uint16(0xFFFF))
        out[d] = _fixed(cost[d], scale) + min(min(prev[d], neighbours + p1), jump) - prev_min
        smallest = min(smallest, out[d])
    return smallest


@njit(cache=True, inline="always")
def _edge_p2(a, b, p1, p2, edge_scale, scale):
    """P2 lowered at an edge of I1, in float32, then in fixed point."""
    return _fixed(max(p1, p2 / (np.float32(1.0) + abs(a - b) / edge_scale)), scale)


@njit(cache=True, error_model="numpy", **NO_REFCOUNTS)
def _vertical_pass(cost, guide, direction, steps, scale, p1, p2, edge_scale, total, rows, mins, zeros):
    """The paths that come from the row before (``direction`` 1: from above, -1: from below),
    summed into ``total`` (uint16, overwritten).  ``p1`` and ``p2`` in cost units.

    ``rows`` (2, paths, W, D) and ``mins`` (2, paths, W) uint16 hold each path's previous
    and current row in turn; ``zeros`` (D,) uint16 is zero.  Without reference counts
    (its caller allocates), so the views taken per step cost nothing: counted, they made
    the pass three times slower.
    """
    h, w, nd = cost.shape
    npaths = steps.shape[0]
    p1_fixed = _fixed(p1, scale)
    for i in range(h):
        y = i if direction == 1 else h - 1 - i
        cur, prev = rows[i % 2], rows[1 - i % 2]
        cur_min, prev_min = mins[i % 2], mins[1 - i % 2]
        for x in range(w):
            for k in range(npaths):
                # The predecessor is one row back and ``steps[k]`` columns back; a path's
                # first pixel is a step from zeros (its costs, unchanged).
                xp = x - steps[k] * direction
                if i == 0 or xp < 0 or xp >= w:
                    before, before_min, p2e = zeros, np.uint16(0), p1_fixed
                else:
                    before, before_min = prev[k, xp], prev_min[k, xp]
                    p2e = _edge_p2(guide[y, x], guide[y - direction, xp], p1, p2, edge_scale, scale)
                cur_min[k, x] = _path_step(cost[y, x], scale, before, before_min, p1_fixed, p2e, cur[k, x])
            _sum_paths(cur, x, total[y, x])


@njit(cache=True, inline="always")
def _sum_paths(cur, x, out):
    """``out`` = the sum over paths k of ``cur[k, x]`` (uint16, below 2**16 by FIXED_LIMIT)."""
    nd = out.shape[0]
    for d in range(nd):
        out[d] = cur[0, x, d]
    for k in range(1, cur.shape[0]):
        row = cur[k, x]
        for d in range(nd):
            out[d] = np.uint16(out[d] + row[d])


@njit(cache=True, **RANGE_KERNEL)
def _vertical_paths(cost, guide, scale, p1, p2, edge_scale, steps, down, up, rows, mins, zeros, first, stop):
    """Passes ``[first, stop)`` of the two vertical ones (0: down, 1: up), each into its own sum,
    on the range's buffers (:func:`_vertical_scratch`).

    Both run at once, each on its own thread: a pass is sequential over rows, and
    splitting a row between threads would make every row wait for the slower one (badly
    so on a busy machine).  ``steps``: the x steps of the paths, [0, 1, -1] with the diagonals."""
    for j in range(first, stop):
        _vertical_pass(cost, guide, 1 if j == 0 else -1, steps, scale, p1, p2, edge_scale, down if j == 0 else up,
                       rows, mins, zeros)


def _vertical_scratch(w, nd, paths):
    """Buffers of one vertical pass: two rows of every path's costs (2, paths, W, D) and minima
    (2, paths, W), and a row of zeros (D,), uint16."""
    return (np.empty((2, paths, w, nd), np.uint16), np.empty((2, paths, w), np.uint16), np.zeros(nd, np.uint16))


@njit(cache=True, inline="always")
def _row_total(cost, guide, scale, p1, p2, edge_scale, down, up, y, row, total, path):
    """``row`` (W, D) float32 = the paths from above at row ``y`` + left to right + right to
    left + the paths from below, in fixed point (whole numbers).

    The left-to-right path is stepped straight into ``total`` (W, D), the right-to-left one
    through ``path[0:2]`` and added in; ``path[2]`` stays zeros (a path's first pixel is a
    step from zeros, as in :func:`_vertical_pass`).  uint16 scratch; sums of whole numbers
    below 2**16 do not depend on their order.
    """
    w, nd = cost.shape[1], cost.shape[2]
    p1_fixed = _fixed(p1, scale)
    zeros = path[2]
    prev_min = _path_step(cost[y, 0], scale, zeros, np.uint16(0), p1_fixed, p1_fixed, total[0])
    for x in range(1, w):
        p2e = _edge_p2(guide[y, x], guide[y, x - 1], p1, p2, edge_scale, scale)
        prev_min = _path_step(cost[y, x], scale, total[x - 1], prev_min, p1_fixed, p2e, total[x])
    prev, cur = path[0], path[1]
    for i in range(w):
        x = w - 1 - i
        if i == 0:
            before, before_min, p2e = zeros, np.uint16(0), p1_fixed
        else:
            before, before_min = prev, prev_min
            p2e = _edge_p2(guide[y, x], guide[y, x + 1], p1, p2, edge_scale, scale)
        prev_min = _path_step(cost[y, x], scale, before, before_min, p1_fixed, p2e, cur)
        prev, cur = cur, prev
        for d in range(nd):
            total[x, d] = np.uint16(total[x, d] + prev[d])
    for x in range(w):
        for d in range(nd):
            row[x, d] = np.float32(np.uint16(np.uint16(total[x, d] + down[y, x, d]) + up[y, x, d]))


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
def _horizontal_paths_into(cost, guide, scale, p1, p2, edge_scale, down, up, out, path, total, first, stop):
    """Rows ``[first, stop)`` of the aggregated volume ``out`` (float32, cost units);
    ``path`` and ``total`` are the range's scratch (:func:`_row_scratch`)."""
    unit = np.float32(1.0) / scale
    for y in range(first, stop):
        _row_total(cost, guide, scale, p1, p2, edge_scale, down, up, y, out[y], total, path)
        for x in range(out.shape[1]):
            for d in range(out.shape[2]):
                out[y, x, d] *= unit


@njit(cache=True, **RANGE_KERNEL)
def _horizontal_paths_winners_rows(cost, guide, scale, p1, p2, edge_scale, down, up, min_disp, left, right, path,
                                   total, row, layers, best_v, best_k, first, stop):
    """Rows ``[first, stop)`` of :func:`_horizontal_paths_winners`, on the range's scratch
    (:func:`_row_scratch`)."""
    for y in range(first, stop):
        _row_total(cost, guide, scale, p1, p2, edge_scale, down, up, y, row, total, path)
        _row_winners(row, min_disp, y, left, right, layers, best_v, best_k)


def _row_scratch(w, nd, winners=True):
    """Scratch of one range of rows: the path pair and a row of zeros (3, D) and the row's
    fixed-point sum (W, D) uint16; with the winners, the row's sum (W, D) and its layers (D, W) float32, and the
    right view's best value and layer (W,) float32 / int32."""
    fixed = (np.zeros((3, nd), np.uint16), np.empty((w, nd), np.uint16))
    if not winners:
        return fixed
    return fixed + (np.empty((w, nd), np.float32), np.empty((nd, w), np.float32), np.empty(w, np.float32),
                    np.empty(w, np.int32))


def _horizontal_paths_winners(cost, guide, scale, p1, p2, edge_scale, down, up, min_disp):
    """The winners of every row of the aggregated volume, each row summed in a buffer."""
    h, w = cost.shape[:2]
    left = np.empty((h, w), np.float32)
    right = np.empty((h, w), np.float32)
    run_parts(_horizontal_paths_winners_rows, h, cost, guide, scale, p1, p2, edge_scale, down, up, min_disp, left,
              right, scratch=lambda: _row_scratch(w, cost.shape[2]))
    return left, right


def _sum_volumes(shape):
    """Two uninitialised uint16 volumes of ``shape`` on the memory of float32 ones
    (:func:`stereobudget._kernels._scratch.empty_volume`: spare ones when a decode gave them
    back, whose pages need no faulting in), and that memory, for :func:`scratch.recycle`."""
    count = int(np.prod(shape, dtype=np.int64))
    memory = [scratch.empty_volume(((count + 1) // 2,)) for _ in range(2)]
    return [floats.view(np.uint16)[:count].reshape(shape) for floats in memory], memory


def _vertical_sums(cost, guide, p1, p2, edge_scale, paths, cost_max):
    if paths not in (4, 8):
        raise ValueError(f"semi-global aggregation takes 4 or 8 paths, not {paths}")
    if cost.dtype != np.uint8:
        cost = np.ascontiguousarray(cost, np.float32)
    cost = np.ascontiguousarray(cost)
    guide = np.ascontiguousarray(guide, np.float32)
    p1, p2 = float(p1), float(max(p1, p2))
    if cost_max is None:
        cost_max = 255.0 if cost.dtype == np.uint8 else float(cost.max())
    scale = np.float32(fixed_point_scale(cost_max, p2))
    # Fixed-point sums: half the memory of float32 and twice the lanes per vector.
    (down, up), memory = _sum_volumes(cost.shape)
    p1, p2, edge = np.float32(p1), np.float32(p2), np.float32(edge_scale)
    steps = np.array([0, 1, -1] if paths == 8 else [0], np.int64)
    run_parts(_vertical_paths, 2, cost, guide, scale, p1, p2, edge, steps, down, up, parts=2,
              scratch=lambda: _vertical_scratch(cost.shape[1], cost.shape[2], len(steps)))
    return cost, guide, scale, p1, p2, edge, down, up, memory


def semiglobal_aggregate(cost: np.ndarray, guide: np.ndarray, *, p1: float, p2: float,
                         edge_scale: float = 8.0, paths: int = 8, cost_max: float | None = None) -> np.ndarray:
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
    cost_max : float, optional
        A bound on the costs, which sets the fixed point (:func:`fixed_point_scale`);
        default 255 for uint8, else the volume's largest cost.

    Returns
    -------
    ndarray, float32 (H, W, D)
        In cost units: the fixed-point sum divided by its scale (exactly).
    """
    cost, guide, scale, p1, p2, edge, down, up, memory = _vertical_sums(cost, guide, p1, p2, edge_scale, paths,
                                                                        cost_max)
    total = np.empty(cost.shape, np.float32)
    run_parts(_horizontal_paths_into, cost.shape[0], cost, guide, scale, p1, p2, edge, down, up, total,
              scratch=lambda: _row_scratch(cost.shape[1], cost.shape[2], winners=False))
    scratch.recycle(*memory)
    return total


def semiglobal_disparities(cost: np.ndarray, guide: np.ndarray, *, min_disp: int, p1: float, p2: float,
                           edge_scale: float = 8.0, paths: int = 8, cost_max: float | None = None):
    """:func:`semiglobal_winners` of :func:`semiglobal_aggregate`, without writing the sum out.

    The last pass (the horizontal paths) takes the winners of each row as soon as the
    row's sum is complete; the result is the two-step route's bit for bit.

    Parameters
    ----------
    cost, guide, p1, p2, edge_scale, paths, cost_max
        As for :func:`semiglobal_aggregate`.
    min_disp : int

    Returns
    -------
    left, right : ndarray, float32 (H, W)
        As from :func:`semiglobal_winners`.
    """
    cost, guide, scale, p1, p2, edge, down, up, memory = _vertical_sums(cost, guide, p1, p2, edge_scale, paths,
                                                                        cost_max)
    winners = _horizontal_paths_winners(cost, guide, scale, p1, p2, edge, down, up, int(min_disp))
    scratch.recycle(*memory)
    return winners


def pixel_margins(cost: np.ndarray, *, step: int = 1) -> np.ndarray:
    """Each pixel's mean cost over the disparities minus its smallest, at every ``step``-th
    row and column: what its data term says for its winner (P1 and P2 are multiples of
    these margins' median).

    Parameters
    ----------
    cost : ndarray, uint8 or float32 (H, W, D), C-contiguous
    step : int

    Returns
    -------
    ndarray, float32 (ceil(H / step), ceil(W / step))
        The mean is summed in float64 and the difference rounded to float32 (numpy's
        float32 ``mean - min`` of the same pixels to within float32 rounding).
    """
    h, w = cost.shape[:2]
    out = np.empty(((h + step - 1) // step, (w + step - 1) // step), np.float32)
    run_parts(_margin_rows, out.shape[0], np.ascontiguousarray(cost), int(step), out)
    return out


@njit(cache=True, **RANGE_KERNEL)
def _margin_rows(cost, step, out, first, stop):
    """Rows ``[first, stop)`` of :func:`pixel_margins`."""
    nd = cost.shape[2]
    for i in range(first, stop):
        for j in range(out.shape[1]):
            layers = cost[i * step, j * step]
            total = 0.0
            smallest = np.float64(layers[0])
            for d in range(nd):
                value = np.float64(layers[d])
                total += value
                smallest = min(smallest, value)
            out[i, j] = np.float32(total / nd - smallest)


def semiglobal_aggregate_reference(cost, guide, *, p1, p2, edge_scale=8.0, paths=8, cost_max=None, fixed_point=True):
    """:func:`semiglobal_aggregate` path by path in plain numpy (for the tests), on the same
    fixed-point costs and penalties, each quantised with the same float32 arithmetic.

    ``fixed_point=False`` sums the paths of the unquantised costs in float64 instead: what
    the fixed point approximates.
    """
    cost = np.asarray(cost)
    guide = np.asarray(guide, np.float32)
    h, w, nd = cost.shape
    p2 = max(float(p1), float(p2))
    if fixed_point:
        if cost_max is None:
            cost_max = 255.0 if cost.dtype == np.uint8 else float(cost.max())
        scale = np.float32(fixed_point_scale(cost_max, p2))
        p1, p2, edge_scale = np.float32(p1), np.float32(p2), np.float32(edge_scale)

        def fixed(value):
            return np.floor(np.asarray(value, np.float32) * scale + np.float32(0.5)).astype(np.int64)
        big = np.iinfo(np.int64).max // 2
    else:
        scale, p1, edge_scale = 1.0, float(p1), float(edge_scale)
        guide = guide.astype(np.float64)

        def fixed(value):
            return np.asarray(value, np.float64)
        big = np.inf

    cost = fixed(cost)
    p1_fixed = fixed(p1)
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
                jump = fixed(max(p1, p2 / (1 + abs(guide[y, x] - guide[py, px]) / edge_scale)))
                up = np.concatenate([[big], prev[:-1]]) + p1_fixed
                down = np.concatenate([prev[1:], [big]]) + p1_fixed
                lr[y, x] = cost[y, x] + np.minimum.reduce([prev, up, down, np.full(nd, low + jump)]) - low
        total += lr
    return total / float(scale)


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
