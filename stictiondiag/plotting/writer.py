"""PNG files of figures, rendered in worker processes while the caller goes on.

Rendering a figure (building its artists, laying out and drawing every tick label,
compressing the PNG) is Python work inside matplotlib that holds the interpreter
lock: in a thread it would only take turns with the analysis running beside it,
not overlap it.  :class:`FigureWriter` therefore renders in forked child processes.
A child starts in milliseconds with the caller's results already in its memory,
builds its figures, writes each with :func:`~stictiondiag.core.atomic.atomic_path` and
reports back only which figures it wrote or the exception that stopped it.  Nothing
computed in a child flows back into a result: the files are the same as those the
caller would write itself.

A worker can also compute a value that its figures need and that the caller wants
too (:meth:`FigureWriter.compute`): the worker computes it first, hands a copy back
(pickled) and draws its figures from it, while the caller works on; where no worker
is available the value is computed in the calling process when it is first needed.

A worker stays until :meth:`FigureWriter.finish`: work added later (figures whose
data exist only now) is sent to it pickled, so a worker that has imported matplotlib
draws them and the caller never imports it.  :meth:`FigureWriter.warm_up` starts a
worker before there is work for it, to import and set up what the work will need on
a core that would otherwise wait.  A worker given several figures at once while the
caller waits draws them side by side in forks of itself.

Workers are used only where forking is safe: on Linux, in a process running a single
thread (a child of a multi-threaded process can inherit a lock that another thread
held; the ``stiction`` command keeps BLAS to one thread), and with more than one CPU
available.  Elsewhere every figure is rendered in the calling process, at
:meth:`FigureWriter.finish`, in the order the figures were added.
"""

from __future__ import annotations

import gc
import itertools
import os
import pickle
import select
import signal
import struct
import sys
import tempfile
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
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


#: The values of this process by key, inherited by its workers: a value pickled
#: into a worker's work resolves there to the worker's own copy.
_PENDING: dict[tuple[int, int], Pending] = {}
_KEYS = itertools.count()


def _pending_from_pickle(key, fn, outcome) -> Pending:
    pending = _PENDING.get(key)
    if pending is None:
        pending = Pending(fn, key=key)
        if outcome is not None:
            pending._take(outcome)
    return pending


class Pending:
    """A value computed by a function, in a worker process or in this one.

    Handed to a worker (by :meth:`FigureWriter.start`), the function runs there and
    a pickled copy of its value, or of the exception it raised, comes back; in any
    other case (no worker, a worker that died, a value that cannot be pickled) the
    function runs in this process the first time the value is asked for.
    """

    def __init__(self, fn: Callable, *, key: tuple[int, int] | None = None) -> None:
        self._fn = fn
        self._key = key if key is not None else (os.getpid(), next(_KEYS))
        self._owner = os.getpid()
        self._done = False
        self._value = None
        self._error: BaseException | None = None
        self._source: _Child | None = None  # the worker computing it
        _PENDING[self._key] = self

    def __reduce__(self):
        # Pickled into a worker's work: the worker's copy of the same value.
        outcome = None
        if self._done:
            outcome = ("value", self._value) if self._error is None else ("error", self._error)
        return (_pending_from_pickle, (self._key, None if self._done else self._fn, outcome))

    def get(self):
        """The value (waits for the worker); re-raises the function's exception."""
        if not self._done:
            if self._source is not None and os.getpid() == self._owner:
                self._source.wait_for(self)
            if not self._done:
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

    def _take(self, outcome, text: str = "") -> None:
        if outcome[0] == "value":
            self._value = outcome[1]
        else:
            self._error = outcome[1]
            if text:
                self._error.add_note(f"raised in a worker process:\n{text}")
        self._done = True

    def _outcome_bytes(self) -> bytes:  # pragma: no cover - in a worker
        """In the worker: compute, return the pickled outcome (empty: not picklable)."""
        self._run()
        try:
            if self._error is None:
                outcome = ("value", self._value)
            else:
                text = "".join(traceback.format_exception(self._error))
                outcome = ("error", _portable(self._error), text)
            return pickle.dumps(outcome, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:
            return b""  # the caller computes it itself


def _save(job: _Job, dpi: int) -> None:
    from stictiondiag.core.atomic import atomic_path

    fig = job.build()
    with atomic_path(job.target) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")


def _shares(jobs: list, n: int) -> list[list]:
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


# -- messages between the caller and a worker ---------------------------------------
#
# Pipes carry only short messages (under PIPE_BUF: written whole, never blocking on a
# full pipe); the data (work, values, reports) lies in two temporary files shared at
# the fork, read and written at the offsets the messages give.

_HEADER = struct.Struct("<I")


def _send_message(fd: int, message: tuple) -> None:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    os.write(fd, _HEADER.pack(len(data)) + data)


def _read_exact(fd: int, n: int) -> bytes | None:
    chunks, left = [], n
    while left:
        chunk = os.read(fd, left)
        if not chunk:
            return None
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def _receive_message(fd: int) -> tuple | None:
    """The next message, None at the end of the pipe."""
    header = _read_exact(fd, _HEADER.size)
    if header is None:
        return None
    data = _read_exact(fd, _HEADER.unpack(header)[0])
    return None if data is None else pickle.loads(data)


def _pread(fd: int, size: int, offset: int) -> bytes:
    chunks, done = [], 0
    while done < size:
        chunk = os.pread(fd, size - done, offset + done)
        if not chunk:
            break
        chunks.append(chunk)
        done += len(chunk)
    return b"".join(chunks)


def _append(fd: int, data: bytes, offset: int) -> None:
    view, done = memoryview(data), 0
    while done < len(data):
        done += os.pwrite(fd, view[done:], offset + done)


def _stop_on_sigterm(signum, frame):  # pragma: no cover - runs in a worker
    # Unwinds through atomic_path, which removes its temporary file.
    raise SystemExit(128 + signum)


class _Worker:  # pragma: no cover - runs in a worker process
    """The worker side: runs its first work (inherited at the fork), then the work
    the caller sends, until the caller closes the command pipe."""

    def __init__(self, dpi: int, report_fd: int, command_fd: int, inbox, outbox) -> None:
        self.dpi = dpi
        self.report_fd = report_fd
        self.command_fd = command_fd
        self.inbox = inbox.fileno()
        self.outbox = outbox.fileno()
        self.offset = 0
        self.helpers: list[int] = []

    def serve(self, first: list, warm: Callable | None) -> None:
        status = 1
        try:
            signal.signal(signal.SIGTERM, _stop_on_sigterm)
            if warm is not None:
                # Imports make objects, not garbage: the collector would only scan
                # them over and over.  Frozen afterwards, they are not scanned again.
                gc.disable()
            if first:
                self.run(0, first, 1)
            if warm is not None:
                try:
                    warm()
                except Exception:  # the work itself will meet the same problem
                    pass
                gc.freeze()
                gc.enable()
            while True:
                message = _receive_message(self.command_fd)
                if message is None:
                    break
                _, number, offset, size, parallel = message
                try:
                    work = pickle.loads(_pread(self.inbox, size, offset))
                except Exception:
                    self.send("report", number, b"")  # unreadable: the caller does it
                    continue
                self.run(number, work, parallel)
            status = 0
        finally:
            for pid in self.helpers:
                try:
                    os.kill(pid, signal.SIGTERM)
                except OSError:
                    pass
            # Never return into the caller's code (its finally blocks, atexit
            # handlers and buffered output belong to the parent).
            try:
                sys.stderr.flush()
            finally:
                os._exit(status)

    def send(self, kind: str, ident, data: bytes) -> None:
        _append(self.outbox, data, self.offset)
        _send_message(self.report_fd, (kind, ident, self.offset, len(data)))
        self.offset += len(data)

    def run(self, number: int, work: list, parallel: int) -> None:
        """Compute the values and render the figures of ``work`` (in ``parallel``
        processes: this one and forks of it, when there are only figures)."""
        indexed = list(enumerate(work))
        shares = [indexed]
        if (
            parallel > 1
            and len(work) > 1
            and not any(isinstance(job, Pending) for job in work)
            and _single_threaded()
        ):
            shares = _shares(indexed, parallel)
        helpers, here = [], shares[-1]
        for share in shares[:-1]:
            read_fd, write_fd = os.pipe()
            try:
                pid = os.fork()
            except OSError:
                os.close(read_fd)
                os.close(write_fd)
                here = share + here
                continue
            if pid == 0:
                os.close(read_fd)
                self.helpers = []
                self._helper(share, write_fd)
            os.close(write_fd)
            helpers.append((pid, read_fd))
            self.helpers.append(pid)
        report = self.render(here)
        for pid, read_fd in helpers:
            data = FigureWriter._read(read_fd)
            os.waitpid(pid, 0)
            self.helpers.remove(pid)
            try:
                report.extend(pickle.loads(data))
            except Exception:
                pass  # a helper that died: its figures are unreported
        self.send("report", number, pickle.dumps(report, protocol=pickle.HIGHEST_PROTOCOL))

    def _helper(self, share: list, fd: int) -> None:
        status = 1
        try:
            data = pickle.dumps(self.render(share), protocol=pickle.HIGHEST_PROTOCOL)
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            status = 0
        finally:
            try:
                sys.stderr.flush()
            finally:
                os._exit(status)

    def render(self, indexed: list) -> list:
        report: list = []
        for i, job in indexed:
            if isinstance(job, Pending):
                self.send("value", job._key, job._outcome_bytes())
                continue
            try:
                _save(job, self.dpi)
            except DependencyFailed:
                report.append((i, "skipped", None))
                continue
            except BaseException as exc:
                text = "".join(traceback.format_exception(exc))
                report.append((i, _portable(exc), text))
                break
            report.append((i, None, None))
        return report


@dataclass
class _Child:
    """A worker process as the caller sees it: its pipes and files, and the work it
    has not reported on yet (by work number)."""

    writer: FigureWriter
    pid: int
    report_fd: int
    command_fd: int | None
    inbox: object
    outbox: object
    work: dict[int, list] = field(default_factory=dict)
    values: dict = field(default_factory=dict)
    offset: int = 0
    numbers: itertools.count = field(default_factory=lambda: itertools.count(1))
    ended: bool = False

    @property
    def idle(self) -> bool:
        return not self.work and self.command_fd is not None and not self.ended

    def send(self, work: list, parallel: int) -> bool:
        """Hand ``work`` (pickled) to this worker; False when that is not possible."""
        if self.command_fd is None or self.ended:
            return False
        try:
            data = pickle.dumps(work, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:
            return False
        number = next(self.numbers)
        try:
            _append(self.inbox.fileno(), data, self.offset)
            _send_message(self.command_fd, ("work", number, self.offset, len(data), parallel))
        except OSError:
            return False
        self.offset += len(data)
        self.handed(number, work)
        return True

    def handed(self, number: int, work: list) -> None:
        self.work[number] = work
        for job in work:
            if isinstance(job, Pending):
                self.values[job._key] = job
                job._source = self

    def close(self) -> None:
        """No more work: the worker ends once it has done what it has."""
        if self.command_fd is not None:
            os.close(self.command_fd)
            self.command_fd = None

    def poll(self, block: bool) -> bool:
        """Take one message (waiting for it with ``block``); False when none came."""
        if self.ended:
            return False
        if not block:
            ready, _, _ = select.select([self.report_fd], [], [], 0)
            if not ready:
                return False
        message = _receive_message(self.report_fd)
        if message is None:
            self.end()
            return False
        kind, ident, offset, size = message
        data = _pread(self.outbox.fileno(), size, offset) if size else b""
        if kind == "value":
            pending = self.values.pop(ident, None)
            if pending is not None:
                self.accept(pending, data)
        else:
            self.writer._take_report(self, self.work.pop(ident, []), data)
        return True

    @staticmethod
    def accept(pending: Pending, data: bytes) -> None:
        try:
            outcome = pickle.loads(data) if data else None
        except Exception:
            outcome = None
        if isinstance(outcome, tuple) and outcome[0] == "value":
            pending._take(outcome)
        elif isinstance(outcome, tuple) and outcome[0] == "error":
            pending._take(outcome[:2], outcome[2])
        # else: the worker could not pickle it; get() computes it here.
        pending._source = None

    def wait_for(self, pending: Pending) -> None:
        while not pending._done and pending._key in self.values and self.poll(block=True):
            pass
        pending._source = None

    def end(self) -> None:
        """The worker is gone: reap it; what it did not report on is lost."""
        self.ended = True
        self.close()
        try:
            os.close(self.report_fd)
        except OSError:  # pragma: no cover
            pass
        try:
            os.waitpid(self.pid, 0)
        except ChildProcessError:  # pragma: no cover - reaped elsewhere
            pass
        for f in (self.inbox, self.outbox):
            f.close()
        for pending in self.values.values():
            pending._source = None  # computed here when asked for
        self.values.clear()
        for number in list(self.work):
            self.writer._take_report(self, self.work.pop(number), b"")


class FigureWriter:
    """Writes figures as PNG files, in worker processes where it can.

    Add figures with :meth:`add` (and values they need with :meth:`compute`);
    :meth:`start` hands what was added so far to a worker (call it before the
    caller's own long work); :meth:`finish` hands the rest to the workers (or shares
    it between new workers and this process), waits for the workers and returns the
    files written.  :meth:`warm_up` starts a worker early.  Used as a context
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
        self._queue: list = []
        self._children: list[_Child] = []
        self._pendings: list[Pending] = []
        self._frozen = False
        self._fallback = True  # render here what a dead worker did not report on

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
        self._pendings.append(pending)
        self._queue.append(pending)
        return pending

    def _can_fork(self) -> bool:
        return self.workers > len(self._children) and _single_threaded()

    def can_start(self) -> bool:
        """True when :meth:`start` would hand work to a worker now."""
        self._collect(block=False)
        return bool(self._serving()) or self._can_fork()

    def warm_up(self, prepare: Callable | None = None) -> bool:
        """Start a worker now, before the work that needs it exists: it takes what
        is queued (a value to compute at once, say), then runs ``prepare()``
        (imports, set-up) and then takes the work that :meth:`start` and
        :meth:`finish` send it (pickled).  False when a worker is there already or
        none can start."""
        if self._children or not self._can_fork():
            return False
        work, self._queue = self._queue, []
        return self._fork(work, warm=prepare)

    def start(self) -> None:
        """Hand what is queued to a worker now: to a waiting worker (pickled), else
        to new workers, else to a busy worker, which takes it next (none at all:
        it waits).

        Queued values (:meth:`compute`) go with every figure queued so far to one
        worker, so that the figures find the values they need there.
        """
        # A value computed here meanwhile needs no worker.
        self._queue = [j for j in self._queue if not (isinstance(j, Pending) and j._done)]
        if not self._queue:
            return
        self._collect(block=False)
        idle = self._idle()
        if idle is not None and idle.send(self._queue, 1):
            self._queue = []
            return
        if not self._can_fork():
            for child in self._serving():
                if child.send(self._queue, 1):
                    self._queue = []
                    return
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

        The queued figures go to a worker that is still there (drawn side by side
        in it and forks of it); without one they are shared between new workers and
        this process (which takes the last share).  The workers are waited for; a
        figure a worker could not report on (it died) is rendered here.

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
            if self._queue:
                # This process only waits from now on: a worker and its forks draw
                # on every core.
                parallel = min(len(self._queue), self.workers + 1)
                for child in sorted(self._serving(), key=lambda c: not c.idle):
                    if child.send(self._queue, parallel):
                        self._queue = []
                        break
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
        for child in self._children:
            child.close()
        self._collect(block=True)
        self._release()
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
            child.close()
            try:
                os.kill(child.pid, signal.SIGTERM)
            except OSError:  # pragma: no cover - already gone
                pass
        self._queue = []
        self._collect(block=True, fallback=False)
        self._release()

    # -- internals --------------------------------------------------------------------

    def _serving(self) -> list[_Child]:
        return [c for c in self._children if c.command_fd is not None and not c.ended]

    def _idle(self) -> _Child | None:
        return next((c for c in self._children if c.idle), None)

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

    def _release(self) -> None:
        if self._frozen:
            import gc

            gc.unfreeze()
            self._frozen = False
        for pending in self._pendings:
            _PENDING.pop(pending._key, None)

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

    def _fork(self, work: list, warm: Callable | None = None) -> bool:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # pragma: no cover - a closed or odd stream
                pass
        self._freeze()
        report_read, report_write = os.pipe()
        command_read, command_write = os.pipe()
        inbox, outbox = tempfile.TemporaryFile(), tempfile.TemporaryFile()
        try:
            pid = os.fork()
        except OSError:
            for fd in (report_read, report_write, command_read, command_write):
                os.close(fd)
            inbox.close()
            outbox.close()
            self._queue.extend(job for job in work if not isinstance(job, Pending))
            return False  # the values read as lost: computed here
        if pid == 0:  # pragma: no cover - the worker
            os.close(report_read)
            os.close(command_write)
            for child in self._children:  # the pipes of the other workers
                for fd in (child.report_fd, child.command_fd):
                    if fd is not None:
                        os.close(fd)
            _Worker(self.dpi, report_write, command_read, inbox, outbox).serve(work, warm)
        os.close(report_write)
        os.close(command_read)
        child = _Child(self, pid, report_read, command_write, inbox, outbox)
        if work:
            child.handed(0, work)
        self._children.append(child)
        return True

    def _collect(self, *, block: bool, fallback: bool = True) -> None:
        """Take the workers' messages (all of them, to their end, with ``block``)."""
        self._fallback = fallback
        for child in self._children:
            while child.poll(block=block):
                pass
            if block and not child.ended:  # pragma: no cover - poll ends it at EOF
                child.end()
        self._children = [c for c in self._children if not c.ended]
        self._fallback = True

    def _take_report(self, child: _Child, work: list, data: bytes) -> None:
        """Mark the figures of ``work`` written, skipped or failed; render here those
        the worker did not report on (it died) unless the writer is stopping."""
        try:
            report = pickle.loads(data) if data else None
        except Exception:
            report = None
        figures = [job for job in work if not isinstance(job, Pending)]
        if not isinstance(report, list):
            lost = figures
        else:
            reported = set()
            failed = False
            for i, error, text in report:
                job = work[i]
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
            lost = [] if failed else [job for job in figures if id(job) not in reported]
        if lost and self._fallback:
            self._render_here(lost)

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
