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

A worker can also compute a value that its figures need and that the caller wants
too (:meth:`FigureWriter.compute`): the worker computes it first, hands a copy back
(pickled) and draws its figures from it, while the caller works on; where no worker
is available the value is computed in the calling process when it is first needed.

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

__all__ = ["DependencyFailed", "FigureWriter", "Pending", "available_workers"]

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
    """A worker process, the read end of its report pipe, its figures and its whole
    work list (figures and values, as the worker numbers them in its report)."""

    pid: int
    fd: int
    jobs: list[_Job]
    work: list


class DependencyFailed(Exception):
    """A figure needs a value (:class:`Pending`) whose computation failed: the figure
    is left out, and the caller learns of the failure from :meth:`Pending.get`."""


class _StandIn:
    """Stands for the value of a :class:`Pending`: attribute access waits for it."""

    def __init__(self, pending: Pending) -> None:
        self._pending = pending

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self._pending.value_for_dependents(), name)


class Pending:
    """A value computed by a function, in a worker process or in this one.

    Handed to a worker (by :meth:`FigureWriter.start`), the function runs there and
    a pickled copy of its value, or of the exception it raised, comes back; in any
    other case (no worker, a worker that died, a value that cannot be pickled) the
    function runs in this process the first time the value is asked for.
    """

    def __init__(self, fn: Callable) -> None:
        self._fn = fn
        self._owner = os.getpid()
        self._done = False
        self._value = None
        self._error: BaseException | None = None
        self._ready: int | None = None  # read end: one byte when the worker has stored
        self._store = None  # temporary file the worker stores the pickled outcome in

    def get(self):
        """The value (waits for the worker); re-raises the function's exception."""
        if not self._done:
            if self._ready is not None and os.getpid() == self._owner:
                self._receive()
            else:
                self._run()
        if self._error is not None:
            raise self._error
        return self._value

    def value_for_dependents(self):
        """The value for a figure or a step that needs it: :class:`DependencyFailed`
        when the function raised (the caller handles that error at :meth:`get`)."""
        try:
            return self.get()
        except Exception as exc:
            raise DependencyFailed(str(exc)) from exc

    def stand_in(self) -> _StandIn:
        """An object whose attributes are those of the value, fetched when read."""
        return _StandIn(self)

    def _run(self) -> None:
        try:
            self._value = self._fn()
        except Exception as exc:
            self._error = exc
        self._done = True

    def _handed_out(self) -> tuple[int, int]:
        """Before forking the worker that computes the value: its pipe and file."""
        import tempfile

        self._store = tempfile.TemporaryFile()
        read_fd, write_fd = os.pipe()
        self._ready = read_fd
        return read_fd, write_fd

    def _deliver(self, write_fd: int) -> None:  # pragma: no cover - in a worker
        """In the worker: compute, store the pickled outcome, signal."""
        self._run()
        try:
            if self._error is None:
                outcome = ("value", self._value)
            else:
                text = "".join(traceback.format_exception(self._error))
                outcome = ("error", _portable(self._error), text)
            data = pickle.dumps(outcome, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:
            data = b""  # not picklable: the caller computes it itself
        fd = self._store.fileno()
        view, offset = memoryview(data), 0
        while offset < len(data):
            offset += os.pwrite(fd, view[offset:], offset)
        os.write(write_fd, b"d" if data else b"-")
        os.close(write_fd)

    def _receive(self) -> None:
        """In the caller: wait for the worker's outcome (or compute it here)."""
        try:
            signal_byte = os.read(self._ready, 1)
        finally:
            os.close(self._ready)
            self._ready = None
        outcome = None
        if signal_byte == b"d":
            try:
                fd = self._store.fileno()
                size = os.fstat(fd).st_size
                outcome = pickle.loads(os.pread(fd, size, 0))
            except Exception:
                outcome = None
        self._store.close()
        self._store = None
        if isinstance(outcome, tuple) and outcome[0] == "value":
            self._value, self._done = outcome[1], True
        elif isinstance(outcome, tuple) and outcome[0] == "error":
            error, text = outcome[1], outcome[2]
            if text:
                error.add_note(f"raised in a worker process:\n{text}")
            self._error, self._done = error, True
        else:
            # The worker died or its value could not be pickled: compute it here.
            self._run()


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


def _work(jobs: list, fd: int, dpi: int, deliver: dict) -> None:  # pragma: no cover - worker
    """Body of a worker process: compute the values and render the figures of ``jobs``
    in order, report, exit.  ``deliver`` maps each value to the write end of its pipe."""
    status = 1
    try:
        signal.signal(signal.SIGTERM, _stop_on_sigterm)
        report: list = []
        for i, job in enumerate(jobs):
            if isinstance(job, Pending):
                job._deliver(deliver[id(job)])
                continue
            try:
                _save(job, dpi)
            except DependencyFailed:
                report.append((i, "skipped", None))
                continue
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

    Add figures with :meth:`add` (and values they need with :meth:`compute`);
    :meth:`start` hands what was added so far to a worker (call it before the
    caller's own long work); :meth:`finish` shares the rest between workers and this
    process, waits for the workers and returns the files written.  Used as a context
    manager, an exception inside the block stops the workers (their temporary files
    are removed).

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
        self._frozen = False

    # -- adding and handing out ---------------------------------------------------

    def add(self, filename: str, build: Callable) -> Path:
        """Queue the figure ``build()`` for the file ``folder / filename``."""
        job = _Job(self.folder / filename, build)
        self._jobs.append(job)
        self._queue.append(job)
        return job.target

    def compute(self, fn: Callable) -> Pending:
        """Queue ``fn()``, a value that figures added after it may need (through
        :meth:`Pending.stand_in`): the worker that draws them computes it first and
        hands a copy back.  Ask for the value with :meth:`Pending.get`."""
        pending = Pending(fn)
        self._queue.append(pending)
        return pending

    def can_start(self) -> bool:
        """True when :meth:`start` would hand work to a worker now."""
        self._collect(block=False)
        return self.workers > len(self._children) and _single_threaded()

    def start(self) -> None:
        """Hand what is queued to free workers now (none free: it waits).

        Queued values (:meth:`compute`) go with every figure queued so far to one
        worker, so that the figures find the values they need there.
        """
        if not self._queue or not self.can_start():
            return
        free = self.workers - len(self._children)
        if any(isinstance(job, Pending) for job in self._queue):
            free = 1
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
            # Values not handed out are computed here when a figure asks for them.
            self._queue = [job for job in self._queue if not isinstance(job, Pending)]
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
        self._thaw()
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
        self._thaw()

    # -- internals --------------------------------------------------------------------

    def _freeze(self) -> None:
        """Before a fork: move the objects that exist now out of the garbage
        collector's sight (``gc.freeze``), unless someone else froze objects already.

        A worker then does not copy every page of the caller's heap by touching the
        objects' collector headers, and the caller's full collections while the
        workers run scan only the objects made since (a full scan of the analysis'
        heap costs 0.1-0.2 s).  :meth:`finish` and :meth:`stop` undo it.
        """
        import gc

        if self._frozen or gc.get_freeze_count() == 0:
            gc.freeze()
            self._frozen = True

    def _thaw(self) -> None:
        if self._frozen:
            import gc

            gc.unfreeze()
            self._frozen = False

    def _render_here(self, jobs: list[_Job]) -> None:
        for job in jobs:
            try:
                _save(job, self.dpi)
            except DependencyFailed:
                continue  # the caller handles the failed value
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
        pendings = [job for job in jobs if isinstance(job, Pending)]
        deliver = {id(p): p._handed_out()[1] for p in pendings}
        self._freeze()
        read_fd, write_fd = os.pipe()
        try:
            pid = os.fork()
        except OSError:
            os.close(read_fd)
            os.close(write_fd)
            for p in pendings:
                os.close(deliver[id(p)])  # the value reads as lost: computed here
            self._queue.extend(job for job in jobs if not isinstance(job, Pending))
            return
        if pid == 0:  # pragma: no cover - the worker
            os.close(read_fd)
            _work(jobs, write_fd, self.dpi, deliver)
        os.close(write_fd)
        for p in pendings:
            os.close(deliver[id(p)])
        figures = [job for job in jobs if not isinstance(job, Pending)]
        self._children.append(_Child(pid, read_fd, figures, jobs))

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
        """Mark the child's figures written, skipped or failed; return the figures
        it did not report on."""
        try:
            report = pickle.loads(data) if data else None
        except Exception:
            report = None
        if not isinstance(report, list):
            return list(child.jobs)
        reported = set()
        failed = False
        for i, error, text in report:
            job = child.work[i]
            reported.add(id(job))
            if error is None:
                job.written = True
            elif error == "skipped":
                pass
            else:
                if text:
                    error.add_note(
                        f"raised while writing {job.target} in a worker process:\n{text}"
                    )
                job.error = error
                failed = True
        return [] if failed else [job for job in child.jobs if id(job) not in reported]
