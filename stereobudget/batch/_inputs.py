"""Inputs of a batch: file lists from arguments, output templates, (left, samples) pairs.

* :func:`expand_inputs` turns arguments (files, folders, quoted globs) into a file list;
  :func:`expand_template` turns an output template (``out/{stem}.sbs``) into a path.
* :func:`pair_by_stem` / :func:`read_manifest` build the (left, samples) pairs of a
  decoding batch; a left image without its sample file (or the reverse) becomes a job
  that fails with a clear message instead of vanishing.

This module imports neither numba nor OpenCV: the camera-side ``sb-encode`` uses it.
"""

from __future__ import annotations

import csv
import glob
import os
import string
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from ..io._atomic import STDIO
from ..errors import OptionError

#: Extensions listed when a folder of images is given as input.
IMAGE_EXTENSIONS = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm", ".bmp", ".webp")
#: Extension listed when a folder of sample files is given as input.
SAMPLE_EXTENSIONS = (".sbs",)
#: Fields an output template may use.
TEMPLATE_FIELDS = ("stem", "name", "parent")

_GLOB_CHARS = frozenset("*?[")


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


def check_distinct_outputs(jobs, *, key: Callable) -> None:
    """Refuse a batch in which two jobs would write the same file.

    ``key(job)`` returns the job's output paths (None entries are ignored).
    """
    owner: dict[str, object] = {}
    for job in jobs:
        own: set = set()
        for out in key(job):
            if out is None or out == STDIO:
                continue
            norm = os.path.normpath(os.path.abspath(out))
            if norm in own:
                raise OptionError(f"two outputs of {job.label} are the same file {out!r}; give each output "
                                  f"its own name")
            if norm in owner:
                raise OptionError(f"two inputs would write the same output {out!r} "
                                  f"({owner[norm]} and {job.label}); add {{parent}} or change the template")
            own.add(norm)
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
        # utf-8-sig: Excel's "CSV UTF-8" starts with a byte-order mark, which would hide the header.
        with open(path, newline="", encoding="utf-8-sig") as handle:
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


__all__ = ["IMAGE_EXTENSIONS", "SAMPLE_EXTENSIONS", "TEMPLATE_FIELDS", "expand_inputs",
           "has_template", "template_fields", "uses_field", "expand_template",
           "check_distinct_outputs", "Pair", "pair_by_stem", "read_manifest"]
