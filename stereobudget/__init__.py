"""stereobudget: depth and the right image from a full left image plus sparse right-image samples.

The camera side (:mod:`stereobudget.container`, :mod:`stereobudget.sampling`) imports
neither numba nor OpenCV; the decoder is loaded on first use of :func:`decode`.
"""

from ._version import __version__

__all__ = ["__version__", "decode", "DecoderParams", "DecodeResult"]


def __getattr__(name):
    # Lazy: importing the decoder compiles/loads numba kernels, which the camera side never needs.
    if name in ("decode", "DecoderParams", "DecodeResult"):
        from . import decoders
        return getattr(decoders, name)
    raise AttributeError(f"module 'stereobudget' has no attribute {name!r}")
