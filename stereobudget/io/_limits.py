"""Hard size limits of the readers, and the memory budget of a decode.

Both readers check these *before* allocating anything proportional to the declared
size, so a 100-byte file that claims to be 10^6 x 10^6 pixels is rejected at once.
The numbers are part of the ``.sbs`` format specification (``docs/format.md``).

:func:`estimate_decode_memory` predicts the peak memory of a decode from the image
size, the disparity range and the method; :func:`stereobudget.decoding.decode` refuses
(:class:`~stereobudget.errors.MemoryLimitError`) a job whose estimate exceeds the limit
(``--max-memory``, ``$STEREOBUDGET_MAX_MEMORY``, or 75 % of the available memory).
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

_FLOAT32 = 4
#: Bytes per pixel the decoders hold besides the cost volumes and bilateral grids:
#: float32 copies of I1 (and of the interpolated right image), the gray guide, the
#: x-gradients, the two trees while they are built (edge keys, sorted edges, order,
#: parent, weight), the low-pass grids of Hybrid and the disparity maps.  Measured
#: peaks stay below this (see tests/cli/test_robustness.py and docs/errors.md).
_PER_PIXEL_OVERHEAD = 192
#: Safety margin on the volume terms (allocator slack, numba thread-local buffers).
_VOLUME_MARGIN = 1.10
#: Fixed allowance for small arrays (kernels, LUTs) independent of the image size.
_FIXED_OVERHEAD = 16 * 2 ** 20

_SIZE_UNITS = {"": 1, "B": 1, "K": 2 ** 10, "M": 2 ** 20, "G": 2 ** 30, "T": 2 ** 40}

#: Volume rows are padded to a multiple of this many float32 layers (32 bytes).
LAYER_QUANTUM = 8


def volume_layers(num_disp: int) -> int:
    """Layers a decoder computes and stores per pixel for ``num_disp`` disparities.

    ``num_disp`` rounded up to a multiple of :data:`LAYER_QUANTUM`: the extra layers
    are the next disparities, computed and aggregated like the others (every layer is
    independent of the rest) but never allowed to win.  Rows of whole 32-byte vectors
    leave no scalar tail in any per-pixel loop and keep the rows of 64 layers on cache
    lines: Teddy's 61 disparities decode faster as 64 layers than as 61 (the cost kernel
    ~14 %, scripts/bench.py).
    """
    num_disp = int(num_disp)
    return -(-num_disp // LAYER_QUANTUM) * LAYER_QUANTUM


def _bilateral_grid_bytes(height: int, width: int, num_disp: int, *, stride: float,
                          sigma_s_per_stride: float, sigma_r: float, cells_per_sigma_s: float,
                          cells_per_sigma_r: float) -> int:
    """Bytes of one float32 (GY, GX, GZ, D) grid of the Sparse fill (see bilateral.grid_geometry)."""
    # Mirrors bilateral.grid_geometry with the largest possible guide value (255: every
    # guide is in 8-bit units), so it never underestimates.
    cell_s = max(sigma_s_per_stride * stride / cells_per_sigma_s, 1.0)
    cell_r = max(sigma_r / cells_per_sigma_r, 1e-3)
    gy = int(_math.floor((height - 1) / cell_s)) + 2
    gx = int(_math.floor((width - 1) / cell_s)) + 2
    gz = int(_math.floor(255.0 / cell_r)) + 2
    return gy * gx * gz * num_disp * _FLOAT32


def estimate_decode_memory(height: int, width: int, num_disp: int, method: str, *,
                           stride_x: int = 5, stride_y: int = 5, sigma_s_per_stride: float = 1.5,
                           sigma_r: float = 15.0, cells_per_sigma_s: float = 1.0,
                           cells_per_sigma_r: float = 1.0) -> int:
    """Conservative estimate of the peak memory of :func:`stereobudget.decoding.decode`, in bytes.

    The decoders are dominated by float32 ``(H, W, D)`` cost volumes (``V`` bytes each)
    and, for the Sparse fill, two float32 bilateral grids ``(GY, GX, GZ, D)`` (``G``
    bytes each) of which a separable blur keeps a third copy:

    ================  ================================  ====================================
    method            at most alive at once             where
    ================  ================================  ====================================
    ``sparse``        ``max(3 G, 2 G + V)``             grid blur; grids + sliced volume
    ``hybrid``        ``max(3 G, 2 G + 3 V)``           grid blur; the cost and the two
                                                        semi-global sums while the sliced
                                                        grids wait in the spare pool for
                                                        the next decode (the tree route
                                                        needs 2 G + 2 V)
    ``full``          ``2 V + V / 4``                   the uint8 census volume and the two
                                                        float32 sums of the semi-global
                                                        paths (from above, from below)
    ``downsample``    ``2 V``                           left + right-view volume during the
                                                        left-right check; left + refinement
                                                        volume after it
    ================  ================================  ====================================

    A margin of 10 % on the volume terms, 192 bytes per pixel for images, trees and
    disparity maps, and 16 MiB of fixed allowance are added.  Measured peaks
    (``scripts/measure_decode_memory.py``: peak RSS above the resting RSS after JIT
    warm-up) are 56-85 % of the estimate at 450x375 and 1152x900; the grid terms are
    those of the general fill (jitter, fps), looser for regular grids (docs/errors.md).

    Parameters
    ----------
    height, width : int
        Image size in pixels.
    num_disp : int
        Number of disparities searched (``max_disp - min_disp + 1``).
    method : {"sparse", "hybrid", "full", "downsample"}
        The decoder that will actually run (a stride-1 file runs ``full``).
    stride_x, stride_y : int
        Sampling strides (the Sparse fill's grid cell is proportional to the stride).
    sigma_s_per_stride, sigma_r : float
        Fill sigmas (:class:`stereobudget.decoding.DecoderParams`).
    cells_per_sigma_s, cells_per_sigma_r : float
        Resolution of the fill's bilateral grid (``DecoderParams.grid_cells_per_sigma_*``).

    Returns
    -------
    int
        Bytes.
    """
    if height < 1 or width < 1 or num_disp < 1:
        raise ValueError(f"size {width}x{height} with {num_disp} disparities is empty")
    pixels = int(height) * int(width)
    num_disp = volume_layers(num_disp)
    volume = pixels * num_disp * _FLOAT32
    if method in ("sparse", "hybrid"):
        stride = _math.sqrt(max(int(stride_x), 1) * max(int(stride_y), 1))
        grid = _bilateral_grid_bytes(height, width, num_disp, stride=stride,
                                     sigma_s_per_stride=sigma_s_per_stride, sigma_r=sigma_r,
                                     cells_per_sigma_s=cells_per_sigma_s, cells_per_sigma_r=cells_per_sigma_r)
        # Hybrid slices its grids inside the kernel that writes both views' volumes.
        peak = max(3 * grid, 2 * grid + (volume if method == "sparse" else 3 * volume))
    elif method == "full":
        peak = 2 * volume + volume // 4
    elif method == "downsample":
        peak = 2 * volume
    else:
        raise ValueError(f"unknown method {method!r}")
    return int(peak * _VOLUME_MARGIN) + _PER_PIXEL_OVERHEAD * pixels + _FIXED_OVERHEAD


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
    if not _math.isfinite(value) or value <= 0:
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


def check_decode_memory(height: int, width: int, num_disp: int, method: str, *,
                        max_memory: int | None = None, stride_x: int = 5, stride_y: int = 5,
                        sigma_s_per_stride: float = 1.5, sigma_r: float = 15.0,
                        cells_per_sigma_s: float = 1.0, cells_per_sigma_r: float = 1.0) -> int:
    """Raise :class:`~stereobudget.errors.MemoryLimitError` when a decode would exceed the limit.

    Parameters
    ----------
    height, width, num_disp, method, stride_x, stride_y, sigma_s_per_stride, sigma_r, cells_per_sigma_s, cells_per_sigma_r
        As :func:`estimate_decode_memory`.
    max_memory : int, optional
        Limit in bytes; default :func:`default_memory_limit`.

    Returns
    -------
    int
        The estimate, in bytes.
    """
    from ..errors import MemoryLimitError, OptionError

    needed = estimate_decode_memory(height, width, num_disp, method, stride_x=stride_x,
                                    stride_y=stride_y, sigma_s_per_stride=sigma_s_per_stride,
                                    sigma_r=sigma_r, cells_per_sigma_s=cells_per_sigma_s,
                                    cells_per_sigma_r=cells_per_sigma_r)
    if max_memory is None:
        try:
            limit = default_memory_limit()
        except ValueError as exc:
            raise OptionError(f"${MEMORY_LIMIT_ENV}: {exc}") from None
        source = f"{int(DEFAULT_MEMORY_FRACTION * 100)} % of the available memory"
        if _os.environ.get(MEMORY_LIMIT_ENV):
            source = f"${MEMORY_LIMIT_ENV}"
    else:
        limit, source = int(max_memory), "--max-memory"
    if limit is not None and needed > limit:
        raise MemoryLimitError(
            f"decoding {width}x{height} with {num_disp} disparities ({method}) needs about "
            f"{format_size(needed)} but {format_size(limit)} is allowed ({source}); narrow the "
            f"--min-disp/--max-disp range, use a smaller image, or raise --max-memory")
    return needed
