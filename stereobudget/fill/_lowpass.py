"""Low-passed views of the pair: what the Hybrid and Downsample decoders match densely.

Hybrid matches a low-passed I1 against a low-passed interpolation of the samples
(:func:`lowpass_interpolation`, :func:`gaussian_lowpass`: the same Gaussian spectrum on
both sides); Downsample matches the upsampled block means against I1 passed through the
same box-and-triangle operator (:func:`block_lowpass`, :func:`upsample_block_means`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._kernels._jit import RANGE_KERNEL
from .._kernels._parallel import run_parts

from ..cost._cost import to_float_image
from ..sampling._patterns import grid_shape


def _sample_values_f32(samples) -> np.ndarray:
    """Sample values as float32 (n, C) RGB in 8-bit units.

    A raw-mosaic sample set gives (n, 3): each value in its colour's channel, NaN in the
    other two (:func:`stereobudget.io._mosaic.rgb_with_gaps`), so each sample meets only
    the matching channel of I1.
    """
    values = to_float_image(samples.values_rgb()[:, None, :])[:, 0, :]
    if getattr(samples, "mosaic", None):
        from ..io._mosaic import rgb_with_gaps
        return rgb_with_gaps(values, samples.sample_colours())
    return values


def gaussian_taps(sigma: float) -> np.ndarray:
    """The float32 Gaussian kernel ``cv2.GaussianBlur`` uses for a float image and this sigma.

    OpenCV takes ``round(8 sigma + 1) | 1`` taps (radius ~4 sigma) and normalises them to
    sum 1; the lattice path of :func:`lowpass_interpolation` uses the same taps, so both
    paths compute the same convolution.
    """
    import cv2
    size = int(round(sigma * 8 + 1)) | 1
    return cv2.getGaussianKernel(size, sigma, cv2.CV_32F).ravel().astype(np.float32)


@njit(cache=True, inline="always")
def _first_last_sample(position, radius, offset, stride, count):
    """Indices ``[first, last]`` of the lattice samples within ``radius`` of ``position`` (empty: first > last)."""
    first = max(0, -(-(position - radius - offset) // stride))
    last = min(count - 1, (position + radius - offset) // stride)
    return first, last


@njit(cache=True, **RANGE_KERNEL)
def _lattice_lowpass_x(lattice, offset_x, stride_x, taps, along_x, first, stop):
    """Lattice rows ``[first, stop)`` of the x pass of :func:`_lattice_lowpass` into ``along_x``
    (rows, W * C), zeroed: only the lattice rows carry impulses (1 / stride_y of the image rows)."""
    cols, channels = lattice.shape[1], lattice.shape[2]
    width = along_x.shape[1] // channels
    radius = taps.shape[0] // 2
    for r in range(first, stop):
        row = along_x[r]
        for x in range(width):
            lo, hi = _first_last_sample(x, radius, offset_x, stride_x, cols)
            for j in range(lo, hi + 1):
                tap = taps[offset_x + j * stride_x - x + radius]
                for c in range(channels):
                    row[x * channels + c] += tap * lattice[r, j, c]


@njit(cache=True, **RANGE_KERNEL)
def _lattice_lowpass_y(along_x, cols, offset_y, stride_y, offset_x, stride_x, taps, threshold, out, weight_x, first,
                       stop):
    """Image rows ``[first, stop)`` of :func:`_lattice_lowpass`: the y pass of ``along_x`` and the
    division (``weight_x`` (W,) float32: the range's scratch for the mask's blur along x)."""
    rows = along_x.shape[0]
    width, channels = out.shape[1], out.shape[2]
    radius = taps.shape[0] // 2
    weight_x[:] = 0.0
    for x in range(width):
        lo, hi = _first_last_sample(x, radius, offset_x, stride_x, cols)
        for j in range(lo, hi + 1):
            weight_x[x] += taps[offset_x + j * stride_x - x + radius]
    for y in range(first, stop):
        row = out[y].reshape(width * channels)
        row[:] = 0
        lo, hi = _first_last_sample(y, radius, offset_y, stride_y, rows)
        weight_y = np.float32(0.0)
        for k in range(lo, hi + 1):
            tap = taps[offset_y + k * stride_y - y + radius]
            weight_y += tap
            source = along_x[k]
            for i in range(width * channels):
                row[i] += tap * source[i]
        for x in range(width):
            weight = weight_y * weight_x[x]
            # Unreached pixels (no sample within the kernel) get 0, like the general path.
            scale = np.float32(1.0) / weight if weight > threshold else np.float32(0.0)
            for c in range(channels):
                row[x * channels + c] *= scale


def _lattice_lowpass(lattice, offset_y, stride_y, offset_x, stride_x, taps, threshold, out):
    """Normalised Gaussian convolution of the impulses of a sample lattice, separably.

    ``lattice`` (rows, cols, C) float32 holds the samples of ``[oy::sy, ox::sx]``; ``out``
    (H, W, C) float32 receives the blurred impulses divided by the blurred mask.  The
    mask's blur is ``wy(y) * wx(x)`` (the lattice is a product of two 1-D combs), so only
    the values need the 2-D pass: x along the lattice rows, then y onto every image row.
    """
    rows, cols, channels = lattice.shape
    along_x = np.zeros((rows, out.shape[1] * channels), np.float32)
    run_parts(_lattice_lowpass_x, rows, lattice, offset_x, stride_x, taps, along_x)
    run_parts(_lattice_lowpass_y, out.shape[0], along_x, cols, offset_y, stride_y, offset_x, stride_x, taps,
              threshold, out, scratch=lambda: (np.empty(out.shape[1], np.float32),))
    return out


def lowpass_interpolation(samples, *, sigma: float) -> np.ndarray:
    """Dense low-passed estimate of I2 from its samples: a normalised Gaussian convolution.

    The samples (as impulses) and their mask are blurred with the same Gaussian and
    divided, so interpolation and low-pass are one operation, for any sampling pattern.
    A grid placed in a rectified frame (:class:`stereobudget.geometry.PlacedSamples`) is
    low-passed on its raw lattice and resampled into the frame.
    Pixels with no sample within the kernel's reach (4 sigma) get 0.  A regular grid is
    blurred separably on its lattice (~8x faster than blurring the impulse image; the
    same taps, sums in another order).

    Parameters
    ----------
    samples : stereobudget.io.SampleSet
    sigma : float
        Standard deviation of the Gaussian, pixels.

    Returns
    -------
    ndarray, float32 (H, W, C), 8-bit units
    """
    import cv2
    placed = getattr(samples, "lattice", None)
    if placed is not None and placed.right_map is not None:
        # A grid rectified at the host: low-passed on its raw lattice, where it is a grid,
        # and read into this frame (0 outside the raw image, like any unreached pixel).
        raw = lowpass_interpolation(placed.raw, sigma=sigma)
        dense = cv2.remap(raw, *placed.right_map, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return dense.reshape(samples.height, samples.width, raw.shape[2])
    values = _sample_values_f32(samples)
    if getattr(samples, "mosaic", None):
        return _per_channel_interpolation(samples, values, sigma=sigma)
    height, width = samples.height, samples.width
    channels = values.shape[1]
    sample_count = values.shape[0]
    # The kernel sums to 1, so the mask's blur is ~ the sample density where samples are.
    threshold = np.float32(1e-4 * sample_count / float(height * width))
    pattern = samples.pattern
    if pattern.is_regular_grid and sample_count:
        lattice = values.reshape(grid_shape(pattern, height, width) + (channels,))
        out = np.empty((height, width, channels), np.float32)
        return _lattice_lowpass(lattice, int(pattern.offset_y), int(pattern.stride_y), int(pattern.offset_x),
                                int(pattern.stride_x), gaussian_taps(sigma), threshold, out)
    rows, cols = samples.positions()
    # Channels and mask blurred together: one pass over one interleaved image.
    impulses = np.zeros((height, width, channels + 1), np.float32)
    impulses[rows, cols, :channels] = values
    impulses[rows, cols, channels] = 1.0
    # Zero outside the frame for the values and the mask alike: the border stays unbiased.
    blurred = cv2.GaussianBlur(impulses, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_CONSTANT)
    blurred = blurred.reshape(impulses.shape)
    weight = blurred[..., channels]
    reached = weight > threshold
    # Unreached pixels divide by infinity (-> 0): one plain division, 2x faster than a masked one.
    return blurred[..., :channels] / np.where(reached, weight, np.float32(np.inf))[..., None]


class _ValuesOf:
    """A sample set's positions and pattern with other values (what :func:`lowpass_interpolation` reads)."""

    def __init__(self, samples, values):
        self.height, self.width, self.pattern = samples.height, samples.width, samples.pattern
        self.positions = samples.positions
        self._values = values

    def values_rgb(self):
        return self._values


def _per_channel_interpolation(samples, values, *, sigma):
    """:func:`lowpass_interpolation` of values with NaN gaps (mosaic samples): every channel
    normalised by its own samples, i.e. the values (0 in the gaps) and their masks
    interpolated together and divided.  A channel with no sample within reach is 0."""
    known = ~np.isnan(values)
    stacked = np.concatenate([np.where(known, values, np.float32(0.0)), known.astype(np.float32)], axis=1)
    both = lowpass_interpolation(_ValuesOf(samples, stacked), sigma=sigma)
    channels = values.shape[1]
    weight = both[..., channels:]
    return np.where(weight > np.float32(1e-6), both[..., :channels] / np.maximum(weight, np.float32(1e-6)),
                    np.float32(0.0)).astype(np.float32)


def gaussian_lowpass(image_f32: np.ndarray, *, sigma: float) -> np.ndarray:
    """Gaussian low-pass of a float32 (H, W, C) image, the same spectrum as :func:`lowpass_interpolation`.

    ``cv2.GaussianBlur`` with the taps :func:`gaussian_taps` gives and reflected borders
    (``BORDER_REFLECT``).  A numba filter on both threads took 0.74 ms at 640 x 480 RGB
    against OpenCV's 1.50, but compiled for 5 s on a decode's first run: not worth it.
    """
    import cv2
    image = np.ascontiguousarray(image_f32, dtype=np.float32)
    out = cv2.GaussianBlur(image, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    return out.reshape(image.shape)


def block_lowpass(image_f32: np.ndarray, sx: int, sy: int) -> np.ndarray:
    """Give I1 the spectrum of upsampled block means, without their sampling.

    The camera's block means are a box filter followed by subsampling; bilinear upsampling
    is a triangle filter.  Convolving I1 with the same box and triangle, but never
    subsampling it, matches the spectra while keeping I1 free of aliasing: re-sampling I1
    on the camera's block grid would alias differently from I2 at every disparity that is
    not a multiple of the block size (measured: Downsample at s = 5 falls from 29 % to
    14 % bad pixels, mean of the four Middlebury scenes).
    """
    import cv2

    def kernels(s):
        # A centred box of width s: for even s, s + 1 taps with half weights at the ends
        # (a plain even-length box would shift I1 by half a pixel against I2's block centres).
        box = np.full(s + 1 - s % 2, 1.0 / s, np.float32)
        if s % 2 == 0:
            box[0] = box[-1] = 0.5 / s
        tri = 1.0 - np.abs(np.arange(-s + 1, s, dtype=np.float32)) / s
        return box, (tri / tri.sum()).astype(np.float32)

    box_x, tri_x = kernels(sx)
    box_y, tri_y = kernels(sy)
    out = cv2.sepFilter2D(image_f32, -1, box_x, box_y, borderType=cv2.BORDER_REFLECT)
    out = cv2.sepFilter2D(out, -1, tri_x, tri_y, borderType=cv2.BORDER_REFLECT)
    return out.reshape(image_f32.shape)


def upsample_block_means(low: np.ndarray, sx: int, sy: int, h: int, w: int) -> np.ndarray:
    """Bilinear upsampling of (rows, cols, C) block means to a float32 (h, w, C) image, block centres aligned."""
    import cv2
    rows, cols = low.shape[:2]
    ys = (np.arange(h, dtype=np.float32) - (sy - 1) / 2.0) / sy
    xs = (np.arange(w, dtype=np.float32) - (sx - 1) / 2.0) / sx
    map_x, map_y = np.meshgrid(xs, ys)
    out = cv2.remap(np.ascontiguousarray(low, np.float32), map_x, map_y, interpolation=cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(h, w, low.shape[2])
