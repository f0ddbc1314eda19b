"""Plain references of the aggregation: Yang's two passes over the tree, written as the paper's
cited method states them, one node at a time in float64.

For tests and for reading; the kernels of :mod:`stereobudget.aggregate._tree` (tree-ordered
rows, side-by-side ranges, two threads, winners taken in the walk) are held to these.
"""

from __future__ import annotations

import numpy as np

from ._mst import MinimumSpanningTree


def aggregate_reference(cost: np.ndarray, tree: MinimumSpanningTree) -> np.ndarray:
    """Yang's non-local aggregation ``C_A(p) = sum_q S(p, q) C(q)`` by its serial two-pass walk.

    Upward, leaves first, each node adds its similarity-weighted sum to its parent:
    ``U(parent) += S(v) U(v)``; downward, root first, each node takes its parent's total:
    ``C_A(v) = S(v) C_A(parent) + (1 - S(v)^2) U(v)``, ``S(v)`` the similarity of the edge to
    the parent.  The reference of :func:`stereobudget.aggregate.aggregate`.

    Parameters
    ----------
    cost : ndarray (H, W, D)
    tree : MinimumSpanningTree
        From :func:`stereobudget.aggregate.build_tree` on an ``(H, W)`` guide.

    Returns
    -------
    ndarray, float64 (H, W, D)
    """
    h, w, d = cost.shape
    if (h, w) != (tree.height, tree.width):
        raise ValueError(f"cost volume {h}x{w} does not fit a {tree.height}x{tree.width} tree")
    upward = np.asarray(cost, np.float64).reshape(h * w, d).copy()
    similarity = tree.weight.astype(np.float64)
    for node in tree.order[:0:-1]:
        upward[tree.parent[node]] += similarity[node] * upward[node]
    total = upward.copy()
    for node in tree.order[1:]:
        s = similarity[node]
        total[node] = s * total[tree.parent[node]] + (1.0 - s * s) * upward[node]
    return total.reshape(h, w, d)


def left_right_refinement_reference(disp_left: np.ndarray, disp_right: np.ndarray, tree: MinimumSpanningTree, *,
                                    min_disp: int, num_disp: int, tolerance: float = 1.0):
    """Yang's left-right check and non-local refinement, by definition.

    A left pixel is stable where the right view's disparity at ``x - round(d)`` agrees with
    its own within ``tolerance``.  The refinement cost is ``|min_disp + i - D(q)|`` at stable
    pixels and 0 elsewhere, aggregated on the left tree (:func:`aggregate_reference`); each
    pixel takes the winner with the parabola fit (:func:`stereobudget.aggregate.winner_take_all`).
    The reference of :func:`stereobudget.aggregate.left_right_stable` followed by
    :func:`stereobudget.aggregate.nonlocal_refinement`.

    Parameters
    ----------
    disp_left, disp_right : ndarray (H, W)
        Disparities of the left and right views.
    tree : MinimumSpanningTree
        Tree of the left image.
    min_disp, num_disp : int
        Layer ``i`` of the refinement cost is disparity ``min_disp + i``.
    tolerance : float
        Largest disagreement of a stable pixel, in pixels.

    Returns
    -------
    refined : ndarray, float32 (H, W)
    stable : ndarray, bool (H, W)
    """
    from ._winner import winner_take_all

    h, w = disp_left.shape
    stable = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            d = float(disp_left[y, x])
            xr = int(np.floor(x - d + 0.5))
            stable[y, x] = 0 <= xr < w and abs(d - float(disp_right[y, xr])) <= tolerance
    layers = min_disp + np.arange(num_disp, dtype=np.float64)
    cost = np.where(stable[..., None], np.abs(layers - np.asarray(disp_left, np.float64)[..., None]), 0.0)
    aggregated = aggregate_reference(cost, tree)
    return winner_take_all(aggregated.astype(np.float32), int(min_disp)), stable
