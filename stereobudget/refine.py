"""Yang's left-right consistency check and non-local disparity refinement.

Used whenever the host has a dense (possibly interpolated) right image: full-pair
decoding (stride 1), Downsample and Hybrid.  With only sparse samples there is no right
view to check against, so Sparse skips it (as the paper does).

Steps (Yang, CVPR 2012, Sec. 2.3):

1. disparity of both views from their aggregated cost volumes;
2. a left pixel is *stable* when ``|D_L(x) - D_R(x - D_L(x))| <= tolerance``;
3. new cost ``C(p, d) = |d - D_L(p)|`` for stable pixels, ``0`` for unstable ones;
4. aggregate it on the left tree and take the winner again: unstable pixels inherit the
   disparity of similar stable pixels.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from . import tree as _tree
from .cost import full_dsi
from .winner import subpixel_winner


@njit(cache=True, parallel=True)
def _right_view_cost_into(left_cost, pixel_of_row, min_disp, out):
    """Row k of ``out`` = the right-view costs of right pixel ``pixel_of_row[k]`` (y, x):
    layer i is ``left_cost[y, x + min_disp + i, i]``, border columns outside the image."""
    h, w, nd = left_cost.shape
    for k in prange(out.shape[0]):
        y = pixel_of_row[k] // w
        x = pixel_of_row[k] - y * w
        # Layers i with x + min_disp + i inside [0, w) form one run; clamp only outside it,
        # so the main loop has no branches.
        lo = min(max(-(x + min_disp), 0), nd)
        hi = max(min(w - (x + min_disp), nd), lo)
        o = out[k]
        for i in range(lo):
            o[i] = left_cost[y, 0, i]
        base = x + min_disp
        for i in range(lo, hi):
            o[i] = left_cost[y, base + i, i]
        for i in range(hi, nd):
            o[i] = left_cost[y, w - 1, i]
    return out


def right_view_cost(left_cost, min_disp, *, out=None, right_layout=None):
    """Cost volume of the right view from the left one: ``C_R(x, d) = C_L(x + d, d)``.

    Parameters
    ----------
    left_cost : ndarray, float32 (H, W, D)
    min_disp : int
    out : ndarray, float32, optional
        Buffer to write into (must not be ``left_cost``), with H * W * D values; a fresh
        one by default.
    right_layout : stereobudget.tree.TreeLayout, optional
        Write the result in the right tree's row layout, ready for
        :func:`stereobudget.tree.aggregate_rows_winners` (the left volume is read in
        small overlapping windows, so the order of the writes costs little).

    Returns
    -------
    ndarray, float32 (H, W, D), or (H * W, D) rows in ``right_layout``
        Right pixels whose partner ``x + d`` lies outside the left image take the cost of
        the last column (border replication, as for the left view).
    """
    h, w, nd = left_cost.shape
    if out is None:
        out = np.empty((h, w, nd), dtype=np.float32)
    pixels = np.arange(h * w, dtype=np.int64) if right_layout is None else right_layout.pixel_of_row
    _right_view_cost_into(left_cost, np.asarray(pixels, np.int64), int(min_disp), out.reshape(h * w, nd))
    return out.reshape(h, w, nd) if right_layout is None else out.reshape(h * w, nd)


@njit(cache=True, parallel=True)
def right_disparity_from_left(aggregated, min_disp, support):
    """Right-view disparity read off the left view's aggregated costs (Hirschmüller's diagonal search).

    Right pixel ``xr`` at disparity ``d`` is left pixel ``xr + d``, so its cost at layer
    ``i`` is that of left pixel ``x = xr + min_disp + i`` (border column outside the image,
    as in :func:`right_view_cost`).  The diagonal compares *different* left pixels, and
    Yang's aggregate is an unnormalised sum whose total weight ``support[y, x] = sum_q
    S(p, q)`` ranges over three orders of magnitude (small in textured areas, large in
    flat ones): unnormalised, the pixel with the least support wins whatever its match
    (on Teddy 90 % of the correct pixels then failed the check).  Each left pixel's costs
    are therefore divided by its support, which turns them into weighted means that can be
    compared across pixels.

    Parameters
    ----------
    aggregated : ndarray, float32 (H, W, D)
        Left-view cost aggregated on the left tree.
    min_disp : int
    support : ndarray, float32 (H, W)
        The left tree's aggregate of a constant 1 (``aggregate(ones, tree)``).

    Returns
    -------
    ndarray, float32 (H, W)
        The winner and its parabola fit over ``aggregated[y, x, i] / support[y, x]`` along
        the diagonal, without a second volume, the right image's tree or its aggregation.
    """
    h, w, nd = aggregated.shape
    out = np.empty((h, w), dtype=np.float32)
    for y in prange(h):
        diagonal = np.empty(nd, dtype=np.float32)
        for xr in range(w):
            for i in range(nd):
                x = xr + min_disp + i
                if x < 0:
                    x = 0
                elif x >= w:
                    x = w - 1
                diagonal[i] = aggregated[y, x, i] / support[y, x]
            out[y, xr] = subpixel_winner(diagonal, min_disp)
    return out


@njit(cache=True, parallel=True)
def left_right_stable(disp_left, disp_right, tolerance):
    """Boolean (H, W): left pixels whose disparity the right view confirms within ``tolerance``."""
    h, w = disp_left.shape
    out = np.zeros((h, w), dtype=np.bool_)
    for y in prange(h):
        for x in range(w):
            d = disp_left[y, x]
            xr = int(np.floor(x - d + 0.5))
            if 0 <= xr < w:
                out[y, x] = abs(d - disp_right[y, xr]) <= tolerance
    return out


@njit(cache=True, parallel=True)
def _refinement_cost_into(disp, stable, min_disp, pixel_of_row, out):
    """Row k of ``out`` = Yang's refinement cost of pixel ``pixel_of_row[k]``."""
    num_disp = out.shape[1]
    disp_flat = disp.reshape(-1)
    stable_flat = stable.reshape(-1)
    for k in prange(out.shape[0]):
        p = pixel_of_row[k]
        row = out[k]
        if stable_flat[p]:
            d = disp_flat[p]
            for i in range(num_disp):
                # float32 subtraction: the exact difference rounded once, as in float64.
                row[i] = abs(np.float32(min_disp + i) - d)
        else:
            for i in range(num_disp):
                row[i] = 0.0
    return out


def nonlocal_refinement(disp: np.ndarray, stable: np.ndarray, tree, *, min_disp: int, num_disp: int,
                        out: np.ndarray | None = None):
    """Propagate stable disparities to unstable pixels along the tree (Yang's refinement).

    Parameters
    ----------
    disp : ndarray, float32 (H, W)
    stable : ndarray, bool (H, W)
    tree : stereobudget.tree.MinimumSpanningTree
        Tree of the left image.
    out : ndarray, float32, C-contiguous with H * W * num_disp values, optional
        Scratch volume for the refinement cost (a dead cost volume can be recycled:
        reusing it saves the page faults of a fresh allocation).  The cost is written in
        the tree's row layout (:class:`stereobudget.tree.TreeLayout`), which the
        aggregation walk streams through.

    Returns
    -------
    ndarray, float32 (H, W)
    """
    layout = _tree.tree_layout(tree)
    h, w = disp.shape
    rows = np.empty((h * w, int(num_disp)), np.float32) if out is None else out.reshape(h * w, int(num_disp))
    _refinement_cost_into(np.ascontiguousarray(disp, np.float32), np.ascontiguousarray(stable), int(min_disp),
                          layout.pixel_of_row, rows)
    return _tree.aggregate_rows_winners(rows, layout, min_disp=int(min_disp))


def left_right_refined_disparity(cost, *, left_tree, right_tree, min_disp, params, timer, scratch=None):
    """Aggregate a left-view cost volume, check it against the right view, refine (Yang).

    Parameters
    ----------
    cost : ndarray, float32 (H, W, D)
        Unaggregated left-view cost; consumed (aggregated in place, then reused).
    left_tree : stereobudget.tree.MinimumSpanningTree
        Tree of the left image.
    right_tree : stereobudget.tree.MinimumSpanningTree or None
        Tree of the (possibly interpolated) right image: the right view's costs are
        aggregated on it, as Yang does.  ``None``: the right disparity is read off the
        left view's aggregated costs instead (:func:`right_disparity_from_left`).
    min_disp : int
    params : stereobudget.decoders.DecoderParams
    timer : callable
        ``timer(stage)`` context manager that records stage times.
    scratch : ndarray, float32 (H, W, D), optional
        A volume the caller no longer needs; it receives the right-view cost, so only
        ``cost`` and ``scratch`` are alive during the check and refinement.

    Returns
    -------
    disparity : ndarray, float32 (H, W)
    stable : ndarray, bool (H, W)
        Pixels that passed the left-right check.

    Notes
    -----
    The right view's volume and the refinement cost are written in their tree's row
    layout (:class:`stereobudget.tree.TreeLayout`), which their aggregation walks
    stream through; the left volume comes from the caller in pixel order.
    """
    from .decoders import median_filter_disparity
    num_disp = cost.shape[2]
    with timer("aggregate"):
        # Winners are taken during the aggregation walks (no separate pass over the volumes).
        cost_r = None
        if right_tree is not None:
            right_layout = _tree.tree_layout(right_tree)
            cost_r = right_view_cost(cost, int(min_disp), out=scratch, right_layout=right_layout)
        disp_l = _tree.aggregate_winners(cost, left_tree, min_disp=int(min_disp), out=cost)
        if cost_r is not None:
            disp_r = _tree.aggregate_rows_winners(cost_r, right_layout, min_disp=int(min_disp))
    if cost_r is None:
        with timer("wta"):
            h, w = cost.shape[:2]
            support = _tree.aggregate(np.ones((h, w, 1), np.float32), left_tree)[:, :, 0]
            disp_r = right_disparity_from_left(cost, int(min_disp), support)
    del cost_r
    with timer("refine"):
        stable = left_right_stable(disp_l, disp_r, np.float32(1.0))
        # The left volume is dead after its winner was taken: it holds the refinement cost.
        disp = nonlocal_refinement(disp_l, stable, left_tree, min_disp=min_disp, num_disp=num_disp, out=cost)
        disp = median_filter_disparity(disp, params.median_size)
    return disp, stable


def full_pair_disparity(left_f, right_f, *, tree, min_disp, num_disp, params, timer):
    """Standard full-pair stereo with Yang's non-local method (the "100 % of I2" reference).

    ``left_f``/``right_f`` are float32 (H, W, C) images in 8-bit units.
    """
    with timer("cost"):
        cost = full_dsi(left_f, right_f, min_disp=min_disp, num_disp=num_disp,
                        truncation=params.full_truncation, grad_weight=params.grad_weight,
                        grad_truncation=params.grad_truncation)
    right_tree = None
    if params.right_check == "tree":
        with timer("tree"):
            right_tree = _tree.build_tree(right_f, sigma=params.tree_sigma, median_size=params.tree_median)
    disp, _ = left_right_refined_disparity(cost, left_tree=tree, right_tree=right_tree, min_disp=min_disp,
                                           params=params, timer=timer)
    return disp
