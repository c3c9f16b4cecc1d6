"""Compiling the numba kernels ahead of use: ``stiction warm-up``, and once per node
before a scan starts its workers.

A fresh installation has an empty numba cache (:mod:`stictiondiag.core.jit`), and
compiling every kernel takes 12-30 s of CPU.  :func:`warm_up` runs the package's
numerical paths once on small simulated loops, so each kernel is compiled (or loaded,
if cached) with the argument types real use gives it, and written to the cache
every later process reads.  The work:

1. the open-loop valve models (Choudhury et al. 2005, Section 5.1; Kano et al. 2004;
   He et al.'s and the band-hold stick models; the physical valve of Section 4,
   Eqs. 1-2);
2. the closed loops of Section 4 (Eq. 3, Table 3) with the data-driven and the
   physical valve, and a generated benchmark case;
3. :func:`stictiondiag.analysis.analyze` with the gap diagnosis on a sticky loop with
   valve position recorded and on the same loop without it, with one thread per
   kernel (a scan's workers) and, without mv, with two (``stiction analyze``).

:func:`warm_cache_once` is what a scan calls before it starts its worker processes:
if the cache is cold (:func:`stictiondiag.core.jit.cache_is_cold`) it warms it in the
calling process,
so the kernels are compiled once on the machine rather than once in every worker.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

# Importing the analysis loads every kernel a scan's worker runs: warm_cache_once
# checks each of them for a cold cache.
from stictiondiag.analysis import analyze
from stictiondiag.core import jit
from stictiondiag.io.tags import Tags
from stictiondiag.models.loops import simulate_paper_loop
from stictiondiag.models.physical import PhysicalValve, karnopp
from stictiondiag.models.stick_models import stick_model
from stictiondiag.models.synthetic import generate_case
from stictiondiag.models.valve import choudhury_model, kano_model
from stictiondiag.stiction.hammerstein.kernels import THREADS_VARIABLE

__all__ = ["WarmUp", "warm_cache_once", "warm_up"]

#: Length of the simulated records [s] at the paper loops' 0.1 s sample time: about
#: ten limit cycles of the level loop with S = 5 %, J = 2 %, enough for every step
#: of the analysis (oscillation, fits, replay, gap) to run.
_DURATION_S = 400.0


@dataclass(frozen=True)
class WarmUp:
    """What :func:`warm_up` did.

    Attributes
    ----------
    compiled : tuple of str
        Kernels compiled by this call (``module.function``), in order.
    kernels : int
        Cached kernels of the package known after the run [count].
    not_cached : tuple of str
        Kernels still missing from the cache after the run: the warm-up did not reach
        them, and they compile at their first use.
    seconds : float
        Wall time of the warm-up [s].
    """

    compiled: tuple[str, ...]
    kernels: int
    not_cached: tuple[str, ...]
    seconds: float


def _valve_models() -> None:
    op = 50.0 + 20.0 * np.sin(np.linspace(0.0, 20.0, 400))
    choudhury_model(op, 5.0, 2.0, ewma_lambda=0.5, characteristic="equal_percentage")
    kano_model(op, 5.0, 2.0)
    stick_model(op, 5.0, 2.0, model="he")  # the band-hold valve runs the same kernel
    karnopp(op, PhysicalValve(), 0.1)


def _closed_loops() -> None:
    for valve in ("choudhury", "kano", "physical"):
        simulate_paper_loop("level", 5.0, 2.0, valve=valve, duration=_DURATION_S)
    generate_case("none", 0, n_samples=2000)
    generate_case("none", 1, n_samples=2000, physical=True)


@contextlib.contextmanager
def _kernel_threads(n: int) -> Iterator[None]:
    """The batch kernels may use ``n`` threads in this block, as in ``stiction
    analyze`` (their threaded variants compile too); the environment is restored."""
    before = os.environ.get(THREADS_VARIABLE)
    os.environ[THREADS_VARIABLE] = str(n)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(THREADS_VARIABLE, None)
        else:
            os.environ[THREADS_VARIABLE] = before


def _analyses() -> None:
    sim = simulate_paper_loop("level", 5.0, 2.0, duration=_DURATION_S, noise_std=0.05)
    for mv in (sim.mv, None):
        tags = Tags.from_arrays(sim.pv, sim.op, mv=mv, ts=sim.dt, loop_type="level")
        analyze(tags)  # one thread per kernel, as in a scan's workers
    with _kernel_threads(2):
        analyze(Tags.from_arrays(sim.pv, sim.op, ts=sim.dt, loop_type="level"))


#: The steps of :func:`warm_up`: (what, function).
STEPS: tuple[tuple[str, Callable[[], None]], ...] = (
    ("valve models", _valve_models),
    ("closed-loop simulations", _closed_loops),
    ("analysis with and without mv, gap diagnosis", _analyses),
)


def warm_up(progress: Callable[[str], None] | None = None) -> WarmUp:
    """Compile (or load from the cache) every kernel the package's main paths use.

    ``progress(line)`` is called at the start of each step and as each kernel starts
    compiling (nothing is reported for a kernel loaded from the cache).
    """
    say = progress or (lambda line: None)
    compiled: list[str] = []

    def on_compile(name: str) -> None:
        compiled.append(name)
        say(f"  compiling {name}")

    t0 = time.perf_counter()
    with jit.reporting_compilation(on_compile):
        for i, (what, step) in enumerate(STEPS, start=1):
            say(f"[{i}/{len(STEPS)}] {what} ({time.perf_counter() - t0:.0f} s)")
            step()
    # What the steps left stale is only ever compiled into its callers (jit.forget_stale).
    jit.forget_stale()
    n_kernels = len(jit.kernels())
    not_cached = tuple(jit.cold_kernels())
    return WarmUp(tuple(compiled), n_kernels, not_cached, time.perf_counter() - t0)


def warm_cache_once(progress: Callable[[str], None] | None = None) -> WarmUp | None:
    """Warm the cache in this process if any imported kernel is missing from it.

    Called before worker processes start, so that they load the kernels instead of
    each compiling them (on a cold cache N workers would pay N times 12-30 s of CPU).
    Returns None when the cache was warm (cost: reading one small index file per
    kernel, milliseconds).
    """
    if not jit.cache_is_cold():
        return None
    return warm_up(progress)
