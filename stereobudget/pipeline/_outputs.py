"""A job's outputs, checked before any work: folders created, formats known, nothing overwritten unasked.

This module imports neither numba nor OpenCV: the camera-side ``sb-encode`` uses it.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..io._atomic import STDIO, check_output_path
from ..errors import OptionError, OutputError


def prepare_outputs(outputs: list[str], inputs: list[str], *, overwrite: bool, make_dirs: bool,
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


def _check_output_formats(job) -> None:
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
    if (job.depth is not None or job.points is not None or job.frame is not None) and job.calibration is None:
        given = [f"--{name}" for name, value in (("depth", job.depth), ("points", job.points),
                                                   ("frame", job.frame)) if value is not None]
        raise OptionError(f"{' and '.join(given)} need{'s' if len(given) == 1 else ''} --calibration (the "
                          "cameras' focal length, baseline and rotation)")
    if job.calibration == "auto" and (job.depth is not None or job.points is not None):
        given = " and ".join(f"--{name}" for name, value in (("depth", job.depth), ("points", job.points))
                             if value is not None)
        raise OptionError(f"{given} need{'s' if ' and ' not in given else ''} a calibration file: --calibration auto "
                          "finds how the cameras are turned, not how far apart they are (no metric scale)")
    if job.frame not in (None, "raw", "rectified"):
        raise OptionError(f"--frame must be raw or rectified, not {job.frame!r}")
    for name, value in (("depth", job.depth), ("points", job.points)):
        if value == STDIO:
            raise OptionError(f"--{name} cannot go to standard output; give a file name")
    if job.depth is not None:
        from ..geometry._output import DEPTH_EXTENSIONS
        if ext(job.depth) not in DEPTH_EXTENSIONS:
            raise OutputError(f"unknown depth format {ext(job.depth) or '(no extension)'!r}; use one of "
                              f"{', '.join(DEPTH_EXTENSIONS)}", path=job.depth)
    if job.points is not None and ext(job.points) != ".ply":
        raise OutputError("a point cloud is written as PLY; use a .ply file name", path=job.points)
    if job.right is not None and job.right != STDIO and ext(job.right) not in (".png", ".tif", ".tiff"):
        raise OutputError(f"unsupported image extension {ext(job.right) or '(none)'!r}; "
                          "use .png, .tif or .tiff", path=job.right)


def check_job_outputs(job) -> None:
    """Refuse a :class:`~stereobudget.pipeline.DecodeJob` with no output, two outputs on one file, or an
    unknown output format."""
    outputs = job.outputs
    if not outputs:
        raise OptionError("nothing to write: give --disparity, --preview, --right, --depth and/or --points")
    seen = {}
    for kind, path in outputs.items():
        if path != STDIO and path in seen:
            raise OptionError(f"--{seen[path]} and --{kind} name the same file", path=path)
        seen[path] = kind
    _check_output_formats(job)


__all__ = ["prepare_outputs", "check_job_outputs"]
