"""Plain references of the aggregation: Yang's two passes over the tree, written as the paper's
cited method states them, one node at a time in float64.

For tests and for reading; the kernels of :mod:`stereobudget.aggregate._tree` (tree-ordered
rows, side-by-side ranges, two threads, winners taken in the walk) are held to these.
"""

from __future__ import annotations

import numpy as np

from ._tree import MinimumSpanningTree


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
