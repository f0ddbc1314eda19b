"""Hard size limits of the readers, and the memory a decode may use.

Both readers check these *before* allocating anything proportional to the declared
size, so a 100-byte file that claims to be 10^6 x 10^6 pixels is rejected at once.
The numbers are part of the ``.sbs`` format specification (``docs/format.md``).

:func:`default_memory_limit` is what a decode may use when no limit is given
(``$STEREOBUDGET_MAX_MEMORY``, or 75 % of the available memory); what a decode needs is
the decoders' own model (:func:`stereobudget.decoding.estimate_decode_memory`).
"""

from __future__ import annotations

import math as _math
import os as _os

#: Largest width or height, in pixels (fits the u16 stride / offset fields of the format).
MAX_DIMENSION = 65535
#: Largest pixel count ``width * height`` (2**28 = 268 435 456 px, e.g. 16384 x 16384).
MAX_PIXELS = 2 ** 28
#: Largest input file read into memory: a 16-bit RGBA image of MAX_PIXELS uncompressed
#: (2 GiB) plus room for headers; a .sbs file is at most 80 + 6 MAX_PIXELS bytes.  Pipes
#: and devices are read in chunks and cut off here, so ``/dev/zero`` cannot exhaust memory.
MAX_INPUT_BYTES = 2 ** 31 + 2 ** 24


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


# =====================================================================================
# Memory: estimate a decode's peak before allocating anything, and the default limit
# =====================================================================================


#: Fraction of the available memory a decode may use when no limit is given.
DEFAULT_MEMORY_FRACTION = 0.75
#: Environment variable that sets the default limit (same syntax as ``--max-memory``).
MEMORY_LIMIT_ENV = "STEREOBUDGET_MAX_MEMORY"

_SIZE_UNITS = {"": 1, "B": 1, "K": 2 ** 10, "M": 2 ** 20, "G": 2 ** 30, "T": 2 ** 40}

def available_memory() -> int | None:
    """Memory a decode can have without swapping, in bytes (None if unknown).

    ``MemAvailable`` from ``/proc/meminfo`` (Linux), else free physical pages from
    ``os.sysconf``; a cgroup memory limit below that (containers) is honoured.  The
    spare volumes this process holds for its next decode (:mod:`stereobudget._kernels._scratch`)
    are added: that decode reuses them or frees them first.
    """
    available = _system_available_memory()
    if available is not None:
        # Not imported here when absent (then nothing is held): the camera side stays
        # free of numpy.
        import sys as _sys
        scratch = _sys.modules.get("stereobudget._kernels._scratch")
        if scratch is not None:
            available += scratch.spare_bytes()
    return available


def _system_available_memory() -> int | None:
    available = None
    try:
        with open("/proc/meminfo", "rb") as handle:
            for line in handle:
                if line.startswith(b"MemAvailable:"):
                    available = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        available = None
    if available is None:
        try:
            available = _os.sysconf("SC_AVPHYS_PAGES") * _os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, ValueError, OSError):
            available = None
    cgroup = _cgroup_headroom()
    if cgroup is not None:
        available = cgroup if available is None else min(available, cgroup)
    return available


def _cgroup_headroom() -> int | None:
    # cgroup v2: memory.max ("max" = unlimited) minus memory.current.
    try:
        with open("/sys/fs/cgroup/memory.max") as handle:
            limit = handle.read().strip()
        if limit == "max":
            return None
        with open("/sys/fs/cgroup/memory.current") as handle:
            used = int(handle.read().strip())
        return max(int(limit) - used, 0)
    except (OSError, ValueError):
        return None


def parse_size(text: str) -> int:
    """``"8G"``, ``"500M"``, ``"1.5GiB"``, ``"123456"`` -> bytes (binary units: K = 1024).

    Raises
    ------
    ValueError
        With a readable message, for anything else or a size that is not positive.
    """
    raw = str(text).strip()
    number = raw.upper().replace(" ", "")
    for suffix in ("IB", "B"):
        if number.endswith(suffix) and len(number) > len(suffix) and number[-len(suffix) - 1] in "KMGT":
            number = number[:-len(suffix)]
            break
    unit = number[-1:] if number[-1:] in "KMGT" and number[-1:] else ""
    digits = number[:-1] if unit else number
    try:
        value = float(digits)
    except ValueError:
        raise ValueError(f"memory size must look like 8G, 500M or 1.5G (units K, M, G, T), "
                         f"got {raw!r}") from None
    if not _math.isfinite(value):
        raise ValueError(f"memory size must be a finite number, got {raw!r}")
    if value <= 0:
        raise ValueError(f"memory size must be positive, got {raw!r}")
    return int(value * _SIZE_UNITS[unit])


def format_size(nbytes: float) -> str:
    """Human-readable binary size: ``1.5 GiB``, ``300 MiB``."""
    value = float(nbytes)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(value) < 1024 or unit == "GiB":
            break
        value /= 1024
    if unit == "GiB" and abs(value) >= 1024:
        return f"{value / 1024:.1f} TiB"
    return f"{value:.0f} {unit}" if unit in ("B", "KiB") or value >= 100 else f"{value:.1f} {unit}"


def default_memory_limit() -> int | None:
    """The limit used when none is given: ``$STEREOBUDGET_MAX_MEMORY``, else 75 % of available memory.

    Returns None when neither is known (then no limit is enforced).

    Raises
    ------
    ValueError
        ``$STEREOBUDGET_MAX_MEMORY`` is set but not a size.
    """
    env = _os.environ.get(MEMORY_LIMIT_ENV)
    if env:
        return parse_size(env)
    available = available_memory()
    return None if available is None else int(available * DEFAULT_MEMORY_FRACTION)
