"""The sample container: what the right camera sends (in memory: :class:`SampleSet`).

The binary ``.sbs`` encoding of a :class:`SampleSet` is specified in ``docs/format.md``
and implemented by :func:`write_samples` / :func:`read_samples` / :func:`probe`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sampling import SamplingPattern, sample_count, sample_positions, grid_shape

CHANNEL_ORDERS = ("gray", "rgb", "bgr")


@dataclass(frozen=True, eq=False)
class SampleSet:
    """Samples of the right image and everything needed to place them.

    Attributes
    ----------
    height, width : int
        Size of the full right image I2.
    channel_order : str
        ``"gray"`` (1 channel), ``"rgb"`` or ``"bgr"`` (3 channels).
    pattern : SamplingPattern
        Where the samples lie.
    values : ndarray, shape (n, channels), uint8 or uint16
        Sample values in transmission order (see :func:`stereobudget.sampling.sample_positions`).
    """

    height: int
    width: int
    channel_order: str
    pattern: SamplingPattern
    values: np.ndarray

    def __post_init__(self):
        if self.channel_order not in CHANNEL_ORDERS:
            raise ValueError(f"channel_order must be one of {CHANNEL_ORDERS}, got {self.channel_order!r}")
        v = self.values
        if v.ndim != 2 or v.shape[1] != self.channels:
            raise ValueError(f"values must have shape (n, {self.channels}), got {v.shape}")
        if v.dtype not in (np.uint8, np.uint16):
            raise ValueError(f"values must be uint8 or uint16, got {v.dtype}")
        n = sample_count(self.pattern, self.height, self.width)
        if v.shape[0] != n:
            raise ValueError(f"pattern {self.pattern.kind} on {self.width}x{self.height} has {n} samples, "
                             f"values has {v.shape[0]}")

    @property
    def channels(self) -> int:
        return 1 if self.channel_order == "gray" else 3

    @property
    def dtype(self) -> np.dtype:
        return self.values.dtype

    @property
    def epsilon(self) -> float:
        """Fraction of I2's pixels that were sent (n / (H W))."""
        return self.values.shape[0] / float(self.height * self.width)

    def positions(self):
        """(rows, cols) of every sample, in transmission order."""
        return sample_positions(self.pattern, self.height, self.width)

    def values_rgb(self) -> np.ndarray:
        """Sample values as (n, channels) with colour in RGB order (gray stays 1 channel)."""
        return self.values[:, ::-1] if self.channel_order == "bgr" else self.values

    def grid_values(self) -> np.ndarray:
        """Values of a ``grid`` pattern as a (rows, cols, channels) lattice ``I2[oy::sy, ox::sx]``."""
        if not self.pattern.is_regular_grid:
            raise ValueError(f"pattern {self.pattern.kind!r} is not a regular grid")
        r, c = grid_shape(self.pattern, self.height, self.width)
        return self.values.reshape(r, c, self.channels)


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
    """
    img = image if image.ndim == 3 else image[:, :, None]
    h, w, c = img.shape
    if channel_order is None:
        channel_order = "gray" if c == 1 else "rgb"
    if pattern.kind == "downsample":
        from .sampling import downsample_blocks  # computes block means, camera side
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
