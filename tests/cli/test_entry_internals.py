"""White-box tests of stereobudget.cli._entry, the console scripts' interrupt-safe entry point: an
interrupt while the command is imported or just as it returns, and the exit it takes only as a script."""

from __future__ import annotations

import importlib
import signal
import sys
import types
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
entry = importlib.import_module("stereobudget.cli._entry")


@pytest.mark.parametrize("command", ["encode", "decode"])
def test_ctrl_c_while_the_command_imports_exits_130_without_traceback(command, monkeypatch, capsys):
    # The console scripts enter through stereobudget.cli._entry, which imports the command
    # (click, and for sb-decode numpy, OpenCV, numba: up to a second) inside a handler.

    def interrupted_import(name):
        raise KeyboardInterrupt

    monkeypatch.setattr(entry.importlib, "import_module", interrupted_import)
    with pytest.raises(SystemExit) as exit_info:
        getattr(entry, command)()
    assert exit_info.value.code == 130
    assert capsys.readouterr().err == f"sb-{command}: interrupted\n"


def test_ctrl_c_just_as_the_command_returns_exits_130_and_leaves_host_handlers(monkeypatch, capsys):
    # An interrupt that lands after the command's own handler has finished (between its
    # return and the exit) is reported like any other; called in-process, the entry point
    # does not replace the host's signal handlers on its way out.

    def returns_then_interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(entry.importlib, "import_module",
                        lambda name: types.SimpleNamespace(main=returns_then_interrupted))
    handlers = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM))
    with pytest.raises(SystemExit) as exit_info:
        entry.encode()
    assert exit_info.value.code == 130
    assert capsys.readouterr().err == "sb-encode: interrupted\n"
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers


def test_entry_point_called_in_process_exits_normally(monkeypatch):
    # Only the console script itself skips the interpreter's teardown (os._exit); called
    # from Python (here: under pytest) the entry point must raise SystemExit as usual.
    monkeypatch.setattr(entry.importlib, "import_module", lambda name: types.SimpleNamespace(main=lambda: 3))
    with pytest.raises(SystemExit) as exit_info:
        entry.decode()
    assert exit_info.value.code == 3


def test_console_scripts_enter_through_the_interrupt_safe_entry_point():
    text = (BIN / "sb-decode").read_text() + (BIN / "sb-encode").read_text()
    assert text.count("stereobudget.cli._entry") == 2
