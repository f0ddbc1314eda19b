"""What made each output of a batch: the record that tells a stale output from an up-to-date one.

File times alone cannot tell that ``sb-encode ... --stride 4`` after a stride-5 run must
redo every file: the outputs are newer than their inputs but were made otherwise.  Each
output of a batch therefore gets a *recipe*, a small JSON sidecar beside it (hidden:
``.NAME.sbrecipe``), holding what made it:

* the tool and its version (``stereobudget 0.x``),
* every input's absolute path, size and modification time,
* the options that shape the output (sampling pattern; method, disparity range as given,
  decoder parameters, output formats),
* what was written: the output's size and SHA-256 digest (``"output"``).

A batch job is skipped only when every output exists, is still what was written (same
size and digest: a truncated, altered or foreign file is redone) and its recipe equals
the job's; otherwise it is redone and :func:`recipe_difference` says why (``"options
changed: stride_x 5 -> 4"``).  Outputs of a version that wrote no recipe are redone once.
The recipe is written after the outputs, atomically, so an interrupted job has none and
is redone by the next run.

A sidecar is only data: one that is not a small regular file (a FIFO, a link to
``/dev/zero``, a folder) or not a recipe's JSON (another shape, nesting without end) is
read as no record, so its output is redone; reading it can neither hang nor fail.

This module imports neither numba nor numpy (the camera side uses it).
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from pathlib import Path

from .._version import __version__
from ..io._atomic import STDIO, write_output_bytes

#: Suffix of the sidecar beside each output (``out/.a.pfm.sbrecipe`` for ``out/a.pfm``).
RECIPE_SUFFIX = ".sbrecipe"
TOOL = f"stereobudget {__version__}"
#: Largest sidecar read: a recipe is about a kilobyte; anything far larger is not one.
MAX_RECIPE_BYTES = 64 * 1024
#: The keys of a recipe and the JSON type each must have (anything else: no record).
_RECIPE_SHAPE = {"tool": str, "kind": str, "inputs": list, "options": dict}


def recipe_path(output: str) -> str:
    """The sidecar file that records what made ``output``."""
    path = Path(output)
    return str(path.parent / f".{path.name}{RECIPE_SUFFIX}")


def _input_record(path: str) -> dict:
    try:
        st = os.stat(path)
    except OSError:
        return {"path": os.path.abspath(path), "missing": True}
    return {"path": os.path.abspath(path), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def make_recipe(kind: str, inputs, options: dict) -> dict:
    """The recipe of a job: tool and version, its inputs as they are now, and ``options``.

    ``options`` must be JSON-able and hold everything (besides the inputs) that changes
    the outputs.
    """
    return {"tool": TOOL, "kind": kind, "inputs": [_input_record(i) for i in inputs if i and i != STDIO],
            "options": json.loads(json.dumps(options, sort_keys=True, default=str))}


def _open_regular(path: str):
    """A binary reader of ``path`` if it is a regular file (never a link, FIFO or device), else None.

    ``O_NONBLOCK`` makes opening a FIFO return at once (instead of waiting for a writer)
    and ``O_NOFOLLOW`` refuses a symbolic link; the type is then checked on the open
    descriptor, so a file swapped in between cannot slip through.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        return None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            os.close(fd)
            return None
        return os.fdopen(fd, "rb")
    except OSError:
        os.close(fd)
        return None


def _read(path: str):
    """The recipe stored at ``path``, or None when there is none that can be trusted."""
    handle = _open_regular(path)
    if handle is None:
        return None
    try:
        with handle:
            data = handle.read(MAX_RECIPE_BYTES + 1)
        if len(data) > MAX_RECIPE_BYTES:
            return None
        stored = json.loads(data.decode("utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(stored, dict):
        return None
    for key, kind in _RECIPE_SHAPE.items():
        if key in stored and not isinstance(stored[key], kind):
            return None
    if not all(isinstance(item, dict) for item in stored.get("inputs") or []):
        return None
    return stored


def _output_record(path: str) -> dict | None:
    """Size and SHA-256 of the output ``path`` as it is now; None unless it is a regular file."""
    handle = _open_regular(path)
    if handle is None:
        return None
    digest = hashlib.sha256()
    size = 0
    try:
        with handle:
            while chunk := handle.read(1 << 20):
                digest.update(chunk)
                size += len(chunk)
    except OSError:
        return None
    return {"size": size, "sha256": digest.hexdigest()}


def _output_changed(path: str, written) -> bool:
    """Whether ``path`` is no longer the file the recipe says was written."""
    if not isinstance(written, dict):
        return True
    try:
        info = os.lstat(path)
    except OSError:
        return True
    # The size first: a truncated or replaced file is told without reading it.
    if not stat.S_ISREG(info.st_mode) or info.st_size != written.get("size"):
        return True
    return _output_record(path) != written


def _option_changes(old: dict, new: dict) -> list[str]:
    changes = []
    for key in sorted(set(old) | set(new)):
        if old.get(key) != new.get(key):
            a, b = old.get(key, "(none)"), new.get(key, "(none)")
            if isinstance(a, dict) and isinstance(b, dict):
                changes.extend(f"{key}.{c}" for c in _option_changes(a, b))
            else:
                changes.append(f"{key} {a} -> {b}")
    return changes


def recipe_difference(outputs, recipe: dict) -> str | None:
    """Why the outputs must be (re)made for ``recipe``; None when they are up to date.

    Reasons: ``"missing output"``, ``"no record of what made it"``, ``"made by
    stereobudget X"``, ``"inputs changed"``, ``"options changed: ..."``, ``"output
    changed since it was written"``.
    """
    outputs = [o for o in outputs if o is not None]
    if not outputs or any(o == STDIO for o in outputs):
        return "output on standard output"
    for out in outputs:
        if not os.path.exists(out):
            return "missing output"
    for out in outputs:
        stored = _read(recipe_path(out))
        if not isinstance(stored, dict):
            return "no record of what made it"
        if stored.get("tool") != recipe["tool"]:
            return f"made by {str(stored.get('tool', 'an older version'))[:60]}"
        if stored.get("kind") != recipe["kind"] or stored.get("inputs") != recipe["inputs"]:
            return "inputs changed"
        if stored.get("options") != recipe["options"]:
            changes = _option_changes(stored.get("options") or {}, recipe["options"])
            shown = ", ".join(changes[:3]) + (f" (+{len(changes) - 3} more)" if len(changes) > 3 else "")
            return f"options changed: {shown}"
        if _output_changed(out, stored.get("output")):
            return "output changed since it was written"
    return None


def _drop_foreign_sidecar(path: str) -> None:
    """Remove what stands at a sidecar's path if it is not a regular file (a FIFO, a link, a device).

    The hidden sidecar is the batch's own file, so whatever took its place is replaced, not
    refused as a user's output would be; a link is removed itself, never what it points to.
    """
    try:
        info = os.lstat(path)
    except OSError:
        return
    if not stat.S_ISREG(info.st_mode) and not stat.S_ISDIR(info.st_mode):
        try:
            os.unlink(path)
        except OSError:
            pass    # the write that follows says what is wrong


def write_recipes(outputs, recipe: dict) -> None:
    """Record ``recipe`` beside every file output, with what was written (after the outputs were written)."""
    for out in outputs:
        if out is not None and out != STDIO:
            record = {**recipe, "output": _output_record(out)}
            data = (json.dumps(record, sort_keys=True, indent=1) + "\n").encode("utf-8")
            _drop_foreign_sidecar(recipe_path(out))
            write_output_bytes(recipe_path(out), data, overwrite=True, fsync=False)


__all__ = ["RECIPE_SUFFIX", "recipe_path", "make_recipe", "recipe_difference", "write_recipes"]
