"""The camera-side job for one frame: read it, select its samples, code them, write the ``.sbs`` file.

:func:`encode_file` is the whole job for one image file; :func:`encode_frame` the same for
a frame already in memory (a stream's frames), returning the file's bytes.  A byte budget
(``size`` / ``size_fraction``) chooses the grid and coding through
:func:`stereobudget.encoding.fit_budget`.  A raw frame on a ``grid`` with the raw coding is
packed by bytes slicing (:mod:`stereobudget.io._rawgrid`), so the camera's common case
runs without numpy.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from ..errors import ImageReadError, OptionError
from ..io._atomic import STDIO, check_output_path, display_name, read_input_bytes, write_output_bytes
from ..io._samples import (HEADER_SIZE_V1_0, _DTYPE_CODE_BY_NAME, _DTYPE_NAMES, _check_writable, _coded_file,
                           _pack_file)
from ..sampling._patterns import SamplingPattern, sample_count
from ._budget import check_budget, fit_budget
from ._select import encode_image

log = logging.getLogger("stereobudget")


@dataclass(frozen=True)
class EncodeReport:
    """What :func:`encode_file` did (JSON-able through :meth:`as_dict`).

    Two fractions describe the file: ``pixel_fraction``, the pixels sampled (samples /
    pixels, the paper's epsilon; also under its older name ``epsilon``), and
    ``bytes_fraction``, the file's bytes over the raw image's (W x H x channels x bytes per
    value), the quantity a ``--epsilon`` / ``size_fraction`` budget bounds.
    """

    source: str
    output: str
    width: int
    height: int
    channels: int
    channel_order: str
    dtype: str
    pattern: str
    stride_x: int
    stride_y: int
    offset_x: int
    offset_y: int
    seed: int
    sample_count: int
    epsilon: float
    header_bytes: int
    payload_bytes: int
    file_size: int
    codec: str = "raw"
    value_bits: int = 8
    quality: int = 0
    bits_per_pixel: float = 0.0
    pixel_fraction: float = 0.0
    bytes_fraction: float = 0.0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def encode_file(source, output, *, pattern: SamplingPattern, raw_size: tuple[int, int] | None = None,
                pix_fmt: str | None = None, overwrite: bool = False, codec: str = "raw",
                value_bits: int | None = None, quality: int | None = None, size: int | None = None,
                size_fraction: float | None = None) -> EncodeReport:
    """Read one right image, keep its samples, and write the ``.sbs`` file atomically.

    This is the per-file unit of work of ``sb-encode`` (and of batch runners).

    Parameters
    ----------
    source : str or os.PathLike
        Image file (PNG, TIFF, JPEG, PPM...), or ``-`` for standard input.
    output : str or os.PathLike
        Sample file to write, or ``-`` for standard output.
    pattern : SamplingPattern
        ``grid`` or ``jitter`` (the patterns whose positions the camera can produce).
    raw_size : (width, height), optional
        Treat the input as one headerless frame of this size (needs ``pix_fmt``).
    pix_fmt : str, optional
        Raw pixel format, see :data:`stereobudget.io.RAW_PIXEL_FORMATS`.
    overwrite : bool
        Replace an existing output.
    codec, value_bits, quality
        Payload coding, see :func:`stereobudget.io.write_samples`.
    size : int, optional
        Byte budget of the file: the grid stride (``pattern`` gives only its kind) and
        the coding are chosen by :func:`stereobudget.encoding.fit_budget`.
    size_fraction : float, optional
        The budget as a fraction of the raw image bytes (W H channels bytes-per-value).

    Returns
    -------
    EncodeReport

    Raises
    ------
    OutputError, ImageReadError, OptionError
        Bad output path (checked before the input is read), unreadable input, or a
        pattern that leaves no sample on this image.
    """
    check_budget(size=size, size_fraction=size_fraction)
    check_output_path(output, [source], overwrite)
    name = display_name(source)
    log.debug("reading %s", name)
    coding = dict(codec=codec, value_bits=value_bits, quality=quality, size=size, size_fraction=size_fraction)
    if raw_size is not None:
        if pix_fmt is None:
            raise OptionError("a raw frame needs a pixel format (--pix-fmt)")
        frame = read_input_bytes(source, error=ImageReadError)
    else:
        from ..io import _images as imageio
        frame = imageio.read_image(source, name=name)
    data, report = encode_frame(frame, name=name, output=output, pattern=pattern, raw_size=raw_size,
                                pix_fmt=pix_fmt, **coding)
    write_output_bytes(output, data, overwrite=overwrite)
    return report


def encode_frame(frame, *, name: str, output, pattern: SamplingPattern, raw_size: tuple[int, int] | None = None,
                 pix_fmt: str | None = None, codec: str = "raw", value_bits: int | None = None,
                 quality: int | None = None, size: int | None = None,
                 size_fraction: float | None = None,
                 budget_hint: EncodeReport | None = None) -> tuple[bytes, EncodeReport]:
    """The ``.sbs`` bytes of one frame already in memory, and their report.

    ``frame`` is the bytes of one headerless frame when ``raw_size`` is given, else an
    ``(image, channel_order)`` pair as :func:`stereobudget.io.read_image` returns; the
    other arguments are those of :func:`encode_file` (``output`` only names the report's
    destination).  A raw frame on a ``grid`` with the raw coding is packed without numpy.
    ``budget_hint``, the report of the previous frame of a stream, starts the budget
    search (``size`` / ``size_fraction``) at that frame's choice: the same file, fewer
    trial encodes (:func:`stereobudget.encoding.fit_budget`).
    """
    if raw_size is not None:
        plain = codec == "raw" and value_bits is None and size is None and size_fraction is None
        if pattern.is_regular_grid and plain:
            # The camera's common case, without numpy: bytes slicing (see rawgrid).
            return _encode_raw_grid(frame, output, name=name, raw_size=raw_size, pix_fmt=pix_fmt,
                                    pattern=pattern)
        from ..io import _images as imageio  # numpy; OpenCV loads only for encoded images
        image, channel_order = imageio.read_raw(frame, width=raw_size[0], height=raw_size[1],
                                                pix_fmt=pix_fmt, name=name)
    else:
        image, channel_order = frame
    height, width = image.shape[:2]
    check_budget(size=size, size_fraction=size_fraction)
    if size_fraction is not None:
        size = int(size_fraction * image.size * image.dtype.itemsize)
    if size is not None:
        if pattern.kind != "grid" or (pattern.offset_x, pattern.offset_y) != (0, 0):
            raise OptionError("--size and --epsilon choose a grid stride: use the default grid pattern, "
                              "no offset")
        try:
            hint = None if budget_hint is None else {
                "stride": budget_hint.stride_x,
                "coding": {"codec": budget_hint.codec, "value_bits": budget_hint.value_bits,
                           "quality": budget_hint.quality}}
            sample_set, data, coding = fit_budget(image, budget=size, codec=None if codec == "raw" else codec,
                                                  value_bits=value_bits, quality=quality,
                                                  channel_order=channel_order, hint=hint)
        except OptionError as exc:
            raise OptionError(exc.message, path=exc.path or name) from None
        pattern = sample_set.pattern
    else:
        _count_samples(pattern, width, height, name)
        sample_set = encode_image(image, pattern=pattern, channel_order=channel_order)
        try:
            data, used, bits, q = _coded_file(sample_set, codec=codec, value_bits=value_bits, quality=quality)
        except OptionError as exc:
            raise OptionError(exc.message, path=exc.path or name) from None
        coding = {"codec": used, "value_bits": bits, "quality": q}
    return data, _report(name, output, width=width, height=height, channels=sample_set.channels,
                         channel_order=channel_order, dtype=str(sample_set.dtype), pattern=pattern,
                         sample_count=sample_set.values.shape[0], file_size=len(data), **coding)


def _encode_raw_grid(data, output, *, name: str, raw_size: tuple[int, int], pix_fmt: str,
                     pattern: SamplingPattern) -> tuple[bytes, EncodeReport]:
    """:func:`encode_frame` for a raw frame on a ``grid``: same checks, errors and bytes, no numpy."""
    from ..io._rawgrid import check_raw_frame, grid_payload

    width, height = raw_size
    channels, value_bytes, channel_order = check_raw_frame(data, width=width, height=height,
                                                           pix_fmt=pix_fmt, name=name)
    n = _count_samples(pattern, width, height, name)
    _check_writable(width, height, pattern)
    payload = grid_payload(data, width=width, height=height, pixel_bytes=channels * value_bytes,
                           stride_x=pattern.stride_x, stride_y=pattern.stride_y,
                           offset_x=pattern.offset_x, offset_y=pattern.offset_y)
    data = _pack_file(width=width, height=height, channel_order=channel_order, dtype_code=value_bytes,
                      pattern=pattern, sample_count=n, payload=payload)
    return data, _report(name, output, width=width, height=height, channels=channels,
                         channel_order=channel_order, dtype=_DTYPE_NAMES[value_bytes], pattern=pattern,
                         sample_count=n, file_size=len(data))


def _count_samples(pattern: SamplingPattern, width: int, height: int, name: str) -> int:
    """Samples the pattern takes from a ``width`` x ``height`` image; OptionError when none."""
    n = sample_count(pattern, height, width)
    if n == 0:
        raise OptionError(f"offset ({pattern.offset_x},{pattern.offset_y}) leaves no sample in a "
                          f"{width}x{height} image", path=name)
    return n


def _report(name: str, output, *, width: int, height: int, channels: int, channel_order: str, dtype: str,
            pattern: SamplingPattern, sample_count: int, file_size: int, codec: str = "raw",
            value_bits: int | None = None, quality: int = 0) -> EncodeReport:
    """The :class:`EncodeReport` of a file written by :func:`encode_file`."""
    return EncodeReport(
        source=name, output="<stdout>" if str(output) == STDIO else str(output),
        width=width, height=height, channels=channels, channel_order=channel_order, dtype=dtype,
        pattern=pattern.kind, stride_x=pattern.stride_x, stride_y=pattern.stride_y,
        offset_x=pattern.offset_x, offset_y=pattern.offset_y, seed=pattern.seed,
        sample_count=sample_count, epsilon=sample_count / float(height * width),
        header_bytes=HEADER_SIZE_V1_0, payload_bytes=file_size - HEADER_SIZE_V1_0, file_size=file_size,
        codec=codec, value_bits=value_bits or 8 * _DTYPE_CODE_BY_NAME[dtype], quality=quality,
        bits_per_pixel=8.0 * file_size / float(width * height),
        pixel_fraction=sample_count / float(height * width),
        bytes_fraction=file_size / float(width * height * channels * _DTYPE_CODE_BY_NAME[dtype]))


__all__ = ["EncodeReport", "encode_file", "encode_frame"]
