"""Evaluation-only baselines of the paper's experiments (they need the full I2, so not in ``sb-decode``).

* :func:`lower_bound_disparity` -- Sec. "A lower bound": the full DSI of the original pair,
  resized down to the budget and back up, then aggregated as usual.  No encoder sending
  that many numbers per disparity layer can hope to do better.
* :func:`jbu_disparity` -- Fig. 5(a) "JBU": stereo on the downsampled pair, disparities
  upsampled with joint bilateral upsampling guided by the full-resolution I1.
* :func:`upsample_no_smoothing_disparity` -- Fig. 5(a) "Upsample I2": the downsampled I2
  upsampled back and matched against the *unsmoothed* I1 with full-pair stereo.

Helpers :func:`full_pair_samples` (a stride-1 :class:`SampleSet`, which ``decode`` treats
as the full pair) and :func:`upsample_block_means` are shared with the reproduction script.
"""

from __future__ import annotations

import math

import numpy as np

from stereobudget.io import SampleSet
from stereobudget.encoding import encode_image
from stereobudget.cost import full_dsi, to_float_image, to_gray
from stereobudget.errors import OptionError
from stereobudget.sampling import SamplingPattern, downsample_blocks, downsample_shape, sample_positions

#: cv2.resize (OpenCV 5) does area interpolation by non-integer factors on at most 4 channels.
_CV_MAX_CHANNELS = 4


def _params(params):
    from stereobudget.decoding import DecoderParams
    return params if params is not None else DecoderParams()


def full_pair_samples(image: np.ndarray) -> SampleSet:
    """A stride-1 grid :class:`SampleSet` of ``image`` (uint8/uint16, RGB): "all of I2"."""
    return encode_image(image, pattern=SamplingPattern("grid", 1, 1))


def full_pair_disparity(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
                        params=None) -> np.ndarray:
    """Standard full-pair stereo (the decoder's ``full`` method); float32 (H, W)."""
    from stereobudget.decoding import decode
    return decode(left, full_pair_samples(right), max_disp=max_disp, min_disp=min_disp, method="full",
                  params=_params(params)).disparity


def _resize_volume(volume: np.ndarray, size_wh: tuple[int, int], interpolation: int) -> np.ndarray:
    """cv2.resize of a float32 (H, W, D) volume, in chunks of at most 4 layers."""
    import cv2
    h_out, w_out = size_wh[1], size_wh[0]
    out = np.empty((h_out, w_out, volume.shape[2]), dtype=np.float32)
    for start in range(0, volume.shape[2], _CV_MAX_CHANNELS):
        chunk = np.ascontiguousarray(volume[:, :, start:start + _CV_MAX_CHANNELS])
        resized = cv2.resize(chunk, size_wh, interpolation=interpolation)
        out[:, :, start:start + chunk.shape[2]] = resized.reshape(h_out, w_out, chunk.shape[2])
    return out


def lower_bound_disparity(left: np.ndarray, right: np.ndarray, *, fraction: float, max_disp: int,
                          min_disp: int = 0, params=None) -> np.ndarray:
    """The paper's lower bound: the full DSI squeezed to the budget and back, then aggregated.

    Parameters
    ----------
    left, right : ndarray, (H, W[, 3]), uint8 or uint16
        The original pair (RGB).
    fraction : float
        Budget as a fraction of I2's pixels, in (0, 1]; each DSI layer is resized to about
        ``fraction * H * W`` entries (both sides scaled by ``sqrt(fraction)``, area
        interpolation), then back up bilinearly.
    max_disp, min_disp : int
        Disparity search range, inclusive.
    params : DecoderParams, optional
        Cost truncation, gradient weight, tree and median settings (defaults: the decoder's).

    Returns
    -------
    ndarray, float32 (H, W)
        Disparity of the left view (MST aggregation on I1, WTA with parabola, median).
    """
    import cv2

    from stereobudget.aggregate import aggregate_winners, build_tree, median_filter_disparity
    if not 0 < fraction <= 1:
        raise OptionError(f"fraction must be in (0, 1], got {fraction}")
    params = _params(params)
    left_f, right_f = to_float_image(left), to_float_image(right)
    h, w = left_f.shape[:2]
    num_disp = int(max_disp - min_disp + 1)
    cost = full_dsi(left_f, right_f, min_disp=min_disp, num_disp=num_disp, truncation=params.truncation,
                    grad_weight=params.grad_weight)                    # float32 (H, W, D)
    scale = math.sqrt(fraction)
    low_size = (max(1, round(w * scale)), max(1, round(h * scale)))
    if low_size != (w, h):
        low = _resize_volume(cost, low_size, cv2.INTER_AREA)           # float32 (h', w', D)
        cost = _resize_volume(low, (w, h), cv2.INTER_LINEAR)
    tree = build_tree(left_f, sigma=params.tree_sigma, median_size=params.tree_median)
    disp = aggregate_winners(cost, tree, min_disp=int(min_disp), out=cost)
    return median_filter_disparity(disp, params.median_size, passes=params.median_passes)


def upsample_block_means(low: np.ndarray, *, stride_x: int, stride_y: int, height: int,
                         width: int) -> np.ndarray:
    """Bilinear upsampling of a block-mean image back to ``height x width``.

    Block ``(i, j)`` of a ``downsample`` pattern covers rows ``[i sy, (i+1) sy)``, so its
    mean is placed at the block's centre ``i sy + (cell_h - 1) / 2`` (partial edge blocks
    use their own centre); pixels between centres are interpolated, pixels beyond the
    outermost centres take the edge value.

    Parameters
    ----------
    low : ndarray, (h', w'[, C])
        Block means, any numeric dtype.
    stride_x, stride_y : int
        Block size.
    height, width : int
        Full size.

    Returns
    -------
    ndarray, float32 (height, width, C)
    """
    import cv2
    low3 = low if low.ndim == 3 else low[:, :, None]
    low_f = np.ascontiguousarray(low3, dtype=np.float32)

    def axis_map(size, stride, cells):
        starts = np.arange(cells, dtype=np.float64) * stride
        centres = starts + (np.minimum(stride, size - starts) - 1) / 2.0
        return np.interp(np.arange(size, dtype=np.float64), centres, np.arange(cells, dtype=np.float64))

    map_y = axis_map(height, stride_y, low_f.shape[0]).astype(np.float32)
    map_x = axis_map(width, stride_x, low_f.shape[1]).astype(np.float32)
    grid_x, grid_y = np.meshgrid(map_x, map_y)
    channels = [cv2.remap(low_f[:, :, c], grid_x, grid_y, interpolation=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE) for c in range(low_f.shape[2])]
    return np.stack(channels, axis=2)


def _block_image(image: np.ndarray, scale: int) -> tuple[np.ndarray, SamplingPattern]:
    """Block means (same dtype) of ``image`` as an (h', w', C) image, and the pattern."""
    pattern = SamplingPattern("downsample", scale, scale)
    img3 = image if image.ndim == 3 else image[:, :, None]
    rows, cols = downsample_shape(pattern, img3.shape[0], img3.shape[1])
    low = downsample_blocks(img3, pattern).reshape(rows, cols, img3.shape[2])
    return (low if image.ndim == 3 else low[:, :, 0]), pattern


def _check_scale(scale) -> int:
    if int(scale) != scale or scale < 1:
        raise OptionError(f"scale must be a positive integer, got {scale}")
    return int(scale)


def jbu_disparity(left: np.ndarray, right: np.ndarray, *, scale: int, max_disp: int, min_disp: int = 0,
                  sigma_s: float | None = None, sigma_r: float = 20.0, params=None) -> np.ndarray:
    """Low-resolution stereo, then joint bilateral upsampling (Kopf et al. 2007) guided by I1.

    Both images are reduced to ``scale x scale`` block means (what a ``downsample``
    camera sends), matched with full-pair stereo at low resolution, the disparities are
    multiplied by ``scale`` and spread from the block centres to every full-resolution
    pixel by a normalised joint bilateral filter guided by the gray full-resolution I1.

    Parameters
    ----------
    left, right : ndarray, (H, W[, 3]), uint8 or uint16
    scale : int
        Block size (>= 1).
    max_disp, min_disp : int
        Full-resolution disparity range; the low-resolution search uses
        ``[floor(min/scale), ceil(max/scale)]``.
    sigma_s : float, optional
        Spatial sigma of the upsampling in full-resolution pixels (default ``scale``).
    sigma_r : float
        Range sigma (8-bit units).
    params : DecoderParams, optional

    Returns
    -------
    ndarray, float32 (H, W)
    """
    from stereobudget.fill import sparse_joint_bilateral
    scale = _check_scale(scale)
    h, w = left.shape[:2]
    left_low, pattern = _block_image(left, scale)
    right_low, _ = _block_image(right, scale)
    low_min = math.floor(min_disp / scale)
    low_max = max(math.ceil(max_disp / scale), low_min + 1)
    disp_low = full_pair_disparity(left_low, right_low, max_disp=low_max, min_disp=low_min, params=params)
    rows, cols = sample_positions(pattern, h, w)                     # block centres, row-major
    values = disp_low.ravel().astype(np.float32) * np.float32(scale)
    known = np.isfinite(values)
    guide = to_gray(to_float_image(left))
    up = sparse_joint_bilateral(guide, rows[known], cols[known], values[known, None],
                                sigma_s=float(scale if sigma_s is None else sigma_s), sigma_r=sigma_r,
                                missing_value=np.nan)
    return np.ascontiguousarray(up[:, :, 0])


def upsample_no_smoothing_disparity(left: np.ndarray, right: np.ndarray, *, scale: int, max_disp: int,
                                    min_disp: int = 0, params=None) -> np.ndarray:
    """Fig. 5(a) "Upsample I2": block-mean I2 upsampled back, matched against the unsmoothed I1.

    Parameters
    ----------
    left, right : ndarray, (H, W[, 3]), uint8 or uint16
    scale : int
        Block size of the downsampling.
    max_disp, min_disp : int
    params : DecoderParams, optional

    Returns
    -------
    ndarray, float32 (H, W)
    """
    scale = _check_scale(scale)
    h, w = right.shape[:2]
    low, _ = _block_image(right, scale)
    up = upsample_block_means(low, stride_x=scale, stride_y=scale, height=h, width=w)
    peak = np.iinfo(right.dtype).max
    up = np.clip(np.rint(up), 0, peak).astype(right.dtype)
    if right.ndim == 2:
        up = up[:, :, 0]
    return full_pair_disparity(left, up, max_disp=max_disp, min_disp=min_disp, params=params)
