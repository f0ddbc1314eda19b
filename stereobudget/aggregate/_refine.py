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
from numba import njit

from .._kernels import _scratch as scratch
from .._kernels._jit import RANGE_KERNEL
from .._kernels._parallel import run_parts
from . import _mst, _tree
from ._winner import subpixel_winner


@njit(cache=True, **RANGE_KERNEL)
def _right_disparity_from_rows(aggregated, row_of_pixel, width, min_disp, support, nd, out, diagonal, first, stop):
    """Rows ``[first, stop)`` of :func:`right_disparity_from_left`; ``diagonal`` (D,) float32 is scratch."""
    for y in range(first, stop):
        for xr in range(width):
            for i in range(nd):
                x = xr + min_disp + i
                if x < 0:
                    x = 0
                elif x >= width:
                    x = width - 1
                diagonal[i] = aggregated[row_of_pixel[y * width + x], i] / support[y, x]
            out[y, xr] = subpixel_winner(diagonal, min_disp)


def right_disparity_from_left(aggregated, min_disp, support, *, layout=None, num_disp=None):
    """Right-view disparity read off the left view's aggregated costs (Hirschmüller's diagonal search).

    Right pixel ``xr`` at disparity ``d`` is left pixel ``xr + d``, so its cost at layer
    ``i`` is that of left pixel ``x = xr + min_disp + i`` (the border column outside the
    image, as for :func:`stereobudget.aggregate.pair_cost_rows`).  The diagonal compares
    *different* left pixels, and Yang's aggregate is an unnormalised sum whose total weight
    ``support[y, x] = sum_q S(p, q)`` ranges over three orders of magnitude (small in
    textured areas, large in flat ones): unnormalised, the pixel with the least support
    wins whatever its match (on Teddy 90 % of the correct pixels then failed the check).
    Each left pixel's costs are therefore divided by its support, which turns them into
    weighted means that can be compared across pixels.

    Parameters
    ----------
    aggregated : ndarray, float32 (H, W, D), or (H * W, D) rows in ``layout``
        Left-view cost aggregated on the left tree.
    min_disp : int
    support : ndarray, float32 (H, W)
        The left tree's aggregate of a constant 1 (``aggregate(ones, tree)``).
    layout : stereobudget.aggregate.TreeLayout, optional
        Row layout of ``aggregated`` when it is given as rows.
    num_disp : int, optional
        Layers searched: the first ``num_disp`` (default: all; the rest are padding, see
        :func:`stereobudget.cost.volume_layers`).

    Returns
    -------
    ndarray, float32 (H, W)
        The winner and its parabola fit over ``aggregated / support`` along the
        diagonal, without a second volume, the right image's tree or its aggregation.
    """
    h, w = support.shape
    if layout is None:
        rows = np.ascontiguousarray(aggregated, np.float32).reshape(h * w, -1)
        row_of_pixel = np.arange(h * w, dtype=np.int64)
    else:
        rows, row_of_pixel = aggregated, layout.row_of_pixel
    layers = rows.shape[1] if num_disp is None else int(num_disp)
    out = np.empty((h, w), dtype=np.float32)
    run_parts(_right_disparity_from_rows, h, rows, row_of_pixel, w, int(min_disp),
              np.ascontiguousarray(support, np.float32), layers, out,
              scratch=lambda: (np.empty(layers, dtype=np.float32),))
    return out


def left_right_stable(disp_left, disp_right, tolerance):
    """Boolean (H, W): left pixels whose disparity the right view confirms within ``tolerance``."""
    out = np.zeros(disp_left.shape, dtype=np.bool_)
    run_parts(_stable_rows, disp_left.shape[0], disp_left, disp_right, tolerance, out)
    return out


@njit(cache=True, **RANGE_KERNEL)
def _stable_rows(disp_left, disp_right, tolerance, out, first, stop):
    """Rows ``[first, stop)`` of :func:`left_right_stable`."""
    w = disp_left.shape[1]
    for y in range(first, stop):
        for x in range(w):
            d = disp_left[y, x]
            xr = int(np.floor(x - d + 0.5))
            if 0 <= xr < w:
                out[y, x] = abs(d - disp_right[y, xr]) <= tolerance


def _stable_levels(disp, stable, pixel_of_row):
    """Row k: the disparity of pixel ``pixel_of_row[k]`` where it is stable, else NaN."""
    out = np.empty(pixel_of_row.shape[0], dtype=np.float32)
    run_parts(_stable_levels_part, out.shape[0], disp, stable, pixel_of_row, out)
    return out


@njit(cache=True, **RANGE_KERNEL)
def _stable_levels_part(disp, stable, pixel_of_row, out, first, stop):
    """Rows ``[first, stop)`` of :func:`_stable_levels` into ``out``."""
    for k in range(first, stop):
        p = pixel_of_row[k]
        out[k] = disp[p] if stable[p] else np.float32(np.nan)


def nonlocal_refinement(disp: np.ndarray, stable: np.ndarray, tree, *, min_disp: int, num_disp: int,
                        out: np.ndarray | None = None):
    """Propagate stable disparities to unstable pixels along the tree (Yang's refinement).

    Parameters
    ----------
    disp : ndarray, float32 (H, W)
    stable : ndarray, bool (H, W)
    tree : stereobudget.aggregate.MinimumSpanningTree
        Tree of the left image.
    out : ndarray, float32, C-contiguous (H * W, L) with L >= num_disp, optional
        Scratch volume for the aggregation (a dead cost volume can be recycled: reusing
        it saves the page faults of a fresh allocation); its contents are overwritten.
        Layers past ``num_disp`` (padding) are aggregated too but never win.
        The refinement cost is never stored: the walk computes each row in the tree's row
        layout when it first reaches it (:func:`stereobudget.aggregate.distance_rows_winners`).

    Returns
    -------
    ndarray, float32 (H, W)
    """
    layout = _mst.tree_layout(tree)
    h, w = disp.shape
    rows = np.empty((h * w, int(num_disp)), np.float32) if out is None else out.reshape(h * w, -1)
    # Yang's cost |d - D(q)| of the stable pixels (0 elsewhere) is computed by the walk
    # itself from each row's level, so it never takes a pass over the volume of its own.
    levels = _stable_levels(np.ascontiguousarray(disp, np.float32).reshape(-1),
                            np.ascontiguousarray(stable).reshape(-1), layout.pixel_of_row)
    return _tree.distance_rows_winners(levels, layout, min_disp=int(min_disp), out=rows, num_disp=int(num_disp))


def left_right_refined_rows(left_rows, right_rows, *, left_layout, right_layout, left_tree, min_disp, params,
                            timer, num_disp=None):
    """Aggregate both views' costs, check the left view against the right, refine (Yang).

    Parameters
    ----------
    left_rows : ndarray, float32 (H * W, D)
        Unaggregated left-view cost in ``left_layout`` (:func:`stereobudget.aggregate.pair_cost_rows`);
        consumed: aggregated in place, then reused for the refinement cost.
    right_rows : ndarray, float32 (H * W, D), or None
        Unaggregated right-view cost in ``right_layout``, aggregated in place on the right
        image's tree, as Yang does.  ``None``: the right disparity is read off the left
        view's aggregated costs instead (:func:`right_disparity_from_left`).
    left_layout, right_layout : stereobudget.aggregate.TreeLayout
    left_tree : stereobudget.aggregate.MinimumSpanningTree
        Tree of the left image (``left_layout`` is its layout).
    min_disp : int
    params : stereobudget.decoding.DecoderParams
    timer : callable
        ``timer(stage)`` context manager that records stage times.
    num_disp : int, optional
        Disparities searched: the first ``num_disp`` layers (default: all ``D``; the rest
        are padding, :func:`stereobudget.cost.volume_layers`).

    Returns
    -------
    disparity : ndarray, float32 (H, W)
    stable : ndarray, bool (H, W)
        Pixels that passed the left-right check.
    """
    num_disp = left_rows.shape[1] if num_disp is None else int(num_disp)
    h, w = left_layout.height, left_layout.width
    with timer("aggregate"):
        # Winners are taken during the aggregation walks (no separate pass over the volumes).
        if right_rows is not None:
            disp_l, disp_r = _tree.aggregate_two_rows_winners(left_rows, left_layout, right_rows, right_layout,
                                                              min_disp=int(min_disp), num_disp=num_disp)
        else:
            disp_l = _tree.aggregate_rows_winners(left_rows, left_layout, min_disp=int(min_disp), num_disp=num_disp)
    if right_rows is None:
        with timer("wta"):
            support = _tree.aggregate(np.ones((h, w, 1), np.float32), left_tree)[:, :, 0]
            disp_r = right_disparity_from_left(left_rows, int(min_disp), support, layout=left_layout,
                                               num_disp=num_disp)
    with timer("refine"):
        stable = left_right_stable(disp_l, disp_r, np.float32(1.0))
        # The left volume is dead after its winner was taken: it holds the refinement cost.
        disp = nonlocal_refinement(disp_l, stable, left_tree, min_disp=min_disp, num_disp=num_disp, out=left_rows)
        disp = median_filter_disparity(disp, params.median_size, passes=params.median_passes)
    return disp, stable


def pair_trees(tree_guide, right_guide, *, params):
    """I1's tree and, when the check uses it (``params.right_check == "tree"``), the right
    image's, built concurrently (:func:`stereobudget.aggregate.build_trees`).

    Returns
    -------
    tree : stereobudget.aggregate.MinimumSpanningTree
        I1's tree.
    left_layout, right_layout : stereobudget.aggregate.TreeLayout
        Their row layouts; ``right_layout`` is None for the diagonal check.
    """
    guides = [tree_guide, right_guide] if params.right_check == "tree" else [tree_guide]
    trees = _mst.build_trees(guides, sigma=params.tree_sigma, median_size=params.tree_median)
    right_layout = _mst.tree_layout(trees[1]) if len(trees) > 1 else None
    return trees[0], _mst.tree_layout(trees[0]), right_layout


def full_pair_disparity(left_f, right_f, *, tree_guide, min_disp, num_disp, params, timer):
    """Standard full-pair stereo with Yang's non-local method (the "100 % of I2" reference).

    ``left_f``/``right_f`` are float32 (H, W, C) images in 8-bit units; the left tree is
    built on ``tree_guide`` (I1 itself, also when ``left_f`` is a low-passed I1), the right
    tree on ``right_f``.
    """
    from ..cost._layers import volume_layers
    from ._pair_volumes import pair_cost_rows
    with timer("tree"):
        tree, left_layout, right_layout = pair_trees(tree_guide, right_f, params=params)
    with timer("cost"):
        left_rows, right_rows = pair_cost_rows(left_f, right_f, min_disp=min_disp, num_disp=volume_layers(num_disp),
                                               truncation=params.full_truncation, grad_weight=params.grad_weight,
                                               grad_truncation=params.grad_truncation, left_layout=left_layout,
                                               right_layout=right_layout)
    disp, _ = left_right_refined_rows(left_rows, right_rows, left_layout=left_layout, right_layout=right_layout,
                                      left_tree=tree, min_disp=min_disp, params=params, timer=timer,
                                      num_disp=num_disp)
    scratch.recycle(left_rows, right_rows)
    return disp


def median_filter_disparity(disparity: np.ndarray, size: int, *, passes: int = 1) -> np.ndarray:
    """Median filter of a disparity map, ``passes`` times over (OpenCV, borders replicated).

    A median repeated converges to a map that it leaves unchanged; two passes of 5 x 5
    remove about what one 7 x 7 median does (OpenCV filters float32 maps only at sizes 3
    and 5) for 2 x 0.8 ms a 640 x 480 map.

    Parameters
    ----------
    disparity : ndarray, float32 (H, W)
    size : {0, 1, 3, 5}
        Window side; 0 or 1 returns ``disparity`` unchanged.
    passes : int, keyword-only

    Returns
    -------
    ndarray, float32 (H, W)
    """
    if size <= 1 or passes < 1:
        return disparity
    import cv2
    out = np.ascontiguousarray(disparity, np.float32)
    for _ in range(int(passes)):
        out = cv2.medianBlur(out, int(size))
    return out


def fill_from_row(disparity, valid, *, background=False):
    """Each invalid pixel takes the disparity of a valid pixel of its row.

    By default the nearest one (the left one wins a tie).  With ``background``, the smaller
    of the disparities of the nearest valid pixels on its left and on its right (the one
    there is, at a row's end): a pixel the left-right check rejects next to a depth edge
    is most often one the nearer surface hides or fattens, and belongs to the farther one
    (Hirschmüller's treatment of occlusions).  A row without a valid pixel keeps its
    values.  After a semi-global left-right check either measured better than propagating
    along I1's tree (Yang's refinement), whose pull towards fronto-parallel neighbours
    undoes slanted surfaces (23 real pairs: Vintage 28 % against 49 %, Playtable 25 %
    against 35 %).

    Parameters
    ----------
    disparity : ndarray, float32 (H, W)
    valid : ndarray, bool (H, W)
    background : bool, keyword-only

    Returns
    -------
    ndarray, float32 (H, W)
    """
    out = disparity.copy()
    run_parts(_fill_rows, disparity.shape[0], disparity, valid, out, bool(background))
    return out


@njit(cache=True, **RANGE_KERNEL)
def _fill_rows(disparity, valid, out, background, first, stop):
    """Rows ``[first, stop)`` of :func:`fill_from_row` into ``out`` (a copy of ``disparity``)."""
    w = disparity.shape[1]
    for y in range(first, stop):
        last = -1                      # the nearest valid column to the left
        x = 0
        while x < w:
            if valid[y, x]:
                last = x
                x += 1
                continue
            nxt = x + 1                # the run of invalid pixels is [x, nxt)
            while nxt < w and not valid[y, nxt]:
                nxt += 1
            for xx in range(x, nxt):
                if last >= 0 and nxt < w and background:
                    out[y, xx] = min(disparity[y, last], disparity[y, nxt])
                elif last >= 0 and (nxt >= w or xx - last <= nxt - xx):
                    out[y, xx] = disparity[y, last]
                elif nxt < w:
                    out[y, xx] = disparity[y, nxt]
            x = nxt
