"""``sb-encode``: the right camera's job -- keep a sparse set of pixels, write a ``.sbs`` file.

The command is a thin layer over :func:`stereobudget.encoding.encode_file`.  It must
start fast on the camera: nothing here (nor in what ``--raw`` reaches) imports numba or
OpenCV; OpenCV is loaded only when an encoded image (PNG, JPEG...) has to be decoded.
A raw frame on the default ``grid`` pattern, and ``--info``, do not import numpy either
(:mod:`stereobudget.io._rawgrid`): its import was most of the process's run time.
"""

from __future__ import annotations

import logging

import click

from stereobudget.errors import OptionError
from stereobudget.sampling import PATTERN_KINDS   # no numpy: --help stays light

from . import _batch
from . import _common as common

log = logging.getLogger("stereobudget")

_RAW_PIX_FMTS = ("gray8", "rgb24", "bgr24", "gray16le",   # = imageio.RAW_PIXEL_FORMATS
                 "bayer_rggb8", "bayer_bggr8", "bayer_grbg8", "bayer_gbrg8",
                 "bayer_rggb16le", "bayer_bggr16le", "bayer_grbg16le", "bayer_gbrg16le")
_U16 = click.IntRange(1, 65535)


class _Fraction(click.ParamType):
    """``--epsilon``: a number in (0, 1]; NaN and infinities are refused like any other value outside."""

    name = "FRACTION"

    def convert(self, value, param, ctx):
        if isinstance(value, float):
            number = value
        else:
            try:
                number = float(str(value).strip())
            except ValueError:
                self.fail(f"{value!r} is not a number", param, ctx)
        if not 0.0 < number <= 1.0:      # also false for nan
            self.fail(f"{value!r} is not a fraction in the range 0<x<=1", param, ctx)
        return number


def _parse_offset(text: str) -> tuple[int, int]:
    parts = text.replace(" ", "").split(",")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise OptionError(f"--offset must look like X,Y (two non-negative integers), got {text!r}")
    return int(parts[0]), int(parts[1])


def build_pattern(*, pattern: str, stride: int, stride_x: int | None, stride_y: int | None,
                  offset: str | None, seed: int | None):
    """The :class:`~stereobudget.sampling.SamplingPattern` described by sb-encode's options.

    Raises
    ------
    OptionError
        Offset outside the stride, an offset with any pattern but ``grid``, a seed with
        ``grid`` or ``downsample``.
    """
    from stereobudget.sampling import SamplingPattern

    sx = stride if stride_x is None else stride_x
    sy = stride if stride_y is None else stride_y
    ox, oy = _parse_offset(offset) if offset is not None else (0, 0)
    if pattern != "grid" and offset is not None:
        raise OptionError(f"--offset applies to --pattern grid only, not {pattern}")
    if pattern in ("grid", "downsample") and seed is not None:
        raise OptionError("--seed applies to --pattern fps, adaptive_fps or jitter only")
    if not (ox < sx and oy < sy):
        raise OptionError(f"--offset {ox},{oy} must be smaller than the stride {sx}x{sy}")
    return SamplingPattern(kind=pattern, stride_x=sx, stride_y=sy, offset_x=ox, offset_y=oy,
                           seed=seed or 0)


def build_coding(*, codec: str, value_bits: int | None, quality: int | None, size: str | None,
                 size_fraction: float | None, pattern: str) -> dict:
    """Keyword arguments of :func:`stereobudget.encoding.encode_file` for sb-encode's coding options.

    Empty for the default raw coding, so that path stays the plain (numpy-free) one.

    Raises
    ------
    OptionError
        --size with --epsilon, --quality without a lossy codec, a budget with another
        pattern than grid, an unparsable size.
    """
    coding = {}
    if size is not None and size_fraction is not None:
        raise OptionError("give --size or --epsilon, not both")
    if quality is not None and codec not in ("webp", "jxl"):
        raise OptionError(f"--quality applies to --codec webp or jxl, not {codec}")
    if (size is not None or size_fraction is not None) and pattern != "grid":
        raise OptionError(f"--size / --epsilon choose a grid stride: they need --pattern grid, not {pattern}")
    if size is not None:
        if not size.strip().isdigit() or int(size) < 1:
            raise OptionError(f"--size must be a positive number of bytes, got {size!r}")
        coding["size"] = int(size)
    if size_fraction is not None:
        coding["size_fraction"] = size_fraction
    if codec != "raw":
        coding["codec"] = codec
    if value_bits is not None:
        coding["value_bits"] = value_bits
    if quality is not None:
        coding["quality"] = quality
    return coding


def _stream_inputs(images, output: str, *, raw_size, pix_fmt) -> list[str] | None:
    """The inputs of a frame stream, or None when this run is one file or a batch of files.

    A stream: a raw input from standard input (a camera pipe), a raw file longer than
    one frame, an ``-o`` naming frames by ``{index}``, or several images to ``-o -``.
    """
    from stereobudget.batch._inputs import IMAGE_EXTENSIONS, expand_inputs, uses_field

    per_frame = uses_field(output, "index", "-o")
    if raw_size is not None:
        if len(images) != 1:
            if per_frame or output == "-":
                raise OptionError(f"a raw stream is one input (a file or '-'), got {len(images)}")
            return None
        source = images[0]
        if source == "-" or per_frame:
            return [source]
        from stereobudget.io import raw_frame_layout
        channels, value_bytes, _ = raw_frame_layout(width=raw_size[0], height=raw_size[1], pix_fmt=pix_fmt,
                                                    name=source)
        import os
        try:
            longer = os.path.getsize(source) > raw_size[0] * raw_size[1] * channels * value_bytes
        except OSError:
            return None      # the single-file path reports it
        return [source] if longer else None
    if not (per_frame or output == "-"):
        return None
    inputs = expand_inputs(images, extensions=IMAGE_EXTENSIONS, what="image")
    if len(inputs) > 1 and "-" in inputs:
        raise OptionError("'-' (standard input) works with a single input only")
    return inputs if len(inputs) > 1 or per_frame else None


def _encode_stream(inputs, output, *, pattern, raw_size, pix_fmt, overwrite, coding, as_json) -> None:
    """``sb-encode`` of a stream: every frame in this process, in order (stereobudget.batch.encode_stream)."""
    import time

    from stereobudget.batch import encode_stream

    start = time.perf_counter()
    frames = 0
    for item in encode_stream(inputs, output, pattern=pattern, raw_size=raw_size, pix_fmt=pix_fmt,
                              overwrite=overwrite, coding=coding):
        frames += 1
        log.info("%s -> %s: %d samples, %d bytes", item["source"], item["output"], item["sample_count"],
                 item["file_size"])
        if as_json:
            common.emit_json(item)
    seconds = time.perf_counter() - start
    if raw_size is not None and frames > 1 and output != "-" and "{" not in output:
        # A wrong --raw size also reads as several frames: say what was written.
        log.warning("%s: %d frames of %dx%d %s, written as one %d-frame stream to %s", inputs[0], frames,
                    raw_size[0], raw_size[1], pix_fmt, frames, output)
    log.info("%d frame(s) in %.3f s (%.1f frames/s)", frames, seconds, frames / max(seconds, 1e-9))


def _show_info(path, *, verify: bool, decode: bool) -> None:
    """One JSON line per frame: one for a file, one per frame of a stream (or of standard input)."""
    from stereobudget.io import holds_several_frames, probe
    if path != "-" and not holds_several_frames(path):
        common.emit_json(probe(path, verify_payload=verify, decode_payload=decode))
        return
    from stereobudget.io import sample_frames
    from stereobudget.io._stream import frame_label
    name = "<stdin>" if path == "-" else path
    for index, frame in enumerate(sample_frames(path)):
        info = probe(frame, verify_payload=verify, decode_payload=decode,
                     name=frame_label(name, index) if index else name)
        info["frame"] = index
        common.emit_json(info)


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("images", nargs=-1, metavar="RIGHT_IMAGE...")
@click.option("-o", "--output", metavar="OUT.sbs",
              help="Sample file to write ('-' = stdout); with several inputs a template such as "
                   "'out/{stem}.sbs' ({stem}, {name}, {parent} of each input); for the frames of a "
                   "stream 'out/{index:05d}.sbs'.")
@click.option("--stride", type=_U16, default=5, show_default=True,
              help="Grid spacing in pixels, both directions (epsilon ~ 1/stride^2).")
@click.option("--stride-x", type=_U16, default=None, help="Horizontal spacing (overrides --stride).")
@click.option("--stride-y", type=_U16, default=None, help="Vertical spacing (overrides --stride).")
@click.option("--offset", metavar="X,Y", default=None,
              help="Position of the first grid sample, 0 <= offset < stride.  [default: 0,0]")
@click.option("--pattern", type=click.Choice(PATTERN_KINDS),
              default="grid", show_default=True,
              help="grid: I2[oy::sy, ox::sx]; jitter: one pseudo-random pixel per cell; fps / "
                   "adaptive_fps: farthest point sampling with the grid's budget; downsample: "
                   "block means (see docs/format.md).")
@click.option("--seed", type=click.IntRange(0, 2 ** 64 - 1), default=None,
              help="Seed of the jitter/fps/adaptive_fps pattern (0..2^64-1).  [default: 0]")
@click.option("--raw", "raw_size", metavar="WxH", default=None,
              help="Input is headerless frames of this size, one or a stream of them (needs --pix-fmt).")
@click.option("--pix-fmt", type=click.Choice(_RAW_PIX_FMTS), default=None,
              help="Pixel format of a --raw frame; bayer_* is a raw sensor mosaic (one value per pixel, "
                   "sent as it is: no demosaicing; use an odd --stride so that every colour is sampled).")
@click.option("--codec", type=click.Choice(["raw", "lossless", "deflate", "webp_lossless", "jxl_lossless",
                                             "webp", "jxl"]),
              default="raw", show_default=True,
              help="Payload coding: raw copies the values (no computation); lossless = JPEG XL "
                   "lossless (WebP lossless without imagecodecs); webp / jxl are lossy (see "
                   "docs/format.md).  Image codecs need --pattern grid or downsample.")
@click.option("--bits", "value_bits", type=click.IntRange(1, 16), default=None,
              help="Keep only the top N bits of every value (any codec; costs nothing).  [default: all]")
@click.option("--quality", type=click.IntRange(1, 100), default=None,
              help="Quality of --codec webp / jxl.  [default: 90; with --size the best that fits]")
@click.option("--size", "size_bytes", metavar="BYTES", default=None, type=str,
              help="Byte budget of the file (e.g. 20000): the densest grid stride and coding "
                   "that fit (raw, or lossless keeping 8 to 5 bits, unless --codec / --bits say "
                   "otherwise); never exceeded.")
@click.option("--epsilon", "size_fraction", type=_Fraction(), default=None,
              help="Byte budget as a fraction of the raw image bytes (W x H x channels x bytes).")
@click.option("--info", "info_file", metavar="FILE.sbs", default=None,
              help="Validate a sample file and print its header as one JSON line; no encoding.")
@click.option("--header-only", is_flag=True,
              help="With --info: check the header and file size but not the payload checksum.")
@click.option("--check", "check_payload", is_flag=True,
              help="With --info: also decode the payload and check the decoded values, as sb-decode "
                   "would (\"payload_verified\": true); without it the values are not decoded.")
@_batch.jobs_options
@common.overwrite_option
@common.json_option
@common.verbosity_options
@common.version_option
@common.handle_errors
def encode_command(images, output, stride, stride_x, stride_y, offset, pattern, seed, raw_size,
                   pix_fmt, codec, value_bits, quality, size_bytes, size_fraction, info_file, header_only,
                   check_payload, jobs, scheduler, overwrite, as_json):
    """Sample RIGHT_IMAGE ('-' = stdin) on a sparse grid and write the .sbs sample file.

    \b
    Examples:
      sb-encode right.png -o right.sbs                 # 5x5 grid, epsilon = 4 %
      sb-encode right.png -o right.sbs --stride 4      # epsilon = 6.25 %
      sb-encode - -o - < right.png > right.sbs         # stdin to stdout
      sb-encode frame.raw --raw 640x480 --pix-fmt bgr24 -o frame.sbs
      cam | sb-encode - --raw 640x480 --pix-fmt bgr24 -o - | ...   # a stream of frames
      sb-encode frames.raw --raw 640x480 --pix-fmt gray8 -o 'S/{index:05d}.sbs'
      sb-encode right.png -o right.sbs --stride 4 --codec lossless
      sb-encode right.png -o right.sbs --size 20000    # densest grid in 20000 bytes
      sb-encode --info right.sbs                       # header as JSON
      sb-encode --info right.sbs --check               # ... after decoding the payload
      sb-encode 'cam_r/*.png' -o 'out/{stem}.sbs' -j 2 # many files (quoted glob)

    With several inputs (files, folders, quoted globs) or a templated -o, an output
    made from the same input with the same options and version is skipped (a rerun
    resumes; a hidden .NAME.sbrecipe beside it records what made it), any other is
    redone; --overwrite redoes all.  Exit status 1 if any file failed.

    A raw input holding several frames (or '-', a camera pipe) is a stream: its frames
    go, in order and as they arrive, to -o - one after another, to one file per frame
    through {index} (from 0, e.g. {index:05d}), or to one stream file.  Several images
    with -o - make a stream too.  sb-decode reads such streams.
    """
    if info_file is not None:
        if images or output is not None:
            raise OptionError("--info takes only the sample file; drop RIGHT_IMAGE and -o")
        if header_only and check_payload:
            raise OptionError("--header-only skips the payload and --check decodes it: give one of them")
        common.require_stdout("--info")
        _show_info(info_file, verify=not header_only, decode=check_payload)
        return
    if header_only or check_payload:
        raise OptionError(f"{'--header-only' if header_only else '--check'} only applies to --info")
    if not images:
        raise OptionError("missing RIGHT_IMAGE (use '-' for standard input); see --help")
    if output is None:
        raise OptionError("missing -o/--output (use '-o -' for standard output)")
    if (raw_size is None) != (pix_fmt is None):
        raise OptionError("--raw WxH and --pix-fmt must be given together")
    if as_json and output == "-":
        raise OptionError("--json cannot be combined with '-o -' (stdout carries the sample file)")
    if as_json:
        common.require_stdout("--json")
    if size_bytes is not None or size_fraction is not None:
        # A budget chooses the stride: a stride given as well would be silently replaced.
        source = click.get_current_context().get_parameter_source
        given = [f"--{name.replace('_', '-')}" for name in ("stride", "stride_x", "stride_y")
                 if source(name) is click.core.ParameterSource.COMMANDLINE]
        if given:
            raise OptionError(f"{'--size' if size_bytes is not None else '--epsilon'} chooses the grid stride "
                              f"from the byte budget: drop {' and '.join(given)}, or drop the budget")
    size = None
    if raw_size is not None:
        from stereobudget.io import parse_raw_size
        try:
            size = parse_raw_size(raw_size)
        except ValueError as exc:
            raise OptionError(f"--raw: {exc}") from None
    sampling = build_pattern(pattern=pattern, stride=stride, stride_x=stride_x, stride_y=stride_y,
                             offset=offset, seed=seed)
    coding = build_coding(codec=codec, value_bits=value_bits, quality=quality, size=size_bytes,
                          size_fraction=size_fraction, pattern=pattern)

    stream_inputs = _stream_inputs(images, output, raw_size=size, pix_fmt=pix_fmt)
    if stream_inputs is not None:
        _encode_stream(stream_inputs, output, pattern=sampling, raw_size=size, pix_fmt=pix_fmt,
                       overwrite=overwrite, coding=coding, as_json=as_json)
        return
    image, batch_jobs = _batch.plan_encode(images, output, pattern=sampling, raw_size=size, pix_fmt=pix_fmt,
                                           overwrite=overwrite, coding=coding)
    if batch_jobs is not None:
        from stereobudget.batch import encode_job
        _batch.run_batch(batch_jobs, encode_job, workers=jobs, scheduler=scheduler, as_json=as_json)
        return

    from stereobudget.encoding import encode_file
    from stereobudget.io import display_name
    from stereobudget.errors import StereoBudgetError
    try:
        report = encode_file(image, output, pattern=sampling, raw_size=size, pix_fmt=pix_fmt,
                             overwrite=overwrite, **coding)
    except StereoBudgetError as exc:
        if as_json and exc.path != "<stdout>":
            # The same record a batch gives a failed file; the error line and code follow.
            common.emit_json({"status": "failed", "input": display_name(image),
                              "output": "<stdout>" if output == "-" else output, **common.failure_fields(exc)})
        raise
    log.info("%s -> %s: %dx%d %s %s, %s %dx%d, %d samples (%.2f %% of the pixels), %d bytes (%.2f %% of the "
             "raw image; header %d + payload %d, %s, %d bits, %.3f bits per pixel)", report.source, report.output,
             report.width, report.height, report.channel_order, report.dtype, report.pattern,
             report.stride_x, report.stride_y, report.sample_count, 100 * report.pixel_fraction, report.file_size,
             100 * report.bytes_fraction, report.header_bytes, report.payload_bytes, report.codec,
             report.value_bits, report.bits_per_pixel)
    if as_json:
        common.emit_json(report.as_dict())


main = common.make_main(encode_command, "sb-encode")

if __name__ == "__main__":   # python -m stereobudget.cli.encode
    main()
