"""State of a worker process: its numba threads, whether a job is running, SIGTERM.

The jobs say here when they start and end; the process pool's initializer sets it up.
Apart from both so that the jobs need not import the runners.
"""

from __future__ import annotations

import os
import signal

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


def _in_job(flag: bool) -> None:
    global _job_running
    if flag and _terminating:
        # SIGTERM already asked this worker to stop: do not start another file.
        os._exit(143)
    _job_running = flag


def _worker_sigterm(signum, frame):
    # Inside a job: unwind so atomic writers delete their temporary files.  Idle: just go.
    global _terminating
    _terminating = True
    if _job_running:
        raise KeyboardInterrupt
    os._exit(128 + signum)


def _worker_init(threads: int | None) -> None:
    """Process-pool initializer: Ctrl-C is the parent's business, SIGTERM cleans up."""
    global _worker_threads
    _worker_threads = threads
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_sigterm)
    redeliver_swallowed_interrupts(signal.SIGTERM)
