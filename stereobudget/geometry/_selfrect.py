"""Self-rectification (``sb-decode --calibration auto``): the epipolar geometry from I1 and the samples alone.

The right camera's grid is a decimated right image, so it can be matched with I1 read at
the grid's spacing (:func:`match_lattice`), which gives point pairs in full-resolution
pixels, refined to a fraction of a pixel through an affine map of each patch;
``cv2.findFundamentalMat`` (RANSAC) keeps the consistent ones.  The pair is then modelled
as a side-by-side rig whose cameras are each turned a little from one rectified
orientation, with a radial distortion k1 per lens and a shared focal length, fitted to the
matches' rows from the untouched rig (an essential matrix's pose of a nearly rectified pair
is poorly conditioned: it can align the rows while tilting the baseline far forward).  The
matches the rig is fitted to are chosen by a RANSAC on the rig itself: the few wrong
matches the fundamental matrix lets through would otherwise pull the rows pixels away from
the good ones.  The pair is rectified as a calibrated one (alpha 1: nothing either camera
sees is cropped).  The residual vertical error of the matches the fit did not see, and the
fit's own uncertainty carried over the frame, are reported; too few reliable matches, a
residual too large, or a rectification that shrinks the image is refused in one line
rather than decoded into garbage.  There is no metric scale.

A stream (:class:`SelfRectifiedStream`) estimates once, checks its rows on fresh matches
every so many frames (:func:`frame_residual`) and estimates again when they drift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import CalibrationError
from ..io._samples import SampleSet

#: Fewest RANSAC-consistent matches accepted.
MIN_MATCHES = 40
#: Largest median vertical residual (full-resolution pixels) accepted after rectification.
MAX_RESIDUAL = 0.5
#: Patches matched: side in samples, how many (spread over the frame).
PATCH = 9
PATCHES = 4096
#: Least gray-level spread of a patch worth matching, least correlation of a match, and
#: least margin over the best correlation elsewhere (repetitive textures fail it).
MIN_TEXTURE = 6.0
MIN_CORRELATION = 0.8
MIN_MARGIN = 0.05
#: Least scale of the rectified frame against the raw one.
MIN_SCALE = 0.5
#: Weight of the prior that keeps the cameras' common pan (turn about the vertical) small: the
#: rows see it only through the scene's depth, while it moves both images sideways.
PAN_PRIOR = 3.0
#: The rig's RANSAC: hypotheses, matches fitted by each (and its Levenberg-Marquardt steps),
#: and the row error (px) within which a match agrees with a rig.
RIG_HYPOTHESES = 60
RIG_SAMPLE = 16
RIG_SAMPLE_ITERATIONS = 20
RIG_AGREEMENT = 0.6
#: The guided pass: side of the lattice patch around each sample (in samples), and how far
#: (full-resolution rows) from where the first estimate's decode puts it a match is searched.
GUIDE_PATCH = 7
GUIDE_SEARCH = 3
#: A stream checks its estimate every this many frames, on this many patches, and estimates
#: again when their median row error exceeds this multiple of the estimate's own.
CHECK_EVERY = 30
CHECK_PATCHES = 256
CHECK_GROWTH = 2.0


@dataclass(frozen=True)
class SelfRectificationReport:
    """What the estimate found: matches kept of those tried, the vertical residual (px) of the
    half of the matches the final refinement did not see, and whether the matches came from
    the guided pass (:func:`guided_matches`)."""

    matches: int
    candidates: int
    residual_median: float
    residual_p90: float
    uncertainty: float = 0.0
    guided: bool = False

    def summary(self) -> dict:
        return {"matches": self.matches, "candidates": self.candidates, "guided": self.guided,
                "residual_vertical_px_median": round(self.residual_median, 3),
                "residual_vertical_px_p90": round(self.residual_p90, 3),
                "uncertainty_vertical_px": round(self.uncertainty, 3)}


def _gray_u8(image):
    import cv2

    a = np.asarray(image)
    if a.dtype == np.uint16:
        a = (a >> 8).astype(np.uint8)
    if a.ndim == 3:
        a = cv2.cvtColor(np.ascontiguousarray(a[:, :, :3]), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(a)


def _gray_images(left, samples):
    """The sample grid as a small gray image (rows, cols) and I1 in gray, both float32."""
    lattice = samples.grid_values()
    if samples.channel_order == "bgr":
        lattice = lattice[:, :, ::-1]
    right_small = _gray_u8(lattice if lattice.shape[2] > 1 else lattice[:, :, 0]).astype(np.float32)
    return right_small, _gray_u8(left).astype(np.float32)


def _patch_texture(image, patch):
    """Standard deviation of ``image`` over each ``patch`` x ``patch`` window."""
    import cv2

    mean = cv2.boxFilter(image, -1, (patch, patch), borderType=cv2.BORDER_REFLECT)
    sq = cv2.boxFilter(image * image, -1, (patch, patch), borderType=cv2.BORDER_REFLECT)
    return np.sqrt(np.maximum(sq - mean * mean, 0))


def _read_patches(image, map_x, map_y, rows, cols):
    """``image`` read bilinearly at ``map_x``/``map_y`` (n, rows * cols), one patch per row: float64 (n, rows * cols).

    ``cv2.remap`` takes maps of fewer than 32767 rows, so the patches go a block at a time.
    """
    import cv2

    block = max(1, 32000 // rows)
    return np.concatenate([
        cv2.remap(image, map_x[i:i + block].reshape(-1, cols), map_y[i:i + block].reshape(-1, cols),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, rows * cols)
        for i in range(0, len(map_x), block)]).astype(np.float64)


def _fail(message):
    raise CalibrationError(message, path="--calibration auto")


def match_lattice(left: np.ndarray, samples: SampleSet, *, patch: int = PATCH, count: int = PATCHES,
                  search: tuple | None = None):
    """Point pairs (n, 2) x (n, 2), in full-resolution pixels, between I1 and the sample grid.

    Patches of the grid (``patch`` x ``patch`` samples) where it has texture, spread over
    the frame, are matched against I1 read at the grid's spacing at every full-resolution
    offset (I1 decimated at each of the ``stride_x * stride_y`` phases: the same point
    sampling as the grid's, so a match is exact to a pixel), by normalised
    cross-correlation (robust to gain and exposure).  A match is kept when it is strong
    and clearly better than the best elsewhere (a repetitive texture is dropped).
    """
    import cv2

    if not samples.pattern.is_regular_grid or samples.mosaic:
        _fail(f"self-rectification matches the samples as a decimated image and needs a grid, not "
              f"{samples.channel_order} {samples.pattern.kind} samples")
    p = samples.pattern
    sx, sy = p.stride_x, p.stride_y
    right_small, left_gray = _gray_images(left, samples)
    h, w = left_gray.shape
    rows, cols = right_small.shape
    half = patch // 2
    if rows < patch + 2 or cols < patch + 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    # Search window around the same place, in grid cells: disparities up to a third of the
    # width either way, rows up to a tenth of the height.
    reach_x, reach_y = search or (max(2, w // (3 * sx)), max(2, h // (10 * sy)))
    # Textured patches, the best of each block of a 12 x 8 partition of the grid.
    texture = _patch_texture(right_small, patch)
    texture[:half, :] = texture[-half:, :] = 0
    texture[:, :half] = texture[:, -half:] = 0
    centres = []
    blocks_y, blocks_x = 8, 12
    for by in range(blocks_y):
        for bx in range(blocks_x):
            r0, r1 = by * rows // blocks_y, (by + 1) * rows // blocks_y
            c0, c1 = bx * cols // blocks_x, (bx + 1) * cols // blocks_x
            block = texture[r0:r1, c0:c1]
            if block.size == 0:
                continue
            flat = np.argsort(block, axis=None)[::-1][:max(1, count // (blocks_x * blocks_y))]
            for k in flat:
                r, c = divmod(int(k), block.shape[1])
                if block[r, c] >= MIN_TEXTURE:
                    centres.append((r0 + r, c0 + c))
    phases = [(py, px, np.ascontiguousarray(left_gray[py::sy, px::sx])) for py in range(sy) for px in range(sx)]
    pts_left, pts_right, templates = [], [], []
    for r, c in centres:
        template = right_small[r - half:r + half + 1, c - half:c + half + 1]
        # Full-resolution centre of the patch in the right image, and the window searched in I1.
        xr, yr = p.offset_x + c * sx, p.offset_y + r * sy
        scores = []
        for py, px, image in phases:
            # Cells of this phase: column j is pixel px + j * sx.
            j0 = max(0, int(np.ceil((xr - px) / sx)) - reach_x - half)
            i0 = max(0, int(np.ceil((yr - py) / sy)) - reach_y - half)
            j1 = min(image.shape[1], j0 + 2 * (reach_x + half) + 1)
            i1 = min(image.shape[0], i0 + 2 * (reach_y + half) + 1)
            window = image[i0:i1, j0:j1]
            if window.shape[0] < patch or window.shape[1] < patch:
                continue
            ncc = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
            ncc = np.nan_to_num(ncc, nan=-1.0)
            iy, jx = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
            x = px + (j0 + jx + half) * sx
            y = py + (i0 + iy + half) * sy
            scores.append((float(ncc[iy, jx]), x, y, ncc, py, px, i0, j0))
        if not scores:
            continue
        best = max(scores, key=lambda item: item[0])
        score, x, y = best[0], best[1], best[2]
        if score < MIN_CORRELATION:
            continue
        # The best elsewhere (more than 2 cells away), over every phase: a clear winner only.
        second = -1.0
        for value, _, _, ncc, py, px, i0, j0 in scores:
            ys = py + (i0 + np.arange(ncc.shape[0]) + half) * sy
            xs = px + (j0 + np.arange(ncc.shape[1]) + half) * sx
            far = (np.abs(ys - y)[:, None] > 2 * sy) | (np.abs(xs - x)[None, :] > 2 * sx)
            if far.any():
                second = max(second, float(ncc[far].max()))
        if score - second < MIN_MARGIN:
            continue
        pts_left.append((x, y))
        templates.append(template)
        pts_right.append((xr, yr))
    pts_left = np.array(pts_left, np.float64).reshape(-1, 2)
    if len(pts_left):
        pts_left = _refine_matches(left_gray, np.array(templates, np.float32), pts_left, sx, sy)
    return pts_left, np.array(pts_right, np.float64).reshape(-1, 2)


def _refine_matches(left_gray, templates, centres, sx, sy, iterations: int = 10):
    """Each match's centre in I1 to a fraction of a pixel: Gauss-Newton on the squared
    difference between the template and I1 read bilinearly at the grid's spacing, through an
    affine map of the patch (the two cameras see a patch turned, scaled and sheared a little
    against each other, which at a coarse grid's span shifts its edges by a good part of a
    pixel) with a gain and an offset per match (the cameras' exposures differ).  A match whose
    centre runs away (more than a pixel from where it started) keeps its whole-pixel position."""
    import cv2

    n, rows, cols = templates.shape
    gx = cv2.Sobel(left_gray, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
    gy = cv2.Sobel(left_gray, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
    # Each template sample's offset (full-resolution pixels) from the patch's centre.
    across = np.broadcast_to(((np.arange(cols) - cols // 2) * sx)[None, :], (rows, cols)).ravel()
    down = np.broadcast_to(((np.arange(rows) - rows // 2) * sy)[:, None], (rows, cols)).ravel()
    start = centres.astype(np.float64)
    # Per match: centre (x, y) and the affine part (x from across, x from down, y from across,
    # y from down) less the identity.
    centre = start.copy()
    affine = np.zeros((n, 4))
    t = templates.reshape(n, -1).astype(np.float64)
    for _ in range(iterations):
        map_x = (centre[:, :1] + (1 + affine[:, :1]) * across + affine[:, 1:2] * down).astype(np.float32)
        map_y = (centre[:, 1:] + affine[:, 2:3] * across + (1 + affine[:, 3:]) * down).astype(np.float32)
        values, dx, dy = (_read_patches(image, map_x, map_y, rows, cols) for image in (left_gray, gx, gy))
        # Unknowns per match: the centre's shift, the affine part's, gain a and offset b in
        # a * I1(map(p)) + b = T(p), relinearised at a = 1, b = 0.
        jac = np.stack([dx, dy, dx * across, dx * down, dy * across, dy * down, values, np.ones_like(values)],
                       axis=2)                                                  # (n, m, 8)
        normal = np.einsum("nmi,nmj->nij", jac, jac) + 1e-6 * np.eye(8)
        rhs = np.einsum("nmi,nm->ni", jac, t - values)
        step = np.linalg.solve(normal, rhs[..., None])[..., 0]
        centre += np.clip(step[:, :2], -0.5, 0.5)
        affine = np.clip(affine + np.clip(step[:, 2:6], -0.05, 0.05), -0.2, 0.2)
    moved = np.abs(centre - start).max(axis=1) > 1.0
    centre[moved] = start[moved]
    return centre


def guided_matches(left: np.ndarray, samples: SampleSet, rectification, disparity: np.ndarray, *,
                   patch: int = GUIDE_PATCH, search: int = GUIDE_SEARCH):
    """Point pairs (n, 2) x (n, 2) for every textured sample, from where a decode puts its match.

    ``disparity`` is a decode of the pair rectified by ``rectification`` (its left frame).
    Each raw left pixel's match in the raw right image follows from it
    (:func:`stereobudget.geometry.raw_right_positions`); the left pixel whose match lands
    nearest a sample, moved by the difference, is where that sample's lattice patch starts.
    The patch is then searched over ``search`` rows either way and a column either way
    (normalised cross-correlation; the estimate's rows may be off by pixels where it had no
    matches) and refined like :func:`match_lattice`'s.  A coarse grid matches few patches
    by search over the whole frame (a textured patch must also stand out from everything
    in a third of the width); here each sample needs only to stand out near its place,
    so matches come from all over the frame, where the first estimate had to extrapolate.
    """
    from ._rectify import raw_right_positions
    p = samples.pattern
    sx, sy = p.stride_x, p.stride_y
    right_small, left_gray = _gray_images(left, samples)
    rows, cols = right_small.shape
    h, w = left_gray.shape
    empty = np.zeros((0, 2)), np.zeros((0, 2))
    # Each left pixel's implied match, and the lattice cell it lands in.
    implied = raw_right_positions(disparity, rectification)
    ly, lx = np.nonzero(np.all(np.isfinite(implied), axis=2))
    ix, iy = implied[ly, lx, 0], implied[ly, lx, 1]
    col = np.rint((ix - p.offset_x) / sx).astype(np.int64)
    row = np.rint((iy - p.offset_y) / sy).astype(np.int64)
    half = patch // 2
    inside = (col >= half) & (col < cols - half) & (row >= half) & (row < rows - half)
    ly, lx, ix, iy, col, row = ly[inside], lx[inside], ix[inside], iy[inside], col[inside], row[inside]
    cx, cy = p.offset_x + col * sx, p.offset_y + row * sy
    # Per cell, the left pixel whose match lands nearest the sample.
    cell = row * cols + col
    order = np.lexsort((np.hypot(ix - cx, iy - cy), cell))
    _, first = np.unique(cell[order], return_index=True)
    pick = order[first]
    row, col = row[pick], col[pick]
    start = np.stack([lx[pick] + (cx[pick] - ix[pick]), ly[pick] + (cy[pick] - iy[pick])], axis=1)
    textured = _patch_texture(right_small, patch)[row, col] >= MIN_TEXTURE
    row, col, start = row[textured], col[textured], start[textured]
    n = len(row)
    if n == 0:
        return empty
    ky, kx = np.mgrid[-half:half + 1, -half:half + 1]
    templates = right_small[row[:, None, None] + ky[None], col[:, None, None] + kx[None]]     # (n, P, P)
    unit = templates.reshape(n, -1).astype(np.float64)
    unit -= unit.mean(axis=1, keepdims=True)
    unit /= np.linalg.norm(unit, axis=1, keepdims=True) + 1e-9
    across = (kx.ravel() * sx).astype(np.float32)
    down = (ky.ravel() * sy).astype(np.float32)
    best, shift = np.full(n, -2.0), np.zeros((n, 2))
    for dy in range(-search, search + 1):
        for dx in (-1, 0, 1):
            map_x = (start[:, :1] + dx + across).astype(np.float32)
            map_y = (start[:, 1:] + dy + down).astype(np.float32)
            read = _read_patches(left_gray, map_x, map_y, patch, patch)
            read -= read.mean(axis=1, keepdims=True)
            read /= np.linalg.norm(read, axis=1, keepdims=True) + 1e-9
            score = np.sum(read * unit, axis=1)
            better = score > best
            best[better], shift[better] = score[better], (dx, dy)
    strong = best >= MIN_CORRELATION
    if not strong.any():
        return empty
    pts_left = _refine_matches(left_gray, templates[strong].astype(np.float32), start[strong] + shift[strong], sx, sy)
    pts_right = np.stack([p.offset_x + col[strong] * sx, p.offset_y + row[strong] * sy], axis=1).astype(np.float64)
    seen = (pts_left[:, 0] >= 0) & (pts_left[:, 0] <= w - 1) & (pts_left[:, 1] >= 0) & (pts_left[:, 1] <= h - 1)
    return pts_left[seen], pts_right[seen]


def _first_decode(left, samples, rectification):
    """The default decode of the pair rectified by ``rectification``, on its estimated range."""
    from ..decoding._decoders import decode
    from ..decoding._disprange import resolve_range
    from ._rectify import rectify_left, rectify_samples

    left_r, placed = rectify_left(left, rectification), rectify_samples(samples, rectification)
    min_disp, max_disp, _ = resolve_range(left_r, placed)
    return decode(left_r, placed, max_disp=max_disp, min_disp=min_disp).disparity


def _fit_and_judge(pts1, pts2, w, h):
    """The rig fitted on half of the matches and its residual on the other half, or None."""
    fit, held = slice(0, None, 2), slice(1, None, 2)
    found = _refine_rig(pts1[fit], pts2[fit], w, h)
    if found is None:
        return None
    rect, spread = found
    return rect, spread, _row_errors(rect, pts1[held], pts2[held])


def _scale(rect):
    """The rectified frame's focal length over the raw one (below 1: the image shrinks)."""
    return rect.focal / rect.calibration.M1[0, 0]


def self_rectification(left: np.ndarray, samples: SampleSet, *, min_matches: int = MIN_MATCHES,
                       max_residual: float = MAX_RESIDUAL, guide: bool = True):
    """Estimate a rectification of the pair from I1 and the right camera's grid alone.

    Parameters
    ----------
    left : ndarray
        I1 (RGB or gray), as given.
    samples : SampleSet
        A ``grid`` sample set of the right camera.
    min_matches, max_residual
        The refusal thresholds (:data:`MIN_MATCHES`, :data:`MAX_RESIDUAL`).
    guide : bool
        Fit the rig again to :func:`guided_matches` from a decode with the first estimate
        (one decode more; the rows' error over the frame drops by a third at stride 5).

    Returns
    -------
    rectification : Rectification
        With a unit baseline: no metric scale, so no depth can be given.
    report : SelfRectificationReport

    Raises
    ------
    CalibrationError
        Too few reliable matches (a textureless or repetitive scene), or a rectification
        whose vertical residual stays above ``max_residual``.
    """
    import cv2

    h, w = left.shape[:2]
    pts1, pts2 = match_lattice(left, samples)
    candidates = len(pts1)
    if candidates < min_matches:
        _fail(f"too few features match between I1 and the samples ({candidates}, at least {min_matches} needed) to "
              "estimate the epipolar geometry (a textureless or repetitive scene?); give a calibration file")
    f, inliers = cv2.findFundamentalMat(pts1, pts2, cv2.FM_RANSAC, ransacReprojThreshold=1.0,
                                        confidence=0.999, maxIters=5000)
    if f is None or f.shape != (3, 3) or inliers is None:
        _fail(f"no epipolar geometry fits the {candidates} feature matches; give a calibration file")
    keep = inliers.ravel().astype(bool)
    if keep.sum() < min_matches:
        _fail(f"too few reliable matches between I1 and the samples ({int(keep.sum())} of {candidates} agree on an "
              f"epipolar geometry, at least {min_matches} needed); give a calibration file")
    pts1, pts2 = pts1[keep], pts2[keep]
    # The rig is fitted on half of the matches and judged on the other half: eight parameters
    # fit a few hundred matches' rows too easily to trust the fit's own residual.  Residuals
    # are in raw pixels, whatever the scale of the rectified frame.
    found = _fit_and_judge(pts1, pts2, w, h)
    if found is None:
        _fail("no turn of the cameras fits the matches as a left/right pair; give a calibration file")
    rect, spread, residual = found
    if _scale(rect) < MIN_SCALE:
        _fail(f"the estimated rectification would shrink the image {1 / _scale(rect):.1f} times (a pose the matches "
              "do not pin down); give a calibration file")
    matches, guided = len(pts1), False
    if guide:
        # A decode with the first estimate says where every sample's match lies; matched there,
        # the samples cover the frame, and the rig fitted to them no longer extrapolates.
        near1, near2 = guided_matches(left, samples, rect, _first_decode(left, samples, rect))
        found = _fit_and_judge(near1, near2, w, h) if len(near1) >= 2 * min_matches else None
        if found is not None and _scale(found[0]) >= MIN_SCALE:
            (rect, spread, residual), matches, guided = found, len(near1), True
    report = SelfRectificationReport(matches=int(matches), candidates=candidates,
                                     residual_median=float(np.median(residual)),
                                     residual_p90=float(np.percentile(residual, 90)), uncertainty=spread,
                                     guided=guided)
    if report.residual_median > max_residual:
        _fail(f"the estimated rectification leaves a median vertical error of {report.residual_median:.2f} px "
              f"(over {report.matches} matches; at most {max_residual} accepted); give a calibration file")
    return rect, report


def frame_residual(left: np.ndarray, samples: SampleSet, rectification, *, count: int = CHECK_PATCHES) -> float:
    """Median vertical error (raw pixels) that ``rectification`` leaves on this frame's matches.

    A few hundred lattice patches are matched afresh (:func:`match_lattice`) and carried
    through the rectification: what a stream checks its estimate with.  NaN when fewer than
    half of :data:`MIN_MATCHES` patches match (the frame cannot tell).
    """
    pts1, pts2 = match_lattice(left, samples, count=count)
    if len(pts1) < MIN_MATCHES // 2:
        return float("nan")
    return float(np.median(_row_errors(rectification, pts1, pts2)))


class SelfRectifiedStream:
    """The self-rectification of a stream of frames from one camera pair.

    The first frame is estimated (:func:`self_rectification`, a few seconds) and the
    estimate reused.  Every ``check_every`` frames (0: never) the rows are checked on
    fresh matches (:func:`frame_residual`, a fraction of a second); when their median error
    exceeds :data:`CHECK_GROWTH` times the estimate's own and :data:`MAX_RESIDUAL` (a camera
    was knocked), that frame is estimated again.  A frame of another size is estimated
    again too.  A refused first estimate raises; a refused later one keeps the previous
    estimate (and says so in its report's ``kept``).

    Attributes
    ----------
    rectification : Rectification or None
    report : SelfRectificationReport or None
    estimates : int
        Estimates made so far.
    """

    def __init__(self, *, check_every: int = CHECK_EVERY):
        self.check_every = int(check_every)
        self.rectification = None
        self.report = None
        self.estimates = 0
        self._size = None
        self._frames = 0

    def for_frame(self, left: np.ndarray, samples: SampleSet):
        """The rectification for this frame and what was done for it.

        Returns
        -------
        rectification : Rectification
        facts : dict
            :meth:`SelfRectificationReport.summary` of the estimate in use, plus
            ``estimated`` (made on this frame), ``checked_residual_px`` (this frame's check,
            or None) and ``kept`` (a new estimate was refused; the previous one is used).
        """
        import logging

        size = (left.shape[1], left.shape[0])
        facts = {"estimated": False, "checked_residual_px": None, "kept": None}
        if self.rectification is None or size != self._size:
            self.rectification, self.report = self_rectification(left, samples)
            self._size, self.estimates, facts["estimated"] = size, self.estimates + 1, True
        elif self.check_every > 0 and self._frames % self.check_every == 0:
            drift = frame_residual(left, samples, self.rectification)
            facts["checked_residual_px"] = None if np.isnan(drift) else round(drift, 3)
            if drift > max(MAX_RESIDUAL, CHECK_GROWTH * self.report.residual_median):
                try:
                    self.rectification, self.report = self_rectification(left, samples)
                    self.estimates, facts["estimated"] = self.estimates + 1, True
                except CalibrationError as exc:
                    facts["kept"] = exc.message
                    logging.getLogger("stereobudget").warning(
                        "warning: the rows drifted to %.2f px, and estimating them again was refused (%s); "
                        "the previous estimate is kept", drift, exc.message)
        self._frames += 1
        return self.rectification, {**self.report.summary(), **facts}


def _row_errors(rect, pts1, pts2):
    """|vertical error| (n,) of matches after ``rect``, in raw pixels (the rectified frame's
    pixels scaled by the raw focal length over the rectified one)."""
    c = rect.calibration
    a = _project_distorted(pts1, rect.R1, rect.P1, c.M1, c.D1)
    b = _project_distorted(pts2, rect.R2, rect.P2, c.M2, c.D2)
    return np.abs(a[:, 1] - b[:, 1]) * (c.M1[0, 0] / rect.focal)


def _rig_camera(theta, w, h):
    focal = float(np.exp(theta[7]) * w)
    return np.array([[focal, 0, (w - 1) / 2.0], [0, focal, (h - 1) / 2.0], [0, 0, 1]])


def _rig_turns(theta):
    """Each camera's turn from the common rectified orientation.  The left one has no turn
    about the baseline: turning both cameras about it keeps every row (the gauge)."""
    import cv2

    left = cv2.Rodrigues(np.array([0.0, theta[0], theta[1]]))[0]
    right = cv2.Rodrigues(np.asarray(theta[2:5], np.float64))[0]
    return left, right


def _rig_residuals(theta, pts1, pts2, w, h):
    """Vertical error (n,) of matches, in pixels, after undoing each camera's turn and k1."""
    from ._rectify import _undistort
    k = _rig_camera(theta, w, h)
    turn_left, turn_right = _rig_turns(theta)
    a = _undistort(pts1, k, np.array([theta[5], 0, 0, 0, 0]), turn_left.T, k)
    b = _undistort(pts2, k, np.array([theta[6], 0, 0, 0, 0]), turn_right.T, k)
    return a[:, 1] - b[:, 1]


def _rig_jacobian(theta, pts1, pts2, w, h, residuals):
    """d residual / d theta (n, 8), by forward differences."""
    jac = np.empty((len(residuals), len(theta)))
    for i in range(len(theta)):
        step = np.zeros_like(theta)
        step[i] = 1e-6
        jac[:, i] = (_rig_residuals(theta + step, pts1, pts2, w, h) - residuals) / step[i]
    return jac


def _fit_rig(pts1, pts2, w, h, iterations: int = 40):
    """The rig's parameters (8,) fitted to the matches' rows: both cameras turned from one
    rectified orientation (5 angles), a k1 for each lens and a shared focal length, by
    Levenberg-Marquardt from the untouched rig, with Huber weights at 1 px and mild priors on
    the focal length and the k1s.  Returns ``(theta, residuals, priors)``."""
    n = len(pts1)
    theta = np.zeros(8)
    # Priors, one row each: the common pan (the two pans' sum; a pan apart from the other camera's
    # is seen in the rows), each k1, the focal length.
    priors = np.zeros((4, 8))
    priors[0, [0, 3]] = PAN_PRIOR
    priors[1, 5] = priors[2, 6] = 0.5
    priors[3, 7] = 1.0
    priors *= np.sqrt(n)

    def cost(r, th):
        return np.sum(np.minimum(r * r, 2 * np.abs(r) - 1)) + np.sum((priors @ th) ** 2)

    damping = 1e-3
    res = _rig_residuals(theta, pts1, pts2, w, h)
    for _ in range(iterations):
        weights = 1.0 / np.maximum(1.0, np.abs(res))
        jac = _rig_jacobian(theta, pts1, pts2, w, h, res)
        a = np.vstack([jac * np.sqrt(weights)[:, None], priors])
        b = np.r_[-res * np.sqrt(weights), -priors @ theta]
        normal = a.T @ a
        delta = np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-12), a.T @ b)
        candidate = _rig_residuals(theta + delta, pts1, pts2, w, h)
        if cost(candidate, theta + delta) < cost(res, theta):
            theta, res, damping = theta + delta, candidate, damping * 0.3
        else:
            damping *= 10
        if np.max(np.abs(delta)) < 1e-8:
            break
    return theta, res, priors


def _rig_consensus(pts1, pts2, w, h, *, seed: int = 0):
    """The matches that agree with the best of :data:`RIG_HYPOTHESES` rigs, each fitted to
    :data:`RIG_SAMPLE` matches drawn at random (RANSAC on the rig itself).

    A few per cent of the fundamental matrix's inliers are still wrong by a pixel or more
    (repetitive leaves, a road's stripes), and a least-squares fit to all of them, even with
    Huber weights, settles on rows that agree with the wrong ones: rows then drift by pixels
    away from the matches.  A rig fitted to a handful of good matches is right nearly
    everywhere, so the rig that most matches agree with (within :data:`RIG_AGREEMENT` px,
    each scored by how closely, as MSAC does) names the good ones.  The draws are seeded:
    one pair always gives one estimate.
    """
    import cv2

    n = len(pts1)
    if n <= RIG_SAMPLE:
        return np.ones(n, bool)
    rng = np.random.default_rng(seed)
    best, best_score = np.ones(n, bool), -1.0
    for _ in range(RIG_HYPOTHESES):
        pick = rng.choice(n, RIG_SAMPLE, replace=False)
        try:
            theta, _, _ = _fit_rig(pts1[pick], pts2[pick], w, h, iterations=RIG_SAMPLE_ITERATIONS)
        except (cv2.error, np.linalg.LinAlgError):
            continue
        residual = np.abs(_rig_residuals(theta, pts1, pts2, w, h))
        score = float(np.sum(np.maximum(0.0, 1.0 - (residual / RIG_AGREEMENT) ** 2)))
        if score > best_score:
            best_score, best = score, residual < RIG_AGREEMENT
    return best


def _refine_rig(pts1, pts2, w, h):
    """The rig (:func:`_fit_rig`) fitted to the matches that agree with it: the consensus of
    :func:`_rig_consensus`, then the matches that agree with the fit to it.  Returns the
    Rectification and the 90th percentile over the frame of the rows' standard error (raw
    pixels), or None."""
    import cv2

    from ._calibration import StereoCalibration
    from ._rectify import rectify_stereo
    try:
        use = _rig_consensus(pts1, pts2, w, h)
        for _ in range(2):
            if use.sum() < RIG_SAMPLE:
                return None
            theta, _, _ = _fit_rig(pts1[use], pts2[use], w, h)
            use = np.abs(_rig_residuals(theta, pts1, pts2, w, h)) < RIG_AGREEMENT
        if use.sum() < RIG_SAMPLE:
            return None
        pts1, pts2 = pts1[use], pts2[use]
        theta, res, priors = _fit_rig(pts1, pts2, w, h)
        # How far the fitted rows could be off across the frame: the parameters' covariance
        # (the matches' robust spread over the weighted normal equations) carried to a grid
        # of points over the whole frame.  Matches bunched in one textured corner pin the
        # rows down there and nowhere else.
        weights = 1.0 / np.maximum(1.0, np.abs(res))
        jac = _rig_jacobian(theta, pts1, pts2, w, h, res)
        normal = (jac * weights[:, None]).T @ jac + priors.T @ priors
        sigma = 1.4826 * float(np.median(np.abs(res)))
        covariance = sigma * sigma * np.linalg.inv(normal)
        gx, gy = np.meshgrid(np.linspace(0, w - 1, 9), np.linspace(0, h - 1, 7))
        grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
        sensitivity = _rig_jacobian(theta, grid, grid, w, h, _rig_residuals(theta, grid, grid, w, h))
        spread = np.sqrt(np.maximum(np.einsum("ni,ij,nj->n", sensitivity, covariance, sensitivity), 0))
        k = _rig_camera(theta, w, h)
        turn_left, turn_right = _rig_turns(theta)
        # Camera i sees x_i = turn_i x, x in the rectified frame, camera 2 at +x: x2 = R x1 + T.
        rotation = turn_right @ turn_left.T
        t = -turn_right @ np.array([1.0, 0.0, 0.0])
        calibration = StereoCalibration(M1=k, D1=np.array([theta[5], 0, 0, 0, 0]), M2=k.copy(),
                                        D2=np.array([theta[6], 0, 0, 0, 0]), R=rotation, T=t, image_size=(w, h),
                                        source="auto")
        return rectify_stereo(calibration, w, h), float(np.percentile(spread, 90))
    except (cv2.error, np.linalg.LinAlgError, CalibrationError):
        return None


def _project_distorted(points, rotation, projection, camera, distortion):
    import cv2

    return cv2.undistortPoints(np.ascontiguousarray(points, np.float64).reshape(-1, 1, 2), camera, distortion,
                               R=rotation, P=projection).reshape(-1, 2)



__all__ = ["MIN_MATCHES", "MAX_RESIDUAL", "PATCH", "PATCHES", "MIN_TEXTURE", "MIN_CORRELATION", "MIN_MARGIN",
           "CHECK_EVERY", "SelfRectificationReport", "SelfRectifiedStream", "match_lattice", "guided_matches",
           "frame_residual", "self_rectification"]
