"""A byte budget for the sample file, as ``cwebp -size`` does: the densest grid that fits.

:func:`fit_budget` starts from the densest square grid whose raw file fits and tries
denser grids while one of the allowed codings fits, keeping the most faithful coding
that fits at the densest such stride.  Every candidate is really encoded and measured,
so the file never exceeds the budget.
"""

from __future__ import annotations

from ..errors import OptionError
from ..sampling._patterns import SamplingPattern, sample_count
from ._codecs import LOSSY_CODECS, resolve_codec

#: Qualities a lossy codec tries, best first, when ``--size`` comes without ``--quality``.
#: The floor keeps the search from trading all fidelity for density.
BUDGET_QUALITIES = (95, 90, 85, 80, 75)
#: Low bits a lossless coding may drop, one at a time, when ``--size`` comes without
#: ``--bits``: a denser grid of coarser values decodes better than a sparser exact one
#: until about 5 bits.  Over the 27 scenes of both sets at budgets of 2-11 % (Hybrid,
#: ``scripts/budget_bits.py``, docs/results.md), allowing 3 dropped bits rather than 2
#: lowers the mean bad pixels on realdev from 21.11 to 20.52 % and on Middlebury from 6.02
#: to 5.94 %; a fourth costs again (weak texture drowns in the quantisation).  Not at
#: stride 1, where the full-pair decoder matches every pixel.
BUDGET_DROPPED_BITS = 3
#: Largest stride tried.
MAX_BUDGET_STRIDE = 64


def grid(stride: int) -> SamplingPattern:
    return SamplingPattern(kind="grid", stride_x=stride, stride_y=stride)


def fit_budget(image, *, budget: int, codec: str | None = None, value_bits: int | None = None,
               quality: int | None = None, channel_order: str | None = None, hint: dict | None = None):
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
        coding also tries dropping up to :data:`BUDGET_DROPPED_BITS` low bits (not at
        stride 1); a lossy
        codec without ``quality`` tries :data:`BUDGET_QUALITIES`.
    channel_order : str, optional
        As :func:`stereobudget.io.encode_image`.
    hint : dict, optional
        The choice for a similar image (the previous frame of a stream): ``stride`` and the
        ``coding`` this function returned.  The search starts there, which spares most of
        its encodes when the choice holds; the result is the one the full search finds
        (file sizes growing with density and fidelity, as the search assumes anyway).

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
    usable = []
    for name, b, q in codings:
        try:
            check_coding(codec=name, value_bits=b, quality=q or DEFAULT_QUALITY, dtype_bytes=value_bytes,
                         pattern_kind="grid", channels=channels)
        except OptionError:
            if codec:
                raise
            continue   # the default search skips what cannot apply (WebP on 16 bits)
        usable.append((name, b, q))
    codings = usable
    def raw_size(stride, b):
        n = sample_count(SamplingPattern(kind="grid", stride_x=stride, stride_y=stride), height, width)
        return HEADER_SIZE_V1_0 + -(-n * channels * b // 8)

    # The sparsest grid is where the search starts: the densest stride whose raw file
    # fits (its size is known without encoding), or the sparsest stride tried.
    start = next((s for s in range(1, MAX_BUDGET_STRIDE + 1) if raw_size(s, bits) <= budget), None)
    coded = [c for c in codings if c[0] != "raw"][::-1]   # leanest first

    def allowed(stride):
        if stride == 1 and value_bits is None:
            # The full pair is matched by a census of the whole right image, which coarse
            # values break (15 % budget: Vintage 37.1 % bad at 5 bits against 24.0 % at
            # stride 2 with 8); dropped bits pay only on a sparse grid.
            return [c for c in coded if c[0] in LOSSY_CODECS or c[1] == bits]
        return coded

    def most_faithful(sample_set, candidates):
        """The last of ``candidates`` (in order of growing size) that fits, walking while they fit."""
        fitting = None
        for name, b, q in candidates:
            try:
                found = _coded_file(sample_set, codec=name, value_bits=b, quality=q)
            except OptionError:
                continue   # e.g. a lattice too large for WebP: try the next coding
            if len(found[0]) > budget:
                break
            fitting = (sample_set,) + found
        return fitting

    def densest_from(stride, best):
        # Denser grids while a coding fits.  At each stride the leanest coding is tried
        # first, then more faithful ones while they fit: a file grows with the stride's
        # density and with fidelity, so the first stride where even the leanest coding is
        # over budget ends the search (every candidate is measured, never estimated).
        for stride in range(stride, 0, -1):
            fitting = most_faithful(encode_image(image, pattern=grid(stride), channel_order=channel_order),
                                    allowed(stride))
            if fitting is None:
                break
            best = fitting
        return best

    sparsest = (start or MAX_BUDGET_STRIDE + 1) - 1

    def from_hint():
        """The most faithful coding that fits at the hinted stride, or None (then search in full).

        Only a hint the full search would reach is used: a coded stride no sparser than
        the search's first, and a coding the search tries.  From the hinted coding the walk
        goes up in fidelity while codings fit, or down until one does.
        """
        if not hint or not 1 <= int(hint.get("stride", 0)) <= sparsest:
            return None
        stride = int(hint["stride"])
        coding = hint.get("coding") or {}
        candidates = allowed(stride)
        # A lossless coding is named by codec and bits; a lossy one also by its quality.
        keys = [(n, b, q if n in LOSSY_CODECS else None) for n, b, q in candidates]
        name = coding.get("codec")
        key = (name, coding.get("value_bits"), coding.get("quality") if name in LOSSY_CODECS else None)
        if key not in keys:
            return None
        at = keys.index(key)
        sample_set = encode_image(image, pattern=grid(stride), channel_order=channel_order)
        fitting = most_faithful(sample_set, candidates[at:at + 1])
        if fitting is not None:
            return most_faithful(sample_set, candidates[at + 1:]) or fitting
        for lower in range(at - 1, -1, -1):
            fitting = most_faithful(sample_set, candidates[lower:lower + 1])
            if fitting is not None:
                return fitting
        return None

    hinted = from_hint()
    if hinted:
        best = densest_from(hinted[0].pattern.stride_x - 1, hinted)
    else:
        best = None
        if start is not None:
            sample_set = encode_image(image, pattern=grid(start), channel_order=channel_order)
            best = (sample_set,) + _coded_file(sample_set, codec="raw", value_bits=value_bits, quality=None)
        best = densest_from(sparsest, best)
    if best is not None:
        sample_set, data, used, kept_bits, used_q = best
        return sample_set, data, {"codec": used, "value_bits": kept_bits, "quality": used_q}
    raise OptionError(f"no grid up to stride {MAX_BUDGET_STRIDE} fits in {budget} bytes for a "
                      f"{width}x{height} image (a file has an {HEADER_SIZE_V1_0}-byte header)")

