"""Names of the decoders.

Kept apart from :mod:`stereobudget.decoding._decoders` so that the command line can list them and
show the default in ``--help`` without importing numba and OpenCV.
"""

#: The decoders :func:`stereobudget.decode` accepts (paper Fig. 2, plus the full pair).
METHODS = ("hybrid", "sparse", "downsample", "full")
#: Method used when the caller does not choose one.
DEFAULT_METHOD = "hybrid"
