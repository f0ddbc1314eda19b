"""Plain references of the aggregation: Yang's two passes over the tree, written as the paper's
cited method states them, one node at a time in float64.

For tests and for reading; the kernels of :mod:`stereobudget.aggregate._tree` (tree-ordered
rows, side-by-side ranges, two threads, winners taken in the walk) are held to these.
"""

from __future__ import annotations

import numpy as np

from ._mst import MinimumSpanningTree
from ._weighted_median import DEFAULT_RADIUS, DEFAULT_SIGMA_C, DEFAULT_SIGMA_S, DEFAULT_STEP, likeness_table


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


def plane_refinement_reference(disparity, confident, gray, *, samples=None, min_disp, max_disp, size=12,
                               compactness=12.0, iterations=3, tolerance=1.0, min_inliers=0.7,
                               min_confident=0.2, replace_confident=True, coarse_size=0, snap_tolerance=0.5,
                               anchored=True):
    """:func:`stereobudget.aggregate.plane_refinement` step by step in float64 numpy, one segment at a time.

    Segmentation: every pixel to the nearest (grey level over ``compactness``, distance over
    ``size``) of the 3 x 3 seeds around its grid cell, first in row-major order on a tie;
    centres move to their pixels' mean.  Per segment: the plane of its confident pixels by
    Cauchy-reweighted least squares (scales ``IRLS_SCALES``) from the fronto-parallel plane at
    their median; accepted when enough pixels are confident and enough of those lie within
    ``tolerance``.  Proposal: the plane at rejected pixels (``anchored``: those whose nearest
    confident pixel of the row on one side lies within ``tolerance`` of the plane) and
    (``replace_confident``) at confident ones within ``snap_tolerance``.  Arbitration: on sample rows, I1 at each place
    where ``x - d(x)`` crosses a sample's column, interpolated between the two pixels, against
    the sample; a segment keeps its current values only when they fit the samples better on
    average.  Then the same with ``coarse_size`` segments for what is still rejected.
    """
    from ._planes import IRLS_SCALES, _lattice_gray, grid_seeds

    disparity = np.asarray(disparity, np.float32)
    confident = np.asarray(confident, bool)
    g = np.asarray(gray, np.float64)
    h, w = g.shape
    # --- segmentation
    ny, nx, rows, cols = grid_seeds(h, w, size)
    cy, cx = np.repeat(rows, nx), np.tile(cols, ny)
    cg = g[np.rint(cy).astype(int), np.rint(cx).astype(int)].copy()
    yy, xx = np.mgrid[0:h, 0:w]
    gy, gx = np.minimum(yy // size, ny - 1), np.minimum(xx // size, nx - 1)
    labels = np.zeros((h, w), np.int64)
    for it in range(max(1, iterations)):
        best = np.full((h, w), np.inf)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                j, i = gy + dy, gx + dx
                ok = (j >= 0) & (j < ny) & (i >= 0) & (i < nx)
                k = np.where(ok, j * nx + i, 0)
                dist = ((g - cg[k]) ** 2 / compactness ** 2 + ((yy - cy[k]) ** 2 + (xx - cx[k]) ** 2) / size ** 2)
                better = ok & (dist < best)
                best[better], labels[better] = dist[better], k[better]
        if it + 1 < iterations:
            for k in np.unique(labels):
                members = labels == k
                cg[k], cy[k], cx[k] = g[members].mean(), yy[members].mean(), xx[members].mean()
    # --- planes and proposal
    n = ny * nx
    proposed = disparity.astype(np.float64).copy()
    snap = snap_tolerance
    for k in range(n):
        members = labels == k
        use = members & confident
        m = int(use.sum())
        if m < 3 or m < min_confident * members.sum():
            continue
        xs, ys, ds = xx[use].astype(float), yy[use].astype(float), disparity[use].astype(float)
        mx, my = xs.mean(), ys.mean()
        plane = np.array([0.0, 0.0, np.median(ds)])
        design = np.stack([xs - mx, ys - my, np.ones(m)], axis=1)
        for s in IRLS_SCALES:
            wgt = 1.0 / (1.0 + ((ds - design @ plane) / s) ** 2)
            normal = design.T @ (wgt[:, None] * design)
            if abs(np.linalg.det(normal)) >= 1e-9 * max(1.0, normal[0, 0] * normal[1, 1] * normal[2, 2]):
                plane = np.linalg.solve(normal, design.T @ (wgt * ds))
        if np.sum(np.abs(ds - design @ plane) <= tolerance) < min_inliers * m:
            continue
        p = plane[0] * (xx - mx) + plane[1] * (yy - my) + plane[2]
        take = members & (p >= min_disp) & (p <= max_disp)
        snapped = confident & replace_confident & (np.abs(disparity - p) <= snap)
        rejected = ~confident
        if anchored:
            # The nearest confident pixel of the row on either side must lie on the plane too.
            for y, x in zip(*np.nonzero(take & rejected)):
                left = np.nonzero(confident[y, :x])[0]
                right = np.nonzero(confident[y, x + 1:])[0]
                rejected[y, x] = ((left.size > 0 and _on_plane(y, left[-1], disparity, plane, mx, my, tolerance))
                                  or (right.size > 0
                                      and _on_plane(y, x + 1 + right[0], disparity, plane, mx, my, tolerance)))
        take &= rejected | snapped
        proposed[take] = p[take]
    # --- arbitration by the samples
    lattice, oy, ox, sy, sx = _lattice_gray(samples)
    out = proposed
    if lattice.shape[0] > 0:
        def errors(field):
            err, hits = np.zeros(n), np.zeros(n)
            for r in range(lattice.shape[0]):
                y = oy + r * sy
                for x in range(w - 1):
                    if y >= h or labels[y, x] != labels[y, x + 1]:
                        continue
                    f0, f1 = x - field[y, x], x + 1 - field[y, x + 1]
                    if not 0 < f1 - f0 < 3:
                        continue
                    for j in range(lattice.shape[1]):
                        xs_ = ox + j * sx
                        if f0 <= xs_ < f1:
                            t = (xs_ - f0) / (f1 - f0)
                            err[labels[y, x]] += abs((1 - t) * g[y, x] + t * g[y, x + 1] - lattice[r, j])
                            hits[labels[y, x]] += 1
            return err, hits
        err_now, hits_now = errors(disparity.astype(np.float64))
        err_new, hits_new = errors(proposed.astype(np.float32).astype(np.float64))
        keep = (hits_now > 0) & (hits_new > 0) & (err_new * hits_now > err_now * hits_new)
        out = np.where(keep[labels], disparity, proposed)
    out = out.astype(np.float32)
    if coarse_size:
        return plane_refinement_reference(out, confident | (out != disparity), gray, samples=samples,
                                          min_disp=min_disp, max_disp=max_disp, size=coarse_size,
                                          compactness=compactness, iterations=iterations, tolerance=tolerance,
                                          min_inliers=min_inliers, min_confident=min_confident,
                                          replace_confident=False, anchored=anchored)
    return out


def _on_plane(y, x, disparity, plane, mx, my, tolerance):
    """Whether pixel (x, y)'s disparity lies within ``tolerance`` of ``plane`` (coordinates about (mx, my))."""
    return abs(float(disparity[y, x]) - (plane[0] * (x - mx) + plane[1] * (y - my) + plane[2])) <= tolerance


def weighted_median_fill_reference(disparity, valid, image, *, radius=DEFAULT_RADIUS, sigma_s=DEFAULT_SIGMA_S,
                                   sigma_c=DEFAULT_SIGMA_C, step=DEFAULT_STEP):
    """:func:`stereobudget.aggregate.weighted_median_fill` in plain numpy, one rejected pixel at a
    time, its sums in float64 in the window's order, as the kernel's."""
    disparity = np.asarray(disparity, np.float32)
    image = np.asarray(image, np.float32)
    if image.ndim == 2:
        image = image[:, :, None]
    out = disparity.copy()
    h, w = disparity.shape
    finite = disparity[np.isfinite(disparity)]
    if finite.size == 0:
        return out
    low = np.floor(finite.min())
    likeness = likeness_table(float(sigma_c))
    reach = (radius // step) * step
    for y, x in zip(*np.nonzero(~np.asarray(valid, bool))):
        weights, values = [], []
        for yy in range(y - reach, y + reach + 1, step):
            for xx in range(x - reach, x + reach + 1, step):
                if not (0 <= yy < h and 0 <= xx < w) or not np.isfinite(disparity[yy, xx]):
                    continue
                difference = max(abs(float(a) - float(b)) for a, b in zip(image[yy, xx], image[y, x]))
                level = int(difference * 4.0 + 0.5)
                if level >= likeness.size:
                    continue
                near = np.exp(-((yy - y) ** 2 + (xx - x) ** 2) / (2.0 * sigma_s * sigma_s))
                weights.append(near * likeness[level])
                values.append(float(disparity[yy, xx]))
        if not weights:
            continue
        bins = [int(np.floor(v - float(low) + 0.5)) for v in values]
        per_bin = np.zeros(max(bins) + 1)
        for b, weight in zip(bins, weights):
            per_bin[b] += weight
        half, reached = 0.5 * sum(weights), 0.0
        for median_bin in range(per_bin.size):
            reached += per_bin[median_bin]
            if reached >= half and per_bin[median_bin] > 0:
                break
        chosen = [(weight, v) for b, weight, v in zip(bins, weights, values) if b == median_bin]
        out[y, x] = sum(weight * v for weight, v in chosen) / sum(weight for weight, _ in chosen)
    return out
