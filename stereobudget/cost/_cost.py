"""Matching cost: the paper's Eq. (1) (full DSI) and Eq. (2) (sparse DSI).

Costs are in 8-bit intensity units whatever the input bit depth (uint16 inputs are
scaled by 1/257 once, in :func:`to_float_image`), so every threshold and sigma in the
library means the same thing for 8- and 16-bit data.

Volumes are float32 with shape (H, W, D), disparity contiguous: that is the layout the
tree aggregation walks and the bilateral grid slices, so it is used everywhere.
Disparity ``d`` of layer ``i`` is ``min_disp + i``; left pixel ``x`` matches right
pixel ``x - d``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL
from .._kernels._parallel import run_parts
from ._census import popcount32

#: Default truncation of the absolute-difference cost (8-bit units). Truncation bounds
#: the influence of occluded and specular pixels on the aggregated cost.
DEFAULT_TRUNCATION = 15.0


def to_float_image(image: np.ndarray) -> np.ndarray:
    """Convert a uint8/uint16 image to float32 (H, W, C) in 8-bit units (0..255).

    This is the one place where input bit depth is normalised.
    """
    img = image if image.ndim == 3 else image[:, :, None]
    if img.dtype == np.uint16:
        return (img.astype(np.float32) * np.float32(1.0 / 257.0))
    if img.dtype == np.uint8:
        return img.astype(np.float32)
    return np.ascontiguousarray(img, dtype=np.float32)


#: Rec. 601 luma weights of R, G and B, float32: every gray image of the library sums
#: ``red * R + green * G + blue * B`` with them, in that order (numpy's and the kernels' alike).
LUMA_WEIGHTS = (np.float32(0.299), np.float32(0.587), np.float32(0.114))


def to_gray(image_f32: np.ndarray) -> np.ndarray:
    """Luma (Rec. 601) of a float32 (H, W, C) RGB image; a one-channel image is returned as (H, W)."""
    if image_f32.shape[2] == 1:
        return np.ascontiguousarray(image_f32[:, :, 0])
    if image_f32.dtype == np.float32:
        h, w = image_f32.shape[:2]
        gray = np.empty((h, w), dtype=np.float32)
        run_parts(_luma_rows, h, image_f32, gray)
        return gray
    red, green, blue = LUMA_WEIGHTS
    r, g, b = image_f32[:, :, 0], image_f32[:, :, 1], image_f32[:, :, 2]
    return (red * r + green * g + blue * b).astype(np.float32)


@njit(cache=True, **RANGE_KERNEL)
def _luma_rows(image, out, first, stop):
    """Rows ``[first, stop)`` of :func:`to_gray` of float32 RGB, on every thread: the same
    float32 products and sums, in numpy's order, so the same values (numpy's three passes
    over strided channels took 0.6 ms on Teddy, five times per decode)."""
    w = image.shape[1]
    red, green, blue = LUMA_WEIGHTS
    for y in range(first, stop):
        for x in range(w):
            out[y, x] = red * image[y, x, 0] + green * image[y, x, 1] + blue * image[y, x, 2]


def float_and_gray(image: np.ndarray) -> tuple:
    """``(to_float_image(image), to_gray(to_float_image(image)))`` with the same values,
    for an 8-bit RGB image in one pass on both threads (numpy's conversion alone took
    0.3 ms of each Teddy decode, on one thread); other images the two calls' way."""
    if image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3:
        h, w = image.shape[:2]
        image_f32, gray = np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32)
        run_parts(_float_and_luma_u8_rows, h, np.ascontiguousarray(image), image_f32, gray)
        return image_f32, gray
    image_f32 = to_float_image(image)
    return image_f32, to_gray(image_f32)


@njit(cache=True, **RANGE_KERNEL)
def _float_and_luma_u8_rows(image, out, gray, first, stop):
    red, green, blue = LUMA_WEIGHTS
    for y in range(first, stop):
        for x in range(image.shape[1]):
            r, g, b = np.float32(image[y, x, 0]), np.float32(image[y, x, 1]), np.float32(image[y, x, 2])
            out[y, x, 0], out[y, x, 1], out[y, x, 2] = r, g, b
            gray[y, x] = red * r + green * g + blue * b


@njit(cache=True, inline="always")
def pixel_cost(left_pixel, right_pixel, truncation):
    """Eq. (2) of the paper for one pixel pair: mean absolute channel difference, truncated.

    The paper's ``max(|I1 - I2|, delta)`` only marks "a sample exists"; the library keeps an
    explicit sample mask instead, so no delta is needed here.

    A NaN channel of ``right_pixel`` is not compared: a raw-mosaic sample carries one colour
    (:func:`stereobudget.io._mosaic.rgb_with_gaps`), so it meets only that channel of I1.
    """
    acc = np.float32(0.0)
    compared = 0
    for c in range(left_pixel.shape[0]):
        r = right_pixel[c]
        if r == r:
            acc += abs(left_pixel[c] - r)
            compared += 1
    acc /= compared
    return min(acc, truncation)


@njit(cache=True, inline="always")
def sparse_pair_cost(left_pixel, right_pixel, left_step, right_step, truncation, step_weight, step_truncation,
                     left_code=0, right_code=-1, census_weight=0.0):
    """Eq. (2) with the terms that sparse samples still support: a step and a lattice census.

    Two samples ``s`` pixels apart on a row of I2 give the difference
    ``right_step = I2(x + s) - I2(x)`` exactly; I1 gives ``left_step`` over the same
    spacing.  Comparing them is Yang's gradient term at the sampling scale, and it is
    free of aliasing because both sides measure the same quantity.  Both terms are
    brought to ``[0, truncation]`` before mixing; where no step exists (NaN: last sample
    of a row, non-grid patterns) the colour term is used alone.

    The lattice census (:func:`stereobudget.cost.lattice_census`) compares the order of a
    sample against its 8 grid neighbours with the order of I1's pixels at the same
    spacing: it survives a gain or exposure difference between the cameras, which the
    colour term reads as a mismatch.  Its 0-8 differing bits are scaled to
    ``[0, truncation]`` and mixed in with ``census_weight`` (``right_code`` < 0: none).
    """
    colour = pixel_cost(left_pixel, right_pixel, truncation)
    if step_weight > 0 and not (np.isnan(left_step) or np.isnan(right_step)):
        step = min(abs(left_step - right_step), step_truncation) * (truncation / step_truncation)
        colour = (1 - step_weight) * colour + step_weight * step
    if census_weight > 0 and right_code >= 0:
        bits = popcount32(np.uint32(left_code) ^ np.uint32(right_code))
        colour = (1 - census_weight) * colour + census_weight * (bits * (truncation / 8))
    return colour


def sample_row_steps(lattice_gray: np.ndarray) -> np.ndarray:
    """``I2(x + s) - I2(x)`` between row neighbours of a (rows, cols) sample lattice; NaN in the last column."""
    steps = np.full(lattice_gray.shape, np.nan, np.float32)
    steps[:, :-1] = lattice_gray[:, 1:] - lattice_gray[:, :-1]
    return steps


@njit(cache=True, inline="always")
def reversed_right_row(right, right_gray, y, first_column, use_grad, rev):
    """Fill ``rev`` (C + 1, span) with row ``y`` of I2 and its gradient (:func:`gradient_at`
    of ``right_gray``), reversed, for :func:`dense_pixel_costs`.

    Column ``k`` holds I2 column ``first_column + span - 1 - k`` clamped to the border
    (standard practice outside the image), so the layers of a pixel read it forwards
    without branches and the loops over layers vectorise.
    """
    w = right.shape[1]
    channels = right.shape[2]
    span = rev.shape[1]
    for k in range(span):
        xr = first_column + span - 1 - k
        if xr < 0:
            xr = 0
        elif xr >= w:
            xr = w - 1
        for ch in range(channels):
            rev[ch, k] = right[y, xr, ch]
        rev[channels, k] = gradient_at(right_gray, y, xr) if use_grad else np.float32(0.0)


@njit(cache=True, inline="always")
def dense_pixel_costs(left, left_gray, y, x, rev, min_disp, first_column, truncation, grad_truncation,
                      grad_weight, acc):
    """Eq. (1) for left pixel (y, x) at every layer: ``acc[i]`` = cost against I2 column ``x - min_disp - i``.

    The colour term is the mean absolute channel difference truncated at ``truncation``;
    with ``grad_weight > 0`` it is mixed with the truncated x-gradient difference,
    ``(1 - alpha) * colour + alpha * gradient`` (Yang).  float32 throughout: the same sum
    as :func:`pixel_cost`, channels added in order.  ``rev`` is the row made by
    :func:`reversed_right_row`.
    """
    num_disp = acc.shape[0]
    channels = left.shape[2]
    inv_channels = np.float32(1.0 / channels)
    colour_weight = np.float32(1.0) - grad_weight
    span = rev.shape[1]
    # Layer i reads I2 column x - min_disp - i, i.e. rev index start + i.
    start = span - 1 - (x - min_disp - first_column)
    # Slices, not rev[ch, start + i]: numba wraps negative indices, and that check on a
    # computed index keeps LLVM from vectorising the loops (measured 5x slower).
    if channels == 3:
        # RGB: the three channel terms summed in registers, one pass instead of three
        # (the same additions in the same order).
        red, green, blue = left[y, x, 0], left[y, x, 1], left[y, x, 2]
        row_r = rev[0, start:start + num_disp]
        row_g = rev[1, start:start + num_disp]
        row_b = rev[2, start:start + num_disp]
        for i in range(num_disp):
            acc[i] = abs(red - row_r[i]) + abs(green - row_g[i]) + abs(blue - row_b[i])
    else:
        lp = left[y, x, 0]
        row = rev[0, start:start + num_disp]
        for i in range(num_disp):
            acc[i] = abs(lp - row[i])
        for ch in range(1, channels):
            lp = left[y, x, ch]
            row = rev[ch, start:start + num_disp]
            for i in range(num_disp):
                acc[i] += abs(lp - row[i])
    if grad_weight > 0:
        lg = gradient_at(left_gray, y, x)
        grad = rev[channels, start:start + num_disp]
        for i in range(num_disp):
            g = min(abs(lg - grad[i]), grad_truncation)
            acc[i] = colour_weight * min(acc[i] * inv_channels, truncation) + grad_weight * g
    else:
        for i in range(num_disp):
            acc[i] = min(acc[i] * inv_channels, truncation)


@njit(cache=True, **RANGE_KERNEL)
def _full_dsi_rows(left, right, left_gray, right_gray, min_disp, num_disp, truncation, grad_truncation, grad_weight,
                   out, rev, first, stop):
    """Rows ``[first, stop)`` of :func:`full_dsi` into ``out``; ``rev`` (C + 1, span) float32 is the
    range's scratch (:func:`reversed_right_row`)."""
    w = left.shape[1]
    use_grad = grad_weight > 0
    first_column = -(min_disp + num_disp - 1)
    for y in range(first, stop):
        reversed_right_row(right, right_gray, y, first_column, use_grad, rev)
        for x in range(w):
            dense_pixel_costs(left, left_gray, y, x, rev, min_disp, first_column, truncation, grad_truncation,
                              grad_weight, out[y, x])


def horizontal_gradient(gray: np.ndarray) -> np.ndarray:
    """Central-difference x-gradient of a float32 (H, W) image, in intensity units per pixel:
    ``0.5 * (I(x + 1) - I(x - 1))`` in float32, 0 in the first and last column (the cost
    kernels take it pixel by pixel with :func:`gradient_at`)."""
    g = np.zeros_like(gray)
    g[:, 1:-1] = 0.5 * (gray[:, 2:] - gray[:, :-2])
    return g


@njit(cache=True, inline="always")
def gradient_at(gray, y, x):
    """:func:`horizontal_gradient` of ``gray`` at (y, x), the same float32 value: computed
    where the cost kernels need it instead of as an image of its own (one pass and, for a
    single-shot decode, one compiled kernel fewer)."""
    w = gray.shape[1]
    if x <= 0 or x >= w - 1:
        return np.float32(0.0)
    return np.float32(0.5) * (gray[y, x + 1] - gray[y, x - 1])


def gradient_sources(left: np.ndarray, right: np.ndarray, grad_weight: float) -> tuple:
    """The gray images the cost kernels take the x-gradients from (:func:`gradient_at`), or
    (1, 1) placeholders when the gradient term is off (``grad_weight <= 0``)."""
    if grad_weight > 0:
        return to_gray(left), to_gray(right)
    placeholder = np.zeros((1, 1), np.float32)
    return placeholder, placeholder


def full_dsi(left: np.ndarray, right: np.ndarray, *, min_disp: int, num_disp: int,
             truncation: float = DEFAULT_TRUNCATION, grad_weight: float = 0.0,
             grad_truncation: float = 2.0) -> np.ndarray:
    """Full disparity-space image, Eq. (1): ``C(x, y, d) = cost(I1(x, y), I2(x - d, y))``.

    Parameters
    ----------
    left, right : ndarray, float32 (H, W, C)
        Images in 8-bit units (see :func:`to_float_image`).
    min_disp, num_disp : int
        Layer ``i`` holds disparity ``min_disp + i``.
    truncation : float
        Truncation of the absolute colour difference.
    grad_weight : float
        Weight ``alpha`` of the truncated x-gradient difference (0 disables it), as in
        Yang's non-local method: ``(1 - alpha) * colour + alpha * gradient``.
    grad_truncation : float
        Truncation of the gradient term.

    Returns
    -------
    ndarray, float32 (H, W, num_disp)

    See Also
    --------
    stereobudget.aggregate.pair_cost_rows : the same costs, with the right view's, in tree layouts.
    """
    h, w, _ = left.shape
    out = np.empty((h, w, num_disp), dtype=np.float32)
    lg, rg = gradient_sources(left, right, grad_weight)
    run_parts(_full_dsi_rows, h, np.ascontiguousarray(left, np.float32), np.ascontiguousarray(right, np.float32),
              lg, rg, int(min_disp), int(num_disp), np.float32(truncation),
              np.float32(grad_truncation), np.float32(grad_weight), out,
              scratch=lambda: (np.empty((left.shape[2] + 1, w + num_disp - 1), dtype=np.float32),))
    return out


def noise_level(image_f32: np.ndarray, *, block: int = 8, percentile: float = 20.0) -> float:
    """Noise standard deviation of an image (gray levels), robust to texture.

    Immerkaer's estimator (the mean absolute response of the Laplacian-difference mask
    ``[[1,-2,1],[-2,4,-2],[1,-2,1]]`` times sqrt(pi/2)/6) measures noise plus texture;
    taking it per ``block x block`` tile and keeping a low percentile of the tiles reads
    it where the image is flattest, so texture barely inflates it.

    Parameters
    ----------
    image_f32 : ndarray, float32 (H, W, C)
        Image in 8-bit units (see :func:`to_float_image`).

    Returns
    -------
    float
    """
    return noise_level_of_gray(to_gray(image_f32), block=block, percentile=percentile)


def noise_level_of_gray(gray: np.ndarray, *, block: int = 8, percentile: float = 20.0) -> float:
    """:func:`noise_level` of an image already converted to gray (float32 (H, W), :func:`to_gray`)."""
    import cv2
    h, w = gray.shape
    if h < 3 * block or w < 3 * block:
        return 0.0
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    response = cv2.filter2D(gray, -1, kernel, borderType=cv2.BORDER_REFLECT)
    np.abs(response, out=response)
    rows, cols = h // block, w // block
    # The tile means by OpenCV's area resampling, which averages whole blocks at an integer
    # factor, rather than numpy's mean over two strided axes: the whole estimate takes a
    # third of the time (Teddy 0.56 -> 0.19 ms); the means differ in their last bits.
    tiles = cv2.resize(response[: rows * block, : cols * block], (cols, rows), interpolation=cv2.INTER_AREA)
    return float(np.sqrt(np.pi / 2.0) / 6.0 * np.percentile(tiles, percentile))
