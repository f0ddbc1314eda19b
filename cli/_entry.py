"""Console-script entry points that catch Ctrl-C from the first import on.

The generated ``sb-encode`` / ``sb-decode`` scripts import their entry point before
anything else runs.  Importing the commands (click, and for ``sb-decode`` numpy and
OpenCV) takes a noticeable moment, and a Ctrl-C in it would otherwise end in a
KeyboardInterrupt traceback; this module imports nothing heavy itself (only
:mod:`stereobudget.errors`), so the window left is the interpreter's own start-up.
"""

from __future__ import annotations

import atexit
import importlib
import os
import signal
import sys
import threading

from stereobudget.errors import EXIT_INTERRUPTED   # a module of plain classes: imports nothing


def _run(command: str):
    try:
        main = importlib.import_module(f"stereobudget.cli.{command}").main
        try:
            code = main()
        except SystemExit as exc:
            code = exc.code
        _ignore_interrupts(command)     # the outputs are complete or absent: nothing to stop
    except KeyboardInterrupt:
        # While the command was imported, or just after it returned (while it runs, its
        # own handler reports an interrupt): the same one line and status.
        _ignore_interrupts(command)
        sys.stderr.write(f"sb-{command}: interrupted\n")
        code = EXIT_INTERRUPTED
    kernels = sys.modules.get("stereobudget._kernels._parallel")
    if kernels is not None:
        kernels.stop_workers()      # idle threads of the kernels' pool: nothing to join for
    if not _is_console_script(command) or threading.active_count() > 1:
        sys.exit(code)      # embedded, or threads to join: the interpreter's normal exit
    _exit_without_teardown(code)


def _is_console_script(command: str) -> bool:
    return os.path.basename(sys.argv[0]) == f"sb-{command}"


def _ignore_interrupts(command: str) -> None:
    """In the console script, let a later SIGINT / SIGTERM do nothing: it is only exiting.

    Called from Python (embedded, tests), the host's handlers are left alone.  A no-op
    handler rather than ``SIG_IGN``: a signal already noted by the interpreter would
    otherwise be reported as "ignored due to race condition" on stderr.
    """
    if not _is_console_script(command) or threading.current_thread() is not threading.main_thread():
        return
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _do_nothing)


def _do_nothing(signum, frame) -> None:
    pass


def _exit_without_teardown(code) -> None:
    """Exit with ``code`` as :func:`sys.exit` would, but skip the interpreter's teardown.

    When a command returns, its outputs are complete (written to temporary files and
    renamed into place) and closed.  What the interpreter would still do is free every
    object, and after a decode that means numba's and LLVM's: measured ~0.5 s of a
    single-shot Teddy decode's ~1.9 s.  The exit handlers still run (logging's flush among
    them) and both standard streams are flushed before :func:`os._exit`.
    """
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:                       # sys.exit("message"): the message on stderr, status 1
        sys.stderr.write(f"{code}\n")
        status = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:        # None: started with the descriptor closed
                stream.flush()
        except (OSError, ValueError):     # a closed pipe: nothing more can be said on it
            pass
    os._exit(status)


def encode():
    """Entry point of ``sb-encode``."""
    return _run("encode")


def decode():
    """Entry point of ``sb-decode``."""
    return _run("decode")
