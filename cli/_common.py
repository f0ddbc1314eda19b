"""Plumbing shared by the ``sb-*`` commands: error reporting, signals, common options.

A command is written as::

    @click.command()
    @common.verbosity_options
    @common.version_option
    @common.handle_errors
    def my_command(...):
        ...

    main = common.make_main(my_command, "sb-xxx")

``handle_errors`` turns every :class:`~stereobudget.errors.StereoBudgetError` into one
line ``sb-xxx: error: <message>`` on stderr and the error's ``exit_code`` (never a
traceback); ``KeyboardInterrupt`` and SIGTERM exit 130 quietly (atomic writers remove
their temporary files on the way out); a closed stdout pipe exits quietly.
Unexpected exceptions are bugs and keep their traceback.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import signal
import sys

import click

from stereobudget import __version__
from stereobudget._kernels._stack import call_with_stack_room
from stereobudget.io import redeliver_swallowed_interrupts
from stereobudget.errors import EXIT_INTERRUPTED, MemoryLimitError, OutputError, StereoBudgetError

#: Exit status of a command whose standard output was closed early (128 + SIGPIPE, like
#: a process killed by the signal).
EXIT_BROKEN_PIPE = 141

def prog_name(default: str = "sb") -> str:
    """Name of the running command (``sb-encode``...), for messages."""
    ctx = click.get_current_context(silent=True)
    if ctx is not None:
        name = ctx.find_root().info_name
        if name:
            return name
    return default


def error_line(message: str) -> None:
    """Print ``<prog>: error: <message>`` as a single line on stderr."""
    one_line = " ".join(str(message).split())
    click.echo(f"{prog_name()}: error: {one_line}", err=True)


def _silence_stdout() -> None:
    # Point stdout at /dev/null so the interpreter's final flush cannot raise again.
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def flush_stdout() -> None:
    """Flush standard output; a full disk there (``> /dev/full``) is an :class:`OutputError`.

    A closed pipe still raises :class:`BrokenPipeError` (exit 141, quietly); a closed
    standard output (``>&-``, ``sys.stdout`` is None) has nothing to flush.
    """
    if sys.stdout is None:
        return
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        from stereobudget.io import stdout_error
        raise stdout_error(exc) from None


def guard_standard_descriptors() -> None:
    """Put ``/dev/null`` on standard descriptors the command was started without (``>&-``, ``<&-``).

    Python sets ``sys.stdout`` (or ``sys.stdin``, ``sys.stderr``) to None then, and that
    stays: writing ``-`` reports the closed stream.  But the next file opened would get the
    free descriptor, and whatever writes to descriptor 1 or 2 (a C library's message) would
    land in an output file; ``/dev/null`` keeps the number taken.
    """
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            try:
                null = os.open(os.devnull, os.O_RDWR)
            except OSError:
                return
            if null != fd:
                os.dup2(null, fd)
                os.close(null)


def handle_errors(func):
    """Decorator for a click callback: user errors become one stderr line + exit code."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            result = func(*args, **kwargs)
            # Flush here so a closed pipe or a full disk is reported by us, not at interpreter exit.
            flush_stdout()
            return result
        except StereoBudgetError as exc:
            if exc.path == "<stdout>":
                _silence_stdout()       # what it could not take must not be retried at exit
            error_line(str(exc))
            sys.exit(exc.exit_code)
        except MemoryError:
            error_line("out of memory")
            sys.exit(MemoryLimitError.exit_code)
        except KeyboardInterrupt:
            click.echo(f"{prog_name()}: interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)
        except BrokenPipeError:
            _silence_stdout()
            sys.exit(EXIT_BROKEN_PIPE)

    return wrapper


def _raise_keyboard_interrupt(signum, frame):
    raise KeyboardInterrupt


def make_main(command: click.Command, name: str):
    """Console-script entry point for ``command``: SIGTERM handling + fixed prog name."""

    def main(argv=None):
        guard_standard_descriptors()
        # SIGTERM takes the same clean path as Ctrl-C (temporary files removed, exit 130).
        try:
            signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
            redeliver_swallowed_interrupts(signal.SIGTERM)
        except ValueError:      # not in the main thread (embedded use): keep the default
            pass
        try:
            # Room on the frame stack: numba's compiler then compiles a first run at full speed.
            return call_with_stack_room(command.main, args=argv, prog_name=name, standalone_mode=False)
        except click.ClickException as exc:
            # Usage errors on one line like every other error (click's own display takes four).
            hint = f" (see {name} --help)" if isinstance(exc, click.UsageError) else ""
            click.echo(f"{name}: error: {' '.join(exc.format_message().split())}{hint}", err=True)
            sys.exit(exc.exit_code)
        except click.Abort:      # Ctrl-C / SIGTERM while the arguments are parsed
            click.echo(f"{name}: interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)

    main.__doc__ = f"Entry point of ``{name}``."
    return main


def _install_log_handler(verbose: int, quiet: int) -> logging.Handler:
    level = max(logging.DEBUG, min(logging.CRITICAL, logging.WARNING - 10 * verbose + 10 * quiet))
    logger = logging.getLogger("stereobudget")
    logger.setLevel(level)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"{prog_name()}: %(message)s"))
    logger.addHandler(handler)
    return handler


def verbosity_options(func):
    """Add ``-v/--verbose`` and ``-q/--quiet`` (both countable) and set up logging on stderr.

    Default level WARNING; each ``-v`` goes one level down (INFO, DEBUG), each ``-q`` one up.
    The wrapped callback does not receive these two parameters.
    """

    @functools.wraps(func)
    def wrapper(*args, verbose: int = 0, quiet: int = 0, **kwargs):
        handler = _install_log_handler(verbose, quiet)
        try:
            return func(*args, **kwargs)
        finally:
            # In-process callers (tests, notebooks) must not keep a handler on a stale stream.
            logging.getLogger("stereobudget").removeHandler(handler)

    wrapper = click.option("-q", "--quiet", count=True,
                           help="Less output on stderr (repeatable).")(wrapper)
    wrapper = click.option("-v", "--verbose", count=True,
                           help="More output on stderr: -v progress and sizes, -vv debug.")(wrapper)
    return wrapper


version_option = click.version_option(__version__, "--version",
                                      message="%(prog)s (stereobudget) %(version)s")
overwrite_option = click.option("--overwrite", is_flag=True,
                                help="Replace output files that already exist.")
json_option = click.option("--json", "as_json", is_flag=True,
                           help="Print a one-line JSON summary on stdout.")


def failure_fields(exc: StereoBudgetError) -> dict:
    """``error``, ``error_class`` and ``exit_code`` of a failed file, as a batch's ``--json`` gives them."""
    return {"error": str(exc), "error_class": type(exc).__name__, "exit_code": exc.exit_code}


def require_stdout(what: str) -> None:
    """Refuse ``what`` (e.g. ``--json``) at once when standard output is closed (``>&-``)."""
    if sys.stdout is None:
        raise OutputError(f"standard output is closed; {what} has nowhere to go", path="<stdout>")


def emit_json(obj) -> None:
    """Print ``obj`` as one line of JSON on stdout.

    Raises
    ------
    OutputError
        Standard output is closed or cannot take the line (a full disk).
    """
    require_stdout("--json")
    line = json.dumps(obj, sort_keys=False, separators=(", ", ": "))
    try:
        click.echo(line)
    except BrokenPipeError:
        raise
    except OSError as exc:
        from stereobudget.io import stdout_error
        raise stdout_error(exc) from None
