"""The search of the Hammerstein fit: coarse grid, zooms, polish, and the linear valve.

The steps of :func:`stictiondiag.stiction.hammerstein.fit_hammerstein` (see its Notes):
a coarse search over the valve variants of Fig. 10 of Choudhury, Thornhill & Shah
(2005) and Kano's, start offsets, process time constants and dead times
(:func:`coarse_search`); grids and zooms around the best (:func:`refine`); a
Nelder-Mead polish (:func:`polish`); and the same search for a linear valve
(:func:`fit_linear`).  Every cost is a least-squares cost of
:class:`stictiondiag.stiction.hammerstein.kernels.Problem`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stictiondiag.stiction.hammerstein.kernels import Problem
from stictiondiag.stiction.valvefit import ValveVariant, valve_variants

#: Starting states tried: the valve is started stuck at the first extreme of op, its
#: stop point this far back from the extreme, in cycle travels of op (see
#: :func:`stictiondiag.stiction.hammerstein.first_extreme`).  With a noisy op a sticky valve sticks again right after
#: every slip, so the point it stopped at is not the extreme of op, and a model
#: started from the wrong point stays out of step with the valve.
START_OFFSETS = (0.0, 0.01, 0.03, 0.1, 0.2, 0.4)

#: Half-cycles whose residual energy exceeds this many times the median are left out
#: of the fit (set-point moves and load steps the model cannot know).
OUTLIER_FACTOR = 8.0

#: Cost evaluations of the final Nelder-Mead polish.
POLISH_EVALUATIONS = 150


@dataclass(frozen=True)
class FitSetup:
    """Time scales, start and least-squares problem of one fit.

    Attributes
    ----------
    problem : Problem
        The least-squares problem; the search changes its delays, time constants and
        rows kept as it goes.
    structure : str
        ``"self-regulating"`` or ``"integrating"``.
    period : int
        Cycle period [samples].
    x : ndarray
        op, centred, in cycle travels of op [-].
    stride : int
        Row stride of the regression [samples].
    d_max : int
        Longest dead time searched [samples].
    coarse_delays : ndarray
        Dead times of the coarse grid [samples].
    taus : ndarray
        Process time constants of the coarse grid [samples].
    scale : float
        Cycle travel of op [units of op]: S and J are searched in units of it.
    noise_var : float
        Variance of white measurement noise on pv in the target's units [-].
    S_max : float
        Search limit of S and J [cycle travels of op].
    pv_unit : float
        pv units per unit of the target (pv's standard deviation; for an
        integrating loop times that of its lagged increments) [units of pv].
    """

    problem: Problem
    structure: str
    period: int
    x: np.ndarray = field(repr=False)
    stride: int
    d_max: int
    coarse_delays: np.ndarray = field(repr=False)
    taus: np.ndarray = field(repr=False)
    scale: float
    noise_var: float
    S_max: float
    pv_unit: float = 1.0


def grid(S_lo, S_hi, J_lo, J_hi, n):
    Sg = np.linspace(S_lo, S_hi, n)
    Jg = np.linspace(J_lo, J_hi, n)
    SS, JJ = np.meshgrid(Sg, Jg, indexing="ij")
    return SS.ravel(), JJ.ravel(), Sg[1] - Sg[0], Jg[1] - Jg[0]


def ordinary_blocks(resid: np.ndarray, block: int) -> np.ndarray:
    """Rows to keep: those outside blocks whose residual energy exceeds
    :data:`OUTLIER_FACTOR` times the median block energy.  Keeps everything when that
    would leave out more than 10 % of the rows: set-point moves and load steps are
    isolated events, a misfit spread over many blocks is the model's own."""
    n = resid.size
    nb = max(1, n // block)
    e = np.array([np.sum(resid[i * block : (i + 1) * block] ** 2) for i in range(nb)])
    keep = np.ones(n, dtype=bool)
    med = float(np.median(e))
    if not med > 0:
        return keep
    for i in np.flatnonzero(e > OUTLIER_FACTOR * med):
        keep[i * block : n if i == nb - 1 else (i + 1) * block] = False
    return keep if keep.mean() >= 0.9 else np.ones(n, dtype=bool)


def delay_window(d_best: int, d_max: int, half: int, most: int) -> np.ndarray:
    """Dead times within ``half`` of ``d_best`` (at most ``most``, evenly spread)."""
    d = np.arange(max(1, d_best - half), min(d_max, d_best + half) + 1, dtype=np.int64)
    if d.size > most:
        d = np.unique(np.round(np.linspace(d[0], d[-1], most)).astype(np.int64))
    return d


@dataclass(frozen=True)
class Start:
    """What the coarse search (step 1) picks; S, J in cycle travels, times in samples."""

    variant: ValveVariant
    delay: int
    offset: float
    tau: float
    S: float
    J: float
    coarse_costs: dict
    n_eval: int


def coarse_search(setup: FitSetup) -> Start:
    """Step 1: valve variant, start offset, process time constant and dead time on a
    coarse grid."""
    prob, S_max = setup.problem, setup.S_max
    J_max = S_max
    offsets_all = np.array(START_OFFSETS)
    SS, JJ, _, _ = grid(0.0, S_max, 0.0, J_max, 9)
    variants = {v.name: v for v in valve_variants(setup.x)}
    if any(v.play_width > 0 for v in variants.values()):
        # On a noisy op the published flowchart re-arms at every noise reversal and
        # never slips, and behind the play operator it differs from Kano's variant
        # only in rare partial reversals: not worth their evaluations.
        variants.pop("choudhury")
        variants.pop("choudhury+play")
    # 1a. Every variant and start offset on the coarse grid, with three process time
    #     constants and every second regression row.
    prob1 = prob.coarser(np.geomspace(prob.taus[0], prob.taus[-1], 3), 2 * prob.stride)
    coarse = {name: prob1.cost(SS, JJ, v, offsets_all) for name, v in variants.items()}
    n_eval = len(coarse) * SS.size * offsets_all.size
    # 1b. The five best cells of each variant with every time constant.
    prob1.taus = prob.taus
    best1: tuple[float, str, int, float, float, float, float]
    best1 = (np.inf, next(iter(variants)), 0, 0.0, 0.0, 0.0, 0.0)
    for name, (c1, _, o1, _) in coarse.items():
        top = np.argsort(c1)[:5]
        for k in top:
            c, d, o, t = prob1.cost(SS[k], JJ[k], variants[name], o1[k])
            n_eval += 1
            if c[0] < best1[0]:
                best1 = (float(c[0]), name, int(d[0]), float(o[0]), float(t[0]), SS[k], JJ[k])
    _, model, d_best, off_best, tau_best, S1, J1 = best1
    return Start(
        variant=variants[model],
        delay=d_best,
        offset=off_best,
        tau=tau_best,
        S=S1,
        J=J1,
        coarse_costs={k: float(v[0].min()) for k, v in coarse.items()},
        n_eval=n_eval,
    )


def leave_out_misfits(setup: FitSetup, start: Start) -> int:
    """Leave out the half-cycles the coarse model cannot explain at all (set-point
    moves, load steps at the process input); returns the number of rows left out."""
    prob = setup.problem
    resid1, *_ = prob.residual(
        start.S, start.J, start.variant, start.delay, start.offset, start.tau
    )
    keep = ordinary_blocks(resid1, max(2, setup.period // (2 * setup.stride)))
    n_left_out = int(keep.size - keep.sum())
    if n_left_out:
        prob.set_keep(keep)
    return n_left_out


class Search:
    """The (S, J) points evaluated in steps 2 to 4, with the best dead time, start
    offset and time constant of each; S, J in cycle travels of op."""

    def __init__(self, setup: FitSetup, variant: ValveVariant, offsets: np.ndarray, n_eval: int):
        self.prob, self.variant, self.offsets = setup.problem, variant, offsets
        self.S_max = self.J_max = setup.S_max
        self.pts: dict[str, list] = {k: [] for k in "SJCDOT"}
        self.n_eval = n_eval

    def evaluate(self, S_arr, J_arr):
        c, bd, bo, bt = self.prob.cost(S_arr, J_arr, self.variant, self.offsets)
        for k, v in zip("SJCDOT", (S_arr, J_arr, c, bd, bo, bt), strict=True):
            self.pts[k].append(v)
        self.n_eval += S_arr.size * self.offsets.size
        return c

    def zoom(self, sb, jb, ds, dj, levels):
        for _ in range(levels):
            Sz, Jz, zs, zj = grid(
                max(0.0, sb - ds),
                min(self.S_max, sb + ds),
                max(0.0, jb - dj),
                min(self.J_max, jb + dj),
                7,
            )
            c = self.evaluate(Sz, Jz)
            k = int(np.argmin(c))
            sb, jb = Sz[k], Jz[k]
            ds, dj = 2 * zs, 2 * zj

    def arrays(self):
        """S, J, cost, dead time, start offset and time constant of every point."""
        return tuple(np.concatenate(self.pts[k]) for k in "SJCDOT")

    def best(self):
        """S, J, dead time and time constant of the best point."""
        k = int(np.argmin(np.concatenate(self.pts["C"])))
        return tuple(np.concatenate(self.pts[key])[k] for key in "SJDT")

    def best_offset(self) -> float:
        k = int(np.argmin(np.concatenate(self.pts["C"])))
        return float(np.concatenate(self.pts["O"])[k])


def refine(setup: FitSetup, search: Search, start: Start) -> tuple[float, float]:
    """Steps 2 and 3: grids and zooms with time constants and dead times near the
    best; returns the step-2 grid spacings of S and J."""
    prob, d_max = setup.problem, setup.d_max
    # 2. Time constants and dead times near the best ones; grid and zooms.
    delays = delay_window(start.delay, d_max, max(3, start.delay // 2), 9)
    prob.taus = start.tau * np.array([0.5, 0.75, 1.0, 1.33, 2.0])
    prob.set_delays(delays)
    SS, JJ, step_s, step_j = grid(0.0, setup.S_max, 0.0, setup.S_max, 11)
    c = search.evaluate(SS, JJ)
    for k in np.argsort(c)[:3]:
        search.zoom(SS[k], JJ[k], 2 * step_s, 2 * step_j, 2)

    # 3. Dead time at one-sample resolution and a finer time constant near the best
    #    pair, then zoom again.
    sb, jb, d_best, tau_best = search.best()
    spacing = int(np.max(np.diff(delays))) if delays.size > 1 else 1
    prob.set_delays(delay_window(int(d_best), d_max, max(2, spacing), 9))
    prob.taus = float(tau_best) * np.array([0.9, 1.0, 1.11])
    search.zoom(sb, jb, 2 * step_s / 3, 2 * step_j / 3, 2)
    return step_s, step_j


def polish(setup: FitSetup, search: Search, step_s, step_j) -> tuple[float, float]:
    """Step 4: Nelder-Mead over S, J and the time constant (continuous), the dead time
    free within two samples of the best and the start offset fixed.  Returns the
    range of time constants allowed [samples]."""
    from scipy.optimize import minimize

    prob, S_max = setup.problem, setup.S_max
    sb, jb, d_best, tau_best = search.best()
    search.offsets = np.array([search.best_offset()])
    prob.set_delays(delay_window(int(d_best), setup.d_max, 2, 5))

    # The time constant stays inside the structure's range (TAU_PERIODS, or where
    # the grids of steps 2 and 3 took it): outside it the basis is no longer the
    # structure's process, and an unbounded polish found lags of hundreds of cycles, integrators
    # through which a deadband imitates a load on pv that op does not drive.
    tau_lo = min(float(setup.taus.min()), float(tau_best))
    tau_hi = max(float(setup.taus.max()), float(tau_best))

    def objective(v):
        S_v, J_v = min(max(v[0], 0.0), S_max), min(max(v[1], 0.0), S_max)
        prob.taus = np.array([min(max(float(tau_best) * math.exp(v[2]), tau_lo), tau_hi)])
        return float(search.evaluate(np.array([S_v]), np.array([J_v]))[0])

    zs = 2 * step_s / 27
    zj = 2 * step_j / 27
    simplex = np.array([[sb, jb, 0.0], [sb + zs, jb, 0.0], [sb, jb + zj, 0.0], [sb, jb, 0.05]])
    minimize(
        objective,
        simplex[0],
        method="Nelder-Mead",
        options={"initial_simplex": simplex, "maxfev": POLISH_EVALUATIONS, "xatol": 1e-4},
    )
    return tau_lo, tau_hi


def fit_linear(setup: FitSetup, tau, tau_range) -> tuple[float, int, float]:
    """The linear valve's best cost, dead time [samples] and time constant [samples].

    It gets every time constant and dead time searched, the stiction fit's own, and
    the same continuous polish of the time constant, so it is not handicapped: the
    improvement compares the two valves, not two searches.
    """
    from scipy.optimize import minimize_scalar

    prob = setup.problem
    tau_lo, tau_hi = tau_range
    linear = ValveVariant("linear", False)
    prob.set_delays(np.union1d(setup.coarse_delays, prob.delays))
    prob.taus = np.union1d(setup.taus, [tau])
    lin_c, lin_d, _, lin_t = prob.cost(0.0, 0.0, linear, 0.0)
    lin_best = (float(lin_c[0]), int(lin_d[0]), float(lin_t[0]))

    def lin_objective(log_tau):
        nonlocal lin_best
        prob.taus = np.array([math.exp(log_tau)])
        c_l, d_l, _, t_l = prob.cost(0.0, 0.0, linear, 0.0)
        if c_l[0] < lin_best[0]:
            lin_best = (float(c_l[0]), int(d_l[0]), float(t_l[0]))
        return float(c_l[0])

    lt0 = math.log(lin_best[2])
    minimize_scalar(
        lin_objective,
        bounds=(
            max(lt0 - math.log(3.0), math.log(tau_lo)),
            min(lt0 + math.log(3.0), math.log(tau_hi)),
        ),
        method="bounded",
        options={"maxiter": 30, "xatol": 0.01},
    )
    return lin_best
