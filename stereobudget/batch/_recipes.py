"""What made each output of a batch: the record that tells a stale output from an up-to-date one.

File times alone cannot tell that ``sb-encode ... --stride 4`` after a stride-5 run must
redo every file: the outputs are newer than their inputs but were made otherwise.  Each
output of a batch therefore gets a *recipe*, a small JSON sidecar beside it (hidden:
``.NAME.sbrecipe``), holding what made it:

* the tool and its version (``stereobudget 0.x``),
* every input's absolute path, size and modification time,
* the options that shape the output (sampling pattern; method, disparity range as given,
  decoder parameters, output formats).

A batch job is skipped only when every output exists and its recipe equals the job's;
otherwise it is redone and :func:`recipe_difference` says why (``"options changed:
stride_x 5 -> 4"``).  Outputs of a version that wrote no recipe are redone once.  The
recipe is written after the outputs, atomically, so an interrupted job has none and is
redone by the next run.

This module imports neither numba nor numpy (the camera side uses it).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from .._version import __version__
from ..io._atomic import STDIO, write_output_bytes

#: Suffix of the sidecar beside each output (``out/.a.pfm.sbrecipe`` for ``out/a.pfm``).
RECIPE_SUFFIX = ".sbrecipe"
TOOL = f"stereobudget {__version__}"


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


def _read(path: str):
    try:
        with open(path, encoding="utf-8") as handle:
            return json.load(handle)
    except (OSError, ValueError):
        return None


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
    stereobudget X"``, ``"inputs changed"``, ``"options changed: ..."``.
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
            return f"made by {stored.get('tool', 'an older version')}"
        if stored.get("kind") != recipe["kind"] or stored.get("inputs") != recipe["inputs"]:
            return "inputs changed"
        if stored.get("options") != recipe["options"]:
            changes = _option_changes(stored.get("options") or {}, recipe["options"])
            shown = ", ".join(changes[:3]) + (f" (+{len(changes) - 3} more)" if len(changes) > 3 else "")
            return f"options changed: {shown}"
    return None


def write_recipes(outputs, recipe: dict) -> None:
    """Record ``recipe`` beside every file output (after the outputs were written)."""
    data = (json.dumps(recipe, sort_keys=True, indent=1) + "\n").encode("utf-8")
    for out in outputs:
        if out is not None and out != STDIO:
            write_output_bytes(recipe_path(out), data, overwrite=True, fsync=False)


__all__ = ["RECIPE_SUFFIX", "recipe_path", "make_recipe", "recipe_difference", "write_recipes"]
