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
``fps``
    Farthest point sampling (Eldar et al. 1997): each sample is the pixel farthest from
    all previous ones, ties broken by a seeded SplitMix64 key.  Only values travel; the
    host regenerates the positions from ``(seed, n, H, W)``.  Same budget as the grid.
``adaptive_fps``
    The first 80 % of the samples as ``fps``; the last 20 % maximise the distance
    weighted by the local intensity range seen in those first samples, so the host
    regenerates the positions from the values it received.
``downsample``
    Block means of ``sx x sy`` cells (partial cells at the right/bottom edge average
    their own pixels), rounded half up: the one pattern that computes on the camera.
    Its "positions" are the block centres.

The exact definitions, precise enough for a C implementation, are in ``docs/format.md``.
The FPS kernels (numba) live in :mod:`stereobudget.sampling._fps` and are imported only when an
FPS pattern is used, so grid/jitter encoders stay free of numba.  numpy itself is
imported inside the functions that compute positions or values: :class:`SamplingPattern`,
:func:`grid_shape` and :func:`sample_count` (all that ``sb-encode --raw`` on a grid and
``sb-encode --info`` need) work without it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

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
        budget (``ceil(H/sy)*ceil(W/sx)`` samples) and, for ``adaptive_fps``, the tiles of
        its activity map; for ``downsample`` the block size.
    offset_x, offset_y : int
        Position of the first grid sample, ``0 <= offset < stride`` (grid only).
    seed : int
        Seed of pseudo-random patterns (jitter, fps, adaptive_fps); 0 for deterministic ones.
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


#: SplitMix64 increment (the golden ratio in 64 bits); a plain int, see ``_jitter_positions``.
_GOLDEN = 0x9E3779B97F4A7C15


def splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser on uint64 arrays (wrapping arithmetic), as specified in docs/format.md."""
    import numpy as np

    with np.errstate(over="ignore"):
        z = x.astype(np.uint64)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def _jitter_positions(pattern: SamplingPattern, height: int, width: int):
    import numpy as np

    sy, sx = pattern.stride_y, pattern.stride_x
    cy = np.arange(0, height, sy, dtype=np.int64)
    cx = np.arange(0, width, sx, dtype=np.int64)
    cell_y, cell_x = np.meshgrid(cy, cx, indexing="ij")
    k = np.arange(cell_y.size, dtype=np.uint64).reshape(cell_y.shape)
    with np.errstate(over="ignore"):
        z = splitmix64(np.uint64(pattern.seed) + (k + np.uint64(1)) * np.uint64(_GOLDEN))
    cell_h = np.minimum(sy, height - cell_y).astype(np.uint64)
    cell_w = np.minimum(sx, width - cell_x).astype(np.uint64)
    dy = ((z >> np.uint64(32)) % cell_h).astype(np.int64)
    dx = ((z & np.uint64(0xFFFFFFFF)) % cell_w).astype(np.int64)
    return (cell_y + dy).ravel(), (cell_x + dx).ravel()


#: adaptive_fps: 1 sample in ADAPTIVE_DIVISOR is adaptive (the last ``n // 5``, i.e. 20 %).
ADAPTIVE_DIVISOR = 5
#: adaptive_fps: weight of a tile = its local intensity range (8-bit units) + ADAPTIVE_BASE.
#: The base keeps flat regions sampled: a range of 255 makes a tile 17x "farther", so
#: adaptive samples sit about 4x denser there than in flat tiles.
ADAPTIVE_BASE = 16


def adaptive_split(count: int) -> tuple[int, int]:
    """(uniform, adaptive) sample counts of ``adaptive_fps`` with ``count`` samples."""
    adaptive = count // ADAPTIVE_DIVISOR
    return count - adaptive, adaptive


def _values_8bit(values: np.ndarray) -> np.ndarray:
    """(n, C) int64 sample values in 8-bit units: uint16 keeps its high byte (v >> 8)."""
    import numpy as np

    v = np.asarray(values)
    if v.ndim == 1:
        v = v[:, None]
    if v.dtype == np.uint16:
        return (v >> 8).astype(np.int64)
    if v.dtype != np.uint8:
        raise ValueError(f"sample values must be uint8 or uint16, got {v.dtype}")
    return v.astype(np.int64)


def adaptive_tile_weights(rows: np.ndarray, cols: np.ndarray, values: np.ndarray, *, height: int,
                          width: int, tile_h: int, tile_w: int) -> np.ndarray:
    """Per-tile weights of the adaptive phase of ``adaptive_fps`` (see docs/format.md).

    Tile ``(ty, tx)`` covers rows ``[ty*tile_h, (ty+1)*tile_h)`` and columns
    ``[tx*tile_w, (tx+1)*tile_w)``.  Its *range* is the largest, over channels, of
    ``max - min`` of the 8-bit sample values lying in the 3x3 tiles around it (0 when
    none); its weight is ``range + ADAPTIVE_BASE``.

    Parameters
    ----------
    rows, cols : ndarray of int
        Positions of the uniform-phase samples.
    values : ndarray, (n, C) uint8 or uint16
        Their values (any channel order).
    height, width, tile_h, tile_w : int

    Returns
    -------
    ndarray, int64 (ceil(H / tile_h), ceil(W / tile_w))
    """
    import numpy as np

    v = _values_8bit(values)
    tiles_y, tiles_x = -(-height // tile_h), -(-width // tile_w)
    channels = v.shape[1]
    lo = np.full((tiles_y + 2, tiles_x + 2, channels), 256, dtype=np.int64)
    hi = np.full((tiles_y + 2, tiles_x + 2, channels), -1, dtype=np.int64)
    ty = np.asarray(rows, np.int64) // tile_h + 1
    tx = np.asarray(cols, np.int64) // tile_w + 1
    for c in range(channels):
        np.minimum.at(lo[:, :, c], (ty, tx), v[:, c])
        np.maximum.at(hi[:, :, c], (ty, tx), v[:, c])
    lo9 = np.full((tiles_y, tiles_x, channels), 256, dtype=np.int64)
    hi9 = np.full((tiles_y, tiles_x, channels), -1, dtype=np.int64)
    for dy in range(3):
        for dx in range(3):
            np.minimum(lo9, lo[dy:dy + tiles_y, dx:dx + tiles_x], out=lo9)
            np.maximum(hi9, hi[dy:dy + tiles_y, dx:dx + tiles_x], out=hi9)
    spread = np.where(hi9 >= 0, hi9 - lo9, 0).max(axis=2)
    return spread + ADAPTIVE_BASE


def fps_positions(height: int, width: int, count: int, *, seed: int):
    """Rows and columns (int64) of ``count`` farthest-point samples, in order (see :mod:`stereobudget.sampling._fps`)."""
    from ._fps import FarthestPointSampler   # numba: only when an FPS pattern is used
    return FarthestPointSampler(height, width, seed).extend(count)


def adaptive_fps_positions(height: int, width: int, count: int, *, seed: int, tile_h: int, tile_w: int,
                           image: np.ndarray | None = None, values: np.ndarray | None = None):
    """Rows and columns (int64) of the ``adaptive_fps`` samples, in transmission order.

    Parameters
    ----------
    height, width, count : int
        Image size and number of samples.
    seed : int
        Pattern seed.
    tile_h, tile_w : int
        Tile size of the activity map (the pattern's strides).
    image : ndarray, (H, W) or (H, W, C), optional
        Encoder side: the image, read at the uniform samples as they are chosen.
    values : ndarray, (>= uniform count, C), optional
        Decoder side: the received values in transmission order (only the first
        ``adaptive_split(count)[0]`` are used).

    Returns
    -------
    rows, cols : ndarray of int64
    """
    import numpy as np

    from ._fps import FarthestPointSampler
    uniform, adaptive = adaptive_split(count)
    sampler = FarthestPointSampler(height, width, seed)
    rows_u, cols_u = sampler.extend(uniform)
    if adaptive == 0:
        return rows_u, cols_u
    if image is not None:
        seen = image[rows_u, cols_u]
    elif values is not None:
        if len(values) < uniform:
            raise ValueError(f"adaptive_fps needs the first {uniform} sample values, got {len(values)}")
        seen = np.asarray(values)[:uniform]
    else:
        raise ValueError("adaptive_fps positions depend on the sample values: pass image= (encoder) "
                         "or values= (decoder)")
    weights = adaptive_tile_weights(rows_u, cols_u, seen, height=height, width=width,
                                    tile_h=tile_h, tile_w=tile_w)
    sampler.set_tile_weights(weights, tile_h=tile_h, tile_w=tile_w)
    rows_a, cols_a = sampler.extend(adaptive)
    return np.concatenate([rows_u, rows_a]), np.concatenate([cols_u, cols_a])


def downsample_shape(pattern: SamplingPattern, height: int, width: int) -> tuple[int, int]:
    """Rows and columns of the low-resolution image of a ``downsample`` pattern: ``ceil(H/sy), ceil(W/sx)``."""
    return -(-height // pattern.stride_y), -(-width // pattern.stride_x)


def downsample_blocks(image: np.ndarray, pattern: SamplingPattern) -> np.ndarray:
    """Block means of ``image``: the payload of the ``downsample`` pattern.

    Parameters
    ----------
    image : ndarray, (H, W, C) or (H, W), uint8 or uint16
    pattern : SamplingPattern
        Block size ``stride_x`` x ``stride_y``; blocks start at (0, 0), the last block
        column/row may be narrower/shorter and averages only its own pixels.

    Returns
    -------
    ndarray, (n, C), the dtype of ``image``
        Row-major block order; each value ``(sum + count // 2) // count`` (integer mean
        rounded half up).
    """
    import numpy as np

    img = image if image.ndim == 3 else image[:, :, None]
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"image must be uint8 or uint16, got {img.dtype}")
    h, w, c = img.shape
    sy, sx = pattern.stride_y, pattern.stride_x
    starts_y = np.arange(0, h, sy)
    starts_x = np.arange(0, w, sx)
    sums = np.add.reduceat(np.add.reduceat(img.astype(np.int64), starts_y, axis=0), starts_x, axis=1)
    counts = (np.minimum(sy, h - starts_y)[:, None] * np.minimum(sx, w - starts_x)[None, :])[:, :, None]
    means = (sums + counts // 2) // counts
    return means.astype(img.dtype).reshape(-1, c)


def _block_centres(pattern: SamplingPattern, height: int, width: int):
    import numpy as np

    sy, sx = pattern.stride_y, pattern.stride_x
    cy = np.arange(0, height, sy, dtype=np.int64)
    cx = np.arange(0, width, sx, dtype=np.int64)
    cy = cy + (np.minimum(sy, height - cy) - 1) // 2
    cx = cx + (np.minimum(sx, width - cx) - 1) // 2
    rr, cc = np.meshgrid(cy, cx, indexing="ij")
    return rr.ravel(), cc.ravel()


def sample_positions(pattern: SamplingPattern, height: int, width: int, *, image=None, values=None):
    """Row and column of every sample, in transmission order.

    Parameters
    ----------
    pattern : SamplingPattern
        The sampling pattern.
    height, width : int
        Full size of the right image.
    image : ndarray, optional
        Encoder side of ``adaptive_fps``: the image, (H, W) or (H, W, C).
    values : ndarray, optional
        Decoder side of ``adaptive_fps``: the received sample values (n, C) in
        transmission order.  Ignored by the other patterns.

    Returns
    -------
    rows, cols : ndarray of int64
        Pixel coordinates, each of length :func:`sample_count`.  For ``downsample`` the
        centre pixel of each block, ``(cy + (cell_h - 1) // 2, cx + (cell_w - 1) // 2)``.
    """
    import numpy as np

    if pattern.kind == "grid":
        r = np.arange(pattern.offset_y, height, pattern.stride_y, dtype=np.int64)
        c = np.arange(pattern.offset_x, width, pattern.stride_x, dtype=np.int64)
        rr, cc = np.meshgrid(r, c, indexing="ij")
        return rr.ravel(), cc.ravel()
    if pattern.kind == "jitter":
        return _jitter_positions(pattern, height, width)
    if pattern.kind == "downsample":
        return _block_centres(pattern, height, width)
    count = sample_count(pattern, height, width)
    if pattern.kind == "fps":
        return fps_positions(height, width, count, seed=pattern.seed)
    if pattern.kind == "adaptive_fps":
        return adaptive_fps_positions(height, width, count, seed=pattern.seed, tile_h=pattern.stride_y,
                                      tile_w=pattern.stride_x, image=image, values=values)
    raise NotImplementedError(f"sample positions for pattern {pattern.kind!r} are not implemented")
