"""A byte budget for the sample file, as ``cwebp -size`` does: the densest grid that fits.

:func:`fit_budget` starts from the densest square grid whose raw file fits and tries
denser grids while one of the allowed codings fits, keeping the most faithful coding
that fits at the densest such stride.  Every candidate is really encoded and measured,
so the file never exceeds the budget.  :class:`BudgetSearch` holds one search's image,
budget and candidate codings; its steps are methods.
"""

from __future__ import annotations

from ..errors import OptionError
from ..io._codecs import DEFAULT_QUALITY, LOSSY_CODECS, check_coding, resolve_codec
from ..io._samples import HEADER_SIZE_V1_0, _coded_file
from ..sampling._patterns import SamplingPattern, sample_count
from ._select import encode_image

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


def check_budget(*, size: int | None = None, size_fraction: float | None = None) -> None:
    """Refuse a byte budget that is not a positive size, or a fraction outside (0, 1] (NaN among them).

    Raises
    ------
    OptionError
        As the ``--size`` / ``--epsilon`` options of ``sb-encode`` would say it.
    """
    if size is not None and not (isinstance(size, int) and size >= 1):
        raise OptionError(f"--size must be a positive number of bytes, got {size!r}")
    if size_fraction is not None:
        import numbers
        real = isinstance(size_fraction, numbers.Real) and not isinstance(size_fraction, bool)
        fraction = float(size_fraction) if real else float("nan")
        if not 0.0 < fraction <= 1.0:        # also false for NaN
            raise OptionError(f"--epsilon must be a fraction of the raw image bytes in (0, 1], "
                              f"got {size_fraction!r}")


class BudgetSearch:
    """One image's search for the densest grid and most faithful coding within a byte budget.

    The arguments are those of :func:`fit_budget`.  Codings are ``(codec, value_bits,
    quality)`` tuples, most faithful first; a candidate is ``(sample_set, data, codec,
    value_bits, quality)``, the file that coding really gives.
    """

    def __init__(self, image, *, budget: int, codec: str | None = None, value_bits: int | None = None,
                 quality: int | None = None, channel_order: str | None = None):
        self.image = image
        self.budget = budget
        self.value_bits = value_bits
        self.channel_order = channel_order
        self.height, self.width = image.shape[:2]
        self.channels = 1 if image.ndim == 2 else image.shape[2]
        self.bits = 8 * image.dtype.itemsize if value_bits is None else value_bits
        self.codings = self._usable_codings(codec, quality, value_bytes=image.dtype.itemsize)
        # The sparsest grid is where the search starts: the densest stride whose raw file
        # fits (its size is known without encoding), or the sparsest stride tried.
        self.start = next((s for s in range(1, MAX_BUDGET_STRIDE + 1) if self.raw_size(s) <= budget), None)
        self.sparsest = (self.start or MAX_BUDGET_STRIDE + 1) - 1
        self.coded = [c for c in self.codings if c[0] != "raw"][::-1]   # leanest first

    def _usable_codings(self, codec, quality, *, value_bytes):
        """Every coding the search may try, each checked now, so that an option error is not
        reported as "nothing fits" later."""
        codings = []
        for name in ([codec] if codec else ["raw", "lossless"]):
            name = resolve_codec(name)
            if name in LOSSY_CODECS:
                codings += [(name, self.bits, q) for q in ([quality] if quality else BUDGET_QUALITIES)]
            elif name == "raw" or self.value_bits is not None:
                codings.append((name, self.bits, None))
            else:
                codings += [(name, b, None)
                            for b in range(self.bits, max(self.bits - BUDGET_DROPPED_BITS, 1) - 1, -1)]
        usable = []
        for name, b, q in codings:
            try:
                check_coding(codec=name, value_bits=b, quality=q or DEFAULT_QUALITY, dtype_bytes=value_bytes,
                             pattern_kind="grid", channels=self.channels)
            except OptionError:
                if codec:
                    raise
                continue   # the default search skips what cannot apply (WebP on 16 bits)
            usable.append((name, b, q))
        return usable

    def raw_size(self, stride: int) -> int:
        """Bytes of the raw-coded file at ``stride``, known without encoding."""
        n = sample_count(grid(stride), self.height, self.width)
        return HEADER_SIZE_V1_0 + -(-n * self.channels * self.bits // 8)

    def select(self, stride: int):
        return encode_image(self.image, pattern=grid(stride), channel_order=self.channel_order)

    def allowed(self, stride: int) -> list:
        """The coded candidates at ``stride``, leanest first."""
        if stride == 1 and self.value_bits is None:
            # The full pair is matched by a census of the whole right image, which coarse
            # values break (15 % budget: Vintage 37.1 % bad at 5 bits against 24.0 % at
            # stride 2 with 8); dropped bits pay only on a sparse grid.
            return [c for c in self.coded if c[0] in LOSSY_CODECS or c[1] == self.bits]
        return self.coded

    def most_faithful(self, sample_set, candidates):
        """The last of ``candidates`` (in order of growing size) that fits, walking while they fit."""
        fitting = None
        for name, b, q in candidates:
            try:
                found = _coded_file(sample_set, codec=name, value_bits=b, quality=q)
            except OptionError:
                continue   # e.g. a lattice too large for WebP: try the next coding
            if len(found[0]) > self.budget:
                break
            fitting = (sample_set,) + found
        return fitting

    def densest_from(self, stride: int, best):
        """Denser grids from ``stride`` while a coding fits; the last that did (else ``best``).

        At each stride the leanest coding is tried first, then more faithful ones while they
        fit: a file grows with the stride's density and with fidelity, so the first stride
        where even the leanest coding is over budget ends the search (every candidate is
        measured, never estimated).
        """
        for stride in range(stride, 0, -1):
            fitting = self.most_faithful(self.select(stride), self.allowed(stride))
            if fitting is None:
                break
            best = fitting
        return best

    def from_hint(self, hint: dict | None):
        """The most faithful coding that fits at the hinted stride, or None (then search in full).

        Only a hint the full search would reach is used: a coded stride no sparser than
        the search's first, and a coding the search tries.  From the hinted coding the walk
        goes up in fidelity while codings fit, or down until one does.
        """
        if not hint or not 1 <= int(hint.get("stride", 0)) <= self.sparsest:
            return None
        stride = int(hint["stride"])
        coding = hint.get("coding") or {}
        candidates = self.allowed(stride)
        # A lossless coding is named by codec and bits; a lossy one also by its quality.
        keys = [(n, b, q if n in LOSSY_CODECS else None) for n, b, q in candidates]
        name = coding.get("codec")
        key = (name, coding.get("value_bits"), coding.get("quality") if name in LOSSY_CODECS else None)
        if key not in keys:
            return None
        at = keys.index(key)
        sample_set = self.select(stride)
        fitting = self.most_faithful(sample_set, candidates[at:at + 1])
        if fitting is not None:
            return self.most_faithful(sample_set, candidates[at + 1:]) or fitting
        for lower in range(at - 1, -1, -1):
            fitting = self.most_faithful(sample_set, candidates[lower:lower + 1])
            if fitting is not None:
                return fitting
        return None

    def run(self, hint: dict | None = None):
        """The search's result, as :func:`fit_budget` returns it."""
        hinted = self.from_hint(hint)
        if hinted:
            best = self.densest_from(hinted[0].pattern.stride_x - 1, hinted)
        else:
            best = None
            if self.start is not None:
                sample_set = self.select(self.start)
                best = (sample_set,) + _coded_file(sample_set, codec="raw", value_bits=self.value_bits,
                                                   quality=None)
            best = self.densest_from(self.sparsest, best)
        if best is not None:
            sample_set, data, used, kept_bits, used_q = best
            return sample_set, data, {"codec": used, "value_bits": kept_bits, "quality": used_q}
        raise OptionError(f"no grid up to stride {MAX_BUDGET_STRIDE} fits in {self.budget} bytes for a "
                          f"{self.width}x{self.height} image (a file has an {HEADER_SIZE_V1_0}-byte header)")


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
        As :func:`stereobudget.encoding.encode_image`.
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
    return BudgetSearch(image, budget=budget, codec=codec, value_bits=value_bits, quality=quality,
                        channel_order=channel_order).run(hint)


__all__ = ["BUDGET_QUALITIES", "BUDGET_DROPPED_BITS", "MAX_BUDGET_STRIDE", "check_budget", "BudgetSearch", "fit_budget"]
