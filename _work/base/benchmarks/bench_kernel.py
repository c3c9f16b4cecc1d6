"""Speed of the public valve models against a plain numba kernel of the same flowchart.

    python benchmarks/bench_kernel.py [--n 1000000] [--repeat 15]

The reference below is the Fig. 10 flowchart of Choudhury, Thornhill & Shah (2005),
Section 5.1, written the way one would by hand for numba: one function, the state in
local variables, the input saturated to [0, 100] % inside the loop.  The public
``choudhury_model`` / ``kano_model`` are timed through their Python entry points
(argument checks, saturation and output characteristic included), on the same input
in the same process, thread CPU time, best of ``--repeat`` alternated runs after a warm-up call (compilation is
excluded).  The outputs are checked equal before timing.  The ratio printed is the
reference's time over the public function's (1.0 = as fast; the target is >= 0.9).
Results are in docs/performance.md, section "Kernels".
"""

from __future__ import annotations

import argparse
import platform
import time

import numba
import numpy as np

from stictiondiag.models.valve import choudhury_model, kano_model


@numba.njit(nogil=True)
def _sgn(v):
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


@numba.njit(nogil=True)
def reference_choudhury(op, S, J):
    """Fig. 10 by hand: saturate, detect stops and reversals, stick, slip (Eq. 4)."""
    n = op.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    x0 = min(max(op[0], 0.0), 100.0)
    y, xss, xprev, vold, dirn, stuck = x0, x0, x0, 0.0, 0.0, True
    out[0] = y
    half = (S - J) / 2.0
    for k in range(1, n):
        x = min(max(op[k], 0.0), 100.0)
        v = _sgn(x - xprev)
        if (v != vold and v != 0.0 and vold != 0.0) or (v == 0.0 and vold == 0.0 and not stuck):
            stuck = True
            xss = xprev
        if stuck:
            d = _sgn(x - xss)
            if d != 0.0:
                thr = S if (dirn == 0.0 or d != dirn) else J
                if abs(x - xss) > thr:
                    stuck = False
                    dirn = d
                    y = x - d * half
        elif v != 0.0:
            dirn = v
            y = x - v * half
        vold = v
        xprev = x
        out[k] = min(max(y, 0.0), 100.0)
    return out


@numba.njit(nogil=True)
def reference_kano(op, S, J):
    """Kano et al. (2004) by hand, same conventions as :func:`reference_choudhury`."""
    n = op.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    x0 = min(max(op[0], 0.0), 100.0)
    y, xss, xprev, dirn, stuck = x0, x0, x0, 0.0, True
    out[0] = y
    half = (S - J) / 2.0
    for k in range(1, n):
        x = min(max(op[k], 0.0), 100.0)
        v = _sgn(x - xprev)
        if not stuck:
            if v == 0.0 or (dirn != 0.0 and v != dirn):
                stuck = True
                xss = xprev
            else:
                dirn = v
                y = x - v * half
        if stuck:
            d = _sgn(x - xss)
            if d != 0.0:
                thr = S if (dirn == 0.0 or d != dirn) else J
                if abs(x - xss) > thr:
                    stuck = False
                    dirn = d
                    y = x - d * half
        xprev = x
        out[k] = min(max(y, 0.0), 100.0)
    return out


def best_of_interleaved(a, b, repeat: int) -> tuple[float, float]:
    """Shortest CPU times [s] of this thread over ``repeat`` calls of ``a`` and of
    ``b``, alternated so that a burst of load from other processes falls on both
    alike.  CPU time, not wall time: on a shared machine the wall time of a call
    holds the time other processes had the core."""
    ta, tb = [], []
    for _ in range(repeat):
        for fn, times in ((a, ta), (b, tb)):
            t0 = time.thread_time()
            fn()
            times.append(time.thread_time() - t0)
    return min(ta), min(tb)


def test_signal(n: int, seed: int = 0) -> np.ndarray:
    """Valve demand [%]: a slow sinusoid around 50 % that saturates at both ends,
    with noise and flat runs (stops), so every branch of the flowchart is taken."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    op = 50.0 + 60.0 * np.sin(2 * np.pi * t / 5000.0) + rng.normal(0.0, 0.5, n)
    hold = rng.random(n) < 0.05
    op[1:][hold[1:]] = op[:-1][hold[1:]]  # repeated samples: the input stops
    return op


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1_000_000, help="samples")
    parser.add_argument("--repeat", type=int, default=15, help="timed runs, best kept")
    args = parser.parse_args()
    op = test_signal(args.n)
    print(f"machine: {platform.processor() or platform.machine()}, numba {numba.__version__}")
    print(f"n = {args.n:,} samples, best of {args.repeat}")
    print(f"{'model':<10} {'S':>4} {'J':>4} {'public ms':>10} {'reference ms':>13} {'ratio':>6}")
    for name, public, reference in (
        ("choudhury", choudhury_model, reference_choudhury),
        ("kano", kano_model, reference_kano),
    ):
        for S, J in ((5.0, 2.0), (5.0, 7.0)):
            same = np.array_equal(public(op, S, J), reference(op, S, J))
            if not same:
                raise SystemExit(f"{name}: outputs differ from the reference at S={S}, J={J}")
            t_pub, t_ref = best_of_interleaved(
                lambda p=public, S=S, J=J: p(op, S, J),
                lambda r=reference, S=S, J=J: r(op, S, J),
                args.repeat,
            )
            print(
                f"{name:<10} {S:>4.1f} {J:>4.1f} {1e3 * t_pub:>10.1f} {1e3 * t_ref:>13.1f} "
                f"{t_ref / t_pub:>6.2f}"
            )


if __name__ == "__main__":
    main()
