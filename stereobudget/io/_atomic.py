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
import contextvars
import errno
import io
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


class _OutputFile(io.BufferedWriter):
    """The temporary file of an output: a write that fails (a full disk) is an :class:`OutputError`."""

    def __init__(self, fd: int, name: str):
        super().__init__(io.FileIO(fd, "wb", closefd=True))
        self.output_name = name

    def write(self, data):
        try:
            return super().write(data)
        except OSError as exc:
            raise _writing_error(exc, self.output_name) from None

    def flush(self):
        try:
            return super().flush()
        except OSError as exc:
            raise _writing_error(exc, self.output_name) from None


def _writing_error(exc: OSError, name: str) -> OutputError:
    if isinstance(exc, OutputError):
        return exc
    return OutputError(f"cannot write: {exc.strerror or exc}", path=name)


#: The outputs staged by :func:`written_together` in this context (None: write each at once).
_STAGED: contextvars.ContextVar = contextvars.ContextVar("stereobudget_staged_outputs", default=None)


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
        The temporary file, opened for binary writing; a write that fails (a full disk,
        a file-size limit) raises :class:`~stereobudget.errors.OutputError`.

    Raises
    ------
    OutputError
        The directory does not exist or is not writable, ``path`` exists, or the data
        cannot be written.  The temporary file is removed.

    Notes
    -----
    Inside :func:`written_together` the complete temporary file is kept and moved into
    place with the other outputs of the block when the block ends.
    """
    target = Path(path)
    name_problem = _name_problem(target)
    if name_problem:
        raise OutputError(name_problem, path=str(path))
    info = _stat(target, path)
    if info is not None and not overwrite:
        raise OutputError("output exists (pass --overwrite to replace it)", path=str(path))
    if info is not None and not stat.S_ISREG(info.st_mode):
        raise OutputError("output is a directory, device, FIFO or socket, not a regular file",
                          path=str(path))
    tmp = None
    try:
        with interrupts_deferred():
            # The file and its name come into being together: an interrupt lands before
            # both (nothing to remove) or after both (the except below removes the file),
            # never in between, inside mkstemp or before this try.
            fd, tmp_name = _make_temporary(target, path)
            tmp = Path(tmp_name)
        handle = _OutputFile(fd, str(path))
        with handle:
            try:
                # mkstemp creates 0600; give the result the permissions a plain open() would.
                os.fchmod(fd, 0o666 & ~_current_umask())
            except OSError as exc:
                raise _writing_error(exc, str(path)) from None
            yield handle
            handle.flush()
            if fsync:
                try:
                    os.fsync(handle.fileno())
                except OSError as exc:
                    raise _writing_error(exc, str(path)) from None
        staged = _STAGED.get()
        if staged is not None:
            staged.append((tmp, target, overwrite))
            return
        try:
            _move_into_place(tmp, target, overwrite=overwrite)
        except OSError as exc:
            raise _writing_error(exc, str(path)) from None
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise


@contextlib.contextmanager
def written_together() -> Iterator[None]:
    """Write the outputs of the block all or none: each complete, moved into place together at the end.

    Inside the block :func:`atomic_write` (and so :func:`write_output_bytes` and every
    ``write_*`` function of :mod:`stereobudget.io`) writes each file to its temporary file
    and keeps it; when the block ends normally every file is moved into place, and when it
    raises (a later output cannot be written, an interrupt) every temporary file is removed,
    so no output of the block appears.  Standard output (``-``) cannot be held back and is
    written at once.  A move that fails at the end (an output that appeared meanwhile,
    without ``overwrite``) removes the outputs of the block already moved that did not exist
    before.
    """
    staged: list = []
    token = _STAGED.set(staged)
    try:
        yield
    except BaseException:
        _STAGED.reset(token)
        for tmp, _, _ in staged:
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise
    _STAGED.reset(token)
    moved: list = []
    try:
        with interrupts_deferred():
            for tmp, target, overwrite in staged:
                existed = overwrite and target.exists()
                try:
                    _move_into_place(tmp, target, overwrite=overwrite)
                except OSError as exc:
                    raise _writing_error(exc, str(target)) from None
                if not existed:
                    moved.append(target)
    except BaseException:
        for tmp, _, _ in staged:
            with contextlib.suppress(OSError):
                tmp.unlink()
        for target in moved:
            with contextlib.suppress(OSError):
                target.unlink()
        raise


def _stat(target: Path, path) -> os.stat_result | None:
    """``os.stat`` of an output, None when there is none yet; OutputError when the path is unusable."""
    try:
        return os.stat(target)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise _path_error(exc, target, path) from None


#: Longest file name (one path component) in bytes where the filesystem cannot be asked.
NAME_MAX = 255


def _name_problem(target: Path) -> str | None:
    """Why ``target``'s file name cannot exist (too long for its filesystem), or None."""
    size = len(os.fsencode(target.name))
    if size <= NAME_MAX:
        return None
    limit = NAME_MAX
    with contextlib.suppress(OSError, ValueError):
        limit = os.pathconf(target.parent if str(target.parent) else ".", "PC_NAME_MAX")
    if size <= limit:
        return None
    return f"file name too long ({size} bytes; the filesystem allows at most {limit} per name)"


def _path_error(exc: OSError, target: Path, path) -> OutputError:
    """The one-line :class:`OutputError` for an output path the system refused."""
    if exc.errno == errno.ENAMETOOLONG:
        longest = max(target.parts, key=lambda part: len(os.fsencode(part)), default="")
        if len(os.fsencode(longest)) > NAME_MAX:
            return OutputError(f"the folder name {longest[:20]!r}... is too long ({len(os.fsencode(longest))} "
                               f"bytes; the filesystem allows at most {NAME_MAX} per name)", path=str(path))
        return OutputError(f"path too long ({len(os.fsencode(str(target)))} bytes): "
                           f"{exc.strerror}", path=str(path))
    if exc.errno == errno.ELOOP:
        return OutputError("too many levels of symbolic links in the path", path=str(path))
    return OutputError(f"cannot use this path: {exc.strerror or exc}", path=str(path))


def _make_temporary(target: Path, path) -> tuple:
    directory = target.parent
    # The temporary name must fit where the final name fits: shorten what it repeats.
    stem = target.name
    while len(os.fsencode(f".{stem}..XXXXXXXX.tmp")) > NAME_MAX and stem:
        stem = stem[:-1]
    try:
        return tempfile.mkstemp(prefix=f".{stem}.", suffix=".tmp", dir=directory)
    except OSError as exc:
        raise _directory_error(exc, directory, path) from None


def _directory_error(exc: OSError, directory: Path, path) -> OutputError:
    """Why no file can be created in ``directory``, as one line naming ``path``."""
    name = str(directory)
    if exc.errno in (errno.ENOENT, errno.ENOTDIR):
        # Which part of the path is wrong: a missing folder, or a file where a folder should be.
        for parent in [directory, *directory.parents]:
            try:
                info = os.stat(parent)
            except OSError:
                continue
            if not stat.S_ISDIR(info.st_mode):
                return OutputError(f"{str(parent)!r} is a file, not a directory", path=str(path))
            if parent == directory:
                # The folder is there but refuses new files (/proc, /sys).
                return OutputError(f"cannot create a file in {name!r}: this filesystem does not allow it",
                                   path=str(path))
            break
        return OutputError(f"directory {name!r} does not exist", path=str(path))
    if exc.errno == errno.ENAMETOOLONG:
        return _path_error(exc, directory, path)
    return OutputError(f"cannot create a file in {name!r}: {exc.strerror or exc}", path=str(path))


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
        ``path`` exists without ``overwrite``, cannot be created or written (a full disk),
        or is ``-`` while standard output is closed, a terminal (binary data would garble
        it) or cannot take the data (``> /dev/full``).
    BrokenPipeError
        Standard output is a pipe whose reader has gone (the CLI exits 141 quietly).
    """
    if _is_stdio(path):
        stdout = standard_stream("stdout")
        if stdout.isatty():
            raise OutputError("refusing to write binary data to a terminal; redirect it or use -o FILE",
                              path="<stdout>")
        try:
            # A pipe whose reader has gone can accept part of a large write and report the
            # short count instead of raising; keep writing so the next write raises EPIPE.
            view = memoryview(data).cast("B")
            while view:
                written = stdout.write(view)
                view = view[written if written is not None else len(view):]
            stdout.flush()
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise stdout_error(exc) from None
        return
    with atomic_write(path, overwrite=overwrite, fsync=fsync) as handle:
        handle.write(data)


def stdout_error(exc: OSError) -> OutputError:
    """The one-line :class:`OutputError` for standard output that cannot take more data."""
    return OutputError(f"cannot write to standard output: {exc.strerror or exc}", path="<stdout>")


def standard_stream(which: str) -> BinaryIO:
    """The binary buffer of ``sys.stdin`` or ``sys.stdout`` (``which``), or a one-line error if it is closed.

    A command started with a closed descriptor (``>&-``, ``<&-``) has ``sys.stdout`` /
    ``sys.stdin`` set to None by Python.

    Raises
    ------
    OutputError
        Standard output is closed (``which="stdout"``).
    NotASampleFileError
        Standard input is closed (``which="stdin"``; callers reading an image re-raise it
        as their own error class through :func:`stdin_or`).
    """
    stream = getattr(sys, which)
    buffer = getattr(stream, "buffer", None)
    if buffer is None or getattr(stream, "closed", False):
        if which == "stdout":
            raise OutputError("standard output is closed; give a file name instead of '-' or run the "
                              "command with its output redirected", path="<stdout>")
        from ..errors import NotASampleFileError
        raise NotASampleFileError("standard input is closed; give a file name instead of '-' or redirect "
                                  "a file into the command", path="<stdin>")
    return buffer


def stdin_or(error: type[StereoBudgetError]) -> BinaryIO:
    """Standard input's binary buffer; when it is closed, ``error`` (one line, naming ``<stdin>``)."""
    try:
        return standard_stream("stdin")
    except StereoBudgetError as exc:
        raise error(exc.message, path=exc.path) from None


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
        stdin = stdin_or(error)
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
        try:
            return a.resolve() == b.resolve()
        except (OSError, RuntimeError):     # a symlink loop: not the input, and refused later
            return False


def check_output_path(output, inputs: Iterable, overwrite: bool) -> None:
    """Refuse an output that would destroy an input, silently replace a file, or cannot be written.

    Call before reading any input, so a bad output path fails fast: the name is checked
    against the filesystem's limit and a file is created (and removed at once) in its
    folder, so a missing, read-only or virtual folder is found before any work.

    Parameters
    ----------
    output : str or os.PathLike
        Output path, or ``-`` for standard output (refused only when it is closed).
    inputs : iterable of str or os.PathLike
        Input paths of the same job (``-`` entries are ignored).
    overwrite : bool
        Whether an existing output may be replaced.

    Raises
    ------
    OutputError
        ``output`` is one of ``inputs`` (even via another name), is a directory, its
        directory does not exist (or is a file), no file can be created there, its name is
        too long, or it exists and ``overwrite`` is false.
    """
    if _is_stdio(output):
        if standard_stream("stdout").isatty():
            raise OutputError("refusing to write binary data to a terminal; redirect it or use -o FILE",
                              path="<stdout>")
        return
    out = Path(output)
    problem = _name_problem(out)
    if problem:
        raise OutputError(problem, path=str(output))
    for item in inputs:
        if _is_stdio(item):
            continue
        if _same_file(out, Path(item)):
            raise OutputError(f"output is the same file as the input {str(item)!r}; "
                              "choose another output name", path=str(output))
    try:
        info = os.stat(out)
    except (FileNotFoundError, NotADirectoryError):
        info = None
    except OSError as exc:
        raise _path_error(exc, out, output) from None
    if info is not None and stat.S_ISDIR(info.st_mode):
        raise OutputError("output is a directory; give a file name", path=str(output))
    if info is not None and not stat.S_ISREG(info.st_mode):
        # An atomic write would replace the device or FIFO itself by a regular file.
        raise OutputError("output is a device, FIFO or socket, not a regular file; write to '-' and "
                          "redirect standard output there instead", path=str(output))
    if info is not None and not overwrite:
        raise OutputError("output exists (pass --overwrite to replace it)", path=str(output))
    _probe_directory(out, output)


def _probe_directory(target: Path, path) -> None:
    """Create and remove a temporary file beside ``target``: the folder takes new files."""
    with interrupts_deferred():
        fd, name = _make_temporary(target, path)
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(name)
