"""Many files at once: input expansion, output templates, per-file jobs and their runners.

The CLI commands are thin; everything a batch needs lives here so that other programs
(and dask workers) can use it:

* :func:`expand_inputs` turns arguments (files, folders, quoted globs) into a file list;
  :func:`expand_template` turns an output template (``out/{stem}.sbs``) into a path.
* :func:`pair_by_stem` / :func:`read_manifest` build the (left, samples) pairs of a
  decoding batch; a left image without its sample file (or the reverse) becomes a job
  that fails with a clear message instead of vanishing.
* :class:`EncodeJob` / :class:`DecodeJob` describe one file's work with plain, picklable
  values; :func:`encode_job` / :func:`decode_job` do it and *never raise* for bad input:
  they return a small JSON-able dict with ``status`` ``"ok"``, ``"skipped"`` or
  ``"failed"`` (plus ``error``, ``error_class`` and ``exit_code`` on failure).
* :func:`run_jobs` runs jobs in-process (1 job), in a local process pool, or on a
  dask.distributed cluster, and yields the result dicts as they complete.

Up-to-date rule: in a batch, each output gets a record of what made it (tool version,
inputs' paths, sizes and times, options, decoder parameters: :mod:`stereobudget.batch._recipes`);
a job whose outputs all exist with the record the job would write is skipped, any other
is redone (its result says why, under ``redone``) and its outputs are replaced.
``overwrite=True`` redoes every job.  Outputs are always written atomically, so an
interrupted batch leaves complete outputs and no partial ones.

This module imports neither numba nor OpenCV: the camera-side ``sb-encode`` uses it.
"""

from __future__ import annotations

import csv
import glob
import logging
import os
import signal
import string
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator

from ..io._atomic import (STDIO, check_output_path, display_name, interrupts_deferred,
                          redeliver_swallowed_interrupts)
from ..errors import MemoryLimitError, OptionError, OutputError, StereoBudgetError
from ..decoding._methods import DEFAULT_METHOD
from ._recipes import make_recipe, recipe_difference, write_recipes

log = logging.getLogger("stereobudget")

#: Extensions listed when a folder of images is given as input.
IMAGE_EXTENSIONS = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm", ".bmp", ".webp")
#: Extension listed when a folder of sample files is given as input.
SAMPLE_EXTENSIONS = (".sbs",)
#: Fields an output template may use.
TEMPLATE_FIELDS = ("stem", "name", "parent")

_GLOB_CHARS = frozenset("*?[")


# =====================================================================================
# Inputs and output templates
# =====================================================================================

def _looks_like_glob(text: str) -> bool:
    return any(ch in _GLOB_CHARS for ch in text)


def expand_inputs(arguments: Iterable[str], *, extensions: tuple[str, ...] | None = IMAGE_EXTENSIONS,
                  what: str = "image") -> list[str]:
    """Expand input arguments into a list of file names, in a stable order.

    Parameters
    ----------
    arguments : iterable of str
        Each is ``-`` (standard input), an existing file (taken literally, even when
        its name contains ``*`` or ``[``), a folder (its files with one of
        ``extensions``, sorted, hidden files excluded), or a glob pattern (expanded
        here, ``**`` included, so a quoted pattern works the same in every shell).
    extensions : tuple of str or None
        Lower-case extensions listed from folders (None: every file).
    what : str
        What the files are, for messages ("image", "sample file").

    Returns
    -------
    list of str
        File names; a name that does not exist and is not a pattern is kept (the job
        reading it reports "no such file").  Duplicates are dropped.

    Raises
    ------
    OptionError
        A pattern matches no file, or a folder holds no file of the expected kind.
    """
    result: list[str] = []
    for argument in arguments:
        argument = str(argument)
        if argument == STDIO:
            found = [argument]
        elif os.path.isdir(argument):
            found = sorted(str(p) for p in Path(argument).iterdir()
                           if p.is_file() and not p.name.startswith(".")
                           and (extensions is None or p.suffix.lower() in extensions))
            if not found:
                kinds = f" ({', '.join(extensions)})" if extensions else ""
                raise OptionError(f"folder {argument!r} holds no {what}{kinds}")
        elif os.path.exists(argument) or not _looks_like_glob(argument):
            found = [argument]
        else:
            found = sorted(p for p in glob.glob(argument, recursive=True) if os.path.isfile(p))
            if not found:
                raise OptionError(f"no file matches {argument!r}")
        result.extend(found)
    seen: set[str] = set()
    unique = []
    for name in result:
        if name not in seen:
            seen.add(name)
            unique.append(name)
    return unique


def _template_parts(template: str, option: str):
    try:
        return list(string.Formatter().parse(template))
    except ValueError as exc:
        raise OptionError(f"{option} {template!r}: bad template ({exc}); write a literal brace "
                          "as {{ or }}") from None


def has_template(template: str | None, option: str = "output") -> bool:
    """Whether ``template`` uses a field such as ``{stem}`` (``{{`` is a literal brace)."""
    if template is None:
        return False
    return any(name is not None for _, name, _, _ in _template_parts(str(template), option))


def uses_field(template: str | None, field: str, option: str = "output") -> bool:
    """Whether ``template`` uses the field ``field`` (e.g. ``index``)."""
    if template is None:
        return False
    return any(name == field for _, name, _, _ in _template_parts(str(template), option))


def template_fields(source: str) -> dict:
    """The values of the template fields for input ``source``.

    ``{stem}`` file name without its last extension, ``{name}`` file name, ``{parent}``
    the folder holding the input as it was given (``.`` for a bare file name).
    """
    path = Path(source)
    return {"stem": path.stem, "name": path.name, "parent": str(path.parent)}


def expand_template(template: str, source: str, *, option: str = "output", index: int | None = None) -> str:
    """Fill ``{stem}``, ``{name}`` and ``{parent}`` of ``template`` from the input ``source``.

    With ``index`` (a frame of a stream, from 0), ``{index}`` is filled too; it takes an
    integer format such as ``{index:05d}``.

    Raises
    ------
    OptionError
        Unknown field, conversion/format spec, or unbalanced braces.
    """
    values = template_fields(source)
    pieces = []
    known = "{stem}, {name}, {parent}" + (" or {index}" if index is not None else "")
    for literal, name, spec, conversion in _template_parts(str(template), option):
        pieces.append(literal)
        if name is None:
            continue
        if name == "index" and index is not None and not conversion:
            try:
                pieces.append(format(index, spec or "d"))
            except ValueError:
                raise OptionError(f"{option} {template!r}: {{index:{spec}}} is not an integer format "
                                  "(e.g. {index:05d})") from None
            continue
        if name not in values or spec or conversion:
            hint = ("; {index} numbers the frames of a stream" if name == "index" else "")
            raise OptionError(f"{option} {template!r}: unknown template field {{{name}"
                              f"{'!' + conversion if conversion else ''}{':' + spec if spec else ''}}}; "
                              f"use {known} (a literal brace is {{{{ or }}}}){hint}")
        pieces.append(values[name])
    return "".join(pieces)


def output_for(template: str | None, source: str, *, option: str) -> str | None:
    """``template`` expanded for ``source`` (None stays None, a plain name stays as it is)."""
    if template is None:
        return None
    return expand_template(template, source, option=option)


def check_distinct_outputs(jobs, *, key: Callable) -> None:
    """Refuse a batch in which two jobs would write the same file.

    ``key(job)`` returns the job's output paths (None entries are ignored).
    """
    owner: dict[str, object] = {}
    for job in jobs:
        for out in key(job):
            if out is None or out == STDIO:
                continue
            norm = os.path.normpath(os.path.abspath(out))
            if norm in owner:
                raise OptionError(f"two inputs would write the same output {out!r} "
                                  f"({owner[norm]} and {job.label}); add {{parent}} or change the template")
            owner[norm] = job.label


# =====================================================================================
# Pairing left images with sample files
# =====================================================================================

@dataclass(frozen=True)
class Pair:
    """One decoding input: a left image and its sample file (either may be missing)."""

    stem: str
    left: str | None
    samples: str | None
    max_disp: int | str | None = None
    min_disp: int | None = None
    problem: str | None = None

    @property
    def template_source(self) -> str:
        # Templates take their fields from the left image; the stem is the pairing key.
        return self.left if self.left is not None else self.samples


def pair_by_stem(lefts: list[str], samples: list[str]) -> list[Pair]:
    """Match left images and sample files with the same stem (``a.png`` <-> ``a.sbs``).

    Every unmatched or ambiguous name is kept as a :class:`Pair` with ``problem`` set,
    so the batch reports it as a failed item.  Pairs are sorted by stem.
    """
    def by_stem(names):
        table: dict[str, list[str]] = {}
        for name in names:
            table.setdefault(Path(name).stem, []).append(name)
        return table

    left_by, samples_by = by_stem(lefts), by_stem(samples)
    pairs = []
    for stem in sorted(set(left_by) | set(samples_by)):
        ls, ss = left_by.get(stem, []), samples_by.get(stem, [])
        problem = None
        if len(ls) > 1:
            problem = f"several left images share the stem {stem!r}: {', '.join(ls)}"
        elif len(ss) > 1:
            problem = f"several sample files share the stem {stem!r}: {', '.join(ss)}"
        elif not ss:
            problem = f"no sample file with the stem {stem!r} for this left image"
        elif not ls:
            problem = f"no left image with the stem {stem!r} for this sample file"
        pairs.append(Pair(stem=stem, left=ls[0] if ls else None, samples=ss[0] if ss else None,
                          problem=problem))
    return pairs


def _manifest_int(value: str, column: str, where: str, *, auto: bool = False) -> int | str | None:
    value = (value or "").strip()
    if not value:
        return None
    if auto and value.lower() == "auto":
        return "auto"
    try:
        return int(value)
    except ValueError:
        raise OptionError(f"{where}: column {column} must be an integer, got {value!r}") from None


def read_manifest(path: str) -> list[Pair]:
    """Read a CSV manifest of decoding pairs.

    Columns ``left,samples[,max_disp[,min_disp]]`` (``max_disp`` may be ``auto``: estimated,
    as an empty cell); a first row naming the columns
    (``left,samples,...`` in any order) is optional.  Relative paths are relative to the
    manifest's folder; empty lines and lines starting with ``#`` are ignored.

    Raises
    ------
    OptionError
        Unreadable file, unknown column, a row with fewer than two fields, or a
        non-integer disparity.
    """
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = [row for row in csv.reader(handle)]
    except OSError as exc:
        raise OptionError(f"cannot read the manifest: {exc.strerror or exc}", path=str(path)) from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise OptionError(f"not a CSV text file ({exc})", path=str(path)) from None
    base = Path(path).parent
    columns = ["left", "samples", "max_disp", "min_disp"]
    pairs: list[Pair] = []
    header_seen = False
    for number, row in enumerate(rows, start=1):
        cells = [c.strip() for c in row]
        if not any(cells) or cells[0].startswith("#"):
            continue
        where = f"{path}:{number}"
        if not header_seen and not pairs and "left" in [c.lower() for c in cells]:
            names = [c.lower() for c in cells]
            unknown = [c for c in names if c not in columns]
            if unknown or "samples" not in names:
                raise OptionError(f"{where}: header must name the columns left, samples "
                                  f"[, max_disp, min_disp], got {', '.join(cells)}")
            columns = names
            header_seen = True
            continue
        if len(cells) < 2:
            raise OptionError(f"{where}: expected at least two columns (left, samples), got {len(cells)}")
        if len(cells) > len(columns):
            raise OptionError(f"{where}: {len(cells)} columns, expected at most {len(columns)}")
        record = dict(zip(columns, cells))
        if not record.get("left") or not record.get("samples"):
            raise OptionError(f"{where}: empty left or samples path")
        left = str(base / record["left"]) if not os.path.isabs(record["left"]) else record["left"]
        samples = (str(base / record["samples"]) if not os.path.isabs(record["samples"])
                   else record["samples"])
        pairs.append(Pair(stem=Path(left).stem, left=left, samples=samples,
                          max_disp=_manifest_int(record.get("max_disp", ""), "max_disp", where, auto=True),
                          min_disp=_manifest_int(record.get("min_disp", ""), "min_disp", where)))
    if not pairs:
        raise OptionError("the manifest lists no pair", path=str(path))
    return pairs


# =====================================================================================
# Up-to-date checks
# =====================================================================================

def _mtime_ns(path: str) -> int | None:
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        return None


def outputs_up_to_date(outputs: Iterable[str], inputs: Iterable[str]) -> bool:
    """True when every output exists and is at least as new as every input (``make``'s rule)."""
    outputs = [o for o in outputs if o is not None]
    if not outputs or any(o == STDIO for o in outputs):
        return False
    input_times = [_mtime_ns(i) for i in inputs if i is not None and i != STDIO]
    if any(t is None for t in input_times):
        return False             # a missing input: let the job report it
    newest_input = max(input_times, default=0)
    for out in outputs:
        t = _mtime_ns(out)
        if t is None or t < newest_input:
            return False
    return True


def _prepare_outputs(outputs: list[str], inputs: list[str], *, overwrite: bool, make_dirs: bool,
                     replace_existing: bool | None = None) -> bool:
    """Check the outputs of one job; return the ``overwrite`` flag to write them with.

    In a batch (``make_dirs``) missing folders are created, and a stale output is
    replaced (the caller has already skipped up-to-date jobs); ``replace_existing=False``
    creates the folders but still refuses an existing output without ``overwrite``.
    """
    replace = overwrite
    replace_existing = make_dirs if replace_existing is None else replace_existing
    for out in outputs:
        if out is None or out == STDIO:
            continue
        if make_dirs:
            parent = Path(out).parent
            if not parent.is_dir():
                try:
                    parent.mkdir(parents=True, exist_ok=True)
                except OSError as exc:
                    raise OutputError(f"cannot create the folder {str(parent)!r}: {exc.strerror or exc}",
                                      path=out) from None
            if replace_existing and os.path.exists(out):
                replace = True      # stale (or partner of a missing output): redo as make would
    for out in outputs:
        if out is not None:
            check_output_path(out, inputs, replace)
    return replace


# =====================================================================================
# Jobs
# =====================================================================================

def _failure(exc: BaseException) -> dict:
    if isinstance(exc, StereoBudgetError):
        return {"error": str(exc), "error_class": type(exc).__name__, "exit_code": exc.exit_code}
    if isinstance(exc, MemoryError):
        return {"error": "out of memory", "error_class": "MemoryLimitError", "exit_code": 11}
    # A bug, not bad input: keep the batch going but say what it was.
    return {"error": f"unexpected {type(exc).__name__}: {exc}", "error_class": type(exc).__name__,
            "exit_code": 1}


_worker_threads: int | None = None


def _limit_numba_threads(threads: int | None) -> None:
    """Cap numba's threads in this process (several jobs on one machine share its cores)."""
    threads = threads or _worker_threads
    if not threads:
        return
    try:
        import numba
        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    except Exception:        # a missing or old numba only costs speed
        pass


@dataclass(frozen=True)
class EncodeJob:
    """One ``sb-encode`` input.

    Attributes
    ----------
    source, output : str
        Right image (or ``-``) and sample file (or ``-``).
    pattern : SamplingPattern
    raw_size : (width, height) or None
    pix_fmt : str or None
    overwrite : bool
        Replace existing outputs (in a batch: redo even up-to-date jobs).
    batch : bool
        Batch semantics: skip up-to-date outputs, replace stale ones, create folders.
    coding : dict, optional
        Keyword arguments of :func:`stereobudget.io.encode_file` choosing the payload
        coding (``codec``, ``value_bits``, ``quality``, ``size``, ``size_fraction``).
    """

    source: str
    output: str
    pattern: object
    raw_size: tuple | None = None
    pix_fmt: str | None = None
    overwrite: bool = False
    batch: bool = False
    coding: dict | None = None

    @property
    def label(self) -> str:
        return display_name(self.source)


def encode_job(job: EncodeJob) -> dict:
    """Do one :class:`EncodeJob`; never raises for bad input.

    Returns
    -------
    dict
        ``status`` (``ok``/``skipped``/``failed``), ``input``, ``output``, ``timings``
        and, when encoded, the fields of :class:`stereobudget.io.EncodeReport`
        (``epsilon``, sizes...); on failure ``error``, ``error_class``, ``exit_code``.
    """
    start = time.perf_counter()
    result = {"status": "ok", "input": display_name(job.source),
              "output": "<stdout>" if job.output == STDIO else job.output}
    _in_job(True)
    try:
        recipe = _encode_recipe(job) if job.batch else None
        if recipe is not None:
            reason = recipe_difference([job.output], recipe)
            if reason is None and not job.overwrite:
                result.update(status="skipped", reason="up to date")
                return result
            if os.path.exists(job.output):
                result["redone"] = "--overwrite" if reason is None else reason
        from ..io._samples import encode_file
        overwrite = _prepare_outputs([job.output], [job.source], overwrite=job.overwrite,
                                     make_dirs=job.batch)
        # Output and record together (see decode_file); an encode takes milliseconds.
        with interrupts_deferred():
            report = encode_file(job.source, job.output, pattern=job.pattern, raw_size=job.raw_size,
                                 pix_fmt=job.pix_fmt, overwrite=overwrite, **(job.coding or {}))
            if recipe is not None:
                write_recipes([job.output], recipe)
        result.update(report.as_dict())
        result["input"] = report.source
    except (StereoBudgetError, MemoryError) as exc:
        result.update(status="failed", **_failure(exc))
    except Exception as exc:  # noqa: BLE001 -- one bad file must not stop a batch
        log.debug("unexpected error on %s", job.label, exc_info=True)
        result.update(status="failed", **_failure(exc))
    finally:
        _in_job(False)
        result["timings"] = {"total": round(time.perf_counter() - start, 4)}
    return result


@dataclass(frozen=True)
class DecodeJob:
    """One ``sb-decode`` pair.

    Attributes
    ----------
    left, samples : str or None
        Left image and sample file (``-`` = standard input for one of them).  None, with
        ``problem`` set, is a pairing failure reported as a failed item.
    disparity, preview, right : str or None
        Outputs: disparity map (format by extension), colour preview PNG, recovered right
        image Î2 (PNG/TIFF, input's channels and bit depth; ``-`` = standard output).
    max_disp : int, "auto" or None
        Largest disparity searched; None or ``"auto"``: estimated from the pair
        (:func:`stereobudget.decoding.estimate_disparity_range`).
    min_disp : int or None
        Smallest disparity searched; None: the estimate's when ``max_disp`` is estimated,
        else 0.
    method : str or None
        Decoder (None: the library default).
    overwrite, batch : bool
        As in :class:`EncodeJob`.
    threads : int or None
        Cap on numba threads in the worker.
    problem : str or None
        Why this pair cannot be decoded (set by the pairing step).
    max_memory : int or None
        Memory limit of the decode in bytes (None: 75 % of the available memory).
    disparity_format : {"pfm", "png"} or None
        Format of a disparity map written to standard output (``disparity="-"``; None: PFM).
    """

    left: str | None
    samples: str | None
    disparity: str | None = None
    preview: str | None = None
    right: str | None = None
    max_disp: int | str | None = None
    min_disp: int | None = None
    method: str | None = None
    overwrite: bool = False
    batch: bool = False
    threads: int | None = None
    problem: str | None = None
    max_memory: int | None = None
    disparity_format: str | None = None

    @property
    def label(self) -> str:
        return display_name(self.left if self.left is not None else self.samples)

    @property
    def outputs(self) -> dict:
        return {k: v for k, v in (("disparity", self.disparity), ("preview", self.preview),
                                  ("right", self.right)) if v is not None}


def _as_image_dtype(image, dtype):
    """Î2 in the input's bit depth; float images are in 8-bit units (the library convention)."""
    import numpy as np

    image = np.asarray(image)
    dtype = np.dtype(dtype)
    if image.dtype == dtype:
        return image
    if image.dtype.kind in "ui":
        scale = (257.0 if dtype == np.uint16 else 1.0) / (257.0 if image.dtype == np.uint16 else 1.0)
    else:
        scale = 257.0 if dtype == np.uint16 else 1.0
    top = np.iinfo(dtype).max
    values = np.nan_to_num(image.astype(np.float64) * scale, nan=0.0)
    return np.clip(np.rint(values), 0, top).astype(dtype)


def recover_right_image(left, disparity, samples):
    """Call :func:`stereobudget.synthesis.recover_right`; returns ``(image, extras)``.

    ``extras`` holds the PSNR at the samples (dB; null when infinite), ``holes_fraction``
    and, under ``"_timings"``, the synthesis stages.
    """
    import math

    from ..synthesis._synthesis import recover_right

    recovered = recover_right(left, disparity, samples)
    extras = {}
    for key in ("psnr_at_samples_before_enhancement", "psnr_at_samples_before_reinsertion"):
        value = float(getattr(recovered, key))
        # JSON has no inf/NaN: an infinite PSNR (exact match) or an undefined one is null.
        extras[key] = value if math.isfinite(value) else None
    if recovered.holes.size:
        extras["holes_fraction"] = float(recovered.holes.mean())
    for stage, seconds in recovered.timings.items():
        extras.setdefault("_timings", {})[f"right_{stage}"] = seconds
    return recovered.image, extras


def _check_output_formats(job: DecodeJob) -> None:
    """Refuse unknown output extensions before any work is done."""
    from ..io._disparity import DISPARITY_EXTENSIONS

    def ext(path):
        return Path(path).suffix.lower()

    if sum(path == STDIO for path in job.outputs.values()) > 1:
        raise OptionError("only one output can go to standard output ('-')")
    if job.disparity is not None:
        if job.disparity == STDIO:
            pass   # the stream's format is job.disparity_format (PFM unless png)
        elif ext(job.disparity) not in DISPARITY_EXTENSIONS:
            raise OutputError(f"unknown disparity format {ext(job.disparity) or '(no extension)'!r}; "
                              f"use one of {', '.join(DISPARITY_EXTENSIONS)}", path=job.disparity)
    if job.preview is not None and job.preview != STDIO and ext(job.preview) != ".png":
        raise OutputError("a disparity preview is written as PNG; use a .png file name (or - for stdout)",
                          path=job.preview)
    if job.right is not None and job.right != STDIO and ext(job.right) not in (".png", ".tif", ".tiff"):
        raise OutputError(f"unsupported image extension {ext(job.right) or '(none)'!r}; "
                          "use .png, .tif or .tiff", path=job.right)


def check_job_outputs(job: DecodeJob) -> None:
    """Refuse a job with no output, two outputs on one file, or an unknown output format."""
    outputs = job.outputs
    if not outputs:
        raise OptionError("nothing to write: give --disparity, --preview and/or --right")
    seen = {}
    for kind, path in outputs.items():
        if path != STDIO and path in seen:
            raise OptionError(f"--{seen[path]} and --{kind} name the same file", path=path)
        seen[path] = kind
    _check_output_formats(job)


def decode_file(job: DecodeJob, *, recipe: dict | None = None) -> dict:
    """Decode one pair and write its outputs; raises on any problem.

    This is the single-file path of ``sb-decode`` (errors keep their class and exit
    code); batches use :func:`decode_job`, which wraps it.  ``recipe``
    (:func:`stereobudget.batch._recipes.make_recipe`) is recorded beside the outputs.

    Returns
    -------
    dict
        JSON-able summary: inputs, size, channels, dtype, epsilon, method, disparity
        range searched and found, ``valid_fraction``, ``timings`` per stage (``read``,
        ``validate``, the decoder's stages, ``right``, ``write``, ``total``), outputs,
        and any extra facts the decoder or the synthesis reports.
    """
    start = time.perf_counter()
    if job.problem:
        raise OptionError(job.problem, path=job.label)
    if job.left == STDIO and job.samples == STDIO:
        raise OptionError("only one of LEFT and SAMPLES can be '-' (standard input)")
    outputs = job.outputs
    check_job_outputs(job)
    inputs = [job.left, job.samples]
    overwrite = _prepare_outputs(list(outputs.values()), inputs, overwrite=job.overwrite,
                                 make_dirs=job.batch)
    from ..io import _images as imageio
    from ..io._samples import load_samples
    timings: dict = {}

    t = time.perf_counter()
    left, _ = imageio.read_image(job.left)
    samples = load_samples(job.samples)
    timings["read"] = time.perf_counter() - t
    return decode_arrays(left, samples, job, left_name=display_name(job.left),
                         samples_name=display_name(job.samples), overwrite=overwrite, timings=timings,
                         start=start, recipe=recipe, announce=not job.batch)


def decode_arrays(left, samples, job: DecodeJob, *, left_name: str, samples_name: str, overwrite: bool,
                  timings: dict, start: float, recipe: dict | None = None, announce: bool = False) -> dict:
    """The part of :func:`decode_file` after reading: decode ``left`` + ``samples``, write ``job``'s outputs.

    The outputs have been checked (``overwrite`` is the flag to write them with);
    ``timings`` holds the stages so far and ``start`` the job's start
    (``time.perf_counter``).  ``announce`` says before the first kernel runs that numba
    may compile for minutes.  Returns the summary of :func:`decode_file`.
    """
    from ..io import _images as imageio
    outputs = job.outputs
    # The decoder (numba) loads only once both inputs have been read successfully.
    import math

    import numpy as np

    from ..decoding import _decoders as decoders
    from ..io import _disparity as dispio
    from ..errors import MismatchError
    _limit_numba_threads(job.threads)
    t = time.perf_counter()
    from ..decoding import _checks as checks
    from ..decoding import _disprange as disprange
    auto = disprange.is_auto(job.max_disp)
    try:
        # Sizes and types first (the estimate needs them to agree), then the range.
        decoders.check_inputs(left, samples, min_disp=0, max_disp=1)
        timings["validate"] = time.perf_counter() - t
        if announce:
            # After an install or upgrade numba compiles for minutes: say so before the
            # first kernel runs (a batch says it once, in the command).
            from .._kernels._first_run import announce_first_compile
            announce_first_compile()
        t = time.perf_counter()
        min_disp, max_disp, estimate = disprange.resolve_range(left, samples, max_disp=job.max_disp,
                                                               min_disp=job.min_disp)
        timings["estimate_range"] = time.perf_counter() - t
        decoders.check_inputs(left, samples, min_disp=min_disp, max_disp=max_disp)
    except (MismatchError, OptionError) as exc:
        raise type(exc)(f"{exc.message} ({samples_name})", path=left_name) from None
    if auto:
        log.info("%s: disparity range %d..%d (estimated from %d matches in %.2f s)", left_name, min_disp,
                 max_disp, estimate.votes, estimate.seconds)

    method = job.method or DEFAULT_METHOD
    try:
        # A process that decodes file after file: each decode takes over the last one's memory.
        result = decoders.shared_decoder().decode(left, samples, max_disp=max_disp, min_disp=min_disp,
                                                  method=method, max_memory=job.max_memory)
    except MemoryLimitError as exc:
        raise MemoryLimitError(exc.message, path=left_name) from None
    disparity = result.disparity
    timings.update(result.timings)

    extras = {}
    right_image = None
    if job.right is not None:
        t = time.perf_counter()
        right_image, extras = recover_right_image(left, disparity, samples)
        right_image = _as_image_dtype(right_image, left.dtype)
        timings.update(extras.pop("_timings", {}))
        timings["right"] = time.perf_counter() - t

    t = time.perf_counter()
    psnr = checks.psnr_at_samples(left, disparity, samples)
    warnings = checks.setup_warnings(estimate) + checks.result_warnings(
        disparity, min_disp=min_disp, max_disp=max_disp, psnr=psnr, auto_range=auto)
    timings["checks"] = time.perf_counter() - t

    t = time.perf_counter()
    # The outputs and the record of what made them are written together: a batch
    # interrupted in between would otherwise redo a finished file.
    with interrupts_deferred():
        if job.disparity is not None:
            dispio.write_disparity(job.disparity, disparity, overwrite=overwrite,
                                   stream_format=(job.disparity_format or "pfm") if job.disparity == STDIO else None)
        if job.preview is not None:
            dispio.write_preview(job.preview, disparity, min_disp=min_disp, max_disp=max_disp,
                                 overwrite=overwrite)
        if right_image is not None:
            imageio.write_image(job.right, right_image,
                                channel_order="rgb" if right_image.ndim == 3 else "gray", overwrite=overwrite)
        if recipe is not None:
            write_recipes(outputs.values(), recipe)
    timings["write"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - start

    valid = np.isfinite(disparity)
    summary = {
        "status": "ok", "left": left_name, "samples": samples_name,
        "width": int(left.shape[1]), "height": int(left.shape[0]),
        "channels": 1 if left.ndim == 2 else int(left.shape[2]), "dtype": str(left.dtype),
        "sample_count": int(samples.values.shape[0]), "epsilon": samples.epsilon,
        "pattern": samples.pattern.kind, "stride_x": samples.pattern.stride_x,
        "stride_y": samples.pattern.stride_y, "codec": samples.codec,
        "value_bits": samples.value_bits or 8 * samples.values.dtype.itemsize,
        "method": result.method, "min_disp": int(min_disp), "max_disp": int(max_disp),
        "range_source": "estimated" if auto else "given", "range_estimate": estimate.summary(),
        "psnr_at_samples": psnr if math.isfinite(psnr) else None,
        "warnings": [w.as_dict() for w in warnings],
        "disparity_range": ([float(disparity[valid].min()), float(disparity[valid].max())]
                            if valid.any() else None),
        "valid_fraction": float(valid.mean()),
        "timings": {k: round(float(v), 4) for k, v in timings.items()},
        "outputs": {k: ("<stdout>" if v == STDIO else v) for k, v in outputs.items()},
    }
    decoder_summary = result.summary() if hasattr(result, "summary") else {}
    for key, value in decoder_summary.items():
        if key not in summary and key not in ("timings",):
            summary[key] = value
    for key, value in extras.items():
        summary.setdefault(key, value)
    return summary


def _encode_recipe(job: EncodeJob) -> dict:
    from dataclasses import asdict
    return make_recipe("sb-encode", [job.source], {
        "pattern": asdict(job.pattern), "raw_size": list(job.raw_size) if job.raw_size else None,
        "pix_fmt": job.pix_fmt, "coding": dict(job.coding or {})})


def _decode_recipe(job: DecodeJob) -> dict:
    from dataclasses import asdict

    from ..decoding._decoders import DecoderParams
    from ..decoding._disprange import is_auto
    return make_recipe("sb-decode", [job.left, job.samples], {
        "method": job.method or DEFAULT_METHOD,
        "max_disp": "auto" if is_auto(job.max_disp) else int(job.max_disp),
        "min_disp": job.min_disp, "params": asdict(DecoderParams()),
        "outputs": sorted(job.outputs), "disparity_format": job.disparity_format})


def decode_job(job: DecodeJob) -> dict:
    """Do one :class:`DecodeJob`; never raises for bad input (see :func:`encode_job`)."""
    start = time.perf_counter()
    base = {"left": display_name(job.left) if job.left else None,
            "samples": display_name(job.samples) if job.samples else None,
            "outputs": job.outputs}
    _in_job(True)
    try:
        recipe = _decode_recipe(job) if job.batch and not job.problem else None
        redone = None
        if recipe is not None:
            reason = recipe_difference(job.outputs.values(), recipe)
            if reason is None and not job.overwrite:
                return {"status": "skipped", **base, "reason": "up to date",
                        "timings": {"total": round(time.perf_counter() - start, 4)}}
            if any(os.path.exists(o) for o in job.outputs.values()):
                redone = "--overwrite" if reason is None else reason
        summary = decode_file(job, recipe=recipe)
        if redone is not None:
            summary["redone"] = redone
        return summary
    except Exception as exc:  # noqa: BLE001 -- one bad file must not stop a batch
        if not isinstance(exc, (StereoBudgetError, MemoryError)):
            log.debug("unexpected error on %s", job.label, exc_info=True)
        return {"status": "failed", **base, **_failure(exc),
                "timings": {"total": round(time.perf_counter() - start, 4)}}
    finally:
        _in_job(False)


# =====================================================================================
# Runners
# =====================================================================================

_job_running = False
_terminating = False


def _in_job(flag: bool) -> None:
    global _job_running
    if flag and _terminating:
        # SIGTERM already asked this worker to stop: do not start another file.
        os._exit(143)
    _job_running = flag


def _worker_sigterm(signum, frame):
    # Inside a job: unwind so atomic writers delete their temporary files.  Idle: just go.
    global _terminating
    _terminating = True
    if _job_running:
        raise KeyboardInterrupt
    os._exit(128 + signum)


def _worker_init(threads: int | None) -> None:
    """Process-pool initializer: Ctrl-C is the parent's business, SIGTERM cleans up."""
    global _worker_threads
    _worker_threads = threads
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_sigterm)
    redeliver_swallowed_interrupts(signal.SIGTERM)


def default_jobs() -> int:
    """Number of usable cores (the default of ``-j``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _crashed(job, exc: BaseException) -> dict:
    label = getattr(job, "label", str(job))
    return {"status": "failed", "input": label, "error": f"{label}: worker failed: {type(exc).__name__}: {exc}",
            "error_class": type(exc).__name__, "exit_code": 1}


def _run_local_pool(jobs: list, fn: Callable, workers: int, threads: int | None) -> Iterator[dict]:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # Forking a process whose numba thread pool is running can deadlock the child; a
    # fresh interpreter is safe.  The CLI never decodes in the parent, so it forks.
    context = multiprocessing.get_context("forkserver" if "numba" in sys.modules else None)
    executor = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                   initializer=_worker_init, initargs=(threads,))
    pending = {}
    clean_exit = False
    try:
        queue = iter(jobs)
        # Submit a bounded window so an interrupt does not leave thousands of futures.
        for job in queue:
            pending[executor.submit(fn, job)] = job
            if len(pending) >= 2 * workers:
                break
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                job = pending.pop(future)
                try:
                    yield future.result()
                except Exception as exc:  # noqa: BLE001 -- a dead worker fails its file only
                    yield _crashed(job, exc)
                nxt = next(queue, None)
                if nxt is not None:
                    pending[executor.submit(fn, nxt)] = nxt
        clean_exit = True
    finally:
        if clean_exit:
            executor.shutdown(wait=True)
        else:
            # Interrupted (Ctrl-C, SIGTERM, closed pipe): stop queued work, ask running
            # workers to unwind (they delete their temporary files), then wait for them.
            for future in pending:
                future.cancel()
            for process in list(getattr(executor, "_processes", {}).values()):
                try:
                    process.terminate()
                except Exception:  # noqa: BLE001
                    pass
            executor.shutdown(wait=True, cancel_futures=True)


def _dask_client(scheduler, workers: int, threads: int | None):
    """(client, cluster) for ``scheduler``: ``"local"``, an address, or a Client."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise OptionError("--scheduler needs dask.distributed; install it with "
                          "pip install 'stereobudget[dask]'") from None
    if not isinstance(scheduler, str):
        return scheduler, None, False
    if scheduler == "local":
        # Shutdown races (a worker's last heartbeat to a closed scheduler) are logged by
        # dask as tracebacks; our results come back as dicts, so keep its logs quiet
        # unless debugging.
        quiet = logging.DEBUG if log.getEffectiveLevel() <= logging.DEBUG else logging.CRITICAL
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=quiet)
        return Client(cluster), cluster, True
    try:
        return Client(scheduler, timeout="20s"), None, True
    except (OSError, TimeoutError) as exc:
        raise OptionError(f"cannot connect to the dask scheduler {scheduler!r}: {exc}") from None


#: Path fields of the jobs, made absolute before they go to a cluster.
_PATH_FIELDS = ("source", "output", "left", "samples", "disparity", "preview", "right")


def _absolute_paths(job):
    """``job`` with every relative path made absolute here.

    A worker of a real cluster runs in its own folder (wherever ``dask worker`` was
    started): a relative input would not be found there, and a relative output would
    land there.  The cluster must see this machine's paths (shared storage).
    """
    from dataclasses import fields, is_dataclass, replace
    if not is_dataclass(job):
        return job
    names = {f.name for f in fields(job)}
    changes = {name: os.path.abspath(getattr(job, name)) for name in _PATH_FIELDS
               if name in names and isinstance(getattr(job, name), str) and getattr(job, name) != STDIO
               and not os.path.isabs(getattr(job, name))}
    return replace(job, **changes) if changes else job


def _on_worker(job, *, fn):
    """``fn(job)`` on a dask worker; a failure names the worker (its files, its memory, its logs)."""
    result = fn(job)
    if result.get("status") == "failed":
        try:
            from distributed import get_worker
            address = get_worker().address
        except Exception:  # noqa: BLE001 -- not on a worker (a threaded client): nothing to add
            address = None
        if address:
            result["worker"] = address
            result["error"] = f"{result.get('error')} (on worker {address})"
    return result


def _run_dask(jobs: list, fn: Callable, scheduler, workers: int, threads: int | None) -> Iterator[dict]:
    client, cluster, owned = _dask_client(scheduler, workers, threads)
    futures = []
    try:
        from distributed import as_completed
        if threads:
            jobs = [_with_threads(job, threads) for job in jobs]
        jobs = [_absolute_paths(job) for job in jobs]
        # pure=False: every job must run even when two are equal (they write files).
        futures = client.map(_on_worker, jobs, pure=False, fn=fn)
        index = {future.key: job for future, job in zip(futures, jobs)}
        for future in as_completed(futures):
            try:
                yield future.result()
            except Exception as exc:  # noqa: BLE001 -- a lost worker fails its file only
                yield _crashed(index.get(future.key), exc)
        if cluster is None:
            _release_worker_volumes(client)
    finally:
        for future in futures:
            if not future.done():
                future.cancel()
        if owned:
            client.close()
        if cluster is not None:
            cluster.close()


def _release_worker_volumes(client) -> None:
    """Drop the spare volumes the jobs left on the workers of a cluster that outlives the batch.

    Each worker keeps its last decode's volumes for the next one of the same frame size
    (:mod:`stereobudget._kernels._scratch`), GiBs at large frames; once the batch is done they are
    memory the cluster's other work cannot have.  Best effort: a worker that is gone is
    skipped.
    """
    from .._kernels._scratch import release
    try:
        client.run(release, on_error="ignore")
    except Exception as exc:  # noqa: BLE001 -- a closed client or an older distributed
        log.debug("could not release the workers' spare volumes: %s", exc)


def _with_threads(job, threads: int):
    if isinstance(job, DecodeJob) and job.threads is None:
        from dataclasses import replace
        return replace(job, threads=threads)
    return job


def run_jobs(jobs: Iterable, fn: Callable, *, workers: int | None = None, scheduler=None,
             progress: Callable[[dict], None] | None = None) -> Iterator[dict]:
    """Run ``fn(job)`` for every job and yield the result dicts as they complete.

    Parameters
    ----------
    jobs : iterable
        Picklable job descriptions (:class:`EncodeJob`, :class:`DecodeJob`).
    fn : callable
        A module-level function returning a small dict and never raising for bad
        input (:func:`encode_job`, :func:`decode_job`).
    workers : int, optional
        Parallel workers (default :func:`default_jobs`).  With 1 (or one job) the work
        runs in this process; otherwise in a local process pool, each worker's numba
        limited to its share of the cores.
    scheduler : str or distributed.Client, optional
        Run on dask.distributed instead: ``"local"`` starts a LocalCluster of
        ``workers`` single-threaded worker processes; any other string is a scheduler
        address (``tcp://host:8786``); a Client is used as it is.  Workers read and write
        the files themselves (shared storage) and send back only the result dicts.
    progress : callable, optional
        Called with each result dict as it arrives.

    Yields
    ------
    dict
        One per job, in completion order.  Closing the generator early (or an interrupt)
        cancels the queued jobs and stops the workers, which remove their temporary files.
    """
    jobs = list(jobs)
    workers = max(1, int(workers or default_jobs()))
    # Jobs on one machine share its cores: each worker's numba gets its share.
    threads = max(1, default_jobs() // workers)

    def report(results):
        for item in results:
            if progress is not None:
                progress(item)
            yield item

    if scheduler is not None:
        yield from report(_run_dask(jobs, fn, scheduler, workers,
                                    threads if scheduler == "local" else None))
    elif workers == 1 or len(jobs) <= 1:
        yield from report(fn(job) for job in jobs)
    else:
        yield from report(_run_local_pool(jobs, fn, min(workers, len(jobs)), threads))


def count_statuses(results: Iterable[dict]) -> dict:
    """``{"ok": n, "skipped": n, "failed": n}`` of a list of result dicts."""
    counts = {"ok": 0, "skipped": 0, "failed": 0}
    for item in results:
        counts[item.get("status", "failed")] = counts.get(item.get("status", "failed"), 0) + 1
    return counts


__all__ = ["IMAGE_EXTENSIONS", "SAMPLE_EXTENSIONS", "TEMPLATE_FIELDS", "expand_inputs", "has_template",
           "template_fields", "expand_template", "output_for", "check_distinct_outputs", "Pair",
           "pair_by_stem", "read_manifest", "outputs_up_to_date", "EncodeJob", "encode_job",
           "DecodeJob", "decode_file", "decode_job", "recover_right_image", "run_jobs", "default_jobs",
           "count_statuses"]
