"""Raw sensor mosaics (Bayer colour filter arrays): which colour each pixel of a raw frame holds.

A Bayer frame has one value per pixel; the 2x2 pattern named by four letters (``rggb``:
R G on even rows, G B on odd rows, starting at pixel (0, 0)) says which.  The camera sends
those values as they are (``sb-encode --pix-fmt bayer_rggb8`` ...); the host compares each
sample with the same colour of I1.  The colour of a sample is a function of its position
only, so any sampling pattern works, and a grid of odd stride simply alternates colours
from one sample to the next.

Inside the decoders a mosaic sample is an RGB value whose two missing channels are NaN
(:func:`rgb_with_gaps`): the matching cost skips NaN channels
(:func:`stereobudget.cost.pixel_cost`), and the interpolations normalise each channel by
its own samples.  Importing this module needs no numpy (the camera's ``--raw`` path
reads the tables).
"""

from __future__ import annotations

#: Bayer patterns: name -> RGB channel index (0 R, 1 G, 2 B) of the pixels (0, 0), (0, 1),
#: (1, 0), (1, 1), i.e. row-major over the 2x2 tile starting at the frame's top-left pixel.
BAYER_PATTERNS = {
    "rggb": (0, 1, 1, 2),
    "bggr": (2, 1, 1, 0),
    "grbg": (1, 0, 2, 1),
    "gbrg": (1, 2, 0, 1),
}
#: Channel orders of mosaic sample sets (``SampleSet.channel_order``): ``bayer_`` + pattern.
MOSAIC_ORDERS = tuple(f"bayer_{name}" for name in BAYER_PATTERNS)


def mosaic_of(channel_order: str) -> str | None:
    """The Bayer pattern (``"rggb"`` ...) of a channel order, None for gray / RGB / BGR."""
    return channel_order[len("bayer_"):] if channel_order in MOSAIC_ORDERS else None


def shifted_order(channel_order: str, *, rows: int = 0, cols: int = 0) -> str:
    """The channel order of the same frame seen from pixel (rows, cols) as its origin.

    A band of a mosaic that starts on an odd row has the pattern of the next tile row
    (``rggb`` -> ``gbrg``); non-mosaic orders are returned unchanged.
    """
    pattern = mosaic_of(channel_order)
    if pattern is None:
        return channel_order
    tile = BAYER_PATTERNS[pattern]
    dy, dx = rows % 2, cols % 2
    shifted = tuple(tile[2 * ((r + dy) % 2) + (c + dx) % 2] for r in (0, 1) for c in (0, 1))
    return "bayer_" + next(name for name, t in BAYER_PATTERNS.items() if t == shifted)


def sample_colours(channel_order: str, rows, cols):
    """RGB channel index (int64, 0..2) of the mosaic pixels ``(rows, cols)``."""
    import numpy as np

    tile = np.asarray(BAYER_PATTERNS[mosaic_of(channel_order)], np.int64)
    return tile[2 * (np.asarray(rows, np.int64) % 2) + np.asarray(cols, np.int64) % 2]


def rgb_with_gaps(values, colours):
    """Mosaic values (n,) or (n, 1) as float32 (n, 3) RGB: each value in its colour, NaN elsewhere."""
    import numpy as np

    out = np.full((len(colours), 3), np.nan, np.float32)
    out[np.arange(len(colours)), colours] = np.asarray(values, np.float32).reshape(-1)
    return out


def mosaic_image(image, pattern: str):
    """The raw frame a Bayer sensor with ``pattern`` would give of the RGB ``image``.

    Parameters
    ----------
    image : ndarray, (H, W, 3)
        RGB, any dtype.
    pattern : str
        ``rggb``, ``bggr``, ``grbg`` or ``gbrg`` (or ``bayer_`` + one of them).

    Returns
    -------
    ndarray, (H, W), ``image``'s dtype
        Pixel (y, x) holds channel ``BAYER_PATTERNS[pattern][2 (y % 2) + x % 2]``.
    """
    import numpy as np

    name = pattern[len("bayer_"):] if pattern.startswith("bayer_") else pattern
    if name not in BAYER_PATTERNS:
        raise ValueError(f"unknown Bayer pattern {pattern!r}; expected one of {', '.join(BAYER_PATTERNS)}")
    h, w = image.shape[:2]
    rows, cols = np.indices((h, w))
    colour = np.asarray(BAYER_PATTERNS[name], np.int64)[2 * (rows % 2) + cols % 2]
    return np.ascontiguousarray(np.take_along_axis(image, colour[:, :, None], axis=2)[:, :, 0])


def colours_present(samples) -> tuple[bool, bool, bool]:
    """Whether the mosaic sample set holds R, G and B samples (an even grid stride holds one colour)."""
    import numpy as np

    counts = np.bincount(samples.sample_colours(), minlength=3)
    return tuple(bool(c) for c in counts[:3])
