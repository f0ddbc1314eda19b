"""A byte budget for the sample file, as ``cwebp -size`` does: the densest grid that fits.

:func:`fit_budget` tries square grid strides from the densest and, at each stride, the
allowed codings from the most faithful; the first file that fits is the answer.  Every
candidate is really encoded and measured, so the file never exceeds the budget.
"""

from __future__ import annotations

from ..errors import OptionError
from ..sampling._patterns import SamplingPattern, sample_count
from ._codecs import LOSSY_CODECS, resolve_codec

#: Qualities a lossy codec tries, best first, when ``--size`` comes without ``--quality``.
#: The floor keeps the search from trading all fidelity for density.
BUDGET_QUALITIES = (95, 90, 85, 80, 75)
#: Low bits a lossless coding may drop, one at a time, when ``--size`` comes without
#: ``--bits``: on Teddy and Cones at the raw stride-5 bytes, stride 4 with 7 bits decodes
#: with 8.2 / 6.4 % bad pixels against 10.8 / 7.1 % for raw stride 5 (benchmarks/rate_distortion.py).
BUDGET_DROPPED_BITS = 2
#: Largest stride tried.
MAX_BUDGET_STRIDE = 64
#: No coding is assumed to shrink a payload more than this, so strides whose raw payload
#: is larger than ``budget * _MAX_RATIO`` are not even tried (saves encoder time only).
_MAX_RATIO = 20


def fit_budget(image, *, budget: int, codec: str | None = None, value_bits: int | None = None,
               quality: int | None = None, channel_order: str | None = None):
    """The densest square grid and coding whose ``.sbs`` file has at most ``budget`` bytes.

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, C), uint8 or uint16
        The right image.
    budget : int
        Largest file size in bytes (header included).
    codec : str, optional
        Only this codec (and raw, when the coded payload is no shorter); default: ``raw``
        then ``lossless``, never lossy unless asked.
    value_bits, quality : int, optional
        As :func:`stereobudget.io.write_samples`.  Without ``value_bits`` a lossless
        coding also tries dropping up to :data:`BUDGET_DROPPED_BITS` low bits; a lossy
        codec without ``quality`` tries :data:`BUDGET_QUALITIES`.
    channel_order : str, optional
        As :func:`stereobudget.io.encode_image`.

    Returns
    -------
    sample_set : SampleSet
    data : bytes
        The file, ``len(data) <= budget``.
    coding : dict
        ``codec``, ``value_bits``, ``quality`` as written.

    Raises
    ------
    OptionError
        Not even the sparsest grid fits.
    """
    from ._samples import HEADER_SIZE_V1_0, _coded_file, encode_image

    height, width = image.shape[:2]
    channels = 1 if image.ndim == 2 else image.shape[2]
    value_bytes = image.dtype.itemsize
    bits = 8 * value_bytes if value_bits is None else value_bits
    from ._codecs import DEFAULT_QUALITY, check_coding

    # (codec, bits, quality), most faithful first; every one is checked now, so that an
    # option error is not reported as "nothing fits" later.
    codings = []
    for name in ([codec] if codec else ["raw", "lossless"]):
        name = resolve_codec(name)
        if name in LOSSY_CODECS:
            codings += [(name, bits, q) for q in ([quality] if quality else BUDGET_QUALITIES)]
        elif name == "raw" or value_bits is not None:
            codings.append((name, bits, None))
        else:
            codings += [(name, b, None) for b in range(bits, max(bits - BUDGET_DROPPED_BITS, 1) - 1, -1)]
    for name, b, q in codings:
        check_coding(codec=name, value_bits=b, quality=q or DEFAULT_QUALITY, dtype_bytes=value_bytes,
                     pattern_kind="grid", channels=channels)
    if ("raw", bits, None) not in codings:
        codings.append(("raw", bits, None))    # what a coded payload falls back to anyway
    for stride in range(1, MAX_BUDGET_STRIDE + 1):
        pattern = SamplingPattern(kind="grid", stride_x=stride, stride_y=stride)
        n = sample_count(pattern, height, width) * channels
        if -(-n * bits // 8) > _MAX_RATIO * budget:
            continue
        sample_set = None
        for name, b, q in codings:
            if name == "raw" and HEADER_SIZE_V1_0 + -(-n * b // 8) > budget:
                continue   # its size is known without encoding
            if sample_set is None:
                sample_set = encode_image(image, pattern=pattern, channel_order=channel_order)
            try:
                data, used, kept_bits, used_q = _coded_file(sample_set, codec=name, value_bits=b, quality=q)
            except OptionError:
                continue   # e.g. a lattice too large for WebP: try the next coding
            if len(data) <= budget:
                return sample_set, data, {"codec": used, "value_bits": kept_bits, "quality": used_q}
    raise OptionError(f"no grid up to stride {MAX_BUDGET_STRIDE} fits in {budget} bytes for a "
                      f"{width}x{height} image (a file has an {HEADER_SIZE_V1_0}-byte header)")
