"""Eq. (2) at one sample, as every kernel of the Sparse DSI evaluates it: the one place its terms live.

:class:`SparseCostTerms` holds the terms as a caller sets them; :class:`SparseTerms` is the
same as the kernels take it.  A kernel gets what a left pixel brings to the cost once per
pixel (:func:`left_terms`) and the cost against sample ``k`` (:func:`sample_cost`), which
applies :func:`stereobudget.cost.sparse_pair_cost`.  A new term of the sparse cost is added
here: a field of both term records, what each side brings (:class:`LeftPixels` and
:func:`left_terms`, :class:`RightSamples`), and its share in ``sparse_pair_cost``; the splat
kernels that call these do not change.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from ._cost import sparse_pair_cost


@dataclass(frozen=True)
class SparseCostTerms:
    """The terms of Eq. (2)'s cost at a sample (:func:`stereobudget.cost.sparse_pair_cost`).

    Attributes
    ----------
    truncation : float
        Truncation of the colour term (:func:`stereobudget.cost.pixel_cost`); every term is
        brought to ``[0, truncation]``.
    step_weight, step_truncation : float
        Weight (0: off) and truncation (gray levels) of the step term, the gray difference
        to the sample ``step_spacing`` pixels to the right.
    step_spacing : int
        Column spacing of the steps (the grid stride).
    census_weight : float
        Weight of the lattice census (0: off).
    census_spacing : (int, int), optional
        ``(stride_x, stride_y)`` of a regular sample grid whose samples arrive row by row;
        ``None`` (not a regular grid) turns the lattice census off.
    """

    truncation: float
    step_weight: float = 0.0
    step_truncation: float = 5.0
    step_spacing: int = 1
    census_weight: float = 0.0
    census_spacing: tuple[int, int] | None = None

    def kernel_terms(self) -> "SparseTerms":
        """These terms as the kernels take them."""
        return SparseTerms(np.float32(self.truncation), int(self.step_spacing), np.float32(self.step_weight),
                           np.float32(self.step_truncation), np.float32(self.census_weight))


class SparseTerms(NamedTuple):
    """Eq. (2)'s terms as the kernels take them (:meth:`SparseCostTerms.kernel_terms`)."""

    truncation: np.float32
    step_spacing: int
    step_weight: np.float32
    step_truncation: np.float32
    census_weight: np.float32


class RightSamples(NamedTuple):
    """What the splat kernels read of the right samples, one row per sample."""

    values: np.ndarray  # float32 (K, C), 8-bit units
    steps: np.ndarray   # float32 (K,), difference to the next sample of the row (NaN: none)
    codes: np.ndarray   # int64 (K,), lattice census code (-1: no census term)
    offsets: np.ndarray  # float32 (K, 2) or (0, 2): (dy, dx) of the true position from (row, col)


class LeftPixels(NamedTuple):
    """What the splat kernels read of I1."""

    image: np.ndarray   # float32 (H, W, C), 8-bit units
    guide: np.ndarray   # float32 (H, W), its gray image
    codes: np.ndarray   # uint8 (H, W), lattice census code


@njit(cache=True, inline="always")
def left_step(guide, y, x, step_spacing, step_weight):
    """I1's gray difference over the sample spacing at (y, x) (NaN: no step term or no neighbour)."""
    if step_weight > 0 and x + step_spacing < guide.shape[1]:
        return guide[y, x + step_spacing] - guide[y, x]
    return np.float32(np.nan)


@njit(cache=True, inline="always")
def left_terms(pixels, y, x, terms):
    """What left pixel (y, x) brings to Eq. (2) against any sample: its colour, step and census code.

    ``pixels``: :class:`LeftPixels`; ``terms``: :class:`SparseTerms`.  A kernel that meets
    several samples at one pixel computes this once.
    """
    return pixels.image[y, x], left_step(pixels.guide, y, x, terms.step_spacing, terms.step_weight), \
        pixels.codes[y, x]


@njit(cache=True, inline="always")
def bilinear_at(image, y, x, h, w, out):
    """``image`` (H, W, C) at the real position (y, x), bilinear, clamped to the image; into ``out`` (C,)."""
    y = min(max(y, 0.0), h - 1.0)
    x = min(max(x, 0.0), w - 1.0)
    y0 = min(int(y), h - 2) if h > 1 else 0
    x0 = min(int(x), w - 2) if w > 1 else 0
    ty = y - y0
    tx = x - x0
    y1 = min(y0 + 1, h - 1)
    x1 = min(x0 + 1, w - 1)
    for c in range(out.shape[0]):
        top = image[y0, x0, c] * (1 - tx) + image[y0, x1, c] * tx
        bottom = image[y1, x0, c] * (1 - tx) + image[y1, x1, c] * tx
        out[c] = top * (1 - ty) + bottom * ty


@njit(cache=True, inline="always")
def left_terms_at(pixels, y, x, dy, dx, terms, out):
    """:func:`left_terms` for a sample whose true position is ``(y + dy, x + dx)`` (a sample placed
    off the pixel grid): I1's colour read there, bilinear, into ``out`` (C,); the step and the
    census code stay those of pixel (y, x)."""
    bilinear_at(pixels.image, y + dy, x + dx, pixels.image.shape[0], pixels.image.shape[1], out)
    return out, left_step(pixels.guide, y, x, terms.step_spacing, terms.step_weight), pixels.codes[y, x]


@njit(cache=True, inline="always")
def sample_cost(at_left, samples, k, terms):
    """Eq. (2) between a left pixel (:func:`left_terms`) and right sample ``k`` of ``samples``
    (:class:`RightSamples`) with ``terms`` (:class:`SparseTerms`)."""
    left_pixel, step, code = at_left
    return sparse_pair_cost(left_pixel, samples.values[k], step, samples.steps[k], terms.truncation,
                            terms.step_weight, terms.step_truncation, code, samples.codes[k],
                            terms.census_weight)


__all__ = ["SparseCostTerms", "SparseTerms", "RightSamples", "LeftPixels", "left_step", "left_terms",
           "left_terms_at", "bilinear_at", "sample_cost"]
