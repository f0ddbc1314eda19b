"""Per-file jobs: what one encode or decode of a batch is, and doing it.

:class:`EncodeJob` / :class:`DecodeJob` describe one file's work with plain, picklable
values; :func:`encode_job` / :func:`decode_job` do it and *never raise* for bad input:
they return a small JSON-able dict with ``status`` ``"ok"``, ``"skipped"`` or
``"failed"`` (plus ``error``, ``error_class`` and ``exit_code`` on failure).

Up-to-date rule: in a batch, each output gets a record of what made it (tool version,
inputs' paths, sizes and times, options, decoder parameters: :mod:`stereobudget.batch._recipes`);
a job whose outputs all exist with the record the job would write is skipped, any other
is redone (its result says why, under ``redone``) and its outputs are replaced.
``overwrite=True`` redoes every job.  Outputs are always written atomically, so an
interrupted batch leaves complete outputs and no partial ones.

This module imports neither numba nor OpenCV: the camera-side ``sb-encode`` uses it.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass

from ..io._atomic import STDIO, display_name, interrupts_deferred
from ..errors import MemoryLimitError, OptionError, StereoBudgetError
from ..decoding._methods import DEFAULT_METHOD
from ._outputs import _prepare_outputs, check_job_outputs
from ._recipes import make_recipe, recipe_difference, write_recipes
from ._worker import _in_job, _limit_numba_threads

log = logging.getLogger("stereobudget")


def _failure(exc: BaseException) -> dict:
    if isinstance(exc, StereoBudgetError):
        return {"error": str(exc), "error_class": type(exc).__name__, "exit_code": exc.exit_code}
    if isinstance(exc, MemoryError):
        return {"error": "out of memory", "error_class": "MemoryLimitError", "exit_code": 11}
    # A bug, not bad input: keep the batch going but say what it was.
    return {"error": f"unexpected {type(exc).__name__}: {exc}", "error_class": type(exc).__name__,
            "exit_code": 1}


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
                  timings: dict, start: float, recipe: dict | None = None, announce: bool = False,
                  decoder=None, check_setup: bool = True) -> dict:
    """The part of :func:`decode_file` after reading: decode ``left`` + ``samples``, write ``job``'s outputs.

    The outputs have been checked (``overwrite`` is the flag to write them with);
    ``timings`` holds the stages so far and ``start`` the job's start
    (``time.perf_counter``).  ``announce`` says before the first kernel runs that numba
    may compile for minutes.  ``decoder``: the :class:`~stereobudget.decoding.Decoder` to
    decode with (a stream's temporal one; default the process's shared one).
    ``check_setup=False`` with a given ``max_disp`` skips the range estimate, which then only
    serves the swapped / not rectified warnings (a stream checks its first frame).  Returns
    the summary of :func:`decode_file`.
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
    from .._kernels._first_run import compile_notice
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
        if auto or check_setup:
            with compile_notice(job.method or DEFAULT_METHOD):    # names the method, not the range estimate
                min_disp, max_disp, estimate = disprange.resolve_range(left, samples, max_disp=job.max_disp,
                                                                       min_disp=job.min_disp)
        else:
            min_disp, max_disp, estimate = (0 if job.min_disp is None else int(job.min_disp),
                                            int(job.max_disp), None)
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
        result = (decoder or decoders.shared_decoder()).decode(left, samples, max_disp=max_disp,
                                                               min_disp=min_disp, method=method,
                                                               max_memory=job.max_memory)
    except MemoryLimitError as exc:
        raise MemoryLimitError(exc.message, path=left_name) from None
    except MismatchError as exc:
        raise MismatchError(f"{exc.message} ({samples_name})", path=left_name) from None
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
        "range_source": "estimated" if auto else "given",
        "range_estimate": None if estimate is None else estimate.summary(),
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


__all__ = ["EncodeJob", "encode_job", "DecodeJob", "recover_right_image", "decode_file",
           "decode_arrays", "decode_job"]
