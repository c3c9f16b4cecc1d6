"""Compilation helper: every per-sample kernel is compiled once by numba and cached
on disk (``cache=True``), so a CLI run does not pay for compiling every time.

The cache lives next to the source in ``__pycache__``; where that is not writable
numba falls back to its user-wide cache directory (``NUMBA_CACHE_DIR`` overrides).
Either way every process of one user on one machine reads the same cache, so a
kernel compiled once (by ``stiction warm-up``, by the first analysis, or by the
parent of a scan before it starts its workers) is loaded, not compiled, by every
later process: see :mod:`stictiondiag.apps.warmup` and docs/performance.md,
"First run".

numba checks a cached kernel against its own source file only, so a kernel that
calls or compiles in a kernel of another file would keep stale machine code when
only that file changes (a ``git pull`` in an editable install, an upgrade).  On
import, before any kernel is defined or loaded, this module therefore runs
:func:`stictiondiag.core.kernelcache.guard`: when the package's source (every layer
that may hold a kernel) differs from the one its caches were made from, all of the
package's numba cache files are dropped, and the run recompiles them, as on a fresh
installation (0.6 ms per import when nothing changed).

A cold cache costs 12-30 s of compilation.  The first time a kernel of this package
is compiled in a main process whose stderr is a terminal, one line says so on stderr
(:data:`FIRST_COMPILE_NOTE`); worker processes and captured or redirected output stay
quiet.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import sys
from collections.abc import Callable, Iterator

import numba
from numba.core import event
from numba.core.caching import NullCache
from numba.core.dispatcher import Dispatcher

from stictiondiag.core import kernelcache

# Before any kernel of the package is loaded from the cache (see the docstring).
kernelcache.guard()

#: Decorator for a compiled, cached, GIL-free kernel.
jit = numba.njit(cache=True, nogil=True)

#: Decorator for a per-sample helper compiled into each of its callers: a call per
#: sample would cost more than the helper itself (a state machine's step).
inline = numba.njit(inline="always", cache=True, nogil=True)

#: Printed once on stderr before the first compilation (see the module docstring).
FIRST_COMPILE_NOTE = (
    "stiction: compiling numba kernels (first run only; 'stiction warm-up' does it ahead)..."
)

_PACKAGE = __name__.split(".")[0]


def kernel_name(dispatcher: Dispatcher) -> str:
    """``module.function`` of a compiled kernel."""
    func = dispatcher.py_func
    return f"{func.__module__}.{func.__qualname__}"


def _ours(dispatcher: object) -> bool:
    return isinstance(dispatcher, Dispatcher) and kernel_name(dispatcher).startswith(_PACKAGE + ".")


def kernels() -> list[Dispatcher]:
    """The cached kernels of this package in the modules imported so far.

    Kernels marked ``inline="always"`` are left out: they are compiled into their
    callers and never on their own.
    """
    found: dict[int, Dispatcher] = {}
    for name, module in list(sys.modules.items()):
        if module is None or not (name == _PACKAGE or name.startswith(_PACKAGE + ".")):
            continue
        for obj in list(vars(module).values()):
            if (
                _ours(obj)
                and not isinstance(getattr(obj, "_cache", None), (NullCache, type(None)))
                and obj.targetoptions.get("inline", "never") != "always"
            ):
                found[id(obj)] = obj
    return sorted(found.values(), key=kernel_name)


def on_disk(dispatcher: Dispatcher) -> bool:
    """Whether the on-disk cache holds a compiled version of ``dispatcher`` for its
    current source (an edited source file makes its old entries stale).

    Reads numba's cache index; if that cannot be read the answer is True, so a
    caller that would compile ahead does nothing rather than compile every time.
    """
    try:
        return bool(dispatcher._cache._cache_file._load_index())  # type: ignore[attr-defined]
    except Exception:  # a numba whose cache internals differ
        return True


def ever_cached(dispatcher: Dispatcher) -> bool:
    """Whether numba's cache has an index for ``dispatcher`` at all (fresh or stale).

    False for a kernel never compiled with this cache: on a fresh installation, or
    a kernel that nothing calls."""
    try:
        return os.path.exists(dispatcher._cache._cache_file._index_path)  # type: ignore[attr-defined]
    except Exception:  # a numba whose cache internals differ
        return True


def forget_stale() -> list[str]:
    """Remove the cache index of every kernel that is stale after a warm-up; their names.

    A kernel called only from other kernels is compiled into its callers and is not
    cached on its own.  If an earlier version of the package cached it, that index
    stays stale for good, and :func:`cache_is_cold` would answer "cold" on every run
    after an upgrade (each command compiling again).  Without the index the kernel
    counts as never cached, as on a fresh installation.  Only this package's kernels'
    index files are touched; numba rewrites them whenever it caches the kernel.
    """
    removed = []
    for d in kernels():
        if ever_cached(d) and not on_disk(d):
            try:
                os.remove(d._cache._cache_file._index_path)  # type: ignore[attr-defined]
            except Exception:  # noqa: S112  (gone already, or cache internals differ)
                continue
            removed.append(kernel_name(d))
    return removed


def cold_kernels() -> list[str]:
    """Names of the imported kernels (:func:`kernels`) that would be compiled, not
    loaded, at their first call in a new process."""
    return [kernel_name(d) for d in kernels() if not on_disk(d)]


def cache_is_cold() -> bool:
    """Whether the imported kernels need compiling: none was ever cached (a fresh
    installation), or one that was is stale (its source changed since).

    A kernel never cached while others are does not count: nothing may call it,
    and it would make every check answer "cold"."""
    found = kernels()
    cached = [d for d in found if ever_cached(d)]
    if not cached:
        return bool(found)
    return not all(on_disk(d) for d in cached)


class _CompileListener(event.Listener):
    """Calls ``callback(name)`` when numba starts compiling a kernel of this package
    (a cache miss; a kernel loaded from the disk cache is not reported)."""

    def __init__(self, callback: Callable[[str], None]):
        self.callback = callback

    def on_start(self, ev) -> None:
        dispatcher = ev.data["dispatcher"]
        if _ours(dispatcher):
            self.callback(kernel_name(dispatcher))

    def on_end(self, ev) -> None:
        pass


@contextlib.contextmanager
def reporting_compilation(callback: Callable[[str], None]) -> Iterator[None]:
    """Inside this block ``callback(name)`` is called as each kernel starts compiling."""
    with event.install_listener("numba:compile", _CompileListener(callback)):
        yield


def _note_first_compile(name: str) -> None:
    """Print :data:`FIRST_COMPILE_NOTE` once, from a main process on a terminal."""
    if _note_first_compile.done:  # type: ignore[attr-defined]
        return
    _note_first_compile.done = True  # type: ignore[attr-defined]
    stream = sys.stderr
    if multiprocessing.parent_process() is None and stream is not None and stream.isatty():
        print(FIRST_COMPILE_NOTE, file=stream, flush=True)


_note_first_compile.done = False  # type: ignore[attr-defined]
event.register("numba:compile", _CompileListener(_note_first_compile))
