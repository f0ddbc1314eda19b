"""Step 2 of recovering I2: the samples as a dense image, to fill the warp's holes.

The samples are the only information the host has about the pixels no left pixel
reaches; :func:`inpaint_from_samples` fills the holes with a low-passed interpolation of
them.  :func:`sample_arrays` gives the samples as the float pipeline takes them.
"""

from __future__ import annotations

import numpy as np

from ..cost._cost import to_float_image
from ..errors import OptionError
from ..io._samples import SampleSet


def sample_arrays(samples: SampleSet):
    """Positions and values of a sample set, ready for the float pipeline.

    Returns
    -------
    rows, cols : ndarray of int64 (n,)
    values : ndarray, float32 (n, C)
        RGB order (or gray), 8-bit units; a raw mosaic gives (n, 3) with NaN in the two
        channels each sample lacks.

    Raises
    ------
    OptionError
        The pattern does not send exact pixels at known positions (``downsample``,
        ``fps``): recovery needs pixel samples.
    """
    try:
        rows, cols = samples.positions()
    except NotImplementedError:
        raise OptionError(f"recovering I2 needs exact pixel samples; pattern {samples.pattern.kind!r} "
                          f"is not supported") from None
    if samples.pattern.kind == "downsample":
        raise OptionError("recovering I2 needs exact pixel samples; 'downsample' sends block means")
    values = to_float_image(samples.values_rgb()[:, None, :])[:, 0, :]
    if samples.mosaic:
        from ..io._mosaic import rgb_with_gaps
        values = rgb_with_gaps(values, samples.sample_colours())
    return np.asarray(rows, np.int64), np.asarray(cols, np.int64), np.ascontiguousarray(values)


def _gap_aware_filter(guide, rows, cols, values, **kwargs):
    """:func:`stereobudget.fill.sparse_joint_bilateral` of values that may hold NaN gaps
    (mosaic samples): each channel normalised by its own samples (0 where none reaches)."""
    from ..fill._grid import sparse_joint_bilateral
    known = ~np.isnan(values)
    if known.all():
        return sparse_joint_bilateral(guide, rows, cols, values, **kwargs)
    n_ch = values.shape[1]
    both = sparse_joint_bilateral(guide, rows, cols, np.concatenate(
        [np.where(known, values, np.float32(0.0)), known.astype(np.float32)], axis=1), **kwargs)
    weight = both[:, :, n_ch:]
    return np.where(weight > 1e-6, both[:, :, :n_ch] / np.maximum(weight, np.float32(1e-6)),
                    np.float32(0.0)).astype(np.float32)


def _stride(samples: SampleSet) -> float:
    return float(np.sqrt(samples.pattern.stride_x * samples.pattern.stride_y))


def interpolate_samples(samples: SampleSet, *, lowpass_sigma: float = 0.0) -> np.ndarray:
    """Dense float32 (H, W, C) image (8-bit units) interpolated from the samples.

    A ``grid`` lattice is resized to full resolution with bilinear interpolation aligned
    on the sample positions (``I2[oy + i sy, ox + j sx]`` is lattice cell ``(i, j)``),
    after an optional Gaussian low-pass of ``lowpass_sigma`` lattice cells; bilinear
    interpolation is itself the anti-aliasing low-pass the paper asks for.  Any other
    pattern uses a normalised spatial Gaussian of the samples (sigma = stride / 2,
    the spread that makes the cells' footprints overlap like bilinear tents).
    """
    import cv2

    p = samples.pattern
    h, w = samples.height, samples.width
    if p.is_regular_grid and not samples.mosaic:
        lattice = to_float_image(samples.grid_values()[:, :, ::-1] if samples.channel_order == "bgr"
                                 else samples.grid_values())
        if lowpass_sigma > 0:
            lattice = cv2.GaussianBlur(lattice, (0, 0), lowpass_sigma, borderType=cv2.BORDER_REFLECT)
            lattice = lattice if lattice.ndim == 3 else lattice[:, :, None]
        map_x = ((np.arange(w, dtype=np.float32) - p.offset_x) / np.float32(p.stride_x))
        map_y = ((np.arange(h, dtype=np.float32) - p.offset_y) / np.float32(p.stride_y))
        map_x, map_y = np.meshgrid(map_x, map_y)
        dense = cv2.remap(np.ascontiguousarray(lattice), map_x, map_y, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
        return np.ascontiguousarray(dense.reshape(h, w, -1), dtype=np.float32)
    rows, cols, values = sample_arrays(samples)
    # A constant guide and a huge range sigma turn the joint bilateral filter into a
    # purely spatial normalised convolution (per channel for a mosaic's samples).
    flat = np.zeros((h, w), np.float32)
    return _gap_aware_filter(flat, rows, cols, values, sigma_s=max(0.5 * _stride(samples), 1.0),
                                  sigma_r=1e4, missing_value=0.0)


def inpaint_from_samples(warped: np.ndarray, holes: np.ndarray, samples: SampleSet, *,
                         lowpass_sigma: float = 0.0) -> np.ndarray:
    """Fill the holes of a warped image with the interpolated samples.

    Parameters
    ----------
    warped : ndarray, float32 (H, W, C)
        Warped estimate, 8-bit units.
    holes : ndarray, bool (H, W)
    samples : SampleSet
    lowpass_sigma : float
        See :func:`interpolate_samples`.

    Returns
    -------
    ndarray, float32 (H, W, C)
        A copy of ``warped`` with every hole pixel taken from the interpolated samples.
    """
    out = np.array(warped, dtype=np.float32, copy=True)
    if holes.any():
        dense = interpolate_samples(samples, lowpass_sigma=lowpass_sigma)
        out[holes] = dense[holes]
    return out


__all__ = ["sample_arrays", "interpolate_samples", "inpaint_from_samples"]
