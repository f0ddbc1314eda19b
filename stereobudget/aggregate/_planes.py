"""Plane refinement of a decoded disparity map: segments of I1, a robust plane per segment
fitted to the pixels that passed the left-right check, and the plane where it explains them.

Semi-global winners are fronto-parallel by construction: every disparity change along a
path pays a penalty, so a slanted surface comes out as terraces, and pixels the left-right
check rejects take the disparity of their row's nearest stable pixel, a constant.  A
surface of I1 that is a plane in the scene has a disparity that is a plane in the image,
``d = a x + b y + c`` (a linear function of the inverse depth).  So:

1. I1 is cut into compact segments of similar grey level (a few iterations of local
   k-means on grey level and position, seeded on a square grid; Achanta et al.'s SLIC
   on one channel), which mostly do not cross depth edges.
2. Per segment, a plane is fitted to the *confident* pixels (those that passed the
   left-right check) by iteratively reweighted least squares with Cauchy weights whose
   scale shrinks from 4 to 0.5 px, starting from the fronto-parallel plane at the median:
   outliers (another surface inside the segment, a mismatch) lose their weight.
3. Where at least ``min_inliers`` of the confident pixels lie within ``tolerance`` of the
   plane, the plane replaces the rejected pixels of the segment (those whose row's nearest
   confident pixel on one side lies on it too) and the confident pixels within
   ``snap_tolerance`` of it (the terraces); confident pixels farther away keep their value.
4. The samples arbitrate: on the rows that carry samples, where the disparity field
   maps left pixels ``x, x + 1`` across a sample's column (``x - d(x)`` passes it), I1
   interpolated at the crossing is compared with that sample, the host's exact right
   pixel.  A segment takes its plane only when the plane reproduces those samples at
   least as well, on average, as the disparities it would replace.

:func:`stereobudget.aggregate.plane_refinement_reference` states the same steps in plain numpy, one segment at a
time; the numba kernels here are held to it by the tests.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL, RANGE_KERNEL_COUNTED
from .._kernels._parallel import run_parts

#: Segment spacing (pixels), grey-level compactness and k-means rounds of the segmentation.
DEFAULT_SEGMENT_SIZE = 12
DEFAULT_COMPACTNESS = 12.0
DEFAULT_SEGMENT_ITERATIONS = 3
#: A confident pixel within this many pixels of its segment's plane is explained by it.
DEFAULT_PLANE_TOLERANCE = 1.0
#: Fraction of a segment's confident pixels the plane must explain; and of its pixels that must be confident.
DEFAULT_MIN_INLIERS = 0.7
DEFAULT_MIN_CONFIDENT = 0.2
#: A confident pixel this close to its segment's accepted plane takes the plane's value.
DEFAULT_SNAP_TOLERANCE = 0.5
#: Cauchy scales (pixels) of the reweighted least-squares rounds.
IRLS_SCALES = (4.0, 2.0, 1.0, 1.0, 0.5, 0.5)


# --------------------------------------------------------------------------- segmentation

def grid_seeds(height: int, width: int, size: int):
    """(rows, cols) of the seed grid: ``ceil(H / size) x ceil(W / size)`` cells, centres clipped inside."""
    ny = max(1, -(-height // size))
    nx = max(1, -(-width // size))
    cy = np.minimum((np.arange(ny) * size + size / 2.0), height - 1.0)
    cx = np.minimum((np.arange(nx) * size + size / 2.0), width - 1.0)
    return ny, nx, cy, cx


@njit(cache=True, **RANGE_KERNEL)
def _assign(gray, cg, cy, cx, ny, nx, size, inv_m2, inv_s2, labels, first, stop):
    """Rows ``[first, stop)`` of ``labels``: each pixel's nearest centre among its 3 x 3 seed cells."""
    w = gray.shape[1]
    for y in range(first, stop):
        gy = min(y // size, ny - 1)
        for x in range(w):
            gx = min(x // size, nx - 1)
            best = 1e300
            arg = -1
            g = gray[y, x]
            for dy in range(-1, 2):
                j = gy + dy
                if j < 0 or j >= ny:
                    continue
                for dx in range(-1, 2):
                    i = gx + dx
                    if i < 0 or i >= nx:
                        continue
                    k = j * nx + i
                    dg = g - cg[k]
                    ey = y - cy[k]
                    ex = x - cx[k]
                    dist = dg * dg * inv_m2 + (ey * ey + ex * ex) * inv_s2
                    if dist < best:
                        best = dist
                        arg = k
            labels[y, x] = arg


@njit(cache=True)
def _centres(gray, labels, n, cg, cy, cx):
    h, w = gray.shape
    sg = np.zeros(n)
    sy = np.zeros(n)
    sx = np.zeros(n)
    cnt = np.zeros(n)
    for y in range(h):
        for x in range(w):
            k = labels[y, x]
            sg[k] += gray[y, x]
            sy[k] += y
            sx[k] += x
            cnt[k] += 1.0
    for k in range(n):
        if cnt[k] > 0:
            cg[k] = sg[k] / cnt[k]
            cy[k] = sy[k] / cnt[k]
            cx[k] = sx[k] / cnt[k]


def segment_image(gray: np.ndarray, *, size: int = DEFAULT_SEGMENT_SIZE, compactness: float = DEFAULT_COMPACTNESS,
                  iterations: int = DEFAULT_SEGMENT_ITERATIONS) -> np.ndarray:
    """Compact segments of similar grey level (SLIC on one channel).

    Parameters
    ----------
    gray : ndarray, float32 (H, W)
        I1's grey image in 8-bit units.
    size : int
        Seed spacing in pixels: segments of about ``size`` x ``size`` pixels.
    compactness : float
        Grey-level difference that weighs as much as a distance of ``size`` pixels.
    iterations : int
        Rounds of assignment (each pixel to the nearest of the 3 x 3 neighbouring seeds'
        centres) and update (centres move to their pixels' mean).

    Returns
    -------
    ndarray, int32 (H, W)
        Segment index of every pixel, ``0 .. ceil(H/size) * ceil(W/size) - 1`` (some may be empty).
    """
    gray = np.ascontiguousarray(gray, np.float64)
    h, w = gray.shape
    ny, nx, rows, cols = grid_seeds(h, w, size)
    cy = np.repeat(rows, nx)
    cx = np.tile(cols, ny)
    cg = gray[np.rint(cy).astype(np.int64), np.rint(cx).astype(np.int64)].copy()
    labels = np.empty((h, w), np.int32)
    inv_m2 = 1.0 / (compactness * compactness)
    inv_s2 = 1.0 / float(size * size)
    for it in range(max(1, iterations)):
        run_parts(_assign, gray.shape[0], gray, cg, cy, cx, ny, nx, size, inv_m2, inv_s2, labels)
        if it + 1 < iterations:
            _centres(gray, labels, ny * nx, cg, cy, cx)
    return labels


# --------------------------------------------------------------------------- planes

@njit(cache=True)
def _solve3(m, v):
    """Cramer's rule for the symmetric 3x3 system ``m p = v``; None-like (ok=False) when singular."""
    a, b, c = m[0, 0], m[0, 1], m[0, 2]
    d, e, f = m[1, 1], m[1, 2], m[2, 2]
    det = a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c)
    if abs(det) < 1e-9 * max(1.0, a * d * f):
        return 0.0, 0.0, 0.0, False
    x0 = v[0] * (d * f - e * e) - b * (v[1] * f - e * v[2]) + c * (v[1] * e - d * v[2])
    x1 = a * (v[1] * f - e * v[2]) - v[0] * (b * f - e * c) + c * (b * v[2] - v[1] * c)
    x2 = a * (d * v[2] - v[1] * e) - b * (b * v[2] - v[1] * c) + v[0] * (b * e - d * c)
    return x0 / det, x1 / det, x2 / det, True


@njit(cache=True)
def _fit_one(xs, ys, ds, scales, tolerance):
    """(a, b, c, inliers) of one segment's robust plane, coordinates relative to their mean."""
    n = ds.shape[0]
    mx = xs.mean()
    my = ys.mean()
    a = 0.0
    b = 0.0
    c = np.median(ds)
    m = np.empty((3, 3))
    v = np.empty(3)
    for s in scales:
        inv = 1.0 / (s * s)
        m[:, :] = 0.0
        v[:] = 0.0
        for i in range(n):
            u = xs[i] - mx
            t = ys[i] - my
            r = ds[i] - (a * u + b * t + c)
            wgt = 1.0 / (1.0 + r * r * inv)
            m[0, 0] += wgt * u * u
            m[0, 1] += wgt * u * t
            m[0, 2] += wgt * u
            m[1, 1] += wgt * t * t
            m[1, 2] += wgt * t
            m[2, 2] += wgt
            v[0] += wgt * u * ds[i]
            v[1] += wgt * t * ds[i]
            v[2] += wgt * ds[i]
        pa, pb, pc, ok = _solve3(m, v)
        if ok:
            a, b, c = pa, pb, pc
    inliers = 0
    for i in range(n):
        if abs(ds[i] - (a * (xs[i] - mx) + b * (ys[i] - my) + c)) <= tolerance:
            inliers += 1
    return a, b, c - a * mx - b * my, inliers


@njit(cache=True)
def _segment_pixels(disparity, confident, labels, n, sizes):
    """Every segment's confident pixels in raster order (x, y, d, and segment k's are
    ``[start[k], start[k + 1])``), by a counting sort; ``sizes`` += each segment's pixels."""
    h, w = disparity.shape
    # Pixels of each segment in raster order, by a counting sort.
    start = np.zeros(n + 1, np.int64)
    for y in range(h):
        for x in range(w):
            k = labels[y, x]
            sizes[k] += 1
            if confident[y, x]:
                start[k + 1] += 1
    for k in range(n):
        start[k + 1] += start[k]
    fill = start[:n].copy()
    px = np.empty(start[n], np.float64)
    py = np.empty(start[n], np.float64)
    pd = np.empty(start[n], np.float64)
    for y in range(h):
        for x in range(w):
            if confident[y, x]:
                k = labels[y, x]
                j = fill[k]
                px[j] = x
                py[j] = y
                pd[j] = disparity[y, x]
                fill[k] = j + 1
    return start, px, py, pd


@njit(cache=True, **RANGE_KERNEL_COUNTED)
def _fit_segments(start, px, py, pd, scales, tolerance, planes, inliers, counts, first, stop):
    """Segments ``[first, stop)`` of :func:`fit_segment_planes`, from :func:`_segment_pixels`."""
    for k in range(first, stop):
        lo = start[k]
        hi = start[k + 1]
        counts[k] = hi - lo
        if hi - lo < 3:
            inliers[k] = 0
            continue
        a, b, c, good = _fit_one(px[lo:hi], py[lo:hi], pd[lo:hi], scales, tolerance)
        planes[k, 0] = a
        planes[k, 1] = b
        planes[k, 2] = c
        inliers[k] = good


def fit_segment_planes(disparity, confident, labels, *, tolerance: float = DEFAULT_PLANE_TOLERANCE):
    """Robust plane ``d = a x + b y + c`` of every segment, fitted to its confident pixels.

    Parameters
    ----------
    disparity : ndarray, float32 (H, W)
    confident : ndarray, bool (H, W)
        Pixels the fit may use (those that passed the left-right check).
    labels : ndarray, int32 (H, W)
        From :func:`segment_image`.
    tolerance : float
        A confident pixel within this many pixels of the plane counts as an inlier.

    Returns
    -------
    planes : ndarray, float64 (L, 3)
        ``(a, b, c)`` per segment (zeros where fewer than 3 confident pixels).
    inliers, counts, sizes : ndarray, int64 (L,)
        Confident pixels within ``tolerance`` of the plane, confident pixels, all pixels.
    """
    n = int(labels.max()) + 1
    planes = np.zeros((n, 3))
    inliers = np.zeros(n, np.int64)
    counts = np.zeros(n, np.int64)
    sizes = np.zeros(n, np.int64)
    pixels = _segment_pixels(np.ascontiguousarray(disparity, np.float32), np.ascontiguousarray(confident, np.bool_),
                             np.ascontiguousarray(labels, np.int32), n, sizes)
    run_parts(_fit_segments, n, *pixels, np.array(IRLS_SCALES), float(tolerance), planes, inliers, counts)
    return planes, inliers, counts, sizes


# --------------------------------------------------------------------------- replacement

@njit(cache=True)
def _crossing_errors(field, gray, labels, lattice, oy, ox, sy, sx, err, hits):
    """Add, per segment, how far I1 is from the samples where ``field`` says they are.

    On a row that carries samples, the disparity field maps left pixel ``x`` to the right
    abscissa ``f(x) = x - field(x)``; where ``f`` passes a sample's column ``xs`` between
    ``x`` and ``x + 1`` (both of one segment, no occlusion jump), I1 linearly interpolated at
    the crossing should equal the sample.
    """
    h, w = field.shape
    for r in range(lattice.shape[0]):
        y = oy + r * sy
        if y >= h:
            break
        for x in range(w - 1):
            k = labels[y, x]
            if labels[y, x + 1] != k:
                continue
            f0 = x - field[y, x]
            f1 = x + 1 - field[y, x + 1]
            if not (f1 > f0 and f1 - f0 < 3.0):
                continue
            j = np.ceil((f0 - ox) / sx)
            while j < lattice.shape[1] and ox + j * sx < f1:
                if j >= 0:
                    t = (ox + j * sx - f0) / (f1 - f0)
                    value = (1.0 - t) * gray[y, x] + t * gray[y, x + 1]
                    err[k] += abs(value - lattice[r, int(j)])
                    hits[k] += 1
                j += 1.0


@njit(cache=True, **RANGE_KERNEL)
def _propose(disparity, confident, labels, planes, accept, tolerance, lo, hi, replace_confident, anchored,
             snap, out, first, stop):
    """Rows ``[first, stop)``: each pixel's value if its segment's plane is taken (module docstring, step 3).

    ``anchored``: a rejected pixel takes the plane only when the plane also explains the
    nearest confident pixel of its row on one side or the other (the pixels the row fill
    chose from), so a plane does not cross into a surface its segment only grazes.
    """
    w = disparity.shape[1]
    for y in range(first, stop):
        last = -1
        for x in range(w):
            k = labels[y, x]
            d = disparity[y, x]
            out[y, x] = d
            if confident[y, x]:
                last = x
            if not accept[k]:
                continue
            a = planes[k, 0]
            b = planes[k, 1]
            c = planes[k, 2]
            p = a * x + b * y + c
            if p < lo or p > hi:
                continue
            if confident[y, x]:
                if replace_confident and abs(d - p) <= snap:
                    out[y, x] = p
                continue
            if anchored:
                ok = last >= 0 and abs(disparity[y, last] - (a * last + b * y + c)) <= tolerance
                if not ok:
                    nxt = x + 1
                    while nxt < w and not confident[y, nxt]:
                        nxt += 1
                    ok = nxt < w and abs(disparity[y, nxt] - (a * nxt + b * y + c)) <= tolerance
                if not ok:
                    continue
            out[y, x] = p


@njit(cache=True, **RANGE_KERNEL)
def _arbitrate(disparity, proposed, labels, take, out, first, stop):
    """Rows ``[first, stop)`` of ``out``: the proposed value where the pixel's segment takes its plane."""
    w = disparity.shape[1]
    for y in range(first, stop):
        for x in range(w):
            out[y, x] = proposed[y, x] if take[labels[y, x]] else disparity[y, x]


def _lattice_gray(samples):
    """(lattice (R, C) float64 grey, oy, ox, sy, sx) of a grid sample set; an empty lattice otherwise."""
    if samples is None or not samples.pattern.is_regular_grid or samples.mosaic:
        return np.zeros((0, 0)), 0, 0, 1, 1
    from ..cost._cost import to_float_image, to_gray
    values = to_float_image(samples.grid_values_rgb() if hasattr(samples, "grid_values_rgb")
                            else _grid_rgb(samples))
    p = samples.pattern
    return (np.ascontiguousarray(to_gray(values), np.float64), int(p.offset_y), int(p.offset_x),
            int(p.stride_y), int(p.stride_x))


def _grid_rgb(samples):
    lattice = samples.grid_values()
    return lattice[:, :, ::-1] if samples.channel_order == "bgr" else lattice


def plane_refinement(disparity: np.ndarray, confident: np.ndarray, gray: np.ndarray, *, samples=None,
                     min_disp: float, max_disp: float, size: int = DEFAULT_SEGMENT_SIZE,
                     compactness: float = DEFAULT_COMPACTNESS, iterations: int = DEFAULT_SEGMENT_ITERATIONS,
                     tolerance: float = DEFAULT_PLANE_TOLERANCE, min_inliers: float = DEFAULT_MIN_INLIERS,
                     min_confident: float = DEFAULT_MIN_CONFIDENT, labels: np.ndarray | None = None,
                     replace_confident: bool = True, coarse_size: int = 0,
                     snap_tolerance: float = DEFAULT_SNAP_TOLERANCE, anchored: bool = True) -> np.ndarray:
    """Replace rejected and terraced pixels by their segment's plane where it explains the confident ones.

    Parameters
    ----------
    disparity : ndarray, float32 (H, W)
        Left disparity, rejected pixels already filled (their values are what the
        samples compare the plane with).
    confident : ndarray, bool (H, W)
        Pixels that passed the left-right check.
    gray : ndarray, float32 (H, W)
        I1's grey image, 8-bit units.
    samples : SampleSet, optional
        A grid's samples arbitrate between a segment's plane and the disparities of its
        rejected pixels (module docstring); None (or another pattern): the plane decides.
    min_disp, max_disp : float
        A plane value outside this range is not used.
    size, compactness, iterations : segmentation (:func:`segment_image`).
    tolerance : float
        Pixels; a confident pixel this close to the plane is explained by it.
    min_inliers : float
        Fraction of a segment's confident pixels its plane must explain.
    min_confident : float
        Fraction of a segment's pixels that must be confident for a plane to be fitted.
    labels : ndarray, int32 (H, W), optional
        A segmentation to use instead of :func:`segment_image`'s.
    replace_confident : bool
        Confident pixels within ``snap_tolerance`` of an accepted plane take it (the
        terraces); False: only rejected pixels change.
    coarse_size : int
        When not 0, a second pass with segments of this spacing for the pixels still
        rejected, fitted to the confident pixels and those the first pass replaced.
    snap_tolerance : float
        See ``replace_confident``.  0.5 measured better than 1 on the paper's four scenes
        (a pixel within 1 of a slightly tilted plane may be the better one) and gained less
        on the real pairs (``scripts/evaluate_real.py --param plane_refinement=True``).
    anchored : bool
        A rejected pixel takes the plane only when the plane also explains the nearest
        confident pixel of its row on either side.

    Returns
    -------
    ndarray, float32 (H, W)
    """
    disparity = np.ascontiguousarray(disparity, np.float32)
    confident = np.ascontiguousarray(confident, np.bool_)
    if labels is None:
        labels = segment_image(gray, size=size, compactness=compactness, iterations=iterations)
    planes, inliers, counts, sizes = fit_segment_planes(disparity, confident, labels, tolerance=tolerance)
    accept = (counts >= 3) & (counts >= min_confident * sizes) & (inliers >= min_inliers * counts)
    labels = np.ascontiguousarray(labels, np.int32)
    proposed = np.empty_like(disparity)
    snap = snap_tolerance
    run_parts(_propose, disparity.shape[0], disparity, confident, labels, planes, accept, float(tolerance),
              float(min_disp), float(max_disp), bool(replace_confident), bool(anchored), float(snap), proposed)
    lattice, oy, ox, sy, sx = _lattice_gray(samples)
    out = proposed
    if lattice.shape[0] > 0:
        # A segment takes its plane unless the samples say its current disparities fit them better.
        gray64 = np.ascontiguousarray(gray, np.float64)
        n = planes.shape[0]
        err_now, err_new = np.zeros(n), np.zeros(n)
        hits_now, hits_new = np.zeros(n, np.int64), np.zeros(n, np.int64)
        _crossing_errors(disparity, gray64, labels, lattice, oy, ox, sy, sx, err_now, hits_now)
        _crossing_errors(proposed, gray64, labels, lattice, oy, ox, sy, sx, err_new, hits_new)
        take = (hits_now == 0) | (hits_new == 0) | (err_new * hits_now <= err_now * hits_new)
        out = np.empty_like(disparity)
        run_parts(_arbitrate, disparity.shape[0], disparity, proposed, labels, take, out)
    if coarse_size:
        # Segments too weakly textured or too rejected for a plane of their own: a coarser
        # segmentation's planes, fitted to the confident pixels and those the fine planes took.
        explained = confident | (out != disparity)
        return plane_refinement(out, explained, gray, samples=samples, min_disp=min_disp, max_disp=max_disp,
                                size=coarse_size, compactness=compactness, iterations=iterations,
                                tolerance=tolerance, min_inliers=min_inliers, min_confident=min_confident,
                                replace_confident=False, anchored=anchored)
    return out
