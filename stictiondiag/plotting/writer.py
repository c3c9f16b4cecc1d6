"""PNG files of figures, rendered in worker processes while the caller goes on.

Rendering a figure (building its artists, laying out and drawing every tick label,
compressing the PNG) is Python work inside matplotlib that holds the interpreter
lock: in a thread it would only take turns with the analysis running beside it,
not overlap it.  :class:`FigureWriter` therefore renders in forked child processes.
A child starts in milliseconds with the caller's results already in its memory,
builds its figures, writes each with :func:`~stictiondiag.atomic.atomic_path` and
reports back only which figures it wrote or the exception that stopped it.  Nothing
computed in a child flows back into a result: the files are the same as those the
caller would write itself.

Workers are used only where forking is safe: on Linux, in a process running a single
thread (a child of a multi-threaded process can inherit a lock that another thread
held; the ``stiction`` command keeps BLAS to one thread), and with more than one CPU
available.  Elsewhere every figure is rendered in the calling process, at
:meth:`FigureWriter.finish`, in the order the figures were added.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

__all__ = ["FigureWriter", "available_workers"]

#: Resolution of the PNG files [dots per inch].
DPI = 110


def available_workers() -> int:
    """Worker processes that can render beside this one: the CPUs this process may
    run on, less one for itself; 0 where workers are not used (not Linux)."""
    if not sys.platform.startswith("linux") or not hasattr(os, "fork"):
        return 0
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - Linux has it
        cpus = os.cpu_count() or 1
    return max(cpus - 1, 0)


def _single_threaded() -> bool:
    """True when this process runs exactly one thread (operating-system threads,
    so that a BLAS thread pool counts too)."""
    import threading

    if threading.active_count() != 1:
        return False
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as status:
            for line in status:
                if line.startswith("Threads:"):
                    return int(line.split()[1]) == 1
    except (OSError, ValueError, IndexError):
        pass
    return False


@dataclass
class _Job:
    """One figure: its file and the function that builds it."""

    target: Path
    build: Callable
    written: bool = False
    error: BaseException | None = None


@dataclass
class _Child:
    """A worker process, the read end of its report pipe and its jobs."""

    pid: int
    fd: int
    jobs: list[_Job]


def _save(job: _Job, dpi: int) -> None:
    from stictiondiag.atomic import atomic_path

    fig = job.build()
    with atomic_path(job.target) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")


def _shares(jobs: list[_Job], n: int) -> list[list[_Job]]:
    """``jobs`` cut into ``n`` consecutive shares of (almost) equal length."""
    n = max(1, min(n, len(jobs)))
    q, r = divmod(len(jobs), n)
    out, start = [], 0
    for i in range(n):
        stop = start + q + (1 if i < r else 0)
        out.append(jobs[start:stop])
        start = stop
    return out


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError naming it."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _stop_on_sigterm(signum, frame):  # pragma: no cover - runs in a worker
    # Unwinds through atomic_path, which removes its temporary file.
    raise SystemExit(128 + signum)


def _work(jobs: list[_Job], fd: int, dpi: int) -> None:  # pragma: no cover - in a worker
    """Body of a worker process: render ``jobs`` in order, report, exit."""
    status = 1
    try:
        signal.signal(signal.SIGTERM, _stop_on_sigterm)
        report: list = []
        for i, job in enumerate(jobs):
            try:
                _save(job, dpi)
            except BaseException as exc:
                text = "".join(traceback.format_exception(exc))
                report.append((i, _portable(exc), text))
                break
            report.append((i, None, None))
        data = pickle.dumps(report, protocol=pickle.HIGHEST_PROTOCOL)
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        status = 0
    finally:
        # Never return into the caller's code (its finally blocks, atexit handlers
        # and buffered output belong to the parent).
        try:
            sys.stderr.flush()
        finally:
            os._exit(status)


class FigureWriter:
    """Writes figures as PNG files, in worker processes where it can.

    Add figures with :meth:`add`; :meth:`start` hands the figures added so far to
    workers (call it before the caller's own long work); :meth:`finish` shares the
    rest between free workers and this process, waits for the workers and returns
    the files written.  Used as a context manager, an exception inside the block
    stops the workers (their temporary files are removed).

    Parameters
    ----------
    folder : str or Path
        Directory of the files (created when missing).
    dpi : int
        Resolution of the PNGs.
    workers : int, optional
        Most worker processes at a time; default :func:`available_workers`; 0
        renders everything in this process.
    """

    def __init__(self, folder, *, dpi: int = DPI, workers: int | None = None) -> None:
        self.folder = Path(folder)
        self.dpi = int(dpi)
        self.workers = available_workers() if workers is None else max(int(workers), 0)
        self._jobs: list[_Job] = []
        self._queue: list[_Job] = []
        self._children: list[_Child] = []

    # -- adding and handing out ---------------------------------------------------

    def add(self, filename: str, build: Callable) -> Path:
        """Queue the figure ``build()`` for the file ``folder / filename``."""
        job = _Job(self.folder / filename, build)
        self._jobs.append(job)
        self._queue.append(job)
        return job.target

    def start(self) -> None:
        """Hand the queued figures to free workers now (none free: they wait)."""
        self._collect(block=False)
        free = self.workers - len(self._children)
        if free > 0 and self._queue and _single_threaded():
            shares = _shares(self._queue, free)
            self._queue = []
            for share in shares:
                self._fork(share)

    def finish(self) -> list[Path]:
        """Write every figure added; return the files in the order they were added.

        The queued figures are shared between new workers and this process (which
        takes the last share).  The workers are waited for; a figure a worker
        could not report on (it died) is rendered here.

        Raises
        ------
        Exception
            The first error, in the order the figures were added, of building or
            saving a figure (re-raised from the worker, with its traceback as a note).
        """
        try:
            self._collect(block=False)
            # Workers still busy with earlier figures are not waited for: they finish
            # soon, and sharing the cores with them a moment is sooner than drawing
            # everything here.
            if self.workers > 0 and len(self._queue) > 1 and _single_threaded():
                shares = _shares(self._queue, self.workers + 1)
                self._queue = shares.pop()
                for share in shares:
                    self._fork(share)
            self._render_here(self._queue)
            self._queue = []
        except BaseException:
            self.stop()
            raise
        self._collect(block=True)
        for job in self._jobs:
            if job.error is not None:
                raise job.error
        return [job.target for job in self._jobs if job.written]

    # -- context manager ------------------------------------------------------------

    def __enter__(self) -> FigureWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.stop()

    def stop(self) -> None:
        """Stop the workers and drop the figures not written yet."""
        for child in self._children:
            try:
                os.kill(child.pid, signal.SIGTERM)
            except OSError:  # pragma: no cover - already gone
                pass
        self._queue = []
        self._collect(block=True, fallback=False)

    # -- internals --------------------------------------------------------------------

    def _render_here(self, jobs: list[_Job]) -> None:
        for job in jobs:
            try:
                _save(job, self.dpi)
            except Exception as exc:
                job.error = exc
                return
            job.written = True

    def _fork(self, jobs: list[_Job]) -> None:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # pragma: no cover - a closed or odd stream
                pass
        read_fd, write_fd = os.pipe()
        try:
            pid = os.fork()
        except OSError:
            os.close(read_fd)
            os.close(write_fd)
            self._queue.extend(jobs)  # rendered here at finish()
            return
        if pid == 0:  # pragma: no cover - the worker
            os.close(read_fd)
            _work(jobs, write_fd, self.dpi)
        os.close(write_fd)
        self._children.append(_Child(pid, read_fd, jobs))

    def _collect(self, *, block: bool, fallback: bool = True) -> None:
        """Reap finished workers (all of them with ``block``) and take their reports."""
        running = []
        for child in self._children:
            if not block:
                try:
                    pid, _ = os.waitpid(child.pid, os.WNOHANG)
                except ChildProcessError:  # pragma: no cover - reaped elsewhere
                    pid = child.pid
                if pid == 0:
                    running.append(child)
                    continue
            data = self._read(child.fd)
            if block:
                try:
                    os.waitpid(child.pid, 0)
                except ChildProcessError:  # pragma: no cover - reaped elsewhere
                    pass
            lost = self._take_report(child, data)
            if lost and fallback:
                # The worker died before it could report: render its figures here.
                self._render_here(lost)
        self._children = running

    @staticmethod
    def _read(fd: int) -> bytes:
        chunks = []
        try:
            while True:
                chunk = os.read(fd, 1 << 16)
                if not chunk:
                    break
                chunks.append(chunk)
        finally:
            os.close(fd)
        return b"".join(chunks)

    @staticmethod
    def _take_report(child: _Child, data: bytes) -> list[_Job]:
        """Mark the child's jobs written or failed; return the jobs it did not report."""
        try:
            report = pickle.loads(data) if data else None
        except Exception:
            report = None
        if not isinstance(report, list):
            return list(child.jobs)
        for i, error, text in report:
            job = child.jobs[i]
            if error is None:
                job.written = True
            else:
                if text:
                    error.add_note(
                        f"raised while writing {job.target} in a worker process:\n{text}"
                    )
                job.error = error
        failed = any(error is not None for _, error, _ in report)
        return [] if failed else list(child.jobs[len(report) :])
