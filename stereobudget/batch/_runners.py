"""Runners of a batch: jobs in this process, in a local process pool, or on dask.distributed.

:func:`run_jobs` runs jobs in-process (1 job), in a local process pool, or on a
dask.distributed cluster, and yields the result dicts as they complete.

This module imports neither numba nor OpenCV: the camera-side ``sb-encode`` uses it.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from typing import Callable, Iterable, Iterator

from ..io._atomic import STDIO
from ..errors import OptionError
from ..pipeline._jobs import DecodeJob, EncodeJob
from ._worker import _run_in_worker, _worker_init

log = logging.getLogger("stereobudget")


def default_jobs() -> int:
    """Number of usable cores (the default of ``-j``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _crashed(job, exc: BaseException) -> dict:
    label = getattr(job, "label", str(job))
    return {"status": "failed", "input": label, "error": f"{label}: worker failed: {type(exc).__name__}: {exc}",
            "error_class": type(exc).__name__, "exit_code": 1}


def _run_local_pool(jobs: list, fn: Callable, workers: int, threads: int | None) -> Iterator[dict]:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # Forking a process whose numba thread pool is running can deadlock the child; a
    # fresh interpreter is safe.  The CLI never decodes in the parent, so it forks.
    context = multiprocessing.get_context("forkserver" if "numba" in sys.modules else None)
    executor = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                   initializer=_worker_init, initargs=(threads, os.getpid()))
    pending = {}
    clean_exit = False
    try:
        queue = iter(jobs)
        # Submit a bounded window so an interrupt does not leave thousands of futures.
        for job in queue:
            pending[executor.submit(_run_in_worker, fn, job)] = job
            if len(pending) >= 2 * workers:
                break
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                job = pending.pop(future)
                try:
                    yield future.result()
                except Exception as exc:  # noqa: BLE001 -- a dead worker fails its file only
                    yield _crashed(job, exc)
                nxt = next(queue, None)
                if nxt is not None:
                    pending[executor.submit(_run_in_worker, fn, nxt)] = nxt
        clean_exit = True
    finally:
        if clean_exit:
            executor.shutdown(wait=True)
        else:
            # Interrupted (Ctrl-C, SIGTERM, closed pipe): ask the workers to unwind (they
            # delete their temporary files) and wait for them; queued work dies with them.
            # The futures are not cancelled here: the pool's manager thread, finding its
            # workers gone, sets an exception on every future it still holds, and a future
            # cancelled from this thread makes it fail with InvalidStateError (a traceback).
            _stop_workers(list(getattr(executor, "_processes", {}).values()))
            executor.shutdown(wait=True, cancel_futures=True)


#: Seconds the workers of an interrupted batch get to unwind their jobs before they are killed.
STOP_GRACE = 10.0


def _stop_workers(processes: list, grace: float = STOP_GRACE) -> None:
    """SIGTERM the pool's workers, wait up to ``grace`` s for them to leave, SIGKILL the rest.

    A worker unwinds its job on SIGTERM (removing its temporary files) and leaves
    (:mod:`._worker`).  The pool's shutdown would wait for ever on one that does not (e.g.
    blocked on a lock of the pool's queues held by a sibling that is gone), so the
    batch's end never depends on it: past the grace it is killed.  Outputs are staged and
    written at the end of a job, in Python, which sees the signal at once; a worker still
    busy past the grace is blocked, or inside a compiled kernel with no output open.
    """
    from multiprocessing.connection import wait

    for process in processes:
        try:
            process.terminate()
        except Exception:  # noqa: BLE001 -- already gone
            pass
    waiting = {}
    for process in processes:
        try:
            waiting[process.sentinel] = process
        except ValueError:      # closed: already joined
            pass
    deadline = time.monotonic() + grace
    while waiting:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        for sentinel in wait(list(waiting), timeout=left):
            waiting.pop(sentinel, None)
    for process in waiting.values():
        log.debug("worker %s did not stop within %.0f s: killed", process.pid, grace)
        try:
            process.kill()
        except Exception:  # noqa: BLE001 -- gone meanwhile
            pass


def _dask_client(scheduler, workers: int, threads: int | None):
    """(client, cluster) for ``scheduler``: ``"local"``, an address, or a Client."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise OptionError("--scheduler needs dask.distributed; install it with "
                          "pip install 'stereobudget[dask]'") from None
    if not isinstance(scheduler, str):
        return scheduler, None, False
    if scheduler == "local":
        # Shutdown races (a worker's last heartbeat to a closed scheduler) are logged by
        # dask as tracebacks; our results come back as dicts, so keep its logs quiet
        # unless debugging.
        quiet = logging.DEBUG if log.getEffectiveLevel() <= logging.DEBUG else logging.CRITICAL
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=quiet)
        return Client(cluster), cluster, True
    try:
        return Client(scheduler, timeout="20s"), None, True
    except (OSError, TimeoutError) as exc:
        raise OptionError(f"cannot connect to the dask scheduler {scheduler!r}: {exc}") from None


#: Path fields of the jobs, made absolute before they go to a cluster.
_PATH_FIELDS = ("source", "output", "left", "samples", "disparity", "preview", "right")


def _absolute_paths(job):
    """``job`` with every relative path made absolute here.

    A worker of a real cluster runs in its own folder (wherever ``dask worker`` was
    started): a relative input would not be found there, and a relative output would
    land there.  The cluster must see this machine's paths (shared storage).
    """
    from dataclasses import fields, is_dataclass, replace
    if not is_dataclass(job):
        return job
    names = {f.name for f in fields(job)}
    changes = {name: os.path.abspath(getattr(job, name)) for name in _PATH_FIELDS
               if name in names and isinstance(getattr(job, name), str) and getattr(job, name) != STDIO
               and not os.path.isabs(getattr(job, name))}
    return replace(job, **changes) if changes else job


def _on_worker(job, *, fn):
    """``fn(job)`` on a dask worker; a failure names the worker (its files, its memory, its logs)."""
    result = fn(job)
    if result.get("status") == "failed":
        try:
            from distributed import get_worker
            address = get_worker().address
        except Exception:  # noqa: BLE001 -- not on a worker (a threaded client): nothing to add
            address = None
        if address:
            result["worker"] = address
            result["error"] = f"{result.get('error')} (on worker {address})"
    return result


def _run_dask(jobs: list, fn: Callable, scheduler, workers: int, threads: int | None) -> Iterator[dict]:
    client, cluster, owned = _dask_client(scheduler, workers, threads)
    futures = []
    try:
        from distributed import as_completed
        if threads:
            jobs = [_with_threads(job, threads) for job in jobs]
        jobs = [_absolute_paths(job) for job in jobs]
        # pure=False: every job must run even when two are equal (they write files).
        futures = client.map(_on_worker, jobs, pure=False, fn=fn)
        index = {future.key: job for future, job in zip(futures, jobs)}
        for future in as_completed(futures):
            try:
                yield future.result()
            except Exception as exc:  # noqa: BLE001 -- a lost worker fails its file only
                yield _crashed(index.get(future.key), exc)
        if cluster is None:
            _release_worker_volumes(client)
    finally:
        for future in futures:
            if not future.done():
                future.cancel()
        if owned:
            client.close()
        if cluster is not None:
            cluster.close()


def _release_worker_volumes(client) -> None:
    """Drop the spare volumes the jobs left on the workers of a cluster that outlives the batch.

    Each worker keeps its last decode's volumes for the next one of the same frame size
    (:mod:`stereobudget._kernels._scratch`), GiBs at large frames; once the batch is done they are
    memory the cluster's other work cannot have.  Best effort: a worker that is gone is
    skipped.
    """
    from .._kernels._scratch import release
    try:
        client.run(release, on_error="ignore")
    except Exception as exc:  # noqa: BLE001 -- a closed client or an older distributed
        log.debug("could not release the workers' spare volumes: %s", exc)


def _with_threads(job, threads: int):
    if isinstance(job, DecodeJob) and job.threads is None:
        from dataclasses import replace
        return replace(job, threads=threads)
    return job


def run_jobs(jobs: Iterable, fn: Callable, *, workers: int | None = None, scheduler=None,
             progress: Callable[[dict], None] | None = None) -> Iterator[dict]:
    """Run ``fn(job)`` for every job and yield the result dicts as they complete.

    Parameters
    ----------
    jobs : iterable
        Picklable job descriptions (:class:`EncodeJob`, :class:`DecodeJob`).
    fn : callable
        A module-level function returning a small dict and never raising for bad
        input (:func:`encode_job`, :func:`decode_job`).
    workers : int, optional
        Parallel workers (default :func:`default_jobs`).  With 1 (or one job) the work
        runs in this process; otherwise in a local process pool, each worker's numba
        limited to its share of the cores.
    scheduler : str or distributed.Client, optional
        Run on dask.distributed instead: ``"local"`` starts a LocalCluster of
        ``workers`` single-threaded worker processes; any other string is a scheduler
        address (``tcp://host:8786``); a Client is used as it is.  Workers read and write
        the files themselves (shared storage) and send back only the result dicts.
    progress : callable, optional
        Called with each result dict as it arrives.

    Yields
    ------
    dict
        One per job, in completion order.  Closing the generator early (or an interrupt)
        cancels the queued jobs and stops the workers, which remove their temporary files.
    """
    jobs = list(jobs)
    workers = max(1, int(workers or default_jobs()))
    # Jobs on one machine share its cores: each worker's numba gets its share.
    threads = max(1, default_jobs() // workers)

    def report(results):
        for item in results:
            if progress is not None:
                progress(item)
            yield item

    if scheduler is not None:
        yield from report(_run_dask(jobs, fn, scheduler, workers,
                                    threads if scheduler == "local" else None))
    elif workers == 1 or len(jobs) <= 1:
        yield from report(fn(job) for job in jobs)
    else:
        yield from report(_run_local_pool(jobs, fn, min(workers, len(jobs)), threads))


__all__ = ["default_jobs", "run_jobs", "EncodeJob", "DecodeJob"]
