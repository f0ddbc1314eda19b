"""The minimum spanning tree of Yang's non-local aggregation (Q. Yang, CVPR 2012): building it.

The guide image (the left view ``I1``) is seen as a 4-connected grid graph whose edge
weight is the largest absolute channel difference between two neighbours.  Its minimum
spanning tree (MST) keeps, for every pixel, the "cheapest" path to every other pixel, and
the similarity of two pixels is the product of ``exp(-w / sigma)`` over the edges of that
unique path.  Here the tree is built (edge keys, a counting sort, Kruskal, a depth-first
order) and laid out for the walks of :mod:`stereobudget.aggregate._tree`: stored in
depth-first pre-order, a node's parent is usually the node just before it, and every subtree
is a contiguous range of the order, which lets two threads take one half of the tree each.

Conventions: nodes are row-major pixel indices ``row * width + col``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numba
import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL, RANGE_KERNEL_COUNTED
from .._kernels._parallel import run_parts
from .._kernels._prefetch import prefetch_for_write
from ..errors import ImageReadError, OptionError

__all__ = ["MinimumSpanningTree", "TreeLayout", "build_tree", "build_trees", "tree_layout"]

_UINT16_TO_8BIT = 1.0 / 257.0

@dataclass(frozen=True)
class MinimumSpanningTree:
    """A spanning tree of the pixel grid, stored as a rooted tree in topological order.

    Attributes
    ----------
    order : numpy.ndarray
        int32 ``(N,)``: node indices (row-major pixel index) in depth-first pre-order
        from the root; ``order[0]`` is the root.  Every node appears after its parent,
        and every subtree is a contiguous run of ``order``.
    parent : numpy.ndarray
        int32 ``(N,)``: parent node of each node; ``-1`` for the root.
    weight : numpy.ndarray
        float32 ``(N,)``: similarity ``S(node, parent) = exp(-w / sigma)`` of the edge to
        the parent, in ``[0, 1]``; ``0`` for the root.
    height, width : int
        Grid size; ``N = height * width``.
    """

    order: np.ndarray
    parent: np.ndarray
    weight: np.ndarray
    height: int
    width: int
    #: The tree's :class:`TreeLayout`, made on first use by :func:`tree_layout`.
    _layout: list = field(default_factory=list, init=False, repr=False, compare=False)

    @property
    def size(self) -> int:
        """Number of nodes ``N = height * width``."""
        return self.height * self.width


@dataclass(frozen=True)
class TreeLayout:
    """A cost volume laid out in the tree's depth-first order: ``(N, D)`` rows, row ``k``
    holding pixel ``tree.order[k]``.

    Walking the tree over such a volume reads and writes rows in sequence (a node's parent
    is usually the row just before it), so the walk streams through memory instead of
    fetching each pixel's row from a data-dependent address: on Teddy the aggregation
    takes about half the time of the same walk over a pixel-ordered volume
    (scripts/bench.py).  Every volume a decoder aggregates is written in this order by
    the kernel that produces it: Sparse's fill and both views' costs
    (:func:`stereobudget.aggregate.pair_cost_rows`); the refinement cost is computed by the
    walk itself, row by row in this order (:func:`stereobudget.aggregate.distance_rows_winners`).

    Attributes
    ----------
    pixel_of_row : numpy.ndarray
        int32 ``(N,)``: the pixel (row-major index) held by row ``k``: ``tree.order``.
    row_of_pixel : numpy.ndarray
        int32 ``(N,)``: the row of pixel ``p``, the inverse of ``pixel_of_row``.
    rows : numpy.ndarray
        int32 ``(N,)``: ``0 .. N-1``, the walk order in row space.
    parent_row : numpy.ndarray
        int32 ``(N,)``: the row of each row's parent; ``-1`` for the root (row 0).
    weight_row : numpy.ndarray
        float32 ``(N,)``: ``S(node, parent)`` of each row's node.
    height, width : int
    walk_split : (int, int) or None
        Where the two-thread walk cuts the rows (:func:`_balanced_subtree`), when the tree
        kernel took it; None: the walk finds it.
    subtree_size : numpy.ndarray or None
        int32 ``(N,)``: the number of rows in each row's subtree (:func:`_subtree_sizes`),
        when the tree kernel counted them; None: the walk counts them.
    """

    pixel_of_row: np.ndarray
    row_of_pixel: np.ndarray
    rows: np.ndarray
    parent_row: np.ndarray
    weight_row: np.ndarray
    height: int
    width: int
    walk_split: tuple | None = None
    subtree_size: np.ndarray | None = None


# --------------------------------------------------------------------------------------
# Guide preparation


def _as_channels_last(guide: np.ndarray, *, check_finite: bool = True) -> np.ndarray:
    """Validate the guide and return it as ``(H, W, C)`` uint8, uint16 or float32
    (``check_finite=False``: the caller checks a float guide's values itself)."""
    if not isinstance(guide, np.ndarray):
        raise ImageReadError(f"guide must be a numpy array, got {type(guide).__name__}")
    if guide.ndim == 2:
        guide = guide[:, :, None]
    if guide.ndim != 3 or guide.shape[0] < 1 or guide.shape[1] < 1 or guide.shape[2] < 1:
        raise ImageReadError(f"guide must be a non-empty (H, W) or (H, W, C) image, got shape {guide.shape}")
    if guide.dtype in (np.uint8, np.uint16):
        return guide
    if guide.dtype.kind == "f":
        guide = guide.astype(np.float32, copy=False)
        if check_finite and not np.all(np.isfinite(guide)):
            raise _non_finite_guide()
        return guide
    raise ImageReadError(f"guide dtype {guide.dtype} is not supported (use uint8, uint16 or float)")


def _non_finite_guide() -> ImageReadError:
    return ImageReadError("guide contains NaN or infinite values")


def _median_filtered(guide: np.ndarray, median_size: int) -> np.ndarray:
    """Median-filter each channel of an ``(H, W, C)`` guide, keeping its dtype if possible.

    OpenCV filters uint16/float32 only with apertures 3 and 5; larger apertures on those
    dtypes work on the guide rounded to 8-bit units (the unit the edge weights use anyway).
    """
    if median_size in (0, 1):
        return guide
    if guide.dtype != np.uint8 and median_size > 5:
        scale = _UINT16_TO_8BIT if guide.dtype == np.uint16 else 1.0
        guide = np.clip(np.rint(guide.astype(np.float32) * np.float32(scale)), 0, 255).astype(np.uint8)
    channels = guide.shape[2]
    if channels in (1, 3, 4):
        # medianBlur takes 1, 3 or 4 interleaved channels; a 2-D view keeps the (H, W, 1) case legal.
        source = np.ascontiguousarray(guide[:, :, 0] if channels == 1 else guide)
        return cv2.medianBlur(source, median_size).reshape(guide.shape)
    filtered = np.empty_like(guide)
    for c in range(channels):
        filtered[:, :, c] = cv2.medianBlur(np.ascontiguousarray(guide[:, :, c]), median_size)
    return filtered


# --------------------------------------------------------------------------------------
# numba kernels


@njit(cache=True, inline="always")
def _largest_difference(row, other, column, other_column, channels):
    """Largest absolute channel difference of two pixels, exact in int32."""
    if channels == 3:
        # RGB spelled out: the channel loop's branches kept the row loops scalar (3x slower).
        return max(abs(np.int32(row[column, 0]) - np.int32(other[other_column, 0])),
                   max(abs(np.int32(row[column, 1]) - np.int32(other[other_column, 1])),
                       abs(np.int32(row[column, 2]) - np.int32(other[other_column, 2]))))
    largest = 0
    for k in range(channels):
        largest = max(largest, abs(np.int32(row[column, k]) - np.int32(other[other_column, k])))
    return largest


@njit(cache=True, nogil=True)
def _edge_keys(image, keys, outside_key):
    """Max absolute channel difference of each grid edge, in the guide's own integer units.

    Edge ``2 * p`` joins pixel ``p`` to its right neighbour, edge ``2 * p + 1`` to the
    pixel below.  Edges leaving the grid get ``outside_key`` and are never read (neither
    Kruskal's edge list nor a 2 x 2 block holds them, :func:`_kept_edges`).  ``image`` is
    uint8 or uint16, so the differences are exact in int32 and fit ``keys``' uint16.
    """
    height, width, channels = image.shape
    for r in range(height):
        row = image[r]
        first = 2 * r * width
        for c in range(width - 1):
            keys[first + 2 * c] = _largest_difference(row, row, c, c + 1, channels)
        keys[first + 2 * (width - 1)] = outside_key
        if r + 1 < height:
            below = image[r + 1]
            for c in range(width):
                keys[first + 2 * c + 1] = _largest_difference(row, below, c, c, channels)
        else:
            for c in range(width):
                keys[first + 2 * c + 1] = outside_key


@njit(cache=True, inline="always")
def _edge_count(height, width):
    """Edges of a ``height x width`` 4-connected grid (to the right and below)."""
    return height * (width - 1) + (height - 1) * width


@njit(cache=True, inline="always")
def _order_value(keys, edge):
    """An edge's place in Kruskal's order as one integer: its key, then its id."""
    return (np.int64(keys[edge]) << 32) | edge


@njit(cache=True, nogil=True)
def _kept_edges(keys, height, width):
    """The grid's edge ids, in id order, that Kruskal has to look at: all but those that
    come last, in Kruskal's order (key, then edge id), on the 4-cycle of some 2 x 2
    block of pixels.

    When Kruskal reaches such an edge the other three edges of its cycle have been
    reached, and each joined its ends or found them joined already: its ends are
    joined, and Kruskal rejects it (the cycle property).  So the tree does not change,
    bit for bit; but those rejections were Kruskal's unpredictable branches, and on a
    grid about 40 % of all edges are such maxima (Teddy: 336 675 -> 198 355 edges for
    I1, 187 168 for the right view), which now neither the sort nor Kruskal sees.
    """
    last = np.zeros(keys.shape[0], dtype=np.uint8)
    for r in range(height - 1):
        for c in range(width - 1):
            p = r * width + c
            # The block's edges: p's right and down edges, the down edge of p + 1 and the
            # right edge of the pixel below p.
            top = _order_value(keys, 2 * p)
            left = _order_value(keys, 2 * p + 1)
            right = _order_value(keys, 2 * p + 3)
            bottom = _order_value(keys, 2 * (p + width))
            last[max(max(top, left), max(right, bottom)) & 0xFFFFFFFF] = 1
    # Compacted without a branch per edge: every id is written, only the kept ones advance
    # (so the last write may land one past the grid's edges).
    edges = np.empty(_edge_count(height, width) + 1, dtype=np.int32)
    kept = 0
    for r in range(height):
        for c in range(width):
            p = r * width + c
            edges[kept] = 2 * p
            kept += (c + 1 < width) & (last[2 * p] == 0)
            edges[kept] = 2 * p + 1
            kept += (r + 1 < height) & (last[2 * p + 1] == 0)
    return edges[:kept]


#: Key counts up to this are sorted in four interleaved streams (:func:`_interleaved_sorted_edges`):
#: 8-bit guides' 256 keys (Teddy's I1: 1.2 -> 0.5 ms).  16-bit guides' 65 536 keys are not:
#: four count tables of that size cost more than the interleaving saves (0.65 -> 0.85 ms).
_INTERLEAVED_KEY_COUNT = 4096


@njit(cache=True, nogil=True)
def _counting_sorted_edges(keys, edges, key_count):
    """``edges`` (ids in increasing order) sorted by integer key; stable, so ties keep
    edge-id order."""
    if key_count <= _INTERLEAVED_KEY_COUNT:
        return _interleaved_sorted_edges(keys, edges, key_count)
    counts = np.zeros(key_count + 1, dtype=np.int32)
    for e in edges:
        counts[keys[e] + 1] += 1
    for k in range(key_count):
        counts[k + 1] += counts[k]
    sorted_edges = np.empty(edges.shape[0], dtype=np.int32)
    for e in edges:
        key = keys[e]
        sorted_edges[counts[key]] = e
        counts[key] += 1
    return sorted_edges


@njit(cache=True, nogil=True)
def _interleaved_sorted_edges(keys, edges, key_count):
    """:func:`_counting_sorted_edges` for few keys, in four interleaved streams.

    With 256 keys neighbouring edges often share one, and each count or position update
    then waits for the previous one (a chain through memory: Teddy's 8-bit sort took
    1.2 ms).  The edge list is cut into four quarters, each counted and placed by its own
    table, one element of each quarter per step: four independent chains.  Within a key
    the quarters' edges are placed in quarter order, so the order is the stable sort's.
    """
    total = edges.shape[0]
    quarter = total // 4
    counts = np.zeros((4, key_count), dtype=np.int32)
    first, second, third, fourth = counts[0], counts[1], counts[2], counts[3]
    for j in range(quarter):
        first[keys[edges[j]]] += 1
        second[keys[edges[quarter + j]]] += 1
        third[keys[edges[2 * quarter + j]]] += 1
        fourth[keys[edges[3 * quarter + j]]] += 1
    for j in range(4 * quarter, total):
        fourth[keys[edges[j]]] += 1
    # Each (quarter, key) table entry becomes its first position: keys ascending, quarters within a key.
    position = 0
    for k in range(key_count):
        for q in range(4):
            n = counts[q, k]
            counts[q, k] = position
            position += n
    placed = np.empty(total, dtype=np.int32)
    for j in range(quarter):
        e = edges[j]
        key = keys[e]
        placed[first[key]] = e
        first[key] += 1
        e = edges[quarter + j]
        key = keys[e]
        placed[second[key]] = e
        second[key] += 1
        e = edges[2 * quarter + j]
        key = keys[e]
        placed[third[key]] = e
        third[key] += 1
        e = edges[3 * quarter + j]
        key = keys[e]
        placed[fourth[key]] = e
        fourth[key] += 1
    for j in range(4 * quarter, total):
        e = edges[j]
        key = keys[e]
        placed[fourth[key]] = e
        fourth[key] += 1
    return placed


@njit(cache=True, nogil=True)
def _find_root(link, node):
    # Path halving keeps the trees flat without recursion.
    while link[node] != node:
        link[node] = link[link[node]]
        node = link[node]
    return node


#: Edges ahead whose union-find entries Kruskal prefetches.
_KRUSKAL_AHEAD = 8


@njit(cache=True, nogil=True)
def _kruskal_tree_bits(sorted_edges, height, width):
    """Kruskal on pre-sorted grid edges; returns per-node bits of the kept tree edges.

    Bit 0: edge to the right neighbour, 1: below, 2: left, 3: above.  Four bits per pixel
    replace an adjacency list, since tree neighbours are always grid neighbours.
    """
    node_count = height * width
    link = np.arange(node_count, dtype=np.int32)
    rank = np.zeros(node_count, dtype=np.uint8)
    bits = np.zeros(node_count, dtype=np.uint8)
    kept = 0
    edge_count = sorted_edges.shape[0]
    for i in range(edge_count):
        if kept == node_count - 1:
            break
        if i + _KRUSKAL_AHEAD < edge_count:
            # The edges come in key order, scattered over the grid: ask for the
            # union-find entries of an edge a few ahead while this one is joined.
            ahead = sorted_edges[i + _KRUSKAL_AHEAD]
            prefetch_for_write(link, ahead >> 1)
            prefetch_for_write(link, (ahead >> 1) + (width if ahead & 1 else 1))
        e = sorted_edges[i]
        p = e >> 1
        down = e & 1
        q = p + width if down else p + 1
        root_p = _find_root(link, p)
        root_q = _find_root(link, q)
        if root_p == root_q:
            continue
        if rank[root_p] < rank[root_q]:
            link[root_p] = root_q
        elif rank[root_p] > rank[root_q]:
            link[root_q] = root_p
        else:
            link[root_q] = root_p
            rank[root_p] += 1
        if down:
            bits[p] |= 2
            bits[q] |= 8
        else:
            bits[p] |= 1
            bits[q] |= 4
        kept += 1
    return bits


@njit(cache=True, nogil=True)
def _depth_first(bits, keys, height, width, root, similarity_of_key, out):
    """Root the tree: depth-first pre-order, parents and edge similarities, and the row layout.

    Writes ``out`` (:func:`_tree_arrays`) and returns the number of nodes reached.

    Pre-order (rather than breadth-first) makes a node's parent usually the node just
    before it and keeps every subtree contiguous in ``order``, which is what lets
    :func:`stereobudget.aggregate.aggregate` stay in cache and split the walk between threads.  The
    :class:`TreeLayout` arrays are written as the nodes are visited (a parent's row is
    known before its children are popped), which saves a pass over the tree.
    """
    node_count = height * width
    order, parent, weight, row_of_pixel, parent_row, weight_row = out
    parent[:] = -1
    weight[:] = 0.0
    stack = np.empty(node_count, dtype=np.int32)
    stack[0] = root
    top = 1
    visited = 0
    while top > 0:
        top -= 1
        p = stack[top]
        order[visited] = p
        row_of_pixel[p] = visited
        above = parent[p]
        parent_row[visited] = row_of_pixel[above] if above >= 0 else -1
        weight_row[visited] = weight[p]
        visited += 1
        b = bits[p]
        for direction in range(4):
            if not (b >> direction) & 1:
                continue
            if direction == 0:
                q = p + 1
                key = keys[2 * p]
            elif direction == 1:
                q = p + width
                key = keys[2 * p + 1]
            elif direction == 2:
                q = p - 1
                key = keys[2 * q]
            else:
                q = p - width
                key = keys[2 * q + 1]
            if q == above:
                continue
            parent[q] = p
            weight[q] = similarity_of_key[key]
            stack[top] = q
            top += 1
    return visited


def _tree_arrays(node_count):
    """Arrays a rooted tree is written into: order, parent, weight, row_of_pixel, parent_row, weight_row."""
    return (np.empty(node_count, np.int32), np.empty(node_count, np.int32), np.empty(node_count, np.float32),
            np.empty(node_count, np.int32), np.empty(node_count, np.int32), np.empty(node_count, np.float32))


@njit(cache=True, nogil=True)
def _fill_subtree_sizes(parent_row, size):
    """``size[k]`` (int32 ``(N,)``) = the number of rows in row ``k``'s subtree, itself
    included, of a layout whose rows are in pre-order (``parent_row``: each row's parent)."""
    size[:] = 1
    for k in range(parent_row.shape[0] - 1, 0, -1):
        size[parent_row[k]] += size[k]
    return size


@njit(cache=True, nogil=True)
def _subtree_sizes(parent_row):
    """:func:`_fill_subtree_sizes` into a new array."""
    return _fill_subtree_sizes(parent_row, np.empty(parent_row.shape[0], dtype=np.int32))


@njit(cache=True, nogil=True)
def _balanced_cut(size):
    """:func:`_balanced_subtree` from the rows' subtree sizes (:func:`_fill_subtree_sizes`)."""
    node_count = size.shape[0]
    best = 1
    best_gap = node_count
    for k in range(1, node_count):
        gap = abs(2 * size[k] - node_count)
        if gap < best_gap:
            best_gap = gap
            best = k
    return best, size[best]


def _balanced_subtree(order, parent):
    """Order position of the non-root node whose subtree is closest to half the tree, and
    that subtree's size, for a tree in pre-order ``order`` with ``parent`` per node (a
    layout's ``rows`` and ``parent_row``, or a tree's ``order`` and ``parent``)."""
    return _balanced_cut(_subtree_sizes(_parent_rows(order, parent, _rows_of(order))))


def _rows_of(order):
    """int32 order position of each node: the inverse of ``order``."""
    row_of_node = np.empty(order.shape[0], dtype=np.int32)
    row_of_node[order] = np.arange(order.shape[0])
    return row_of_node


def _parent_rows(order, parent, row_of_node):
    """int32 order position of each position's parent (-1 for the root): a layout's ``parent_row``."""
    parents = parent[order]
    return np.where(parents >= 0, row_of_node[np.maximum(parents, 0)], -1).astype(np.int32)


@njit(cache=True, inline="always")
def _key_of(value, scale):
    """``clip(rint(value * scale), 0, 65535)`` as uint16, for a finite float32 ``value``."""
    return np.uint16(min(max(np.rint(value * scale), np.float32(0.0)), np.float32(65535.0)))


@njit(cache=True, inline="always")
def _sorted_pair(a, b):
    return min(a, b), max(a, b)


def _median3_uint16_keys(image):
    """:func:`_uint16_keys` of the 3 x 3 median of each channel of a float32 (H, W, C)
    guide (borders replicated, as cv2.medianBlur), on both threads.

    The key is a non-decreasing function of the value, so the median of the keys is the
    key of the median: the result is that of cv2.medianBlur then :func:`_uint16_keys`,
    exactly.  The keys are laid out per channel with a replicated column at both ends,
    so the median network (19 compare-exchanges, Paeth's) runs over contiguous runs of
    x and vectorises.

    Returns the keys and the number of values that are not finite (the guide's check,
    made in this pass over it instead of one of its own: 0.2 ms on Teddy's right guide).
    """
    h, w, channels = image.shape
    keys = np.empty((h, channels, w + 2), dtype=np.uint16)
    non_finite = np.zeros(h, dtype=np.int64)
    run_parts(_key_rows, h, image, keys, non_finite)
    out = np.empty((h, w, channels), dtype=np.uint16)
    run_parts(_median3_rows, h, keys, out, scratch=lambda: (np.empty(w, dtype=np.uint16),))
    return out, int(non_finite.sum())


@njit(cache=True, **RANGE_KERNEL)
def _key_rows(image, keys, non_finite, first, stop):
    """Rows ``[first, stop)`` of :func:`_median3_uint16_keys`' keys, with a replicated column at
    both ends; ``non_finite[y]`` counts row y's values that are not finite."""
    w, channels = image.shape[1], image.shape[2]
    scale = np.float32(257.0)
    for y in range(first, stop):
        count = 0
        for c in range(channels):
            row = keys[y, c, 1:w + 1]
            for x in range(w):
                value = image[y, x, c]
                # v - v is 0 for a finite v and NaN otherwise: a count that vectorises.
                count += (value - value) != 0
                row[x] = _key_of(value, scale)
            keys[y, c, 0] = keys[y, c, 1]
            keys[y, c, w + 1] = keys[y, c, w]
        non_finite[y] = count


@njit(cache=True, **RANGE_KERNEL)
def _median3_rows(keys, out, median, first, stop):
    """Rows ``[first, stop)`` of :func:`_median3_uint16_keys`' medians of the keys (``median`` (W,)
    uint16: scratch)."""
    h, w, channels = out.shape
    for y in range(first, stop):
        above, below = max(y - 1, 0), min(y + 1, h - 1)
        for c in range(channels):
            a0, a1, a2 = keys[above, c, 0:w], keys[above, c, 1:w + 1], keys[above, c, 2:w + 2]
            b0, b1, b2 = keys[y, c, 0:w], keys[y, c, 1:w + 1], keys[y, c, 2:w + 2]
            c0, c1, c2 = keys[below, c, 0:w], keys[below, c, 1:w + 1], keys[below, c, 2:w + 2]
            for x in range(w):
                p0, p1, p2, p3, p4, p5, p6, p7, p8 = a0[x], a1[x], a2[x], b0[x], b1[x], b2[x], c0[x], c1[x], c2[x]
                p1, p2 = _sorted_pair(p1, p2)
                p4, p5 = _sorted_pair(p4, p5)
                p7, p8 = _sorted_pair(p7, p8)
                p0, p1 = _sorted_pair(p0, p1)
                p3, p4 = _sorted_pair(p3, p4)
                p6, p7 = _sorted_pair(p6, p7)
                p1, p2 = _sorted_pair(p1, p2)
                p4, p5 = _sorted_pair(p4, p5)
                p7, p8 = _sorted_pair(p7, p8)
                p0, p3 = _sorted_pair(p0, p3)
                p5, p8 = _sorted_pair(p5, p8)
                p4, p7 = _sorted_pair(p4, p7)
                p3, p6 = _sorted_pair(p3, p6)
                p1, p4 = _sorted_pair(p1, p4)
                p2, p5 = _sorted_pair(p2, p5)
                p4, p7 = _sorted_pair(p4, p7)
                p4, p2 = _sorted_pair(p4, p2)
                p6, p4 = _sorted_pair(p6, p4)
                p4, p2 = _sorted_pair(p4, p2)
                median[x] = p4
            for x in range(w):
                out[y, x, c] = median[x]


def _uint16_keys(image):
    """``clip(rint(image * 257), 0, 65535)`` as uint16 for a float32 (H, W, C) guide, on every thread."""
    out = np.empty(image.shape, dtype=np.uint16)
    run_parts(_uint16_key_rows, image.shape[0], image, out)
    return out


@njit(cache=True, **RANGE_KERNEL)
def _uint16_key_rows(image, out, first, stop):
    """Rows ``[first, stop)`` of :func:`_uint16_keys`."""
    w, channels = image.shape[1], image.shape[2]
    scale = np.float32(257.0)
    for y in range(first, stop):
        for x in range(w):
            for c in range(channels):
                out[y, x, c] = _key_of(image[y, x, c], scale)


@njit(cache=True, nogil=True)
def _rooted_tree(image, key_count, similarity_of_key, out, split, size):
    """Edge keys -> the edges Kruskal needs (:func:`_kept_edges`) -> counting sort ->
    Kruskal -> depth-first rooting at pixel 0, in one kernel (one compiled object to load
    instead of five: ~10 ms each for a single-shot decode).
    Writes ``out`` (:func:`_tree_arrays`), the rows' subtree sizes into ``size`` when it
    has room for them (:func:`_fill_subtree_sizes`), and then, when ``split`` has room
    for them, the two-thread walk's split of the row layout (:func:`_balanced_subtree`);
    returns the number of nodes reached."""
    height, width = image.shape[0], image.shape[1]
    # uint16 keys (either guide's fit): half the bytes of int32 for the four passes that
    # read them, scattered in the rooting (the tree pair 8.50-8.58 -> 8.14-8.23 ms on Teddy).
    keys = np.empty(2 * height * width, dtype=np.uint16)
    _edge_keys(image, keys, 0xFFFF)
    sorted_edges = _counting_sorted_edges(keys, _kept_edges(keys, height, width), key_count)
    bits = _kruskal_tree_bits(sorted_edges, height, width)
    reached = _depth_first(bits, keys, height, width, 0, similarity_of_key, out)
    if size.shape[0] == reached == height * width:
        _fill_subtree_sizes(out[4], size)
        if split.shape[0] >= 2 and reached >= 2:
            split[0], split[1] = _balanced_cut(size)
    return reached


@njit(cache=True, **RANGE_KERNEL_COUNTED)
def _rooted_tree_pair(first, first_keys, first_similarity, first_out, first_split, first_size,
                      second, second_keys, second_similarity, second_out, second_split, second_size, reached,
                      first_part, stop_part):
    """Parts ``[first_part, stop_part)`` of :func:`_rooted_tree` of two guides (0: the first,
    1: the second), one per thread (:func:`~stereobudget._kernels.run_parts`).

    The first guide (I1's) also gets its subtree sizes and walk split here (0.3 ms on Teddy
    that the refinement walk would otherwise spend on one thread).  The second tree's
    sizes are counted by the walk of the pair (``_aggregate_pair`` in ``_tree.py``), whose second
    walk is the shorter one; here they made the tree stage 0.3 ms longer.
    """
    for part in range(first_part, stop_part):
        if part == 0:
            reached[0] = _rooted_tree(first, first_keys, first_similarity, first_out, first_split, first_size)
        else:
            reached[1] = _rooted_tree(second, second_keys, second_similarity, second_out, second_split,
                                      second_size)


# --------------------------------------------------------------------------------------
# Public API


def build_tree(guide: np.ndarray, *, sigma: float = 0.1 * 255, median_size: int = 3) -> MinimumSpanningTree:
    """Minimum spanning tree of the guide's 4-connected pixel grid, rooted at pixel 0.

    Parameters
    ----------
    guide : numpy.ndarray
        ``(H, W)`` or ``(H, W, C)`` image (usually ``I1``, RGB), uint8, uint16 or float.
        Float guides are taken to be in 8-bit units (0..255, clipped), like uint8, and
        keyed at 1/257 of a unit, the resolution of a uint16 guide.
    sigma : float, keyword-only
        Similarity falloff in 8-bit units: an edge of weight ``w`` has similarity
        ``exp(-w / sigma)``.  Default ``0.1 * 255`` (Yang's 0.1 on a 0..1 scale).
    median_size : int, keyword-only
        Aperture of the median filter applied to the guide before the edge weights are
        taken (odd, >= 3); 0 or 1 disables it.

    Returns
    -------
    MinimumSpanningTree
        ``order``/``parent``/``weight`` of the tree rooted at pixel 0.

    Notes
    -----
    Edge weight = largest absolute channel difference between the two neighbours, in
    8-bit units (uint16 differences are divided by 257).  Kruskal's algorithm runs on the
    edges in stable key order (a counting sort), so ties, including the
    many zero-weight edges of flat regions, are broken deterministically by edge id; the
    edges that come last on a 2 x 2 block's cycle in that order, which it would reject,
    are left out beforehand.
    """
    image, key_count, similarity_of_key = _tree_inputs(guide, sigma=sigma, median_size=median_size)
    out = _tree_arrays(image.shape[0] * image.shape[1])
    split = np.zeros(2, np.int64)
    size = np.empty(image.shape[0] * image.shape[1], np.int32)
    reached = _rooted_tree(image, key_count, similarity_of_key, out, split, size)
    return _rooted_tree_result(out, reached, image.shape, split, size)


def _tree_inputs(guide, *, sigma, median_size):
    """The guide filtered and keyed for :func:`_rooted_tree`: (image, key_count, similarity_of_key)."""
    if not np.isfinite(sigma) or sigma <= 0:
        raise OptionError(f"sigma must be a positive number, got {sigma}")
    if median_size not in (0, 1) and (median_size < 3 or median_size % 2 == 0):
        raise OptionError(f"median_size must be 0, 1 or an odd number >= 3, got {median_size}")
    median_keys = median_size == 3 and isinstance(guide, np.ndarray) and guide.dtype.kind == "f"
    image = _as_channels_last(guide, check_finite=not median_keys)
    if median_keys:
        # Median and keys in one kernel on both threads (Teddy's right guide: 0.69 -> 0.40 ms).
        image, non_finite = _median3_uint16_keys(image)
        if non_finite:
            raise _non_finite_guide()
    else:
        image = _median_filtered(image, int(median_size))
    if image.dtype != np.uint8 and image.dtype != np.uint16:
        # Float guides are keyed at 1/257 of a gray level, the resolution of a uint16 guide:
        # far below any similarity difference exp(-w / sigma) can show, and one counting
        # sort then orders the edges (2x faster than a radix sort of float keys).
        image = (_uint16_keys(image) if image.dtype == np.float32
                 else np.clip(np.rint(image * np.float32(257.0)), 0, 65535).astype(np.uint16))
    key_count = 256 if image.dtype == np.uint8 else 65536
    key_scale = _UINT16_TO_8BIT if image.dtype == np.uint16 else 1.0
    return image, key_count, _similarity_of_key(key_count, key_scale, float(sigma))


@functools.lru_cache(maxsize=8)
def _similarity_of_key(key_count, key_scale, sigma):
    """``exp(-key * key_scale / sigma)`` for every key, float32, read-only.

    One exp per possible key instead of one per pixel; kept between decodes, since 65536
    of them (a float guide's keys) take ~0.8 ms.
    """
    table = np.exp(np.arange(key_count) * (-key_scale / sigma)).astype(np.float32)
    table.flags.writeable = False
    return table


def _rooted_tree_result(out, reached, shape, split=None, size=None):
    """The :class:`MinimumSpanningTree` (with its layout) of arrays :func:`_rooted_tree` wrote
    (``split``, ``size``: the walk split and the subtree sizes it took, if any)."""
    height, width = shape[:2]
    node_count = height * width
    order, parent, weight, row_of_pixel, parent_row, weight_row = out
    if reached != node_count:  # a spanning tree of a grid always reaches every pixel
        raise AssertionError(f"spanning tree reached {reached} of {node_count} pixels")
    tree = MinimumSpanningTree(order=order, parent=parent, weight=weight, height=height, width=width)
    walk_split = (int(split[0]), int(split[1])) if split is not None and node_count >= 2 else None
    tree._layout.append(TreeLayout(pixel_of_row=order, row_of_pixel=row_of_pixel,
                                   rows=np.arange(node_count, dtype=np.int32), parent_row=parent_row,
                                   weight_row=weight_row, height=height, width=width, walk_split=walk_split,
                                   subtree_size=size))
    return tree


def tree_layout(tree: MinimumSpanningTree) -> TreeLayout:
    """The depth-first row layout of ``tree`` (see :class:`TreeLayout`).

    :func:`build_tree` makes it with the tree; a tree built otherwise gets it here, once,
    and keeps it, so the cost volume's producer and the refinement share it.
    """
    if not tree._layout:
        node_count = tree.order.shape[0]
        row_of_pixel = _rows_of(tree.order)
        tree._layout.append(TreeLayout(pixel_of_row=tree.order, row_of_pixel=row_of_pixel,
                                       rows=np.arange(node_count, dtype=np.int32),
                                       parent_row=_parent_rows(tree.order, tree.parent, row_of_pixel),
                                       weight_row=tree.weight[tree.order], height=tree.height,
                                       width=tree.width))
    return tree._layout[0]


def build_trees(guides, *, sigma: float = 0.1 * 255, median_size: int = 3) -> list:
    """:func:`build_tree` for several guides at once, each with its :func:`tree_layout` made.

    The tree kernel is serial, so with two or more numba threads two guides are built
    concurrently, one per thread (:func:`stereobudget._kernels.run_parts`; a decode that
    checks the left view against the right builds both trees in the time of one).

    Parameters
    ----------
    guides : sequence of numpy.ndarray
        Guides as for :func:`build_tree`.
    sigma, median_size : keyword-only
        As for :func:`build_tree`.

    Returns
    -------
    list of MinimumSpanningTree
        In the order of ``guides``.
    """
    guides = list(guides)
    trees = []
    while len(guides) >= 2 and numba.get_num_threads() >= 2:
        inputs = [_tree_inputs(g, sigma=sigma, median_size=median_size) for g in guides[:2]]
        outs = [_tree_arrays(image.shape[0] * image.shape[1]) for image, _, _ in inputs]
        reached = np.zeros(2, np.int64)
        # The second tree's walks run unsplit, and the walk of the pair counts its subtree sizes.
        splits = [np.zeros(2, np.int64), np.zeros(0, np.int64)]
        sizes = [np.empty(outs[0][0].shape[0], np.int32), np.zeros(0, np.int32)]
        run_parts(_rooted_tree_pair, 2, *inputs[0], outs[0], splits[0], sizes[0], *inputs[1], outs[1], splits[1],
                  sizes[1], reached, parts=2)
        trees += [_rooted_tree_result(out, int(r), image.shape, split if split.size else None,
                                      size if size.size else None)
                  for out, r, (image, _, _), split, size in zip(outs, reached, inputs, splits, sizes)]
        guides = guides[2:]
    return trees + [build_tree(g, sigma=sigma, median_size=median_size) for g in guides]
