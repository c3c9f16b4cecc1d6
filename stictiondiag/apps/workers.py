"""Running one function over many loops in worker processes, and stopping them cleanly.

Used by :mod:`stictiondiag.apps.scan` (local pool or Dask) and
:mod:`stictiondiag.apps.report` (local pool).

Interrupts: Ctrl-C in a terminal sends SIGINT to every process of the foreground
group, workers included.  Workers therefore ignore SIGINT (and die quietly on
SIGTERM), so only the main process sees the interrupt; on its way out it cancels
what has not started and terminates the workers still running, instead of waiting
for their loops to finish or for a worker stuck on a lock.  The caller has written
each finished loop whole (:mod:`stictiondiag.core.atomic`), so a rerun resumes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any

from stictiondiag.core.blas import one_blas_thread
from stictiondiag.core.errors import UsageError

__all__ = ["children_ignore_sigint", "quiet_worker", "run_dask", "run_local", "watch_parent"]


#: How often a worker checks that its parent is alive [s].
PARENT_POLL_S = 0.5


def _exit_with_parent(parent: int) -> None:
    """End this process (at once, no clean-up) as soon as ``parent`` is gone.

    A parent killed with SIGKILL (or the out-of-memory killer) cannot stop its
    workers; without this, each (about 300 MB) would run on for good.  The parent
    is gone when this process has been handed to another (``getppid`` changes).
    """
    import time

    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


def watch_parent() -> None:
    """Start a daemon thread that ends this process when its parent dies."""
    parent = os.getppid()
    threading.Thread(
        target=_exit_with_parent, args=(parent,), name="stiction-parent-watch", daemon=True
    ).start()


def quiet_worker() -> None:
    """Initializer of a worker process: Ctrl-C is the main process's to handle.

    SIGINT is ignored (the main process stops the worker) and SIGTERM has its
    default action, so a worker that is terminated prints no traceback.  The
    worker ends by itself when the main process dies (:func:`watch_parent`).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    watch_parent()


@contextlib.contextmanager
def children_ignore_sigint() -> Iterator[None]:
    """Processes started inside this block ignore SIGINT from their first instruction.

    A worker that is still importing when Ctrl-C comes would print a traceback; an
    ignored signal is inherited across ``spawn`` (fork and exec), a Python handler
    is not.  So SIGINT is ignored while the workers start, and also blocked in this
    thread (and in the threads started here, such as Dask's event loop), so a
    Ctrl-C in the meantime stays pending and arrives, as KeyboardInterrupt, when the
    block ends instead of being lost.  Only in the main thread (where Python
    handles signals); elsewhere a no-op.

    Known limit: threads started inside the block (Dask's) do not keep the block,
    so a Ctrl-C in the one or two seconds while a Dask LocalCluster starts its
    workers can be lost (measured: twice in nine timed tries); pressing it again
    stops the scan.  A local pool's window is milliseconds.
    """
    if threading.current_thread() is not threading.main_thread() or not hasattr(
        signal, "pthread_sigmask"
    ):
        yield
        return
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _warm_cache_here() -> None:
    """Compile any kernel missing from numba's cache in this process, before the
    workers start: they then load it instead of each compiling it (once per machine
    rather than once per worker; :func:`stictiondiag.apps.warmup.warm_cache_once`).

    Only an optimisation: should the warm-up fail, the workers compile at first use
    as before (tests/test_warmup.py keeps the warm-up itself working).
    """
    # Imported here: the warm-up brings numba and the analysis, which importing the
    # scan (its own process) does not load; only a scan that starts workers needs it.
    from stictiondiag.apps.warmup import warm_cache_once

    with contextlib.suppress(Exception):
        warm_cache_once()


def _stop_pool(pool, *, interrupted: bool) -> None:
    """Shut a process pool down; on an interrupt terminate its running workers."""
    if not interrupted:
        pool.shutdown(wait=True, cancel_futures=True)
        return
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(Exception):
            process.terminate()
    for process in processes:
        with contextlib.suppress(Exception):
            process.join(timeout=5)
            if process.is_alive():
                process.kill()
                process.join(timeout=5)


def run_local(
    todo,
    fn,
    args: tuple,
    workers: int,
    on_error: Callable[[Any, BaseException], object] | None = None,
) -> Iterator:
    """Yield ``fn(src, *args)`` for each source, on a process pool of ``workers``.

    At most ``2 x workers`` loops are in flight, so memory is bounded by the loops
    being analysed, not by their number.  Results come in completion order.

    Parameters
    ----------
    todo : iterable
        Sources (picklable), consumed lazily.
    fn : callable
        Module-level function run in the workers (``spawn`` start method).
    args : tuple
        Further arguments of ``fn``.
    workers : int
        Worker processes; 1 runs ``fn`` in this process.
    on_error : callable, optional
        ``on_error(src, exc)`` gives the result for a source whose call raised or
        whose worker died; without it the exception propagates.  After a worker
        dies the pool is replaced and the remaining sources continue.

    A ``KeyboardInterrupt`` (or any exception of the caller, e.g. a full disk)
    terminates the workers and propagates.
    """
    if workers <= 1:
        for src in todo:
            try:
                res = fn(src, *args)
            except Exception as exc:
                if on_error is None:
                    raise
                res = on_error(src, exc)
            yield res
        return
    import concurrent.futures as cf
    import multiprocessing as mp
    from concurrent.futures.process import BrokenProcessPool

    ctx = mp.get_context("spawn")  # no forked numba/BLAS state in workers
    _warm_cache_here()
    it = iter(todo)
    pool = None
    pending: dict = {}
    interrupted = True  # until the loop below ends normally
    # Workers (this pool's, and a fresh pool's after a worker died) get one BLAS
    # thread each.  The scan already runs one worker per core; a multi-threaded BLAS
    # in each put two threads on every core: on two cores 100 loops took 206 s with
    # two workers against 79-90 s with one BLAS thread each (benchmarks/bench_scan.py).
    with one_blas_thread():
        try:
            while True:
                if pool is None:
                    pool = cf.ProcessPoolExecutor(
                        max_workers=workers, mp_context=ctx, initializer=quiet_worker
                    )
                with children_ignore_sigint():  # submit starts the worker processes
                    for src in it:
                        pending[pool.submit(fn, src, *args)] = src
                        if len(pending) >= 2 * workers:
                            break
                if not pending:
                    interrupted = False
                    return
                done, _ = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
                broken = False
                for fut in done:
                    src = pending.pop(fut)
                    try:
                        res = fut.result()
                    except Exception as exc:
                        if on_error is None:
                            raise
                        broken = broken or isinstance(exc, BrokenProcessPool)
                        res = on_error(src, exc)
                    yield res
                if broken:
                    # A dead worker breaks the whole pool: the loops still in flight fail
                    # with it, and a fresh pool takes the rest.
                    assert on_error is not None  # broken is only set after on_error ran
                    for fut in cf.as_completed(list(pending)):
                        src = pending.pop(fut)
                        error = fut.exception()
                        yield fut.result() if error is None else on_error(src, error)
                    _stop_pool(pool, interrupted=False)
                    pool = None
        finally:
            # Not ending normally: the caller stopped reading (Ctrl-C, a failed write):
            # nobody will collect the loops in flight, so do not wait for them.
            if pool is not None:
                _stop_pool(pool, interrupted=interrupted)


@contextlib.contextmanager
def _quiet_dask_logs() -> Iterator[None]:
    """Silence distributed's loggers while a cluster is torn down after an interrupt."""
    loggers = [logging.getLogger(name) for name in ("distributed", "tornado", "asyncio")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


@contextlib.contextmanager
def _quiet_workers() -> Iterator[None]:
    """Worker processes started here log errors only (their cancelled-task warnings
    after an interrupt are noise on a terminal); a level the user set is kept."""
    name = "DASK_LOGGING__DISTRIBUTED"
    added = name not in os.environ
    if added:
        os.environ[name] = "error"
    try:
        yield
    finally:
        if added:
            os.environ.pop(name, None)


#: Dask settings of the LocalCluster a scan starts (``dask.config`` keys).
#:
#: * ``MALLOC_TRIM_THRESHOLD_``: the nanny puts ``65536`` in every worker's
#:   environment by default.  That pins glibc's mmap threshold at 128 KiB, so every
#:   numpy temporary of that size or more is a fresh mmap whose pages fault in one by
#:   one: 1.41-1.47x the local pool's CPU per loop (docs/history.md, "Dask").
#:   ``None`` takes the key off the nanny's list; a value the user set in the
#:   environment is still inherited by the workers.
#: * The periodic work of an idle cluster, for a dashboard nobody watches: the
#:   workers' statistical profiler (every thread sampled each 10 ms), work stealing
#:   (every 100 ms; a scan has at most two loops per worker in flight), the event-loop
#:   tick (20 ms) and system monitor (0.5 s).  Measured on two workers, the cluster
#:   used 2.8 CPU-s per 30 s idle with Dask's defaults and 0.4 CPU-s with these.
#: * The memory monitor (every 100 ms in each worker and nanny) runs every second:
#:   during a loop's analysis the threads beside the task used 8.5-8.7 % of the
#:   task's CPU with 100 ms and 5.1 % with 1 s (3.1 % in a local pool's worker).  A
#:   worker that outgrows its memory limit is paused or stopped up to a second later.
_LOCAL_CLUSTER_CONFIG = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.worker.profile.enabled": False,
    "distributed.scheduler.work-stealing": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
}


@contextlib.contextmanager
def _scan_cluster_config() -> Iterator[None]:
    """A LocalCluster created in this block has :data:`_LOCAL_CLUSTER_CONFIG`
    (nannies and scheduler read it as they start; the workers get it from them)."""
    import dask

    with dask.config.set(_LOCAL_CLUSTER_CONFIG):
        yield


def _restore_environ(saved: dict[str, str]) -> None:
    """Make ``os.environ`` equal to ``saved`` again, key for key.

    A Dask nanny writes its worker settings (``MALLOC_TRIM_THRESHOLD_``,
    ``OMP_NUM_THREADS``, ``PYTHONHASHSEED`` ...) into the environment of the process
    it runs in, which for a LocalCluster is the caller's: a later local pool in the
    same process would inherit them (a local scan after a Dask scan ran 1.5x slower).
    """
    for key in [k for k in os.environ if k not in saved]:
        del os.environ[key]
    for key, value in saved.items():
        if os.environ.get(key) != value:
            os.environ[key] = value


def _connect(workers: int, scheduler: str | None):
    """(client, cluster or None): a client of ``scheduler`` or of a new LocalCluster."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise UsageError(
            "the dask engine needs Dask, an optional extra: pip install 'stiction[dask]'"
        ) from None
    cluster = None
    if not scheduler:
        _warm_cache_here()
    try:
        if scheduler:
            client = Client(scheduler, timeout="10s")
        else:
            # The scheduler's HTTP server (health, dashboard) takes a free port: another
            # cluster on the default 8787 must not make the scan fail or warn.
            with (
                one_blas_thread(),
                children_ignore_sigint(),
                _quiet_workers(),
                _scan_cluster_config(),
            ):
                cluster = LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
                )
            # Its workers end by themselves when this process is killed (distributed's
            # own watch; measured with SIGKILL, docs/robustness.md).
            client = Client(cluster)
    except (OSError, ValueError, TypeError) as exc:
        # OSError: nothing listens there (timeout); ValueError/TypeError: not an
        # address at all (``garbage://``).
        if cluster is not None:
            cluster.close()
        reason = " ".join(str(exc).split())[:160] or type(exc).__name__
        raise UsageError(
            f"cannot reach Dask scheduler {scheduler!r} ({reason}): give an address like "
            "tcp://host:8786, or leave --scheduler out for a local cluster"
        ) from None
    if scheduler:
        _warm_each_host(client)
    return client, cluster


def _warm_each_host(client) -> None:
    """Warm the kernel cache on one worker of each host of a remote cluster.

    The workers of one host share numba's on-disk cache, so the others then load
    the kernels instead of each compiling them.  Runs as ordinary tasks (in the
    workers' threads, not their event loops); a failure here only means the
    workers compile at first use, so it is not an error of the scan.
    """
    hosts: dict[str, str] = {}
    for address, worker in client.scheduler_info().get("workers", {}).items():
        hosts.setdefault(worker.get("host", address), address)
    # Imported here, as in _warm_cache_here: the warm-up brings numba and the analysis.
    from stictiondiag.apps.warmup import warm_cache_once

    futures = [
        client.submit(warm_cache_once, workers=[address], allow_other_workers=False, pure=False)
        for address in hosts.values()
    ]
    with contextlib.suppress(Exception):
        client.gather(futures)


def run_dask(
    todo,
    fn,
    args: tuple,
    workers: int,
    scheduler: str | None,
    on_error: Callable[[Any, BaseException], object] | None = None,
) -> Iterator:
    """Like :func:`run_local` on ``dask.distributed`` (a LocalCluster or ``scheduler``).

    The LocalCluster has ``workers`` single-threaded worker processes; with a
    ``scheduler`` address its workers must have ``stiction`` installed and see the
    data at the same paths.  At most ``2 x`` (number of workers) loops are
    submitted at a time.  The LocalCluster's workers run without the nanny's
    ``MALLOC_TRIM_THRESHOLD_`` setting, and the caller's ``os.environ`` is the same
    after the scan as before it.  On an interrupt the loops in flight are cancelled and a
    LocalCluster is closed (its worker processes end); a remote cluster is left
    running with nothing of this scan on it.
    """
    # Connected now, not at the first result: the cluster's processes start before
    # the caller starts anything else (a progress bar's thread), so a Ctrl-C while
    # they start is held for this thread (children_ignore_sigint), not lost.
    # The caller's environment is restored once the workers run, and again when the
    # cluster is closed (a nanny that restarts a dead worker writes it again).
    saved = dict(os.environ)
    try:
        client, cluster = _connect(workers, scheduler)
    finally:
        _restore_environ(saved)
    return _dask_results(client, cluster, todo, fn, args, workers, on_error, saved)


def _dask_results(client, cluster, todo, fn, args, workers, on_error, environ) -> Iterator:
    from distributed import as_completed

    pending: dict = {}
    interrupted = True
    try:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or workers)
        it = iter(todo)
        for _, src in zip(range(2 * n_workers), it, strict=False):
            pending[client.submit(fn, src, *args, pure=False)] = src
        ac = as_completed(list(pending))
        for fut in ac:
            src = pending.pop(fut)
            try:
                res = fut.result()
            except Exception as exc:  # KilledWorker, or a failure outside fn
                if on_error is None:
                    raise
                res = on_error(src, exc)
            fut.release()
            yield res
            nxt = next(it, None)
            if nxt is not None:
                new = client.submit(fn, nxt, *args, pure=False)
                pending[new] = nxt
                ac.add(new)
        interrupted = False
    finally:
        try:
            _close(client, cluster, pending, interrupted=interrupted)
        finally:
            _restore_environ(environ)


def _close(client, cluster, pending, *, interrupted: bool) -> None:
    """Close the client and a LocalCluster; after an interrupt quietly and with timeouts."""
    if not interrupted:
        client.close()
        if cluster is not None:
            cluster.close()
        return
    with _quiet_dask_logs():
        if cluster is None:
            # A remote cluster keeps running: take this scan's tasks off it.
            # (A LocalCluster is closed with its workers; cancelling there
            # only makes each worker log the cancelled task.)
            with contextlib.suppress(Exception):
                client.cancel(list(pending), force=True)
        with contextlib.suppress(Exception):
            client.close(timeout=5)
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)
