"""Effect ``time_varying_stiction``: S and J changing during the record.

Acts on mv: a step, a ramp between two instants or a drift over the record of the
thresholds of Fig. 10 and Eq. 4 (Choudhury, Thornhill & Shah 2005).  Parameters: the
end values and the instants.  Signature: the slips measured before and after the
change differ (rank test, :func:`stictiondiag.gap.effects.signatures.slips_differ`),
or, where too few are measured on one side to compare, their rate does
(:func:`stictiondiag.gap.effects.signatures.slip_rate_differs`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from stictiondiag.core.serialize import to_plain
from stictiondiag.gap.context import ReplayContext
from stictiondiag.gap.effects.base import (
    BaseFit,
    Effect,
    EffectFit,
    EffectParams,
)
from stictiondiag.gap.effects.kernels import valve_rows
from stictiondiag.gap.effects.search import TVS_STAGES, grid_search_nd, needle_search
from stictiondiag.gap.effects.signatures import (
    SLIP_TEST_P,
    slip_rate_differs,
    slips_comparable,
    slips_differ,
    untested_p,
)
from stictiondiag.gap.effects.valve import (
    ValveLogic,
    ValveProblem,
    base_problem,
    demand_travel,
    logic_name,
    needle_sj,
    pick_problem,
    recorded_mv,
    slip_medians,
    threshold_scale,
    travel_seeds,
)


def change_sides(times: np.ndarray, t1: float, t2: float, n: int) -> tuple:
    """Slips before and after a change of stiction between samples t1 and t2 (masks
    of ``times``): those before t1 and after t2; for a drift over the whole record,
    those in its first and second half.  A change placed at an end of the record
    leaves (almost) no slips on that side: then those before and after the middle of
    the change, so that the fit cannot place a change where the slips cannot test it
    (fewer than three on a side leave the decision to the replay,
    :func:`slips_differ`)."""
    if t1 <= 0.0 and t2 >= n - 1:
        return times < n / 2, times >= n / 2
    early, late = times < t1, times > t2
    if min(int(early.sum()), int(late.sum())) < 3:
        mid = 0.5 * (t1 + t2)
        early, late = times < mid, times >= mid
    return early, late


def _slips_test(
    slips: dict, t1: float, t2: float, n: int, untested: float = 0.0, expect: dict | None = None
) -> float:
    """p-value that the slips differ across a change of stiction between samples t1
    and t2: their sizes by rank (:func:`slips_differ` on :func:`change_sides`); when
    fewer than three are measured before t1 or after t2, also their rate
    (:func:`slip_rate_differs`), the smaller of the two p-values doubled
    (Bonferroni: either test may carry the change).

    ``untested`` (:func:`untested_p`) 1: the change must be shown by the slips
    measured; where too few are measured to compare their sizes, their rate alone
    decides (1 when it cannot be tested either), not the replay alone.  ``expect``:
    the signs of the fitted change of S and J, for a size test in that direction
    (:func:`slips_differ`)."""
    times = slips["time"]
    early, late = change_sides(times, t1, t2, n)
    if untested >= 1.0 and not slips_comparable(slips, early, late):
        return slip_rate_differs(times, t1, t2, n)
    p = slips_differ(slips, early, late, expect=expect)
    drift = t1 <= 0.0 and t2 >= n - 1
    if drift or min(int(np.sum(times < t1)), int(np.sum(times > t2))) >= 3:
        return p
    return min(1.0, 2.0 * min(p, slip_rate_differs(times, t1, t2, n)))


def _profile(n: int, t1: float, t2: float) -> np.ndarray:
    """0 before sample t1, 1 after t2, linear between (a step when t2 <= t1)."""
    k = np.arange(n, dtype=float)
    if t2 <= t1 + 1e-9:
        return (k >= t1).astype(float)
    return np.clip((k - t1) / (t2 - t1), 0.0, 1.0)


@dataclass(frozen=True)
class StictionWindow:
    """S and J fitted on one window of the record on its own.

    Attributes
    ----------
    time_s : float
        Middle of the window [s].
    S, J : float
        Its thresholds [% of span].
    """

    time_s: float
    S: float
    J: float


@dataclass(frozen=True)
class TimeVaryingStictionParams(EffectParams):
    """S and J changing during the record: a step, a ramp or a drift.

    Attributes
    ----------
    S_start, J_start, S_end, J_end : float
        Thresholds before and after the change [% of span].
    change_start_s, change_end_s : float
        When the change starts and ends [s].
    logic : ValveLogic
        The stuck-phase logic replayed.
    slips_differ_p : float
        p-value of the rank test that the slips differ before and after [-].
    windows : tuple of StictionWindow or None
        S and J fitted on windows of the record (None where a window has too few
        slips); empty unless they were fitted (whole-record fit only).
    """

    SIGNATURE = "slips_differ_p"

    S_start: float
    J_start: float
    S_end: float
    J_end: float
    change_start_s: float
    change_end_s: float
    logic: ValveLogic
    slips_differ_p: float
    windows: tuple[StictionWindow | None, ...] = ()

    def to_dict(self) -> dict:
        """The fields by name; ``windows`` only where they were fitted, each a dict."""
        out = to_plain({f.name: getattr(self, f.name) for f in fields(self) if f.name != "windows"})
        if self.windows:
            out["windows"] = [
                None if v is None else to_plain({"time_s": v.time_s, "S": v.S, "J": v.J})
                for v in self.windows
            ]
        return out


def _window_fits(ctx: ReplayContext, w: np.ndarray, base: BaseFit, n_win: int) -> list:
    """S and J fitted on each of ``n_win`` windows of the record on its own.

    Each window is replayed from the data: it starts at the window's first sample
    and is judged from its first measured slip on (the valve state before is
    unknown), so a window costs a fraction of a whole-record replay.
    """
    sig = ctx.sig
    n = sig.n
    travel = demand_travel(sig.op)
    valve = base.recorded_valve()
    mv = recorded_mv(ctx)
    S0, J0 = valve.S, valve.J
    edges = np.linspace(0, n, n_win + 1).astype(int)
    slip_t = ctx.slips["time"] if ctx.slips is not None else np.zeros(0)
    slip_d = ctx.slips["direction"] if ctx.slips is not None else np.zeros(0)
    out: list[tuple[float, float, float, float] | None] = []
    for i in range(n_win):
        a, b = edges[i], edges[i + 1]
        ww = w[a:b].copy()
        inside = (slip_t >= a) & (slip_t < b)
        first = int(slip_t[inside][0]) - a if inside.any() else (b - a) // 10
        ww[: first + 2] = 0.0
        if ww.sum() < 0.25 * (b - a):
            out.append(None)
            continue
        before = slip_d[slip_t < a]
        d0 = float(before[-1]) if before.size else valve.initial_direction
        prob = ValveProblem(
            sig.op[a:b],
            mv[a:b],
            ww,
            ctx.norm["mv"],
            valve.kano,
            d0,
            float(np.median(mv[a : a + 3])),
        )
        seeds = [(S0, J0)]
        med = slip_medians(ctx.slips, inside)
        if med is not None:
            seeds.append(med)
        seeds += travel_seeds(ctx.slips, mask=inside)
        ratios = np.geomspace(1 / 3, 3.0, 13)
        RR, JJ = np.meshgrid(ratios, np.linspace(0.0, 1.5, 7), indexing="ij")
        sc = threshold_scale(S0, J0)
        coarse = np.column_stack([(sc * RR).ravel(), (sc * RR * JJ).ravel()])
        c = prob.costs(valve_rows(coarse[:, 0], coarse[:, 1]))
        seeds += [tuple(coarse[k]) for k in np.argsort(c)[:2]]
        x, _ = needle_sj(prob, seeds, travel, rel=0.15, zooms=1)
        out.append((0.5 * (a + b), float(x[0]), float(x[1]), float(ww.sum())))
    return out


def _profile_of_windows(pts: list, n: int) -> tuple[float, float]:
    """The instants (t1, t2) [samples] of the step or ramp that best matches the S
    and J fitted on windows (``pts``: (centre [samples], S, J) each), by least
    squares over 17 starts and three widths."""
    centers = np.array([p[0] for p in pts])
    vals = np.array([[p[1], p[2]] for p in pts])
    best_shape: tuple[float, float, float] | None = None
    for t1 in np.linspace(0.1, 0.9, 17) * n:
        for width in (0.0, 0.15 * n, 0.3 * n):
            if width > 0:
                h = np.clip((centers - t1) / width, 0.0, 1.0)
            else:
                h = (centers >= t1).astype(float)
            A = np.column_stack([1.0 - h, h])
            coef, *_ = np.linalg.lstsq(A, vals, rcond=None)
            c = float(np.sum((A @ coef - vals) ** 2))
            if best_shape is None or c < best_shape[0]:
                best_shape = (c, t1, t1 + width)
    assert best_shape is not None  # the loops above scored 17 x 3 shapes
    return best_shape[1], best_shape[2]


def _start_of_windows(pts: list, t1: float, t2: float, base_sj: tuple) -> np.ndarray:
    """Start and end S and J [% of span] to search from: the medians of the windows
    before t1 and after t2 (the first and last window when none is), else the base
    valve's S and J (``base_sj``) throughout."""
    early = [p for p in pts if p[0] < t1] or pts[:1]
    late = [p for p in pts if p[0] > t2] or pts[-1:]
    if early and late:
        return np.array(
            [
                np.median([p[1] for p in early]),
                np.median([p[2] for p in early]),
                np.median([p[1] for p in late]),
                np.median([p[2] for p in late]),
            ]
        )
    S0, J0 = base_sj
    return np.array([S0, J0, S0, J0])


def _move_instants(cost, c: float, t1: float, t2: float, n: int) -> tuple[float, float, float]:
    """Move the instants by 2 % of the record at a time while that lowers
    ``cost(t1, t2)`` (at most four rounds); the cost and the instants [samples]."""
    for _ in range(4):
        moved = False
        for d1, d2 in ((-1, -1), (1, 1), (-1, 0), (1, 0), (0, -1), (0, 1)):
            a, b = t1 + d1 * 0.02 * n, t2 + d2 * 0.02 * n
            if a < 0 or b > n - 1 or b < a:
                continue
            cc = cost(a, b)
            if cc < c:
                c, t1, t2, moved = cc, a, b, True
        if not moved:
            break
    return c, t1, t2


def _variant_of(t1: float, t2: float, n: int) -> tuple[str, int]:
    """The form of a change between the instants t1 and t2 [samples] of a record of
    ``n`` samples, and its parameters beyond the base model's: a drift over the whole
    record (S and J at its end), a step (and its instant) or a ramp (and both)."""
    if t1 <= 0.0 and t2 >= n - 1:
        return "drift", 2
    if t2 - t1 < 1.0:
        return "step", 3
    return "ramp", 4


def _changing_rows(S_start, J_start, S_end, J_end):
    """Valve rows (:func:`~stictiondiag.gap.effects.valve.valve_rows`) whose S and J
    change from their start to their end values, the same in both directions."""
    return valve_rows(
        S_start, J_start, S_open_end=S_end, J_open_end=J_end, S_close_end=S_end, J_close_end=J_end
    )


def fit_time_varying_stiction(
    ctx: ReplayContext,
    w: np.ndarray,
    base: BaseFit,
    init: EffectFit[TimeVaryingStictionParams] | None = None,
) -> EffectFit[TimeVaryingStictionParams]:
    """S and J changing during the record: a step, a ramp between two instants, or a drift.

    ``S(t) = S0 + (S1 - S0) h(t)``, the same for J, with ``h`` rising from 0 to 1
    between t1 and t2 (a step when t1 = t2; a drift over the record when t1 = 0 and
    t2 = T).  S and J are first fitted on six windows of the record; the profile
    that best matches those values starts the joint search.
    """
    n = ctx.sig.n
    travel = demand_travel(ctx.sig.op)
    lower, upper = np.zeros(4), np.array([travel, 1.5 * travel] * 2)
    valve = base.recorded_valve()
    prob = base_problem(ctx, w, valve) if init is None else pick_problem(ctx, w, base, init, None)

    def cost_h(h):
        def cost(X, bound):
            return prob.costs(_changing_rows(X[:, 0], X[:, 1], X[:, 2], X[:, 3]), h, bound=bound)

        return cost

    def search(t1, t2, x, rel, zooms):
        cost = cost_h(_profile(n, t1, t2))
        # Start and end values together (coupled through where the valve stops),
        # then each pair finely.
        stages = TVS_STAGES if rel > 0.1 else ((0.02, 5), (0.005, 5))
        x, _ = grid_search_nd(cost, x, (0, 1, 2, 3), stages=stages)
        for pair in ((0, 1), (2, 3)):
            x, c = needle_search(
                cost, x, pair, lower, upper, rel=rel, zooms=zooms, n_grid=11 if rel < 0.1 else 31
            )
        return x, c

    S0, J0 = valve.S, valve.J
    win = []
    if init is not None:
        t1, t2 = (
            init.params.change_start_s / ctx.sig.dt,
            init.params.change_end_s / ctx.sig.dt,
        )
        # Thresholds and instants only: kept from the whole record.
        x = np.array(init.x)
        results = [(0.0, x, t1, t2, prob)]
    else:
        win = _window_fits(ctx, w, base, 6)
        pts = [v for v in win if v is not None]
        shapes = [(0.0, float(n - 1))]
        if len(pts) >= 3:
            shapes.append(_profile_of_windows(pts, n))
        results = []
        for t1, t2 in shapes:
            # Either stuck-phase logic, whichever reads the profile's start better.
            x = _start_of_windows(pts, t1, t2, (S0, J0))
            h0 = _profile(n, t1, t2)
            row0 = _changing_rows(x[0], x[1], x[2], x[3])
            prob = pick_problem(
                ctx, w, base, None, lambda pr, h0=h0, row0=row0: float(pr.costs(row0, h0)[0])
            )
            x, c = search(t1, t2, x, 0.15, 2)
            c, t1, t2 = _move_instants(
                lambda a, b, x=x: float(cost_h(_profile(n, a, b))(x[None, :], np.inf)[0]),
                c,
                t1,
                t2,
                n,
            )
            x, c = search(t1, t2, x, 0.05, 1)
            results.append((c, x, t1, t2, prob))
    c, x, t1, t2, prob = min(results, key=lambda r: r[0])
    h = _profile(n, t1, t2)
    row = _changing_rows(x[0], x[1], x[2], x[3])[0]
    mv_hat, _ = prob.series(row, h)
    # Too few measured slips: the replay decides alone, except on a quantised mv.
    untested = untested_p(ctx.sig.mv)
    # The slips after the change must differ from those before it the way the fitted
    # change of S (the travel at reversals) and J (the jump) goes.
    expect = {"travel": x[2] - x[0], "J": x[3] - x[1]}
    p_slips = untested if ctx.slips is None else _slips_test(ctx.slips, t1, t2, n, untested, expect)
    variant, n_params = _variant_of(t1, t2, n)
    params = TimeVaryingStictionParams(
        S_start=float(x[0]),
        J_start=float(x[1]),
        S_end=float(x[2]),
        J_end=float(x[3]),
        change_start_s=float(t1) * ctx.sig.dt,
        change_end_s=float(t2) * ctx.sig.dt,
        logic=logic_name(prob),
        slips_differ_p=p_slips,
        windows=tuple(
            None if v is None else StictionWindow(v[0] * ctx.sig.dt, v[1], v[2])
            for v in (win or ())
        ),
    )
    return EffectFit(
        supported=p_slips < SLIP_TEST_P,
        effect="time_varying_stiction",
        variant=variant,
        n_params=n_params,
        params=params,
        predictions={"mv": mv_hat},
        x=tuple(float(v) for v in x),
    )


EFFECT = Effect(
    name="time_varying_stiction",
    acts_on=("mv",),
    parameters=("S_end", "J_end", "change_start_s", "change_end_s"),
    fit=fit_time_varying_stiction,
    signature="measured slips differ before and after the change",
    signature_test=slips_differ,
    valve_side=True,
)
