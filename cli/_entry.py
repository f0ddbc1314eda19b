"""Console-script entry points that catch Ctrl-C from the first import on.

The generated ``sb-encode`` / ``sb-decode`` scripts import their entry point before
anything else runs.  Importing the commands (click, and for ``sb-decode`` numpy and
OpenCV) takes a noticeable moment, and a Ctrl-C in it would otherwise end in a
KeyboardInterrupt traceback; this module imports nothing heavy itself (only
:mod:`stereobudget.errors`), so the window left is the interpreter's own start-up.
"""

from __future__ import annotations

import importlib
import sys

from stereobudget.errors import EXIT_INTERRUPTED   # a module of plain classes: imports nothing


def _run(command: str):
    try:
        main = importlib.import_module(f"stereobudget.cli.{command}").main
    except KeyboardInterrupt:
        sys.stderr.write(f"sb-{command}: interrupted\n")
        sys.exit(EXIT_INTERRUPTED)
    return main()


def encode():
    """Entry point of ``sb-encode``."""
    return _run("encode")


def decode():
    """Entry point of ``sb-decode``."""
    return _run("decode")
