"""Atomic outputs, stdout/stdin as '-', and output-path checks."""

from __future__ import annotations

import io
import os
import signal
import sys
import tempfile

import pytest

from stereobudget.io import (atomic_write, check_output_path, interrupts_deferred, read_input_bytes,
                             write_output_bytes)
from stereobudget.errors import ImageReadError, OutputError


def test_atomic_write_publishes_only_complete_files(tmp_path):
    path = tmp_path / "out.bin"
    with atomic_write(path) as handle:
        handle.write(b"part one ")
        assert not path.exists()             # nothing visible while writing
        handle.write(b"part two")
    assert path.read_bytes() == b"part one part two"
    assert os.listdir(tmp_path) == ["out.bin"]


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_temporary_file_is_removed_on_any_exception(tmp_path, exc):
    path = tmp_path / "out.bin"
    path.write_bytes(b"old")
    with pytest.raises(type(exc)):
        with atomic_write(path, overwrite=True) as handle:
            handle.write(b"new, half written")
            raise exc
    assert path.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["out.bin"]


def test_no_clobber_without_overwrite(tmp_path):
    path = tmp_path / "out.bin"
    path.write_bytes(b"keep me")
    with pytest.raises(OutputError, match="exists"):
        write_output_bytes(path, b"new")
    # a file that appears while we write is not replaced either
    with pytest.raises(OutputError, match="exists"):
        with atomic_write(tmp_path / "late.bin") as handle:
            handle.write(b"mine")
            (tmp_path / "late.bin").write_bytes(b"theirs")
    assert (tmp_path / "late.bin").read_bytes() == b"theirs"
    assert path.read_bytes() == b"keep me"
    assert sorted(os.listdir(tmp_path)) == ["late.bin", "out.bin"]
    write_output_bytes(path, b"new", overwrite=True)
    assert path.read_bytes() == b"new"


def test_permissions_follow_the_umask(tmp_path):
    old = os.umask(0o027)
    try:
        write_output_bytes(tmp_path / "f", b"x")
    finally:
        os.umask(old)
    assert (tmp_path / "f").stat().st_mode & 0o777 == 0o640


def test_missing_directory_is_an_output_error(tmp_path):
    with pytest.raises(OutputError, match="does not exist"):
        write_output_bytes(tmp_path / "no" / "f.bin", b"x")


def test_dash_writes_to_stdout(capsysbinary):
    write_output_bytes("-", b"\x00binary\x89")
    assert capsysbinary.readouterr().out == b"\x00binary\x89"


def test_dash_reads_stdin(monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"\x89raw bytes")))
    assert read_input_bytes("-", error=ImageReadError) == b"\x89raw bytes"


def test_check_output_path(tmp_path):
    src = tmp_path / "in.png"
    src.write_bytes(b"x")
    link = tmp_path / "link.png"
    os.link(src, link)
    for out in (src, link, tmp_path / "." / "in.png"):
        with pytest.raises(OutputError, match="same file as the input"):
            check_output_path(out, [src], overwrite=True)
    with pytest.raises(OutputError, match="is a directory"):
        check_output_path(tmp_path, [src], overwrite=True)
    with pytest.raises(OutputError, match="does not exist"):
        check_output_path(tmp_path / "nodir" / "o.sbs", [src], overwrite=False)
    (tmp_path / "o.sbs").write_bytes(b"")
    with pytest.raises(OutputError, match="--overwrite"):
        check_output_path(tmp_path / "o.sbs", [src], overwrite=False)
    check_output_path(tmp_path / "o.sbs", [src, "-"], overwrite=True)
    check_output_path("-", [src], overwrite=False)


def test_swallowed_interrupt_is_redelivered_not_printed(tmp_path):
    # A KeyboardInterrupt raised inside a finaliser (as inside numba's ctypes cache
    # callback) cannot propagate; it must come back a moment later, without a traceback.
    import subprocess
    script = tmp_path / "swallow.py"
    script.write_text(
        "import signal, time\n"
        "from stereobudget.io import redeliver_swallowed_interrupts\n"
        "def handler(signum, frame):\n"
        "    raise KeyboardInterrupt\n"
        "signal.signal(signal.SIGTERM, handler)\n"
        "redeliver_swallowed_interrupts(signal.SIGTERM)\n"
        "raised_at = []\n"
        "class Finaliser:\n"
        "    def __del__(self):\n"
        "        raised_at.append(time.monotonic())\n"
        "        raise KeyboardInterrupt\n"
        "Finaliser()\n"
        "try:\n"
        # Blocked in a system call, as an idle worker waiting for its next job: the
        # redelivered signal must wake it, not wait for the sleep to end.
        "    time.sleep(10)\n"
        "    print('not interrupted')\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted', time.monotonic() - raised_at[0])\n")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60,
                          cwd=tempfile.gettempdir())
    outcome, _, elapsed = proc.stdout.strip().partition(" ")
    assert outcome == "interrupted", proc.stdout
    # 20 ms by design; 0.5 s leaves room for a loaded machine, not for a lost interrupt.
    assert float(elapsed) < 0.5, f"redelivered {float(elapsed):.3f} s after the swallowed interrupt"
    assert "Exception ignored" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


@pytest.fixture
def sigint_raises_keyboard_interrupt():
    """Python's own SIGINT handler for the test, whatever the suite was started with: a
    shell starts background jobs (``cmd &``) with SIGINT ignored, and Python then keeps
    ignoring it, so a raised SIGINT would do nothing."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


@pytest.mark.usefixtures("sigint_raises_keyboard_interrupt")
def test_an_interrupt_as_the_temporary_file_is_created_leaves_no_file(tmp_path, monkeypatch):
    # A Ctrl-C that arrives while mkstemp runs (or just as it returns) must not leave the
    # new file behind under a name nobody recorded.
    real_mkstemp = tempfile.mkstemp

    def mkstemp_then_signal(*args, **kwargs):
        created = real_mkstemp(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)
        return created

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp_then_signal)  # the one atomic_write calls
    with pytest.raises(KeyboardInterrupt):
        with atomic_write(tmp_path / "out.bin") as handle:
            handle.write(b"never")
    assert os.listdir(tmp_path) == []


@pytest.mark.usefixtures("sigint_raises_keyboard_interrupt")
def test_interrupts_deferred_delivers_sigint_and_sigterm_after_the_block():
    def sigterm_as_interrupt(signum, frame):       # what the sb-* commands install
        raise KeyboardInterrupt

    before_int = signal.getsignal(signal.SIGINT)
    before_term = signal.signal(signal.SIGTERM, sigterm_as_interrupt)
    try:
        for signum in (signal.SIGINT, signal.SIGTERM):
            reached_the_end = False
            with pytest.raises(KeyboardInterrupt):
                with interrupts_deferred():
                    signal.raise_signal(signum)
                    reached_the_end = True
            assert reached_the_end
            assert signal.getsignal(signal.SIGINT) is before_int
            assert signal.getsignal(signal.SIGTERM) is sigterm_as_interrupt
        with interrupts_deferred():                 # nothing noted: nothing raised
            pass
    finally:
        signal.signal(signal.SIGTERM, before_term)


def test_written_together_publishes_all_or_none(tmp_path):
    from stereobudget.io import written_together

    a, b = tmp_path / "a.bin", tmp_path / "b.bin"
    with pytest.raises(OutputError, match="output exists"):
        with written_together():
            write_output_bytes(a, b"first")
            assert not a.exists()                  # held back until the block ends
            write_output_bytes(tmp_path / "taken.bin", b"x")   # published? no: staged too
            (tmp_path / "c.bin").write_bytes(b"someone else's")
            write_output_bytes(tmp_path / "c.bin", b"second")  # refused: c exists
    assert sorted(os.listdir(tmp_path)) == ["c.bin"]
    assert (tmp_path / "c.bin").read_bytes() == b"someone else's"
    with written_together():
        write_output_bytes(a, b"first")
        write_output_bytes(b, b"second")
    assert a.read_bytes() == b"first" and b.read_bytes() == b"second"
    assert sorted(os.listdir(tmp_path)) == ["a.bin", "b.bin", "c.bin"]


def test_a_move_that_fails_at_the_end_takes_back_the_new_outputs(tmp_path):
    from stereobudget.io import written_together

    a, b = tmp_path / "a.bin", tmp_path / "b.bin"
    with pytest.raises(OutputError, match="output exists"):
        with written_together():
            write_output_bytes(a, b"first")
            write_output_bytes(b, b"second")
            b.write_bytes(b"appeared meanwhile")      # after the check, before the move
    assert sorted(os.listdir(tmp_path)) == ["b.bin"] and b.read_bytes() == b"appeared meanwhile"


def test_a_write_that_fails_is_an_output_error_and_leaves_nothing(tmp_path, monkeypatch):
    import errno

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError, match="out.bin: cannot write: No space left on device"):
        with atomic_write(tmp_path / "out.bin") as handle:
            handle.write(b"data")
    assert os.listdir(tmp_path) == []


def test_output_paths_the_system_refuses(tmp_path):
    (tmp_path / "f").write_bytes(b"")
    with pytest.raises(OutputError, match="'.*f' is a file, not a directory"):
        check_output_path(tmp_path / "f" / "g" / "d.pfm", [], False)
    with pytest.raises(OutputError, match=r"file name too long \(304 bytes"):
        check_output_path(tmp_path / ("x" * 300 + ".pfm"), [], False)
    with pytest.raises(OutputError, match="file name too long"):
        write_output_bytes(tmp_path / ("x" * 300 + ".pfm"), b"")
    long_ok = tmp_path / ("y" * 250 + ".pfm")                 # 254 bytes: its temporary name is shortened
    check_output_path(long_ok, [], False)
    write_output_bytes(long_ok, b"fits")
    assert long_ok.read_bytes() == b"fits"
    assert sorted(os.listdir(tmp_path)) == sorted(["f", long_ok.name])
    if os.path.isdir("/proc"):
        with pytest.raises(OutputError, match="this filesystem does not allow it"):
            check_output_path("/proc/d.pfm", [], False)
    if os.path.exists("/dev/null"):          # --overwrite must not replace a device by a file
        with pytest.raises(OutputError, match="not a regular file"):
            check_output_path("/dev/null", [], True)


def test_closed_standard_streams_are_named(monkeypatch):
    from stereobudget.errors import NotASampleFileError
    from stereobudget.io import standard_stream

    monkeypatch.setattr(sys, "stdout", None)
    monkeypatch.setattr(sys, "stdin", None)
    with pytest.raises(OutputError, match="<stdout>: standard output is closed"):
        write_output_bytes("-", b"x")
    with pytest.raises(OutputError, match="<stdout>: standard output is closed"):
        check_output_path("-", [], False)
    with pytest.raises(ImageReadError, match="<stdin>: standard input is closed"):
        read_input_bytes("-", error=ImageReadError)
    with pytest.raises(NotASampleFileError, match="standard input is closed"):
        standard_stream("stdin")


@pytest.mark.parametrize("fraction", [float("nan"), float("inf"), 0.0, -0.1, 1.5, "0.1"])
def test_budget_fractions_outside_0_1_are_option_errors(fraction):
    from stereobudget.errors import OptionError
    from stereobudget.encoding import check_budget

    with pytest.raises(OptionError, match="--epsilon"):
        check_budget(size_fraction=fraction)
