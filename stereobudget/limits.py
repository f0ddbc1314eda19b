"""Hard size limits shared by the sample-file reader and the image reader.

Both readers check these *before* allocating anything proportional to the declared
size, so a 100-byte file that claims to be 10^6 x 10^6 pixels is rejected at once.
The numbers are part of the ``.sbs`` format specification (``docs/format.md``).
"""

from __future__ import annotations

#: Largest width or height, in pixels (fits the u16 stride / offset fields of the format).
MAX_DIMENSION = 65535
#: Largest pixel count ``width * height`` (2**28 = 268 435 456 px, e.g. 16384 x 16384).
MAX_PIXELS = 2 ** 28


def dimension_problem(width: int, height: int) -> str | None:
    """Why ``width x height`` is not an acceptable image size, or None when it is.

    Parameters
    ----------
    width, height : int
        Declared size in pixels.

    Returns
    -------
    str or None
        A short human-readable reason (no file name), or None.
    """
    if width < 1 or height < 1:
        return f"image size {width}x{height} is empty"
    if width > MAX_DIMENSION or height > MAX_DIMENSION:
        return f"image size {width}x{height} exceeds the limit of {MAX_DIMENSION} pixels per side"
    if width * height > MAX_PIXELS:
        return (f"image size {width}x{height} ({width * height} px) exceeds the limit of "
                f"{MAX_PIXELS} px")
    return None
