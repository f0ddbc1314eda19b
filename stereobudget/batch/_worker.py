"""State of a worker process: its numba threads, whether a job is running, SIGTERM, its parent.

The jobs say here when they start and end; the process pool's initializer sets it up.
Apart from both so that the jobs need not import the runners.

A worker dies with the batch that started it.  A parent killed outright (SIGKILL, the
OOM killer) cannot stop its pool, and orphaned workers would go on writing files for a
run that no longer exists.  Two mechanisms, because neither is enough alone:

* on Linux, ``prctl(PR_SET_PDEATHSIG, SIGTERM)``: the kernel signals the worker the moment
  its parent goes, at no cost;
* everywhere, a watchdog thread that checks every half second that the batch's process
  still runs.  ``prctl`` is Linux-only, it sees a parent that died before the call was
  made, and it watches the *parent*: under the forkserver start method (used once numba
  is loaded) that is the fork server, which outlives the batch for as long as any worker
  does.

Either way the worker takes the SIGTERM path: a running job unwinds (its temporary files
are removed) and the worker exits without starting another.

A worker asked to stop never goes back to the pool's queues.  Their locks are semaphores
shared by all the workers, and a sibling stopped at the same moment may have left while
holding one (SIGTERM found it idle, reading the next call or sending a result): a worker
that then sent its unwound job's result, or asked for the next call, would wait on that
lock for ever, and the batch with it, in its pool's shutdown.  So a job interrupted by
SIGTERM ends the worker as soon as it has unwound (:func:`_run_in_worker`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

from ..io._atomic import redeliver_swallowed_interrupts


_worker_threads: int | None = None


def _limit_numba_threads(threads: int | None) -> None:
    """Cap numba's threads in this process (several jobs on one machine share its cores)."""
    threads = threads or _worker_threads
    if not threads:
        return
    try:
        import numba
        numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    except Exception:        # a missing or old numba only costs speed
        pass


_job_running = False
_terminating = False
#: The worker is running its exit handlers.
_leaving = False
#: The worker's parent process and the batch's process (None outside a pool worker).
_parent_pid: int | None = None
_owner_pid: int | None = None
#: Seconds between two looks of the watchdog at the parent, and how long a running job
#: gets to unwind once the parent is gone.
WATCH_INTERVAL = 0.5
UNWIND_GRACE = 5.0


def _exit_worker(code: int) -> None:
    """Leave the worker now, after multiprocessing's exit finalizers.

    numba's thread launch lock is a named semaphore of this process; skipping the
    finalizers (plain :func:`os._exit`) would leave it to the resource tracker, which
    then prints a "leaked semaphore objects" warning on the user's terminal.
    """
    global _job_running, _leaving
    # A further SIGTERM (the pool stops every worker once one has gone) must not cut the
    # exit handlers short: a semaphore unlinked but not yet unregistered would make the
    # resource tracker warn of a leak.
    _leaving = True
    _job_running = False
    try:
        from multiprocessing import util
        util._exit_function()
    except Exception:  # noqa: BLE001 -- leaving matters more than tidying
        pass
    os._exit(code)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:       # exists, owned by someone else (cannot happen for our parent)
        return True
    return True


def _orphaned() -> bool:
    """Whether the batch this worker serves is gone."""
    if _parent_pid is None:
        return False
    return os.getppid() != _parent_pid or (_owner_pid is not None and not _alive(_owner_pid))


def _in_job(flag: bool) -> None:
    global _job_running
    if _terminating and (flag or _orphaned()):
        # SIGTERM already asked this worker to stop: do not start another file; and with
        # the parent gone, no one would read this file's result.
        _exit_worker(143)
    _job_running = flag


def _run_in_worker(fn, job):
    """``fn(job)`` in a pool worker; once SIGTERM has asked the worker to stop, leave after the job.

    The job has unwound by then (its temporary files removed).  Its result is not sent: no
    one is waiting for it, and the result queue's lock may be held by a sibling that is
    gone (see the module's docstring).
    """
    try:
        return fn(job)
    finally:
        if _terminating:
            _exit_worker(143)


def _worker_sigterm(signum, frame):
    # Inside a job: unwind so atomic writers delete their temporary files.  Idle: just go.
    global _terminating
    if _leaving:
        return
    _terminating = True
    if _job_running:
        raise KeyboardInterrupt
    _exit_worker(128 + signum)


def _set_parent_death_signal() -> None:
    """Linux: have the kernel send SIGTERM to this process when its parent dies."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):   # no libc prctl: the watchdog alone
        pass


def _watch_parent() -> None:
    """Watchdog thread: once the parent is gone, stop the job (SIGTERM path), then the worker."""
    while not _orphaned():
        time.sleep(WATCH_INTERVAL)
    if _job_running and not _terminating:
        os.kill(os.getpid(), signal.SIGTERM)
    deadline = time.monotonic() + UNWIND_GRACE
    while _job_running and time.monotonic() < deadline:
        time.sleep(0.05)
    # Idle, unwound, or stuck in a kernel (no output is being written then): go.
    _exit_worker(143)


def _worker_init(threads: int | None, owner_pid: int | None = None) -> None:
    """Process-pool initializer: Ctrl-C is the parent's business, SIGTERM cleans up.

    ``owner_pid``: the batch's process; the worker exits when it (or the worker's parent)
    goes.
    """
    global _worker_threads, _parent_pid, _owner_pid
    _worker_threads = threads
    _owner_pid = owner_pid
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_sigterm)
    redeliver_swallowed_interrupts(signal.SIGTERM)
    _parent_pid = os.getppid()
    _set_parent_death_signal()
    if _orphaned():    # the parent died before the death signal was set
        _exit_worker(143)
    threading.Thread(target=_watch_parent, name="stereobudget-parent-watch", daemon=True).start()
