"""Sampling patterns: the one place that answers "which right-image pixels were sent?".

The encoder (camera) and the decoder (host) both call :func:`sample_positions`, so the
two sides can never disagree.  Positions are returned in *transmission order*: the
``k``-th sample value in a sample file belongs to ``(rows[k], cols[k])``.

Patterns
--------
``grid``
    ``I2[oy::sy, ox::sx]`` in row-major order.  No computation on the camera.
``jitter``
    One pixel per ``sy x sx`` cell at a pseudo-random offset drawn from ``seed`` with
    SplitMix64 (see ``docs/format.md``); both sides regenerate the same positions.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PATTERN_KINDS = ("grid", "jitter", "fps", "adaptive_fps", "downsample")


@dataclass(frozen=True)
class SamplingPattern:
    """Where the right camera's samples come from.

    Attributes
    ----------
    kind : str
        One of :data:`PATTERN_KINDS`.
    stride_x, stride_y : int
        Grid spacing in pixels (>= 1).  For ``fps``/``adaptive_fps`` they set the sample
        budget (``ceil(H/sy)*ceil(W/sx)`` samples); for ``downsample`` the block size.
    offset_x, offset_y : int
        Position of the first grid sample, ``0 <= offset < stride`` (grid only).
    seed : int
        Seed of pseudo-random patterns (jitter, fps); 0 for deterministic ones.
    """

    kind: str = "grid"
    stride_x: int = 5
    stride_y: int = 5
    offset_x: int = 0
    offset_y: int = 0
    seed: int = 0
    extra: dict = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self):
        if self.kind not in PATTERN_KINDS:
            raise ValueError(f"unknown sampling pattern {self.kind!r}; expected one of {PATTERN_KINDS}")
        if self.stride_x < 1 or self.stride_y < 1:
            raise ValueError(f"stride must be >= 1, got {self.stride_x}x{self.stride_y}")
        if not (0 <= self.offset_x < self.stride_x and 0 <= self.offset_y < self.stride_y):
            raise ValueError(
                f"offset ({self.offset_x},{self.offset_y}) must satisfy 0 <= offset < stride "
                f"({self.stride_x},{self.stride_y})")

    @property
    def is_regular_grid(self) -> bool:
        """True when samples form the lattice ``[oy::sy, ox::sx]`` (enables the fast decoder paths)."""
        return self.kind == "grid"


def grid_shape(pattern: SamplingPattern, height: int, width: int) -> tuple[int, int]:
    """Rows and columns of the sample lattice ``[oy::sy, ox::sx]`` of an ``height x width`` image."""
    rows = max(0, -(-(height - pattern.offset_y) // pattern.stride_y))
    cols = max(0, -(-(width - pattern.offset_x) // pattern.stride_x))
    return rows, cols


def sample_count(pattern: SamplingPattern, height: int, width: int) -> int:
    """Number of samples (pixels, or low-resolution pixels for ``downsample``) the pattern sends."""
    if pattern.kind in ("grid", "fps", "adaptive_fps"):
        r, c = grid_shape(pattern, height, width)
        return r * c
    # jitter and downsample: one sample per (possibly partial) cell
    return (-(-height // pattern.stride_y)) * (-(-width // pattern.stride_x))


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser on uint64 arrays (wrapping arithmetic), as specified in docs/format.md."""
    with np.errstate(over="ignore"):
        z = x.astype(np.uint64)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def _jitter_positions(pattern: SamplingPattern, height: int, width: int):
    sy, sx = pattern.stride_y, pattern.stride_x
    cy = np.arange(0, height, sy, dtype=np.int64)
    cx = np.arange(0, width, sx, dtype=np.int64)
    cell_y, cell_x = np.meshgrid(cy, cx, indexing="ij")
    k = np.arange(cell_y.size, dtype=np.uint64).reshape(cell_y.shape)
    with np.errstate(over="ignore"):
        z = splitmix64(np.uint64(pattern.seed) + (k + np.uint64(1)) * _GOLDEN)
    cell_h = np.minimum(sy, height - cell_y).astype(np.uint64)
    cell_w = np.minimum(sx, width - cell_x).astype(np.uint64)
    dy = ((z >> np.uint64(32)) % cell_h).astype(np.int64)
    dx = ((z & np.uint64(0xFFFFFFFF)) % cell_w).astype(np.int64)
    return (cell_y + dy).ravel(), (cell_x + dx).ravel()


def sample_positions(pattern: SamplingPattern, height: int, width: int, *, image=None):
    """Row and column of every sample, in transmission order.

    Parameters
    ----------
    pattern : SamplingPattern
        The sampling pattern.
    height, width : int
        Full size of the right image.
    image : ndarray, optional
        Needed only by content-adaptive patterns on the encoder side.

    Returns
    -------
    rows, cols : ndarray of int64
        Pixel coordinates, each of length :func:`sample_count`.
    """
    if pattern.kind == "grid":
        r = np.arange(pattern.offset_y, height, pattern.stride_y, dtype=np.int64)
        c = np.arange(pattern.offset_x, width, pattern.stride_x, dtype=np.int64)
        rr, cc = np.meshgrid(r, c, indexing="ij")
        return rr.ravel(), cc.ravel()
    if pattern.kind == "jitter":
        return _jitter_positions(pattern, height, width)
    raise NotImplementedError(f"sample positions for pattern {pattern.kind!r} are not implemented yet")
