"""Recovering the right image I2 at the host (paper, section "Recovering I2").

Three steps, each a pure function on arrays:

1. :func:`warp_left_to_right` (``_warp.py``) -- forward-warp I1 with the decoded left-view disparity
   into the right view (left ``(x, y)`` lands on right ``(x - d, y)``), nearer surfaces
   winning through a z-buffer.  Right pixels no left pixel reaches are *holes*
   (occlusions, the strip beyond I1's field of view, invalid disparities).
2. :func:`inpaint_from_samples` (``_inpaint.py``) -- fill the holes with a low-passed interpolation of the
   right camera's samples (the only information the host has about those pixels).
3. :func:`enhance_with_samples` (``_enhance.py``) -- the samples are exact pixels of I2: spread the sparse
   difference ``sample - warped`` with a joint bilateral filter guided by the estimate and
   add it in the non-occluded area, then write every sample back verbatim (clamped into
   its interval when low bits were dropped; not at all after a lossy codec).

:func:`recover_right` chains them for one left image + sample set + disparity map, with
the settings of every step in one :class:`SynthesisParams` (what ``sb-decode --right``
records beside a batch's outputs).  A
``downsample`` file sends block means instead of pixels; :func:`recover_right_from_block_means`
replaces steps 2-3 by upsampled means in the holes and a block-mean back-projection.

Working images are float32 ``(H, W, C)`` in 8-bit units (0..255) whatever the input bit
depth (see :func:`stereobudget.cost.to_float_image`); the result is converted back to
the input's dtype and channel layout at the very end.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..io._samples import SampleSet
from ..cost._cost import to_float_image
from ..errors import MismatchError, OptionError
from ._enhance import DEFAULT_ENHANCE_SHRINKAGE, DEFAULT_ENHANCE_SIGMA_R, enhance_with_samples
from ._inpaint import inpaint_from_samples, sample_arrays
from ._warp import DEFAULT_WARP_MODE, DEFAULT_Z_TOLERANCE, WARP_MODES, warp_left_to_right

#: Back-projection rounds of the block-mean recovery (see :func:`recover_right_from_block_means`).
BLOCK_MEAN_ITERATIONS = 3


@dataclass(frozen=True)
class SynthesisParams:
    """The settings of every step of recovering Î2 (defaults: measured, see each step).

    Attributes
    ----------
    warp_mode : {"linear", "splat", "nearest"}
        Forward-warp rule (:func:`warp_left_to_right`).
    z_tolerance : float
        Disparities within this many pixels blend on one right pixel; a larger difference
        is two surfaces, and the nearer wins (:func:`warp_left_to_right`).
    inpaint_lowpass_sigma : float
        Low-pass of the samples' interpolation that fills the holes, pixels
        (:func:`interpolate_samples`; 0: none).
    enhance : bool
        Correct the warp with the samples (:func:`enhance_with_samples`); for a
        ``downsample`` file, the block-mean back-projection.
    enhance_sigma_s : float or None
        Spatial sigma of the enhancement, pixels; None: one sampling stride.
    enhance_sigma_r : float
        Range sigma of the enhancement, 8-bit units.
    enhance_shrinkage : float or None
        Wiener shrinkage of the enhancement, in samples; None: the paper's unshrunk correction.
    reinsert_samples : bool
        Write the samples back at their positions (verbatim when exact, clamped into their
        interval when low bits were dropped, not after a lossy codec).
    block_mean_iterations : int
        Back-projection rounds for a ``downsample`` file.
    """

    warp_mode: str = DEFAULT_WARP_MODE
    z_tolerance: float = DEFAULT_Z_TOLERANCE
    inpaint_lowpass_sigma: float = 0.0
    enhance: bool = True
    enhance_sigma_s: float | None = None
    enhance_sigma_r: float = DEFAULT_ENHANCE_SIGMA_R
    enhance_shrinkage: float | None = DEFAULT_ENHANCE_SHRINKAGE
    reinsert_samples: bool = True
    block_mean_iterations: int = BLOCK_MEAN_ITERATIONS

    def __post_init__(self):
        if self.warp_mode not in WARP_MODES:
            raise OptionError(f"unknown warp mode {self.warp_mode!r}; expected one of {', '.join(WARP_MODES)}")


@dataclass
class RecoveredRight:
    """Output of :func:`recover_right`.

    Attributes
    ----------
    image : ndarray, (H, W) or (H, W, C), the input's dtype (uint8/uint16)
        The recovered right image Î2, RGB (or gray) like the left input.
    holes : ndarray, bool (H, W)
        Right pixels the warp did not reach (filled by inpainting).
    psnr_at_samples_before_enhancement : float
        PSNR (dB, peak of the dtype) of warp + inpaint against the samples, at the sample
        positions.  The samples are the only truth a host has, and this estimate has not
        used them yet (except through the disparity and in holes), so it is an honest
        measure of the warp.
    psnr_at_samples_before_reinsertion : float
        The same for the final estimate just before the samples are written back
        (after enhancement when it ran).  The enhancement fits the samples, so this one is
        optimistic; after reinsertion it would be infinite.
    timings : dict
        Seconds per stage.
    """

    image: np.ndarray
    holes: np.ndarray
    psnr_at_samples_before_enhancement: float
    psnr_at_samples_before_reinsertion: float
    timings: dict = field(default_factory=dict)


def _psnr_8bit(estimate_at_samples: np.ndarray, values: np.ndarray) -> float:
    diff = estimate_at_samples.astype(np.float64) - values.astype(np.float64)
    # NaN: channels a mosaic sample does not carry.
    mse = float(np.nanmean(diff * diff)) if diff.size else math.nan
    if math.isnan(mse):
        return math.nan
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0 ** 2 / mse)


def _to_dtype(image_f32: np.ndarray, dtype) -> np.ndarray:
    if dtype == np.uint16:
        return np.clip(np.rint(image_f32 * np.float32(257.0)), 0, 65535).astype(np.uint16)
    return np.clip(np.rint(image_f32), 0, 255).astype(np.uint8)


def check_recovery_inputs(left: np.ndarray, disparity: np.ndarray, samples: SampleSet) -> None:
    """Raise :class:`MismatchError` when I1, the disparity map and the samples disagree."""
    h, w = left.shape[:2]
    c = 1 if left.ndim == 2 else left.shape[2]
    if (h, w) != (samples.height, samples.width):
        raise MismatchError(f"left image is {w}x{h} but the samples are of a "
                            f"{samples.width}x{samples.height} image")
    if c != samples.colour_channels:
        raise MismatchError(f"left image has {c} channel(s) but the samples have {samples.channels}"
                            + (" (a raw mosaic: compared with an RGB left image)" if samples.mosaic else ""))
    if left.dtype != samples.dtype:
        raise MismatchError(f"left image is {left.dtype} but the samples are {samples.dtype}")
    if np.shape(disparity) != (h, w):
        raise MismatchError(f"disparity is {np.shape(disparity)[1]}x{np.shape(disparity)[0]} but the "
                            f"left image is {w}x{h}")




def _block_means_f32(image: np.ndarray, sx: int, sy: int) -> np.ndarray:
    """Float32 (rows, cols, C) means of ``image`` over the ``downsample`` pattern's blocks
    (the last block row / column averages only its own pixels, as the camera does)."""
    h, w = image.shape[:2]
    starts_y = np.arange(0, h, sy)
    starts_x = np.arange(0, w, sx)
    sums = np.add.reduceat(np.add.reduceat(image.astype(np.float64), starts_y, axis=0), starts_x, axis=1)
    counts = np.minimum(sy, h - starts_y)[:, None, None] * np.minimum(sx, w - starts_x)[None, :, None]
    return (sums / counts).astype(np.float32)


def _psnr_of_blocks(estimate: np.ndarray, sent: np.ndarray, sx: int, sy: int) -> float:
    return _psnr_8bit(_block_means_f32(estimate, sx, sy).reshape(-1, sent.shape[2]), sent.reshape(-1, sent.shape[2]))


def recover_right_from_block_means(left: np.ndarray, disparity: np.ndarray, samples: SampleSet, *,
                                   params: SynthesisParams | None = None) -> RecoveredRight:
    """Recover Î2 from I1, the disparity and a ``downsample`` sample file (block means of I2).

    The warp of I1 gives the detail; holes take the bilinearly upsampled block means.
    The enhancement is a back-projection: each round adds the upsampled difference
    between the sent block means and the estimate's own block means, so the estimate
    converges to an image whose block means are the camera's (the only truth the host
    has) while keeping the warp's detail inside the blocks.

    Parameters
    ----------
    left, disparity, samples
        As :func:`recover_right`; ``samples`` must use the ``downsample`` pattern.
    params : SynthesisParams, optional
        ``warp_mode``, ``z_tolerance``, ``enhance`` (run the back-projection) and
        ``block_mean_iterations`` apply.

    Returns
    -------
    RecoveredRight
        The two PSNR fields compare the estimate's block means with the sent ones.
    """
    from ..fill._lowpass import upsample_block_means
    params = params or SynthesisParams()
    check_recovery_inputs(left, disparity, samples)
    if samples.pattern.kind != "downsample":
        raise OptionError(f"block-mean recovery needs a 'downsample' sample file, not {samples.pattern.kind!r}")
    sx, sy = samples.pattern.stride_x, samples.pattern.stride_y
    h, w = left.shape[:2]
    rows, cols = -(-h // sy), -(-w // sx)
    sent = to_float_image(samples.values_rgb()[:, None, :])[:, 0, :].reshape(rows, cols, -1)
    timings = {}
    t0 = time.perf_counter()
    warped, holes = warp_left_to_right(left, disparity, mode=params.warp_mode, z_tolerance=params.z_tolerance)
    timings["warp"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    estimate = np.array(warped, dtype=np.float32, copy=True)
    if holes.any():
        estimate[holes] = upsample_block_means(sent, sx, sy, h, w)[holes]
    timings["inpaint"] = time.perf_counter() - t0
    psnr_before_enhancement = _psnr_of_blocks(estimate, sent, sx, sy)
    if params.enhance:
        t0 = time.perf_counter()
        for _ in range(int(params.block_mean_iterations)):
            estimate += upsample_block_means(sent - _block_means_f32(estimate, sx, sy), sx, sy, h, w)
            np.clip(estimate, 0.0, 255.0, out=estimate)
        timings["enhance"] = time.perf_counter() - t0
    psnr_after = _psnr_of_blocks(estimate, sent, sx, sy)
    image = _to_dtype(estimate, left.dtype)
    if left.ndim == 2:
        image = image[:, :, 0]
    return RecoveredRight(image=image, holes=holes, psnr_at_samples_before_enhancement=psnr_before_enhancement,
                          psnr_at_samples_before_reinsertion=psnr_after, timings=timings)


def _reinsert(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, samples: SampleSet) -> None:
    """Write what the samples say about their pixels into ``image`` (same dtype, RGB order).

    Exact samples are the pixels: written verbatim.  With ``value_bits`` < full depth the
    true pixel lies in ``[v & ~mask, v | mask]`` (``mask`` = the dropped bits), so the
    estimate is clamped into that interval -- never further from the truth than either.
    A lossy codec gives no such bound: the estimate, already pulled towards the decoded
    values by the enhancement, is kept.
    """
    # A mosaic sample is its pixel's value in one colour: only that channel is written.
    channel = samples.sample_colours() if samples.mosaic else slice(None)
    if samples.exact:
        image[rows, cols, channel] = samples.values_rgb()[:, 0] if samples.mosaic else samples.values_rgb()
        return
    if samples.lossy:
        return
    full = 8 * samples.values.dtype.itemsize
    mask = (1 << (full - samples.value_bits)) - 1
    values = samples.values_rgb()[:, 0] if samples.mosaic else samples.values_rgb()
    low = values & ~values.dtype.type(mask)
    image[rows, cols, channel] = np.clip(image[rows, cols, channel], low, low | values.dtype.type(mask))


def recover_right(left: np.ndarray, disparity: np.ndarray, samples: SampleSet, *,
                  params: SynthesisParams | None = None) -> RecoveredRight:
    """Recover the right image Î2 from I1, the left-view disparity and the right samples.

    Parameters
    ----------
    left : ndarray, (H, W) or (H, W, C), uint8 or uint16
        I1, RGB or gray (the library's convention).
    disparity : ndarray, float (H, W)
        Left-view disparity, NaN = invalid; use the decoder's output
        (:func:`stereobudget.decode`).
    samples : SampleSet
        What the right camera sent (any channel order; ``bgr`` is handled).
    params : SynthesisParams, optional
        The settings of the warp, the inpainting, the enhancement and the reinsertion of
        the samples (default: :class:`SynthesisParams()`).

    Returns
    -------
    RecoveredRight

    Notes
    -----
    A ``downsample`` file carries block means, not pixels: it is recovered by
    :func:`recover_right_from_block_means` (the reinsertion and the enhancement sigmas do
    not apply).
    """
    params = params or SynthesisParams()
    check_recovery_inputs(left, disparity, samples)
    if samples.pattern.kind == "downsample":
        return recover_right_from_block_means(left, disparity, samples, params=params)
    timings = {}
    t0 = time.perf_counter()
    warped, holes = warp_left_to_right(left, disparity, mode=params.warp_mode, z_tolerance=params.z_tolerance)
    timings["warp"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    estimate = inpaint_from_samples(warped, holes, samples, lowpass_sigma=params.inpaint_lowpass_sigma)
    timings["inpaint"] = time.perf_counter() - t0

    rows, cols, values = sample_arrays(samples)
    psnr_before_enhancement = _psnr_8bit(estimate[rows, cols], values)
    if params.enhance:
        t0 = time.perf_counter()
        estimate = enhance_with_samples(estimate, holes, samples, sigma_s=params.enhance_sigma_s,
                                        sigma_r=params.enhance_sigma_r, shrinkage=params.enhance_shrinkage)
        timings["enhance"] = time.perf_counter() - t0
    psnr_before_reinsertion = _psnr_8bit(estimate[rows, cols], values)

    image = _to_dtype(estimate, left.dtype)
    if params.reinsert_samples:
        _reinsert(image, rows, cols, samples)
    if left.ndim == 2:
        image = image[:, :, 0]
    return RecoveredRight(image=image, holes=holes,
                          psnr_at_samples_before_enhancement=psnr_before_enhancement,
                          psnr_at_samples_before_reinsertion=psnr_before_reinsertion,
                          timings=timings)


__all__ = ["SynthesisParams", "RecoveredRight", "check_recovery_inputs", "BLOCK_MEAN_ITERATIONS",
           "recover_right_from_block_means", "recover_right"]
