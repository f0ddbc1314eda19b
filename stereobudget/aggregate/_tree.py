"""Non-local cost aggregation on a minimum spanning tree (Q. Yang, CVPR 2012): the two walks.

The aggregated cost of pixel ``p`` is ``sum_q S(p, q) C(q)`` over *all* pixels ``q``, where
``S`` is the product of the edge similarities along the tree path (the tree:
:mod:`stereobudget.aggregate._mst`), which two linear passes over the tree compute exactly:

* leaf to root: ``C_up(v) = C(v) + sum_children S(v, c) C_up(c)``;
* root to leaf: ``C_A(v) = S(p, v) C_A(p) + (1 - S(p, v)^2) C_up(v)``.

Both passes run on all disparities of a node at once, so the cost is ``O(N D)``.  The
tree is stored in depth-first pre-order, so the walk over the volume stays mostly in
cache, and every subtree is a contiguous range of the order, which lets two threads take
one half of the tree each.

Conventions: nodes are row-major pixel indices ``row * width + col``; cost volumes are
float32 ``(H, W, D)`` with the disparity axis contiguous, or ``(N, D)`` rows in the tree's
order (:class:`stereobudget.aggregate.TreeLayout`).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit

from .._kernels._jit import NO_REFCOUNTS, RANGE_KERNEL_COUNTED
from .._kernels._parallel import run_parts, take
from .._kernels._prefetch import prefetch_row
from .._kernels._simd import LANES, blend_rows_first_min
from ._mst import MinimumSpanningTree, TreeLayout, _balanced_cut, _fill_subtree_sizes, _subtree_sizes, tree_layout
from ._winner import refined_winner, subpixel_winner

__all__ = ["aggregate", "aggregate_winners", "aggregate_rows_winners", "aggregate_two_rows_winners",
           "distance_rows_winners"]

# Below this many pixels `aggregate` stays on one thread: waking a second one costs more.
_PARALLEL_MIN_NODES = 16384
# Walk steps ahead whose rows are prefetched.
_PREFETCH_AHEAD = 16
# Walks side by side (:func:`_side_by_side_cuts`): the fewest nodes of the shorter range
# worth a pair, and the most pairs cut from one range (each cut after the first takes
# ranges from the nodes before the previous one, fewer each time).
_MIN_SIDE_BY_SIDE = 1024
_MAX_CUTS = 4
# No subtree sizes given: the serial walk computes them where it needs them.
_NO_SIZES = np.zeros(0, np.int32)


@njit(cache=True, inline="always")
def _distance_row(level, min_disp, target):
    """``target[i] = |min_disp + i - level|``, or 0 where ``level`` is NaN: the cost of Yang's
    non-local refinement (:func:`stereobudget.aggregate.nonlocal_refinement`)."""
    if level != level:
        for d in range(target.shape[0]):
            target[d] = 0.0
    else:
        for d in range(target.shape[0]):
            # float32 subtraction: the exact difference rounded once, as in float64.
            target[d] = abs(np.float32(min_disp + d) - level)


@njit(cache=True, inline="always")
def _prefetch_node(out_flat, order, parent, position, disparities):
    """Prefetch the rows of the node at order position ``position`` and of its parent: in
    pixel order both are at data-dependent addresses, and in tree order the parent often is."""
    node = order[position]
    prefetch_row(out_flat, node, disparities)
    prefetch_row(out_flat, parent[node], disparities)


@njit(cache=True, inline="always")
def _upward_rows(order, parent, weight, out, out_flat, position, first, disparities):
    """The node at order position ``position`` in the upward pass (``first``: the range's
    first position, where the prefetch stops): its node, its parent, their similarity,
    and its row and its parent's."""
    if position - _PREFETCH_AHEAD >= first:
        _prefetch_node(out_flat, order, parent, position - _PREFETCH_AHEAD, disparities)
    v = order[position]
    p = parent[v]
    return v, p, weight[v], out[v], out[p]


@njit(cache=True, inline="always")
def _push_in_place(order, parent, weight, out, out_flat, position, first, disparities):
    """The node at order position ``position`` pushes its row into its parent's; its own
    row already holds its cost (:func:`_upward_range`, in place)."""
    _, _, s, child, target = _upward_rows(order, parent, weight, out, out_flat, position, first, disparities)
    for d in range(disparities):
        target[d] += s * child[d]


@njit(cache=True, inline="always")
def _push_cost(cost, order, parent, weight, out, out_flat, ready, position, first, disparities):
    """:func:`_push_in_place` with the cost read from ``cost`` as a row is first touched."""
    v, p, s, child, target = _upward_rows(order, parent, weight, out, out_flat, position, first, disparities)
    if not ready[v]:  # a leaf: nothing was pushed into it
        source = cost[v]
        for d in range(disparities):
            child[d] = source[d]
        ready[v] = 1
    if ready[p]:
        for d in range(disparities):
            target[d] += s * child[d]
    else:
        source = cost[p]
        for d in range(disparities):
            target[d] = source[d] + s * child[d]
        ready[p] = 1


@njit(cache=True, inline="always")
def _push_distance(levels, min_disp, order, parent, weight, out, out_flat, ready, position, first, disparities):
    """:func:`_push_cost` with the cost of :func:`_distance_row` made as a row is first touched."""
    v, p, s, child, target = _upward_rows(order, parent, weight, out, out_flat, position, first, disparities)
    if not ready[v]:
        _distance_row(levels[v], min_disp, child)
        ready[v] = 1
    if not ready[p]:
        # The same two roundings as a stored cost row plus the child.
        _distance_row(levels[p], min_disp, target)
        ready[p] = 1
    for d in range(disparities):
        target[d] += s * child[d]


@njit(cache=True, **NO_REFCOUNTS)
def _upward_range(cost, levels, min_disp, order, parent, weight, out, ready, lo, hi):
    """Leaf-to-root pass over order positions ``[lo, hi)``, each node pushing into its parent.

    ``ready[v]`` says whether ``out[v]`` already holds ``C(v)`` plus pushed children, so
    the copy of ``C(v)`` is fused into the walk instead of being a separate pass.  ``C``
    is ``cost``, or with ``levels`` (float32 ``(N,)`` instead of None) the refinement
    cost of :func:`_distance_row`, computed here and never stored on its own.  With
    ``cost`` and ``levels`` both None the volume is aggregated in place: every row of
    ``out`` already holds its cost, and ``ready`` is not used.  (numba compiles the cases
    apart, so the ``is None`` tests cost nothing.)

    In place, a parent's first pushed child needs no copy of the parent's cost, and above
    all no loop whose source and target are the same row: LLVM guards its vector loops
    with an overlap check, which such a loop fails, so it ran scalar on three nodes in
    four.  The sums are the same, bit for bit.
    """
    disparities = out.shape[1]
    out_flat = out.reshape(out.size)
    if cost is None and levels is None:
        for k in range(hi - 1, lo - 1, -1):
            _push_in_place(order, parent, weight, out, out_flat, k, lo, disparities)
    elif levels is None:
        for k in range(hi - 1, lo - 1, -1):
            _push_cost(cost, order, parent, weight, out, out_flat, ready, k, lo, disparities)
    else:
        for k in range(hi - 1, lo - 1, -1):
            _push_distance(levels, min_disp, order, parent, weight, out, out_flat, ready, k, lo, disparities)


@njit(cache=True, **NO_REFCOUNTS)
def _upward_side_by_side(cost, levels, min_disp, order, parent, weight, out, ready, lo, hi, other_lo, other_hi):
    """:func:`_upward_range` of ``[lo, hi)`` and ``[other_lo, other_hi)``, a node of each in turn.

    The ranges must write no row in common (:func:`_side_by_side_cuts`).  Each node's
    push waits for its child's, which waited for the grandchild's: along a chain the
    pass is one long dependency through memory.  Two independent chains in turn keep
    the core busy while each waits.
    """
    disparities = out.shape[1]
    out_flat = out.reshape(out.size)
    k = hi - 1
    j = other_hi - 1
    if cost is None and levels is None:
        while k >= lo and j >= other_lo:
            _push_in_place(order, parent, weight, out, out_flat, k, lo, disparities)
            _push_in_place(order, parent, weight, out, out_flat, j, other_lo, disparities)
            k -= 1
            j -= 1
    elif levels is None:
        while k >= lo and j >= other_lo:
            _push_cost(cost, order, parent, weight, out, out_flat, ready, k, lo, disparities)
            _push_cost(cost, order, parent, weight, out, out_flat, ready, j, other_lo, disparities)
            k -= 1
            j -= 1
    else:
        while k >= lo and j >= other_lo:
            _push_distance(levels, min_disp, order, parent, weight, out, out_flat, ready, k, lo, disparities)
            _push_distance(levels, min_disp, order, parent, weight, out, out_flat, ready, j, other_lo,
                           disparities)
            k -= 1
            j -= 1
    # The rest of the longer range on its own.
    _upward_range(cost, levels, min_disp, order, parent, weight, out, ready, lo, k + 1)
    _upward_range(cost, levels, min_disp, order, parent, weight, out, ready, other_lo, j + 1)


@njit(cache=True)
def _make_ready(cost, levels, min_disp, out, ready, v):
    if cost is None and levels is None:
        return  # aggregated in place: the row holds its cost
    if not ready[v]:
        if levels is None:
            source = cost[v]
            target = out[v]
            for d in range(out.shape[1]):
                target[d] = source[d]
        else:
            _distance_row(levels[v], min_disp, out[v])
        ready[v] = 1


@njit(cache=True, inline="always")
def _settle(order, parent, weight, out, out_flat, position, last, winners, min_disp, competing, fused,
            disparities):
    """The node at order position ``position`` takes its final row from its parent's, and
    its winner (:func:`_downward_range`).  ``last``: the range's end, where the prefetch stops."""
    if position + _PREFETCH_AHEAD < last:
        _prefetch_node(out_flat, order, parent, position + _PREFETCH_AHEAD, disparities)
    v = order[position]
    s = weight[v]
    keep = np.float32(1.0) - s * s
    above = out[parent[v]]
    row = out[v]
    if fused:
        best = blend_rows_first_min(row, above, s, keep, competing)
        if row[0] != row[0]:
            best = 0  # a NaN first layer wins, as in first_min
        winners[v] = refined_winner(row[:competing], best, min_disp)
    else:
        for d in range(disparities):
            row[d] = s * above[d] + keep * row[d]
        if winners.shape[0] > 0:
            winners[v] = subpixel_winner(row[:competing], min_disp)


@njit(cache=True, **NO_REFCOUNTS)
def _downward_range(order, parent, weight, out, lo, hi, winners, min_disp, competing):
    """Root-to-leaf pass over order positions ``[lo, hi)``; parents must be final already.

    With a non-empty ``winners`` (float32 ``(N,)``) each node's winner among its first
    ``competing`` layers is taken while its final row is still in cache, which saves a
    separate pass over the volume.
    """
    disparities = out.shape[1]
    # Whole vectors of layers (the decoders' padded volumes): the blend and the search for
    # the winner in one vector loop.
    fused = winners.shape[0] > 0 and disparities % LANES == 0
    out_flat = out.reshape(out.size)
    for k in range(lo, hi):
        _settle(order, parent, weight, out, out_flat, k, hi, winners, min_disp, competing, fused, disparities)


@njit(cache=True, **NO_REFCOUNTS)
def _downward_side_by_side(order, parent, weight, out, lo, hi, other_lo, other_hi, winners, min_disp, competing):
    """:func:`_downward_range` of ``[lo, hi)`` and ``[other_lo, other_hi)``, a node of each in
    turn (see :func:`_upward_side_by_side`); neither range holds a parent of the other's nodes."""
    disparities = out.shape[1]
    fused = winners.shape[0] > 0 and disparities % LANES == 0
    out_flat = out.reshape(out.size)
    k = lo
    j = other_lo
    while k < hi and j < other_hi:
        _settle(order, parent, weight, out, out_flat, k, hi, winners, min_disp, competing, fused, disparities)
        _settle(order, parent, weight, out, out_flat, j, other_hi, winners, min_disp, competing, fused,
                disparities)
        k += 1
        j += 1
    _downward_range(order, parent, weight, out, k, hi, winners, min_disp, competing)
    _downward_range(order, parent, weight, out, j, other_hi, winners, min_disp, competing)


@njit(cache=True, nogil=True)
def _side_by_side_cuts(size, lo, hi, cuts):
    """Cut order positions ``[lo, hi)`` into pairs of ranges one thread walks side by side.

    In pre-order the subtree of the node at position ``a0`` is ``[a0, a1)``, and the nodes
    after it up to ``hi``, ``[a1, hi)``, are neither its ancestors nor its descendants:
    upward, the two ranges push into rows of their own or into rows before ``a0``, which
    the pass reaches only after both; downward, their parents are final once ``[lo, a0)``
    is.  Walked a node of each in turn, each parent still receives its children's pushes
    in the serial walk's order, so every sum is the same, bit for bit.

    ``size`` (int32) holds the subtree size of the node at each order position
    (:func:`_subtree_sizes`).  The cut takes the ``a0`` whose shorter range is longest,
    then cuts ``[lo, a0)`` the same way, up to ``cuts.shape[0]`` times, while the shorter
    range has at least :data:`_MIN_SIDE_BY_SIDE` nodes.  Writes ``(a0, a1, end)`` rows
    into ``cuts`` (int64; the first ``end`` is ``hi``, the next ones the previous ``a0``)
    and returns their number.
    """
    count = 0
    end = hi
    while count < cuts.shape[0] and end - lo >= 2 * _MIN_SIDE_BY_SIDE:
        # The longest shorter range (a maximum: a vector loop), then the first position that
        # has it; one arg-max loop would be scalar (Teddy's three cuts of I1's rows: 0.24 ms
        # that way, 0.07 ms this way).
        sizes = size[lo:end]
        longest = _MIN_SIDE_BY_SIDE - 1
        for i in range(sizes.shape[0]):
            # Negative where the subtree reaches past `end` (an ancestor of a later node).
            longest = max(longest, min(sizes[i], end - lo - i - sizes[i]))
        if longest < _MIN_SIDE_BY_SIDE:
            break
        best = lo
        while min(size[best], end - best - size[best]) != longest:
            best += 1
        cuts[count, 0] = best
        cuts[count, 1] = best + size[best]
        cuts[count, 2] = end
        count += 1
        end = best
    return count


@njit(cache=True, **NO_REFCOUNTS)
def _upward_cut(cost, levels, min_disp, order, parent, weight, out, ready, lo, hi, cuts):
    """:func:`_upward_range` of ``[lo, hi)``, its ``cuts`` (:func:`_side_by_side_cuts`) side by side."""
    rest = hi
    for i in range(cuts.shape[0]):
        a0, a1, end = cuts[i, 0], cuts[i, 1], cuts[i, 2]
        # The subtree without its top node, beside the nodes after it; then the top's push.
        _upward_side_by_side(cost, levels, min_disp, order, parent, weight, out, ready, a0 + 1, a1, a1, end)
        _upward_range(cost, levels, min_disp, order, parent, weight, out, ready, a0, a0 + 1)
        rest = a0
    _upward_range(cost, levels, min_disp, order, parent, weight, out, ready, lo, rest)


@njit(cache=True, **NO_REFCOUNTS)
def _downward_cut(order, parent, weight, out, lo, hi, cuts, winners, min_disp, competing):
    """:func:`_downward_range` of ``[lo, hi)``, its ``cuts`` side by side."""
    count = cuts.shape[0]
    rest = cuts[count - 1, 0] if count else hi
    _downward_range(order, parent, weight, out, lo, rest, winners, min_disp, competing)
    for i in range(count - 1, -1, -1):
        _downward_side_by_side(order, parent, weight, out, cuts[i, 0], cuts[i, 1], cuts[i, 1], cuts[i, 2],
                               winners, min_disp, competing)


@njit(cache=True)
def _aggregate_serial(cost, levels, order, parent, weight, out, winners, min_disp, competing, size):
    """Both passes on one thread; ``cost``/``out`` are ``(N, D)`` float32, may alias;
    ``cost=None``: ``out`` holds the cost and is aggregated in place (``levels``: see
    :func:`_upward_range`).  ``size``: the subtree size at each order position
    (:func:`_subtree_sizes`), to walk ranges side by side; empty: one range."""
    node_count = order.shape[0]
    ready = np.zeros(node_count if cost is not None else 0, dtype=np.uint8)
    cuts = np.empty((_MAX_CUTS, 3), dtype=np.int64)
    count = _side_by_side_cuts(size, 1, node_count, cuts) if size.shape[0] else 0
    _upward_cut(cost, levels, min_disp, order, parent, weight, out, ready, 1, node_count, cuts[:count])
    _make_ready(cost, levels, min_disp, out, ready, order[0])
    if winners.shape[0] > 0:
        winners[order[0]] = subpixel_winner(out[order[0]][:competing], min_disp)
    _downward_cut(order, parent, weight, out, 1, node_count, cuts[:count], winners, min_disp, competing)


@njit(cache=True, **RANGE_KERNEL_COUNTED)
def _aggregate_pair(first, first_order, first_parent, first_weight, first_size, second, second_order,
                    second_parent, second_weight, second_size, counted, winners, min_disp, competing, first_part,
                    stop_part):
    """Walks ``[first_part, stop_part)`` of two independent serial walks (0: the first volume,
    1: the second), one per thread (:func:`~stereobudget._kernels.run_parts`).

    The orders are layouts' rows (``0 .. N-1``).  ``*_size``: the trees' subtree sizes,
    or, where ``counted`` (bool (2,)) is False, an int32 ``(N,)`` array they are counted
    into (:func:`_fill_subtree_sizes`) by the thread that walks that tree.  (Memory the
    worker allocated itself would be new pages on every decode: its allocator arena
    gives freed blocks back.)
    """
    for part in range(first_part, stop_part):
        if part == 0:
            if not counted[0]:
                _fill_subtree_sizes(first_parent, first_size)
            _aggregate_serial(None, None, first_order, first_parent, first_weight, first, winners[0], min_disp,
                              competing, first_size)
        else:
            if not counted[1]:
                _fill_subtree_sizes(second_parent, second_size)
            _aggregate_serial(None, None, second_order, second_parent, second_weight, second, winners[1],
                              min_disp, competing, second_size)


def _aggregate_two_threads(cost, levels, order, parent, weight, out, winners, min_disp, competing, a0,
                           subtree_size, size):
    """Both passes with the tree cut into a subtree A and the rest B, one thread each.

    In pre-order the subtree of the node at position ``a0`` (``subtree_size`` nodes,
    :func:`_balanced_subtree`) is the contiguous range ``[a0, a1)``.  Upward, A and B are
    summed independently, then A's total is carried up the path to the root.  Downward,
    the final aggregate of A's parent is computed along that path first, so A and B can
    again run independently.  Threads never write the same row.  Each thread walks its
    ranges cut into pairs side by side (:func:`_side_by_side_cuts`, from ``size``: the
    subtree size at each order position, :func:`_subtree_sizes`).
    """
    node_count = out.shape[0]
    ready = np.zeros(node_count if cost is not None else 0, dtype=np.uint8)
    # The cuts of A (below its top), of B after A, and of B before A.
    cuts = np.empty((3, _MAX_CUTS, 3), dtype=np.int64)
    counts = np.zeros(3, dtype=np.int64)
    run_parts(_upward_halves, 2, cost, levels, order, parent, weight, out, min_disp, a0, subtree_size, size, ready,
              cuts, counts, parts=2)
    above = _carry_up(order, parent, weight, out, winners, min_disp, competing, a0)
    run_parts(_downward_halves, 2, order, parent, weight, out, winners, min_disp, competing, a0, subtree_size,
              cuts, counts, above, parts=2)


@njit(cache=True, **RANGE_KERNEL_COUNTED)
def _upward_halves(cost, levels, order, parent, weight, out, min_disp, a0, subtree_size, size, ready, cuts, counts,
                   first, stop):
    """Halves ``[first, stop)`` (0: A, 1: B) of :func:`_aggregate_two_threads`' upward pass."""
    node_count = out.shape[0]
    a1 = a0 + subtree_size
    for part in range(first, stop):
        if part == 0:
            counts[0] = _side_by_side_cuts(size, a0 + 1, a1, cuts[0])
            _upward_cut(cost, levels, min_disp, order, parent, weight, out, ready, a0 + 1, a1, cuts[0, :counts[0]])
            _make_ready(cost, levels, min_disp, out, ready, order[a0])
        else:
            counts[1] = _side_by_side_cuts(size, a1, node_count, cuts[1])
            counts[2] = _side_by_side_cuts(size, 1, a0, cuts[2])
            _upward_cut(cost, levels, min_disp, order, parent, weight, out, ready, a1, node_count,
                        cuts[1, :counts[1]])
            _upward_cut(cost, levels, min_disp, order, parent, weight, out, ready, 1, a0, cuts[2, :counts[2]])
            _make_ready(cost, levels, min_disp, out, ready, order[0])


@njit(cache=True)
def _carry_up(order, parent, weight, out, winners, min_disp, competing, a0):
    """Between the passes of :func:`_aggregate_two_threads`: carry A's upward sum into every
    ancestor, then return the final aggregate of A's parent (the root's winner taken)."""
    disparities = out.shape[1]
    # Carry A's upward sum into every ancestor, attenuated along the path.
    top = order[a0]
    total = out[top]
    path_length = 0
    factor = np.float32(1.0)
    node = top
    while parent[node] >= 0:
        factor *= weight[node]
        node = parent[node]
        path_length += 1
        row = out[node]
        for d in range(disparities):
            row[d] += factor * total[d]
    # Final aggregate of A's parent, walking the path down from the root.
    path = np.empty(path_length, dtype=np.int32)
    node = top
    for i in range(path_length):
        node = parent[node]
        path[i] = node
    above = out[path[path_length - 1]].copy()  # the root: its upward sum is final
    for i in range(path_length - 2, -1, -1):
        s = weight[path[i]]
        keep = np.float32(1.0) - s * s
        row = out[path[i]]
        for d in range(disparities):
            above[d] = s * above[d] + keep * row[d]

    if winners.shape[0] > 0:  # the root's upward sum, now including A's, is its final aggregate
        winners[order[0]] = subpixel_winner(out[order[0]][:competing], min_disp)
    return above


@njit(cache=True, **RANGE_KERNEL_COUNTED)
def _downward_halves(order, parent, weight, out, winners, min_disp, competing, a0, subtree_size, cuts, counts, above,
                     first, stop):
    """Halves ``[first, stop)`` (0: A, 1: B) of :func:`_aggregate_two_threads`' downward pass."""
    node_count, disparities = out.shape
    a1 = a0 + subtree_size
    top = order[a0]
    total = out[top]
    take_winners = winners.shape[0] > 0
    for part in range(first, stop):
        if part == 0:
            top_similarity = weight[top]
            top_keep = np.float32(1.0) - top_similarity * top_similarity
            for d in range(disparities):
                total[d] = top_similarity * above[d] + top_keep * total[d]
            if take_winners:
                winners[top] = subpixel_winner(total[:competing], min_disp)
            _downward_cut(order, parent, weight, out, a0 + 1, a1, cuts[0, :counts[0]], winners, min_disp, competing)
        else:
            _downward_cut(order, parent, weight, out, 1, a0, cuts[2, :counts[2]], winners, min_disp, competing)
            _downward_cut(order, parent, weight, out, a1, node_count, cuts[1, :counts[1]], winners, min_disp,
                          competing)


def aggregate(cost: np.ndarray, tree: MinimumSpanningTree, *, out: np.ndarray | None = None) -> np.ndarray:
    """Aggregate a cost volume over the tree: ``C_A(p) = sum_q S(p, q) C(q)``.

    Parameters
    ----------
    cost : numpy.ndarray
        float32 ``(H, W, D)`` matching cost, C-contiguous (a copy is made otherwise).
    tree : MinimumSpanningTree
        Tree from :func:`build_tree` on an ``(H, W)`` guide.
    out : numpy.ndarray, optional, keyword-only
        float32 C-contiguous ``(H, W, D)`` array to write into; may be ``cost`` itself
        for in-place aggregation.

    Returns
    -------
    numpy.ndarray
        float32 ``(H, W, D)`` aggregated cost (``out`` if given).  ``S(p, q)`` is the
        product of edge similarities on the tree path between ``p`` and ``q``
        (``S(p, p) = 1``).  Besides ``out`` only O(N) bookkeeping is allocated.

    Notes
    -----
    Grids of at least ``_PARALLEL_MIN_NODES`` pixels are split into two subtrees walked
    on two threads when numba has two or more; ``numba.set_num_threads(1)`` keeps it on
    one thread (better when other work already occupies the cores).  Results agree with
    the single-thread walk to float32 rounding and are identical from run to run.

    Raises
    ------
    ValueError
        If the volume or ``out`` does not fit the tree.
    """
    out, _ = _aggregate(cost, tree, out=out, min_disp=None)
    return out


def aggregate_winners(cost: np.ndarray, tree: MinimumSpanningTree, *, min_disp: int,
                      out: np.ndarray | None = None) -> np.ndarray:
    """Aggregate a cost volume over the tree and take each pixel's winner in the same walk.

    The result is ``winner_take_all(aggregate(cost, tree), min_disp)`` bit for bit, but each
    node's winner is taken as soon as its aggregate is final, while its row is in cache,
    instead of in a second pass over the whole volume.

    Parameters
    ----------
    cost : numpy.ndarray
        float32 ``(H, W, D)`` matching cost (see :func:`aggregate`).
    tree : MinimumSpanningTree
    min_disp : int, keyword-only
        Disparity of layer 0.
    out : numpy.ndarray, optional, keyword-only
        float32 ``(H, W, D)`` array that receives the aggregated volume; may be ``cost``.

    Returns
    -------
    numpy.ndarray
        float32 ``(H, W)`` disparity: the smallest aggregated cost, refined by a parabola
        (:func:`stereobudget.aggregate.subpixel_winner`).
    """
    _, winners = _aggregate(cost, tree, out=out, min_disp=int(min_disp))
    return winners


def _aggregate(cost, tree, *, out, min_disp):
    """Shared body of :func:`aggregate` and :func:`aggregate_winners` (``min_disp=None``: no winners)."""
    if cost.ndim != 3 or cost.shape[:2] != (tree.height, tree.width):
        raise ValueError(f"cost volume shape {cost.shape} does not match the tree's {tree.height}x{tree.width} grid")
    cost = np.ascontiguousarray(cost, dtype=np.float32)
    if out is None:
        out = np.empty_like(cost)
    elif out.shape != cost.shape or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float32 array of shape {cost.shape}")
    node_count = tree.height * tree.width
    disparities = cost.shape[2]
    take_winners = min_disp is not None
    winners = np.empty(node_count if take_winners else 0, dtype=np.float32)
    if node_count == 0 or disparities == 0:
        return out, (winners.reshape(tree.height, tree.width) if take_winners else None)
    # The pixel-order walk's positions are its layout's rows: the rows' subtree sizes.
    size = _subtree_sizes(tree_layout(tree).parent_row) if node_count >= 2 * _MIN_SIDE_BY_SIDE else None
    _walk(cost.reshape(node_count, disparities), tree.order, tree.parent, tree.weight,
          out.reshape(node_count, disparities), winners, int(min_disp) if take_winners else 0, disparities,
          size=size)
    return out, (winners.reshape(tree.height, tree.width) if take_winners else None)


def _walk(cost, order, parent, weight, out, winners, min_disp, competing, *, levels=None, split=None, size=None,
          rows=False):
    """Both passes over ``(N, D)`` rows: on two threads for large trees, else on one.

    Winners are taken among the first ``competing`` layers.  ``levels``: the cost is
    Yang's refinement cost of these levels (:func:`_distance_row`), ``cost`` is not read.
    ``split``, ``size``: the tree's :func:`_balanced_subtree` and the subtree size at each
    order position (:func:`_subtree_sizes` of its layout's ``parent_row``), if already
    known (``rows``: ``order`` is a layout's ``0 .. N-1``, and they are counted here if not).
    """
    if levels is None and cost.shape == out.shape and cost.ctypes.data == out.ctypes.data:
        cost = None  # aggregated in place
    node_count = order.shape[0]
    if size is None and node_count >= 2 * _MIN_SIDE_BY_SIDE:
        if not rows:
            raise ValueError("a walk in pixel order needs the subtree sizes of its rows")
        size = _subtree_sizes(parent)
    if node_count < _PARALLEL_MIN_NODES or numba.get_num_threads() < 2:
        _aggregate_serial(cost, levels, order, parent, weight, out, winners, min_disp, competing,
                          size if size is not None else _NO_SIZES)
    else:
        a0, subtree_size = split if split is not None else _balanced_cut(size)
        _aggregate_two_threads(cost, levels, order, parent, weight, out, winners, min_disp, competing, a0,
                               subtree_size, size)


def aggregate_rows_winners(volume: np.ndarray, layout: TreeLayout, *, min_disp: int,
                           num_disp: int | None = None) -> np.ndarray:
    """:func:`aggregate_winners` for a volume in the tree's row layout, aggregated in place.

    Parameters
    ----------
    volume : numpy.ndarray
        float32 C-contiguous ``(N, D)``: row ``k`` holds pixel ``layout.pixel_of_row[k]``
        (written so by the producing kernel, e.g. ``filled_sparse_dsi(pixel_of_row=...)``).
    layout : TreeLayout
    min_disp : int, keyword-only
    num_disp : int, optional, keyword-only
        Layers that compete for the winner: the first ``num_disp`` (default: all ``D``).
        Rows may carry more layers, padded to a vector-friendly width
        (:func:`stereobudget.cost.volume_layers`); those are aggregated alongside, as
        any layer is on its own, and never win.

    Returns
    -------
    numpy.ndarray
        float32 ``(H, W)`` disparity, in pixel order.  The arithmetic is that of the walk
        over a pixel-ordered volume, step for step, so the result is bit-identical.
    """
    _check_rows(volume, layout)
    competing = _competing_layers(volume, num_disp)
    winners = np.empty(layout.height * layout.width, dtype=np.float32)
    if volume.size:
        _walk(volume, layout.rows, layout.parent_row, layout.weight_row, volume, winners, int(min_disp), competing,
              split=layout.walk_split, size=layout.subtree_size, rows=True)
    return _in_pixel_order(winners, layout)


def aggregate_two_rows_winners(first: np.ndarray, first_layout: TreeLayout, second: np.ndarray,
                               second_layout: TreeLayout, *, min_disp: int, num_disp: int | None = None) -> tuple:
    """:func:`aggregate_rows_winners` for two independent volumes, each walked on one thread.

    Two views' volumes on their own trees (Yang's left-right check) do not depend on each
    other, so each gets the serial walk on a thread of its own, instead of one after
    the other with each split between two threads: on two cores the split walks share
    the cores and the memory bandwidth anyway, and pay the split's bookkeeping (Teddy's
    pair inside a Hybrid decode: 32 -> 27 ms, scripts/bench.py).  The serial walk
    sums in plain tree order, so a value can differ from the split walk's in the last bit.

    Parameters
    ----------
    first, second : numpy.ndarray
        float32 C-contiguous ``(N, D)`` volumes in their layouts' row order, aggregated in
        place.
    first_layout, second_layout : TreeLayout
    min_disp, num_disp : int, keyword-only
        As for :func:`aggregate_rows_winners`.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        float32 ``(H, W)`` disparity of each volume, in pixel order.
    """
    _check_rows(first, first_layout)
    _check_rows(second, second_layout)
    competing = _competing_layers(first, num_disp)
    node_count = first_layout.height * first_layout.width
    if (numba.get_num_threads() < 2 or node_count < _PARALLEL_MIN_NODES or second.shape != first.shape
            or first.size == 0):
        # (Below the split's size aggregate_rows_winners walks serially too.)
        return (aggregate_rows_winners(first, first_layout, min_disp=min_disp, num_disp=num_disp),
                aggregate_rows_winners(second, second_layout, min_disp=min_disp, num_disp=num_disp))
    winners = np.empty((2, node_count), dtype=np.float32)
    counted = np.array([first_layout.subtree_size is not None, second_layout.subtree_size is not None])
    run_parts(_aggregate_pair, 2, first, first_layout.rows, first_layout.parent_row, first_layout.weight_row,
              _sizes_or_room(first_layout), second, second_layout.rows, second_layout.parent_row,
              second_layout.weight_row, _sizes_or_room(second_layout), counted, winners, int(min_disp), competing,
              parts=2)
    return _in_pixel_order(winners[0], first_layout), _in_pixel_order(winners[1], second_layout)


def distance_rows_winners(levels: np.ndarray, layout: TreeLayout, *, min_disp: int, out: np.ndarray,
                          num_disp: int | None = None) -> np.ndarray:
    """Winners of the aggregated cost ``|min_disp + i - level|`` (0 where the level is NaN).

    The cost of Yang's non-local refinement (:func:`stereobudget.aggregate.nonlocal_refinement`),
    aggregated on the tree without being stored first: the walk computes each row when
    it first touches it.

    Parameters
    ----------
    levels : numpy.ndarray
        float32 ``(N,)``, in the layout's row order: the level of each row's pixel, NaN
        where the pixel contributes no cost.
    layout : TreeLayout
    min_disp : int, keyword-only
        Disparity of layer 0.
    out : numpy.ndarray, keyword-only
        float32 C-contiguous ``(N, D)`` scratch volume (its contents are overwritten and
        left undefined); ``D`` is the number of layers.
    num_disp : int, optional, keyword-only
        Layers that compete for the winner, as for :func:`aggregate_rows_winners`.

    Returns
    -------
    numpy.ndarray
        float32 ``(H, W)`` disparity, in pixel order: the same values as aggregating the
        stored cost with :func:`aggregate_rows_winners`, bit for bit.
    """
    _check_rows(out, layout)
    levels = np.ascontiguousarray(levels, np.float32)
    if levels.shape != (out.shape[0],):
        raise ValueError(f"levels must have one value per row ({out.shape[0]}), got {levels.shape}")
    competing = _competing_layers(out, num_disp)
    winners = np.empty(layout.height * layout.width, dtype=np.float32)
    if out.size:
        _walk(out, layout.rows, layout.parent_row, layout.weight_row, out, winners, int(min_disp), competing,
              levels=levels, split=layout.walk_split, size=layout.subtree_size, rows=True)
    return _in_pixel_order(winners, layout)


def _sizes_or_room(layout):
    """The layout's subtree sizes, or an array for the walk to count them into."""
    return layout.subtree_size if layout.subtree_size is not None else np.empty(layout.rows.shape[0], np.int32)


def _in_pixel_order(winners, layout):
    """Per-row winners of a walk over ``layout`` as an ``(H, W)`` image in pixel order."""
    return take(winners, layout.row_of_pixel).reshape(layout.height, layout.width)


def _competing_layers(volume, num_disp):
    """The layers of ``volume``'s rows that compete for the winner (``num_disp``; None: all)."""
    layers = volume.shape[1]
    if num_disp is None:
        return layers
    if not 1 <= num_disp <= layers:
        raise ValueError(f"num_disp must be between 1 and the rows' {layers} layers, got {num_disp}")
    return int(num_disp)


def _check_rows(volume, layout):
    node_count = layout.height * layout.width
    if volume.ndim != 2 or volume.shape[0] != node_count or volume.dtype != np.float32 \
            or not volume.flags.c_contiguous:
        raise ValueError(f"volume must be a C-contiguous float32 array of {node_count} rows, got {volume.shape}")
