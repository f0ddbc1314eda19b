"""Console-script entry points that catch Ctrl-C from the first import on.

The generated ``sb-encode`` / ``sb-decode`` scripts import their entry point before
anything else runs.  Importing the commands (click, and for ``sb-decode`` numpy and
OpenCV) takes a noticeable moment, and a Ctrl-C in it would otherwise end in a
KeyboardInterrupt traceback; this module imports nothing heavy itself, so the window
left is the interpreter's own start-up.
"""

from __future__ import annotations

import importlib
import sys

_EXIT_INTERRUPTED = 130   # = stereobudget.errors.EXIT_INTERRUPTED (not imported: keep this module bare)


def _run(command: str):
    try:
        main = importlib.import_module(f"stereobudget.cli.{command}").main
    except KeyboardInterrupt:
        sys.stderr.write(f"sb-{command}: interrupted\n")
        sys.exit(_EXIT_INTERRUPTED)
    return main()


def encode():
    """Entry point of ``sb-encode``."""
    return _run("encode")


def decode():
    """Entry point of ``sb-decode``."""
    return _run("decode")
