"""White-box tests of the stop of an interrupted local pool (``_stop_workers``).

The behaviour through the commands (a batch whose standard output fails ends with its one line
and leaves no worker) is held by tests/cli/test_batch_stdout_errors_cli.py.
"""

from __future__ import annotations

import multiprocessing
import signal
import sys
import time

import pytest

from stereobudget.batch._runners import _stop_workers

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork start method as on Linux")


def _sleep(ignore_sigterm: bool, ready) -> None:
    if ignore_sigterm:      # stands for a worker blocked where SIGTERM cannot end it
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    ready.set()
    time.sleep(600)


def _start(ignore_sigterm: bool):
    context = multiprocessing.get_context("fork")
    ready = context.Event()
    process = context.Process(target=_sleep, args=(ignore_sigterm, ready), daemon=True)
    process.start()
    assert ready.wait(60)
    return process


def test_workers_that_leave_on_sigterm_are_not_killed():
    processes = [_start(False), _start(False)]
    _stop_workers(processes, grace=60)
    for process in processes:
        process.join(60)
        assert process.exitcode == -signal.SIGTERM


def test_a_worker_that_does_not_leave_is_killed_after_the_grace():
    stubborn, polite = _start(True), _start(False)
    _stop_workers([stubborn, polite], grace=0.5)
    stubborn.join(60)
    polite.join(60)
    assert stubborn.exitcode == -signal.SIGKILL
    assert polite.exitcode == -signal.SIGTERM


def test_workers_already_gone_are_fine():
    process = _start(False)
    process.terminate()
    process.join(60)
    closed = _start(False)
    closed.terminate()
    closed.join(60)
    closed.close()      # its sentinel is gone
    _stop_workers([process, closed], grace=0.5)
