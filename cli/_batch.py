"""CLI side of batch runs shared by ``sb-encode`` and ``sb-decode``.

The per-file work and the runners are in :mod:`stereobudget.batch`; this module adds
what only a terminal needs: the ``-j``/``--scheduler`` options, a progress bar on stderr
(only when stderr is a terminal and not ``-q``), one JSON line per file on stdout, a
one-line message per failed file, and the exit status (1 if any file failed).
"""

from __future__ import annotations

import contextlib
import logging
import sys

import click

from stereobudget.errors import OptionError

from . import _common as common

log = logging.getLogger("stereobudget")


def jobs_options(func):
    """Add ``-j/--jobs`` and ``--scheduler``."""
    func = click.option("--scheduler", metavar="ADDRESS", default=None,
                        help="Run the files on a dask.distributed cluster (tcp://host:8786), or "
                             "'local' for a LocalCluster of --jobs single-threaded workers. "
                             "Workers need the same paths (shared storage).")(func)
    func = click.option("-j", "--jobs", "jobs", type=click.IntRange(1, 4096), default=None,
                        help="Files processed in parallel.  [default: number of cores]")(func)
    return func


def _show_progress() -> bool:
    try:
        tty = sys.stderr.isatty()
    except (AttributeError, ValueError):
        tty = False
    return tty and log.getEffectiveLevel() <= logging.WARNING


def run_batch(jobs: list, fn, *, workers: int | None, scheduler: str | None, as_json: bool,
              on_result=None) -> None:
    """Run ``jobs`` with ``fn``; print JSON lines / failures; exit 1 if any file failed.

    ``on_result(item)`` is called for every file done (``ok``), e.g. to print its warnings.
    Returns normally only when every file is ``ok`` or ``skipped``.
    """
    from stereobudget.batch import run_jobs

    counts = {"ok": 0, "skipped": 0, "failed": 0}
    redone: dict[str, int] = {}
    bar_context = (click.progressbar(length=len(jobs), label=common.prog_name(), file=sys.stderr)
                   if _show_progress() and len(jobs) > 1 else contextlib.nullcontext())
    with bar_context as bar:
        results = run_jobs(jobs, fn, workers=workers, scheduler=scheduler)
        with contextlib.closing(results):
            for item in results:
                status = item.get("status", "failed")
                counts[status] = counts.get(status, 0) + 1
                if status == "failed":
                    log.error("error: %s", item.get("error"))
                elif status == "skipped":
                    log.info("%s: up to date, skipped", item.get("input") or item.get("left"))
                else:
                    if item.get("redone"):
                        reason = item["redone"]
                        redone[reason] = redone.get(reason, 0) + 1
                        log.info("%s: redone (%s)", item.get("input") or item.get("left"), reason)
                    if on_result is not None:
                        on_result(item)
                if as_json:
                    common.emit_json(item)
                    common.flush_stdout()
                if bar is not None:
                    bar.update(1)
    total = sum(counts.values())
    # Said at the default verbosity: a rerun that changes nothing must not look like one that worked.
    if counts["skipped"]:
        log.warning("%d of %d file(s) skipped: up to date (same inputs, options and version; "
                    "--overwrite redoes them)", counts["skipped"], total)
    for reason, count in sorted(redone.items(), key=lambda kv: -kv[1]):
        log.warning("%d file(s) redone: %s", count, reason)
    log.info("%d file(s): %d done, %d skipped, %d failed", total, counts["ok"], counts["skipped"],
             counts["failed"])
    if counts["failed"]:
        if total > 1:
            log.error("%d of %d file(s) failed", counts["failed"], total)
        sys.exit(1)


def plan_encode(images, output: str, *, pattern, raw_size, pix_fmt, overwrite: bool, coding: dict | None = None):
    """``(single_input, jobs)``: the one input of a single-file run, or the batch's jobs.

    A single run (one input after expansion and an ``-o`` without template) keeps the
    classic behaviour: the error's own exit code, no skipping of existing outputs.

    Raises
    ------
    OptionError
        Several inputs and an ``-o`` without a template, ``-`` among several inputs,
        two inputs that would write the same file.
    """
    from stereobudget.batch._inputs import (IMAGE_EXTENSIONS, check_distinct_outputs, expand_inputs,
                                            expand_template, has_template)
    from stereobudget.pipeline import EncodeJob

    templated = has_template(output, "-o")
    inputs = expand_inputs(images, extensions=None if raw_size is not None else IMAGE_EXTENSIONS,
                           what="raw frame" if raw_size is not None else "image")
    if len(inputs) == 1 and not templated:
        return inputs[0], None
    if len(inputs) > 1 and not templated:
        raise OptionError(f"{len(inputs)} inputs but -o {output!r} has no template; use e.g. "
                          "-o 'out/{stem}.sbs' ({stem}, {name}, {parent} of each input)")
    if "-" in inputs:
        raise OptionError("'-' (standard input) works with a single input only")
    jobs = [EncodeJob(source=name, output=expand_template(output, name, option="-o"), pattern=pattern,
                      raw_size=raw_size, pix_fmt=pix_fmt, overwrite=overwrite, batch=True, coding=coding)
            for name in inputs]
    check_distinct_outputs(jobs, key=lambda job: [job.output])
    return None, jobs
