"""``sb-decode``: the host's job -- left image + sample file -> disparity map (+ right image).

A thin layer over :mod:`stereobudget.pipeline` (:func:`~stereobudget.pipeline.decode_file` for
one pair) and :mod:`stereobudget.batch` (:func:`~stereobudget.batch.decode_job` and
:func:`~stereobudget.batch.run_jobs` for many, :func:`~stereobudget.batch.decode_stream` for frames).  One pair keeps the error's own exit code; a batch (several pairs, or output
templates) reports each failed pair and exits 1 if any failed.
"""

from __future__ import annotations

import logging
import os

import click

from stereobudget.errors import OptionError, StereoBudgetError
from stereobudget.decoding import DEFAULT_METHOD, METHODS

from . import _batch
from . import _common as common

log = logging.getLogger("stereobudget")

_OUTPUT_OPTIONS = (("disparity", "--disparity"), ("preview", "--preview"), ("right", "--right"),
                   ("depth", "--depth"), ("points", "--points"))


class _MaxDisp(click.ParamType):
    """``--max-disp``: a positive integer, or ``auto`` (estimated from the pair)."""

    name = "N|auto"

    def convert(self, value, param, ctx):
        if isinstance(value, int) or value is None:
            return value
        text = str(value).strip().lower()
        if text == "auto":
            return "auto"
        try:
            number = int(text)
        except ValueError:
            self.fail(f"{value!r} is neither an integer nor 'auto'", param, ctx)
        if not 1 <= number <= 65535:
            self.fail(f"{number} is not in the range 1<=x<=65535 (or 'auto')", param, ctx)
        return number


def report_warnings(summary: dict, *, label: str | None = None) -> None:
    """Print a decode's warnings on stderr, one line each (``-q`` silences them)."""
    prefix = f"{label}: " if label else ""
    for warning in summary.get("warnings") or ():
        log.warning("warning: %s%s [%s]", prefix, warning["message"], warning["code"])


def _pairs_from_arguments(inputs, left_dir, samples_dir, manifest):
    """The (left, samples) pairs and whether they came from a multi-file source."""
    from stereobudget.batch._inputs import (IMAGE_EXTENSIONS, SAMPLE_EXTENSIONS, Pair, expand_inputs,
                                            pair_by_stem, read_manifest)

    sources = sum(x for x in (bool(inputs), left_dir is not None or samples_dir is not None,
                              manifest is not None))
    if sources > 1:
        raise OptionError("give LEFT SAMPLES, or --left-dir/--samples-dir, or --manifest; not several")
    if manifest is not None:
        return read_manifest(manifest)
    if left_dir is not None or samples_dir is not None:
        if left_dir is None or samples_dir is None:
            raise OptionError("--left-dir and --samples-dir go together")
        left_args, sample_args = [left_dir], [samples_dir]
    else:
        if len(inputs) != 2:
            raise OptionError(f"expected LEFT and SAMPLES (got {len(inputs)} argument(s)); for many "
                              "pairs use folders, quoted globs, or --manifest; see --help")
        left_args, sample_args = [inputs[0]], [inputs[1]]
    lefts = expand_inputs(left_args, extensions=IMAGE_EXTENSIONS, what="image")
    samples = expand_inputs(sample_args, extensions=SAMPLE_EXTENSIONS, what="sample file (.sbs)")
    if len(lefts) == 1 and len(samples) == 1:
        # One explicit pair: no stem matching (left.png + right.sbs is fine).
        from pathlib import Path
        return [Pair(stem=Path(lefts[0]).stem, left=lefts[0], samples=samples[0])]
    if "-" in lefts or "-" in samples:
        raise OptionError("'-' (standard input) works with a single pair only")
    return pair_by_stem(lefts, samples)


def _is_stream(inputs, left_dir, samples_dir, manifest, templates: dict) -> bool:
    """Whether LEFT SAMPLES name a stream of frames (see :func:`stereobudget.batch.decode_stream`).

    SAMPLES must be one source (a file or ``-``); it is a stream when an output or LEFT
    names frames by ``{index}``, when SAMPLES is ``-`` and an output goes to ``-``, or
    when the file holds several frames.

    Raises
    ------
    OptionError
        A file of several frames whose outputs are plain file names, or LEFT on ``-``.
    """
    from stereobudget.batch import has_template, uses_field
    from stereobudget.io import holds_several_frames

    if len(inputs) != 2 or left_dir is not None or samples_dir is not None or manifest is not None:
        return False
    left, samples = inputs
    indexed = uses_field(left, "index", "LEFT") or any(
        uses_field(value, "index", f"--{name}") for name, value in templates.items())
    several = holds_several_frames(samples)
    stream = indexed or several or (samples == "-" and "-" in templates.values())
    if not stream:
        return False
    if left == "-":
        raise OptionError("LEFT cannot be '-' for a stream of frames: give an image, a folder or glob of "
                          "images, or a template such as 'L/{index:05d}.png'")
    if samples != "-" and os.path.isdir(samples):
        raise OptionError(f"{{index}} numbers the frames of a stream, whose SAMPLES is one file or '-', but "
                          f"{samples} is a folder; for a folder of pairs use {{stem}} in the output names")
    if several:
        plain = [f"--{name}" for name, value in templates.items()
                 if value != "-" and not has_template(value, f"--{name}")]
        if plain:
            raise OptionError(f"{samples} holds several .sbs frames (a stream) but {', '.join(plain)} names "
                              "one file; put {index} in the name (e.g. 'D/{index:05d}.pfm') or write to '-'")
    return True


def _decode_stream(left, samples, templates: dict, *, as_json: bool, **options) -> None:
    """``sb-decode`` of a stream: every frame in this process (stereobudget.batch.decode_stream)."""
    import time

    from stereobudget.batch import decode_stream

    start = time.perf_counter()
    frames = 0
    try:
        for summary in decode_stream(left, samples, **templates, **options):
            frames += 1
            log.info("%s + %s -> %s: %s, disparity %d..%d (%s), %.2f s", summary["left"], summary["samples"],
                     ", ".join(summary["outputs"].values()), summary["method"], summary["min_disp"],
                     summary["max_disp"], summary["range_source"], summary["timings"]["total"])
            report_warnings(summary, label=f"frame {summary['frame']}")
            if as_json:
                common.emit_json(summary)
    except StereoBudgetError as exc:
        if as_json and exc.path != "<stdout>":
            # The frame that ended the stream gets its record too (a camera's log keeps the failure).
            from stereobudget.io import display_name
            common.emit_json({"status": "failed", "frame": frames, "samples": display_name(samples),
                              **common.failure_fields(exc)})
        raise
    seconds = time.perf_counter() - start
    log.info("%d frame(s) in %.2f s (%.2f frames/s)", frames, seconds, frames / max(seconds, 1e-9))


def _warm(ctx, _param, value):
    """--warm: python -m stereobudget.warm in this installation, then exit."""
    if not value or ctx.resilient_parsing:
        return
    from stereobudget.warm import main as warm_main
    ctx.exit(warm_main([]))


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("inputs", nargs=-1, metavar="LEFT SAMPLES")
@click.option("--left-dir", metavar="DIR", default=None,
              help="Folder (or quoted glob) of left images, paired by stem with --samples-dir.")
@click.option("--samples-dir", metavar="DIR", default=None,
              help="Folder (or quoted glob) of .sbs sample files.")
@click.option("--manifest", metavar="PAIRS.csv", default=None,
              help="CSV of pairs: left,samples[,max_disp[,min_disp]] (paths relative to the CSV; "
                   "max_disp may be auto).")
@click.option("--max-disp", type=_MaxDisp(), default=None, metavar="N|auto",
              help="Largest disparity searched, in pixels, or 'auto': estimated from the pair (a "
                   "manifest's max_disp column wins).  [default: auto]")
@click.option("--min-disp", type=int, default=None,
              help="Smallest disparity searched.  [default: the estimate's with --max-disp auto "
                   "(0 unless the matches are negative), else 0]")
@click.option("--method", type=click.Choice(METHODS), default=None,
              help=f"Decoder.  [default: {DEFAULT_METHOD}]")
@click.option("--disparity", metavar="OUT", default=None,
              help="Disparity map: .pfm, .tif/.tiff (float32), .png (16-bit x256) or .npy; '-' = stdout "
                   "(PFM, or PNG with --format png).")
@click.option("--format", "disparity_format", type=click.Choice(("pfm", "png")), default=None,
              help="Format of --disparity - on standard output.  [default: pfm]")
@click.option("--preview", metavar="OUT.png", default=None, help="Colour preview of the disparity (PNG).")
@click.option("--right", metavar="OUT", default=None,
              help="Recovered right image (PNG/TIFF, the input's channels and bit depth; '-' = stdout).")
@click.option("--warp", "warp_mode", type=click.Choice(("linear", "splat", "nearest")), default=None,
              help="How --right forward-warps LEFT with the disparity.  [default: linear]")
@click.option("--no-enhance", is_flag=True, default=False,
              help="--right without the correction of the warp by the samples (faster; the samples are "
                   "still written back at their pixels).")
@click.option("--calibration", metavar="FILE|auto", default=None,
              help="Stereo calibration of the two cameras (OpenCV YAML/XML with M1 D1 M2 D2 R T, the same "
                   "in JSON, or Middlebury calib.txt): the pair is rectified at the host and decoded in the "
                   "rectified left frame.  Needed by --depth and --points.  'auto': the rectification is "
                   "estimated from LEFT and the samples (grid samples; no metric scale; a stream estimates "
                   "once and checks every 30 frames), or refused when they do not pin it down.")
@click.option("--depth", metavar="OUT", default=None,
              help="Depth in metres along the left camera's axis, for each pixel of LEFT as given: .tif/.pfm/"
                   ".npy float32 (NaN, PFM +inf = invalid) or .png 16-bit millimetres (0 = invalid).")
@click.option("--points", metavar="OUT.ply", default=None,
              help="Point cloud: binary PLY, x y z float32 in metres in the left camera's coordinates (x right, "
                   "y down, z forward) + red green blue; invalid pixels left out.")
@click.option("--frame", type=click.Choice(("rectified", "raw")), default=None,
              help="With --calibration: the pixel grid of --disparity, --preview and --depth: the rectified "
                   "left frame, or LEFT as given.  [default: disparity and preview rectified, depth raw]")
@click.option("--temporal/--no-temporal", default=True, show_default=True,
              help="A stream of frames: each frame searches a band of disparities around the previous "
                   "frame's (the whole range on the first frame, a scene cut, or winners at the band's "
                   "edge); --no-temporal decodes every frame on the whole range.")
@click.option("--max-memory", metavar="SIZE", default=None,
              help="Refuse a pair whose decode would need more memory than SIZE (e.g. 8G, 500M).  "
                   "[default: 75 % of the available memory, or $STEREOBUDGET_MAX_MEMORY]")
@_batch.jobs_options
@common.overwrite_option
@common.json_option
@common.verbosity_options
@common.version_option
@click.option("--warm", is_flag=True, expose_value=False, is_eager=True, callback=_warm,
              help="Compile every method's kernels now (two processes side by side), then exit; "
                   "a first decode of any method then starts without compiling.")
@common.handle_errors
def decode_command(inputs, left_dir, samples_dir, manifest, max_disp, min_disp, method, disparity,
                   disparity_format, preview, right, warp_mode, no_enhance, calibration, depth, points, frame,
                   temporal, max_memory, jobs, scheduler, overwrite, as_json):
    """Recover the disparity of LEFT from the right camera's SAMPLES (.sbs).

    One of LEFT and SAMPLES may be '-' (standard input).  LEFT and SAMPLES may also be
    folders or quoted globs: pairs are matched by file stem and every output must then
    be a template using {stem}, {name} or {parent} (of the left image).

    In a batch an output made from the same inputs with the same options and version
    is skipped (a rerun resumes; a hidden .NAME.sbrecipe beside it records what made
    it), any other is redone; --overwrite redoes everything.  Exit status 1 if any
    pair failed.

    The pair must be rectified (a scene point on the same row in both images), or its
    calibration given with --calibration, and LEFT is the left camera's image.  Warnings (stderr, and "warnings" in --json) say when
    many pixels sit at the range limits, when the result does not reproduce the
    samples, and when the pair looks swapped or not rectified.

    SAMPLES may be a stream of .sbs frames (a file of concatenated frames, or '-'):
    each frame is decoded in this process as it arrives, against LEFT (one image for
    all frames, a folder or glob of images in name order, or 'L/{index:05d}.png'), and
    written through {index} (from 0) in the output names, or to '-' one image after
    another (--disparity -: PFM frames, or 16-bit PNG frames with --format png).

    \b
    Examples:
      sb-decode left.png right.sbs --disparity d.pfm -v        # range estimated
      sb-decode left.png right.sbs --max-disp 60 --disparity d.pfm --preview d.png
      sb-decode left.png right.sbs --max-disp 60 --disparity d.tif --right r.png --json
      sb-decode left.png right.sbs --disparity - --format png > d.png
      ssh cam sb-encode - -o - < r.png | sb-decode left.png - --max-disp 60 --disparity d.pfm
      sb-decode left.png right.sbs --calibration stereo.yml --depth z.tif --points cloud.ply
      sb-decode --left-dir L --samples-dir S --max-disp 60 \\
          --disparity 'D/{stem}.pfm' --right 'R/{stem}.png' -j 2
      sb-decode --manifest pairs.csv --max-disp 60 --disparity 'D/{stem}.pfm' --scheduler local
      cam | sb-encode - --raw 640x480 --pix-fmt gray8 -o - \\
          | sb-decode 'L/{index:05d}.png' - --max-disp 60 --disparity - > d.pfms
    """
    from stereobudget.batch import check_distinct_outputs, decode_job, has_template
    from stereobudget.pipeline import DecodeJob, decode_file

    if max_memory is not None:
        from stereobudget.io import parse_size
        try:
            max_memory = parse_size(max_memory)
        except ValueError as exc:
            raise OptionError(f"--max-memory: {exc}") from None
    templates = {name: value for name, value in (("disparity", disparity), ("preview", preview),
                                                  ("right", right), ("depth", depth), ("points", points))
                 if value is not None}
    # The settings of stereobudget.synthesis.SynthesisParams that differ from its defaults.
    synthesis = {key: value for key, value in (("warp_mode", warp_mode), ("enhance", False if no_enhance else None))
                 if value is not None} or None
    if synthesis and right is None:
        raise OptionError("--warp and --no-enhance set how --right is recovered; give --right")
    if not templates:
        raise OptionError("nothing to write: give --disparity, --preview, --right, --depth and/or --points")
    geometry = dict(calibration=calibration, frame=frame)
    if _is_stream(inputs, left_dir, samples_dir, manifest, templates):
        if scheduler is not None:
            raise OptionError("a stream is decoded in order, in one process: --scheduler applies to "
                              "batches of files")
        if disparity_format is not None and disparity != "-":
            raise OptionError("--format sets the format of --disparity - (standard output); a file's format "
                              "follows its extension")
        if as_json and "-" in templates.values():
            raise OptionError("--json cannot be combined with an output on '-' (stdout carries the images)")
        _decode_stream(inputs[0], inputs[1], templates, max_disp=max_disp, min_disp=min_disp, method=method,
                       synthesis=synthesis,
                       overwrite=overwrite, max_memory=max_memory, disparity_format=disparity_format,
                       temporal=temporal, as_json=as_json, **geometry)
        return
    templated = {name: has_template(value, f"--{name}") for name, value in templates.items()}
    pairs = _pairs_from_arguments(inputs, left_dir, samples_dir, manifest)
    batch = len(pairs) > 1 or any(templated.values())
    if batch:
        plain = [f"--{name}" for name, is_template in templated.items() if not is_template]
        if len(pairs) > 1 and plain:
            raise OptionError(f"{len(pairs)} pairs but {', '.join(plain)} has no template; use e.g. "
                              f"'out/{{stem}}.pfm' ({{stem}}, {{name}}, {{parent}} of the left image)")
        if "-" in templates.values():
            raise OptionError("'-' (standard output) works with a single pair only")
    if as_json and "-" in templates.values():
        raise OptionError("--json cannot be combined with an output on '-' (stdout carries the image)")
    if as_json:
        common.require_stdout("--json")
    if disparity_format is not None and disparity != "-":
        raise OptionError("--format sets the format of --disparity - (standard output); a file's format "
                          "follows its extension")
    if scheduler is not None and not batch:
        log.info("--scheduler ignored for a single pair")

    from stereobudget.batch import expand_template
    job_list = []
    for pair in pairs:
        source = pair.template_source
        outputs = {name: (expand_template(value, source, option=f"--{name}") if templated[name] else value)
                   for name, value in templates.items()}
        pair_max = pair.max_disp if pair.max_disp is not None else max_disp
        job_list.append(DecodeJob(
            left=pair.left, samples=pair.samples, max_disp=pair_max,
            min_disp=pair.min_disp if pair.min_disp is not None else min_disp, method=method,
            overwrite=overwrite, batch=batch, problem=pair.problem, max_memory=max_memory,
            disparity_format=disparity_format, synthesis=synthesis, **geometry, **outputs))
    if not batch:
        from stereobudget._kernels import avoid_huge_pages
        avoid_huge_pages()      # one pair: every volume is touched once (see its docstring)
        job = job_list[0]
        try:
            summary = decode_file(job)
        except StereoBudgetError as exc:
            if as_json and exc.path != "<stdout>":
                # The same record a batch gives a failed pair; the error line and code follow.
                from stereobudget.io import display_name
                common.emit_json({"status": "failed",
                                  "left": display_name(job.left) if job.left else None,
                                  "samples": display_name(job.samples) if job.samples else None,
                                  "outputs": job.outputs, **common.failure_fields(exc)})
            raise
        log.info("%s + %s -> %s: %dx%d, %.2f %% of the pixels sampled, %s, disparity %d..%d (%s), %.2f s",
                 summary["left"], summary["samples"], ", ".join(summary["outputs"].values()), summary["width"],
                 summary["height"], 100 * summary["pixel_fraction"], summary["method"], summary["min_disp"],
                 summary["max_disp"], summary["range_source"], summary["timings"]["total"])
        report_warnings(summary)
        if as_json:
            common.emit_json(summary)
        return
    check_distinct_outputs(job_list, key=lambda job: job.outputs.values())
    # After an install or upgrade numba compiles for minutes: say so once, here (a single
    # pair says it in decode_file, once its inputs have been read and checked).
    from stereobudget._kernels._first_run import announce_first_compile
    announce_first_compile()
    _batch.run_batch(job_list, decode_job, workers=jobs, scheduler=scheduler, as_json=as_json,
                     on_result=lambda item: report_warnings(item, label=item.get("left")))


main = common.make_main(decode_command, "sb-decode")

if __name__ == "__main__":   # python -m stereobudget.cli.decode
    main()
