"""Atomic output files, ``-`` for stdin/stdout, and the output-path sanity checks.

Every output of stereobudget is either complete or absent: data goes to a temporary
file in the target directory (same filesystem, so the final rename is atomic) and is
moved into place with :func:`os.replace` only once fully written.  Any exception,
including ``KeyboardInterrupt`` (and SIGTERM, which the CLI turns into one), removes
the temporary file.

An interrupt that lands inside a callback that cannot propagate exceptions (numba's
object-cache writer is a ctypes callback; ``__del__`` methods are another) would be
swallowed and printed as "Exception ignored"; :func:`redeliver_swallowed_interrupts`
makes such an interrupt arrive again a moment later, where it can unwind normally.
"""

from __future__ import annotations

import contextlib
import os
import signal
import stat
import sys
import tempfile
import threading
from pathlib import Path
from typing import BinaryIO, Iterable, Iterator

from ..errors import OutputError, StereoBudgetError

STDIO = "-"


def redeliver_swallowed_interrupts(signum: int) -> None:
    """Re-send an interrupt that Python had to swallow, instead of printing it.

    Installs a :data:`sys.unraisablehook`: a ``KeyboardInterrupt`` raised where it cannot
    propagate (a ctypes callback, a finaliser) is not printed; ``signum``'s Python handler
    is run again in the main thread 20 ms later, by then normally outside the callback: as a
    real signal to the main thread where the platform has one (so that a main thread
    blocked in a system call wakes up), else as a simulated one.
    Other unraisable exceptions go to the previous hook.  For processes whose handler for
    ``signum`` raises ``KeyboardInterrupt`` (the ``sb-*`` commands, batch workers).
    """
    import _thread
    import signal

    previous = sys.unraisablehook

    def resend():
        if hasattr(signal, "pthread_kill"):
            # _thread.interrupt_main only flags the handler: a main thread waiting in
            # sleep() or on a queue would run it when the wait ends, seconds later.
            signal.pthread_kill(threading.main_thread().ident, signum)
        else:
            _thread.interrupt_main(signum)

    def hook(unraisable):
        if unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt):
            timer = threading.Timer(0.02, resend)
            timer.daemon = True
            for _ in range(8):
                try:
                    timer.start()
                    break
                except KeyboardInterrupt:
                    # A second signal while the timer thread starts: swallowed here too
                    # (an exception leaving the hook would be printed with a traceback);
                    # the one redelivery stands for both once the thread is running.
                    if timer.ident is not None:
                        break
            return
        previous(unraisable)

    sys.unraisablehook = hook


def _is_stdio(path) -> bool:
    return str(path) == STDIO


def _current_umask() -> int:
    # os.umask can only be read by setting it; restore immediately.
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(path, *, overwrite: bool = False, fsync: bool = True) -> Iterator[BinaryIO]:
    """Open ``path`` for binary writing so that it appears only when complete.

    Parameters
    ----------
    path : str or os.PathLike
        Final file name (not ``-``; use :func:`write_output_bytes` for stdout).
    overwrite : bool
        Replace an existing file.  Without it an existing ``path`` raises
        :class:`~stereobudget.errors.OutputError`, also when it appears while we write.
    fsync : bool
        Flush the data to disk before the rename, so a crash cannot leave an empty file.

    Yields
    ------
    file object
        The temporary file, opened ``"wb"``.

    Raises
    ------
    OutputError
        The directory does not exist or is not writable, or ``path`` exists.
    """
    target = Path(path)
    if not overwrite and target.exists():
        raise OutputError("output exists (pass --overwrite to replace it)", path=str(path))
    tmp = None
    try:
        with interrupts_deferred():
            # The file and its name come into being together: an interrupt lands before
            # both (nothing to remove) or after both (the except below removes the file),
            # never in between, inside mkstemp or before this try.
            fd, tmp_name = _make_temporary(target, path)
            tmp = Path(tmp_name)
        # mkstemp creates 0600; give the result the permissions a plain open() would.
        os.fchmod(fd, 0o666 & ~_current_umask())
        with os.fdopen(fd, "wb") as handle:
            yield handle
            handle.flush()
            if fsync:
                os.fsync(handle.fileno())
        _move_into_place(tmp, target, overwrite=overwrite)
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        raise


def _make_temporary(target: Path, path) -> tuple:
    directory = target.parent
    try:
        return tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=directory)
    except FileNotFoundError:
        raise OutputError(f"directory {str(directory)!r} does not exist", path=str(path)) from None
    except OSError as exc:
        raise OutputError(f"cannot create a file in {str(directory)!r}: {exc.strerror}",
                          path=str(path)) from None


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back meanwhile; they take effect as soon as it ends.

    For the few statements that must not be split by a ``KeyboardInterrupt`` (creating
    a file and recording its name).  The signals' handlers are swapped for one that
    notes them; afterwards the old handlers are restored and a noted signal is raised
    again, so it does whatever it would have done (raise ``KeyboardInterrupt``, end the
    process, nothing).  Masking the signals would not do: a signal sent to the process
    goes to another thread that does not mask it, and Python still runs its handler in
    the main thread.  Only the main thread runs handlers, so elsewhere this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list = []
    previous = {}
    try:
        for signum in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(signum) is not None:    # None: a handler set outside Python
                previous[signum] = signal.signal(signum, lambda number, frame: noted.append(number))
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in dict.fromkeys(noted):
            signal.raise_signal(signum)


def _move_into_place(tmp: Path, target: Path, *, overwrite: bool) -> None:
    if overwrite:
        os.replace(tmp, target)
        return
    # A hard link fails if the target exists, so "no clobber" holds even against a
    # file that appeared while we were writing.
    try:
        os.link(tmp, target)
    except FileExistsError:
        raise OutputError("output exists (pass --overwrite to replace it)", path=str(target)) from None
    except OSError:
        # Filesystem without hard links (FAT, some network mounts): check, then rename.
        if target.exists():
            raise OutputError("output exists (pass --overwrite to replace it)",
                              path=str(target)) from None
        os.replace(tmp, target)
        return
    tmp.unlink()


def write_output_bytes(path, data: bytes, *, overwrite: bool = False, fsync: bool = True) -> None:
    """Write ``data`` to ``path`` atomically, or to standard output when ``path`` is ``-``.

    Raises
    ------
    OutputError
        ``path`` exists without ``overwrite``, cannot be created, or is ``-`` while
        standard output is a terminal (binary data would garble it).
    """
    if _is_stdio(path):
        stdout = sys.stdout.buffer
        if stdout.isatty():
            raise OutputError("refusing to write binary data to a terminal; redirect it or use -o FILE",
                              path="<stdout>")
        # A pipe whose reader has gone can accept part of a large write and report the
        # short count instead of raising; keep writing so the next write raises EPIPE.
        view = memoryview(data).cast("B")
        while view:
            written = stdout.write(view)
            view = view[written if written is not None else len(view):]
        stdout.flush()
        return
    try:
        with atomic_write(path, overwrite=overwrite, fsync=fsync) as handle:
            handle.write(data)
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror or exc}", path=str(path)) from None


def read_input_bytes(path, *, error: type[StereoBudgetError], max_bytes: int | None = None) -> bytes:
    """All bytes of the file ``path``, or of standard input when ``path`` is ``-``.

    Parameters
    ----------
    path : str or os.PathLike
        Input file or ``-``.
    error : type
        The :class:`~stereobudget.errors.StereoBudgetError` subclass raised when the file
        cannot be read (missing, a directory, no permission, too large).
    max_bytes : int, optional
        Refuse larger inputs (default :data:`stereobudget.io.MAX_INPUT_BYTES`, more
        than any image or sample file within the size limits).  A regular file is
        checked before it is read; a pipe or device (``/dev/zero``) is read in chunks
        and refused as soon as it exceeds the limit, so no input can exhaust memory.
    """
    from ._limits import MAX_INPUT_BYTES, format_size
    limit = MAX_INPUT_BYTES if max_bytes is None else int(max_bytes)
    name = display_name(path)

    def too_large(size_text=None):
        what = f"input is {size_text}" if size_text else "input goes on past that limit"
        return error(f"{what}; stereobudget reads at most {format_size(limit)} "
                     "(more than any image or sample file within the size limits)", path=name)

    if _is_stdio(path):
        stdin = sys.stdin.buffer
        if stdin.isatty():
            raise error("refusing to read binary data from a terminal; pipe or redirect a file", path=name)
        return _read_capped(stdin, limit, too_large)
    try:
        with open(path, "rb") as handle:
            info = os.fstat(handle.fileno())
            if stat.S_ISREG(info.st_mode):
                if info.st_size > limit:
                    raise too_large(format_size(info.st_size))
                return handle.read()
            return _read_capped(handle, limit, too_large)
    except OSError as exc:
        raise reading_error(exc, error, str(path)) from None


def reading_error(exc: OSError, error: type[StereoBudgetError], name: str) -> StereoBudgetError:
    """The one-line ``error`` for an input that could not be opened or read."""
    if isinstance(exc, FileNotFoundError):
        return error("no such file", path=name)
    if isinstance(exc, IsADirectoryError):
        return error("is a directory, not a file", path=name)
    return error(f"cannot read: {exc.strerror or exc}", path=name)


def _read_capped(stream, limit: int, too_large) -> bytes:
    chunks, total = [], 0
    while True:
        chunk = stream.read(min(1 << 20, limit + 1 - total))
        if not chunk:
            return b"".join(chunks)
        chunks.append(chunk)
        total += len(chunk)
        if total > limit:
            raise too_large()


def display_name(path) -> str:
    """The name used for ``path`` in messages (``<stdin>`` for ``-``)."""
    return "<stdin>" if _is_stdio(path) else str(path)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def check_output_path(output, inputs: Iterable, overwrite: bool) -> None:
    """Refuse an output that would destroy an input or silently replace a file.

    Call before reading any input, so a bad output path fails fast.

    Parameters
    ----------
    output : str or os.PathLike
        Output path, or ``-`` for standard output (always accepted).
    inputs : iterable of str or os.PathLike
        Input paths of the same job (``-`` entries are ignored).
    overwrite : bool
        Whether an existing output may be replaced.

    Raises
    ------
    OutputError
        ``output`` is one of ``inputs`` (even via another name), is a directory, its
        directory does not exist, or it exists and ``overwrite`` is false.
    """
    if _is_stdio(output):
        return
    out = Path(output)
    for item in inputs:
        if _is_stdio(item):
            continue
        if _same_file(out, Path(item)):
            raise OutputError(f"output is the same file as the input {str(item)!r}; "
                              "choose another output name", path=str(output))
    if out.is_dir():
        raise OutputError("output is a directory; give a file name", path=str(output))
    if not out.parent.is_dir():
        raise OutputError(f"directory {str(out.parent)!r} does not exist", path=str(output))
    if out.exists() and not overwrite:
        raise OutputError("output exists (pass --overwrite to replace it)", path=str(output))
