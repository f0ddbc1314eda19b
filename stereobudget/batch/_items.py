"""A batch's items: one file's encode or decode that never raises, skipped when up to date.

:func:`encode_job` / :func:`decode_job` wrap the pipeline's single-file paths
(:func:`stereobudget.pipeline.encode_one`, :func:`stereobudget.pipeline.decode_file`) and
return a small JSON-able dict with ``status`` ``"ok"``, ``"skipped"`` or ``"failed"`` (plus
``error``, ``error_class`` and ``exit_code`` on failure), so that one bad file does not stop
a batch.

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

from ..io._atomic import STDIO, display_name
from ..errors import OutputError, StereoBudgetError
from ..decoding._methods import DEFAULT_METHOD
from ..pipeline._jobs import DecodeJob, EncodeJob, decode_file, encode_one
from ._recipes import make_recipe, recipe_difference, write_recipes
from ._worker import _in_job, _limit_numba_threads

log = logging.getLogger("stereobudget")

#: How long a job whose output appeared while it ran waits for that output's recipe: the
#: run that wrote it records the recipe right after the output (milliseconds later).
RECIPE_WAIT = 2.0


def _finished_elsewhere(exc: BaseException, outputs, recipe: dict | None) -> bool:
    """Whether ``exc`` (an output that exists) is another run having made the same outputs.

    Two identical batches into one folder race for each file: the loser finds the
    winner's output at its final rename.  When that output, and its partners, now carry
    the recipe this job would have written, the job is up to date, not failed.
    """
    if recipe is None or not isinstance(exc, OutputError):
        return False
    deadline = time.monotonic() + RECIPE_WAIT
    while True:
        if recipe_difference(outputs, recipe) is None:
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)


def _failure(exc: BaseException) -> dict:
    if isinstance(exc, StereoBudgetError):
        return {"error": str(exc), "error_class": type(exc).__name__, "exit_code": exc.exit_code}
    if isinstance(exc, MemoryError):
        return {"error": "out of memory", "error_class": "MemoryLimitError", "exit_code": 11}
    # A bug, not bad input: keep the batch going but say what it was.
    return {"error": f"unexpected {type(exc).__name__}: {exc}", "error_class": type(exc).__name__,
            "exit_code": 1}


def _recorder(recipe: dict | None):
    """The pipeline's ``after_write`` hook that records ``recipe`` beside the outputs."""
    if recipe is None:
        return None
    return lambda outputs: write_recipes(outputs, recipe)


def encode_job(job: EncodeJob) -> dict:
    """Do one :class:`~stereobudget.pipeline.EncodeJob`; never raises for bad input.

    Returns
    -------
    dict
        ``status`` (``ok``/``skipped``/``failed``), ``input``, ``output``, ``timings``
        and, when encoded, the fields of :class:`stereobudget.encoding.EncodeReport`
        (``epsilon``, sizes...); on failure ``error``, ``error_class``, ``exit_code``.
    """
    start = time.perf_counter()
    result = {"status": "ok", "input": display_name(job.source),
              "output": "<stdout>" if job.output == STDIO else job.output}
    _in_job(True)
    recipe = None
    try:
        recipe = _encode_recipe(job) if job.batch else None
        if recipe is not None:
            reason = recipe_difference([job.output], recipe)
            if reason is None and not job.overwrite:
                result.update(status="skipped", reason="up to date")
                return result
            if os.path.exists(job.output):
                result["redone"] = "--overwrite" if reason is None else reason
        result.update(encode_one(job, after_write=_recorder(recipe)))
    except (StereoBudgetError, MemoryError) as exc:
        if _finished_elsewhere(exc, [job.output], recipe):
            result.pop("redone", None)
            result.update(status="skipped", reason="up to date")
            return result
        result.update(status="failed", **_failure(exc))
    except Exception as exc:  # noqa: BLE001 -- one bad file must not stop a batch
        log.debug("unexpected error on %s", job.label, exc_info=True)
        result.update(status="failed", **_failure(exc))
    finally:
        _in_job(False)
        result["timings"] = {"total": round(time.perf_counter() - start, 4)}
    return result


def _encode_recipe(job: EncodeJob) -> dict:
    from dataclasses import asdict
    return make_recipe("sb-encode", [job.source], {
        "pattern": asdict(job.pattern), "raw_size": list(job.raw_size) if job.raw_size else None,
        "pix_fmt": job.pix_fmt, "coding": dict(job.coding or {})})


def _decode_recipe(job: DecodeJob) -> dict:
    from dataclasses import asdict

    from ..decoding._decoders import DecoderParams
    from ..decoding._disprange import is_auto
    options = {
        "method": job.method or DEFAULT_METHOD,
        "max_disp": "auto" if is_auto(job.max_disp) else int(job.max_disp),
        "min_disp": job.min_disp, "params": asdict(DecoderParams()),
        "outputs": sorted(job.outputs), "disparity_format": job.disparity_format,
        "calibration": "auto" if job.calibration == "auto" else job.calibration is not None, "frame": job.frame}
    if job.right is not None:
        # A change of how Î2 is made (an option, or a default of a new version) redoes it.
        from ..synthesis._recover import SynthesisParams
        options["synthesis"] = asdict(SynthesisParams(**(job.synthesis or {})))
    return make_recipe("sb-decode", [job.left, job.samples, job.calibration_file], options)


def decode_job(job: DecodeJob) -> dict:
    """Do one :class:`~stereobudget.pipeline.DecodeJob`; never raises for bad input (see :func:`encode_job`)."""
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
        _limit_numba_threads(job.threads)
        try:
            summary = decode_file(job, after_write=_recorder(recipe))
        except OutputError as exc:
            if _finished_elsewhere(exc, job.outputs.values(), recipe):
                return {"status": "skipped", **base, "reason": "up to date",
                        "timings": {"total": round(time.perf_counter() - start, 4)}}
            raise
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


__all__ = ["encode_job", "decode_job"]
