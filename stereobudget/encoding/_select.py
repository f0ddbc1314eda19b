"""Selecting the samples: the camera's only job (no arithmetic on pixel values).

numpy is imported inside the function: the raw-grid path of ``sb-encode --raw`` never calls it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..errors import OptionError
from ..io._mosaic import mosaic_of
from ..io._samples import SampleSet
from ..sampling._patterns import SamplingPattern, sample_positions

if TYPE_CHECKING:
    import numpy as np


def encode_image(image: np.ndarray, *, pattern: SamplingPattern, channel_order: str | None = None) -> SampleSet:
    """Select the samples of ``image`` (the camera's only job: no arithmetic on pixel values).

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, C), uint8 or uint16
        The right image.  C = 1 or 3.
    pattern : SamplingPattern
        Where to sample.  ``downsample`` is the one pattern that computes (block means).
    channel_order : str, optional
        Channel order of ``image``; default ``"gray"`` for one channel, ``"rgb"`` for three.
        A raw Bayer frame is one channel with its mosaic's order (``"bayer_rggb"`` ...).
    """
    import numpy as np

    img = image if image.ndim == 3 else image[:, :, None]
    h, w, c = img.shape
    if channel_order is None:
        channel_order = "gray" if c == 1 else "rgb"
    if mosaic_of(channel_order) and pattern.kind == "downsample":
        raise OptionError("--pattern downsample averages pixels and would mix a Bayer mosaic's colours; "
                          "use grid, jitter, fps or adaptive_fps")
    if pattern.kind == "downsample":
        from ..sampling._patterns import downsample_blocks  # computes block means, camera side
        values = downsample_blocks(img, pattern)
    elif pattern.kind in ("fps", "adaptive_fps"):
        rows, cols = sample_positions(pattern, h, w, image=img)
        values = img[rows, cols]
    elif pattern.is_regular_grid:
        values = img[pattern.offset_y::pattern.stride_y, pattern.offset_x::pattern.stride_x].reshape(-1, c)
    else:
        rows, cols = sample_positions(pattern, h, w)
        values = img[rows, cols]
    return SampleSet(height=h, width=w, channel_order=channel_order, pattern=pattern,
                     values=np.ascontiguousarray(values))


__all__ = ["encode_image"]
