"""Stick, slip and moving phases of a valve from its demand (op) and position (mv).

Choudhury, Thornhill & Shah (2005), Section 2.3 and Fig. 2: a sticky valve at rest
does not move while its demand crosses the deadband plus stickband ``S``; it then
slips by ``J`` and moves with the demand until it stops again.  Section 3 reads
these phases off the mv-op plots of plant valves (Figs. 3 and 6).

:func:`segment_valve` finds the phases in recorded data and measures every slip;
:func:`estimate_from_mv` turns the measurements into S and J with an interval, and
refines them by a least-squares fit of the model (Fig. 10) to mv.

How one slip gives S and J
--------------------------
Let the valve stop with demand ``x0`` after moving in direction ``d_prev``: by Eq. 4
it rests at ``mv_stuck = x0 - d_prev (S - J)/2``.  It breaks away in direction ``d``
when the demand has travelled ``S`` from ``x0`` (a reversal, ``d = -d_prev``) or ``J``
(the same direction, "stickband only"), at ``op_break = x0 + d (S or J)``, and jumps to
``mv_after = op_break - d (S - J)/2``.  In both cases

* ``d (mv_after - mv_stuck) = J`` (the jump), and
* ``d (op_break - mv_stuck) = (S + J)/2``,

so each slip gives ``J`` and ``S = 2 d (op_break - mv_stuck) - J`` without having to
locate ``x0`` in a noisy op; only at reversals is ``S`` also the op travel
``d (op_break - x0)``, which is reported as a cross-check.  The demand is sampled, so it
overshoots the breakaway point by up to one op step; half the last op step is taken
off both (the expected overshoot for a ramp).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from stictiondiag.core.checks import signal_pair
from stictiondiag.core.errors import DataError
from stictiondiag.core.jit import jit
from stictiondiag.core.robust import second_difference_noise_std
from stictiondiag.core.serialize import to_plain
from stictiondiag.core.stats import bootstrap_median_ci
from stictiondiag.stiction.fit_details import (
    LeastSquaresEstimate,
    MvFitDetails,
    ParameterCounts,
    SegmentStatistics,
)
from stictiondiag.stiction.fit_result import BlockCosts, StictionFit
from stictiondiag.stiction.resolution import archive_resolution, resolution
from stictiondiag.stiction.valvefit import (
    block_sse,
    cost_threshold,
    cycle_samples,
    determinacy,
    effective_samples,
    profile_interval,
    valve_run,
    valve_sse_many,
    valve_variants,
)

#: Half-width of the "mv is still" band, in robust noise standard deviations of mv.
STILL_BAND_SIGMAS = 4.0

#: Fewest slips for an event-based interval (bootstrap of the median).
MIN_EVENTS_FOR_INTERVAL = 3

#: How :func:`estimate_from_mv` states its intervals of S and J.
INTERVAL_METHOD = (
    "hull of the 95 % profile-cost interval of the least-squares fit (F test, "
    "effective samples) and the 95 % bootstrap interval of the median over slips"
)

#: Longest slip transition [samples]: a recorded slip may take a few samples
#: (positioner, sampling), a longer change is a moving phase.
MAX_SLIP_SAMPLES = 5

# Sample labels of :class:`Segments`.
LABEL_REST = 0
LABEL_STUCK = 1
LABEL_SLIP = 2
LABEL_MOVING = 3


# --------------------------------------------------------------------------------------
# Segmentation
# --------------------------------------------------------------------------------------


def median_small(x: np.ndarray) -> float:
    """``np.median`` of a short finite 1-D array, the same number without its overhead
    (the level of each still run of mv, of which a record has thousands).

    The middle element of the sorted values, or for an even count the two middle
    ones added and halved (what ``np.median`` computes: the mean of the two).
    O(k log k) for k values.
    """
    k = x.size
    if k == 0:
        return float(np.median(x))
    s = np.sort(x)
    if k % 2:
        return float(s[k // 2])
    return float((s[k // 2 - 1] + s[k // 2]) / 2.0)


@jit
def _flat_runs(mv, h):
    """Maximal runs where mv stays within +-h of the run's mean.

    A single sample outside the band followed by one inside is a noise spike and
    does not end the run.  Returns (starts, ends) with ends exclusive.
    """
    n = mv.shape[0]
    starts = np.empty(n, dtype=np.int64)
    ends = np.empty(n, dtype=np.int64)
    m = 0
    i = 0
    while i < n:
        s1 = mv[i]
        cnt = 1.0
        mean = mv[i]
        k = i + 1
        while k < n:
            if abs(mv[k] - mean) <= h:
                s1 += mv[k]
                cnt += 1.0
                mean = s1 / cnt
                k += 1
            elif k + 1 < n and abs(mv[k + 1] - mean) <= h:
                k += 2
                s1 += mv[k - 1]
                cnt += 1.0
                mean = s1 / cnt
            else:
                break
        starts[m] = i
        ends[m] = k
        m += 1
        i = k
    return starts[:m], ends[:m]


@dataclass(frozen=True)
class Segments:
    """Stick, slip and moving phases of a recorded valve (Fig. 2, Section 2.3).

    Intervals are ``[start, end)`` sample indices.  Per-slip arrays have one entry
    per slip, in time order.

    Attributes
    ----------
    stuck : ndarray, shape (k, 2)
        Intervals where mv is still while op travels (deadband + stickband) [samples].
    slip : ndarray, shape (k, 2)
        Slip transitions right after each stuck interval [samples]; usually one sample.
    moving : ndarray, shape (m, 2)
        Intervals where mv follows op (moving phase) [samples].
    labels : ndarray of int8, shape (n,)
        Per-sample phase: 0 at rest or undecided, 1 stuck, 2 slip, 3 moving.
    direction : ndarray of int8
        Direction of each slip (+1 opening, -1 closing).
    reversal : ndarray of bool
        The slip goes against the valve's previous movement (deadband + stickband
        crossed); False also when the previous direction is unknown.
    previous_direction : ndarray of int8
        Direction of the movement before each stuck interval (0 unknown).
    monotone : ndarray of bool
        op travelled without turning back while the valve was stuck (the Kano and
        Choudhury flowcharts then agree on the breakaway point).
    mv_stuck, mv_after : ndarray
        Valve position while stuck and right after the slip [units of mv].
    op_stop, op_break : ndarray
        Demand where the valve stopped and where it broke away [units of op].
    jump : ndarray
        Slip jump ``J`` of each slip [units of op].
    band : ndarray
        ``S`` of each slip from ``2 d (op_break - mv_stuck) - J`` [units of op].
    travel : ndarray
        Demand travel from stop to breakaway [units of op]; equals ``S`` at reversals.
    still_band : float
        Half-width of the band within which mv counts as still [units of mv].
    noise_mv, noise_op : float
        Robust noise standard deviations [units of mv, op].
    quantum_mv : float
        Resolution of mv: its quantisation step or its archive's deadband
        (:func:`~stictiondiag.stiction.resolution.resolution`; 0 when neither) [units of mv].
    dt : float
        Sampling time [s].
    """

    stuck: np.ndarray
    slip: np.ndarray
    moving: np.ndarray
    labels: np.ndarray = field(repr=False)
    direction: np.ndarray
    reversal: np.ndarray
    previous_direction: np.ndarray
    monotone: np.ndarray
    mv_stuck: np.ndarray
    mv_after: np.ndarray
    op_stop: np.ndarray
    op_break: np.ndarray
    jump: np.ndarray
    band: np.ndarray
    travel: np.ndarray
    still_band: float
    noise_mv: float
    noise_op: float
    quantum_mv: float
    dt: float

    @property
    def n_slips(self) -> int:
        """Number of slips found [-]."""
        return int(self.direction.size)

    def to_dict(self) -> dict:
        """JSON-able summary: intervals as [start, end) sample pairs, per-slip values."""
        return to_plain(
            {
                "n_slips": self.n_slips,
                "stuck": self.stuck,
                "slip": self.slip,
                "moving": self.moving,
                "direction": self.direction,
                "reversal": self.reversal,
                "monotone": self.monotone,
                "jump": self.jump,
                "band": self.band,
                "travel": self.travel,
                "still_band": self.still_band,
                "noise_mv": self.noise_mv,
                "noise_op": self.noise_op,
                "quantum_mv": self.quantum_mv,
                "dt_s": self.dt,
            }
        )


def _check_pair(op, mv, dt) -> tuple[np.ndarray, np.ndarray, float]:
    op, mv, dt = signal_pair(op, mv, dt, ("op", "mv"), min_samples=20)
    if np.ptp(op) <= 0:
        raise DataError("op is constant: the valve demand never moves, nothing to estimate")
    return op, mv, dt


def _intervals(mask: np.ndarray) -> np.ndarray:
    """[start, end) intervals of the True runs of a boolean mask."""
    m = np.concatenate(([False], mask.astype(bool), [False]))
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return edges.reshape(-1, 2).astype(np.int64)


def _stuck_runs(op, mv, h, op_tol):
    """Runs of still mv (within ``h``) and which of them are stuck intervals (op
    travels more than ``op_tol`` meanwhile); labels the stuck samples."""
    n = op.size
    starts, ends = _flat_runs(mv, h)
    labels = np.zeros(n, dtype=np.int8)
    run_stuck = np.zeros(starts.size, dtype=bool)
    run_level = np.empty(starts.size)
    for i, (a, e) in enumerate(zip(starts, ends, strict=True)):
        level = median_small(mv[a:e])
        # A flat run that starts at the tail of a moving phase: drop its leading
        # samples that are off the stuck level.
        while e - a > 3 and abs(mv[a] - level) > 0.5 * h:
            a += 1
        starts[i] = a
        run_level[i] = level
        if e - a >= 2 and np.ptp(op[a:e]) > op_tol:
            run_stuck[i] = True
            labels[a:e] = LABEL_STUCK
    return starts, ends, labels, run_stuck, run_level


def _measure_slips(op, mv, h, pull_tol, runs, labels) -> dict[str, list]:
    """Every slip after a stuck run: where it starts and ends, its direction, the
    direction before, and the op and mv levels that give S and J; labels the slip
    samples."""
    n = op.size
    starts, ends, run_stuck, run_level = runs
    # Slips: the sample after each stuck run, extended while mv outruns op.
    ev: dict[str, list] = {
        k: []
        for k in (
            "stuck",
            "slip",
            "d",
            "prev",
            "mono",
            "mv_stuck",
            "mv_after",
            "op_stop",
            "op_break",
        )
    }
    last_dir = 0
    last_end = 0
    stuck_idx = np.flatnonzero(run_stuck)
    for j, i in enumerate(stuck_idx):
        a, e = int(starts[i]), int(ends[i])
        level = run_level[i]
        # Direction of the last movement before this stuck interval.
        prev = last_dir
        if a - last_end >= 2 or last_dir == 0:
            ref = mv[max(last_end, a - 10) : a + 1] if a > 0 else mv[:1]
            if ref.size >= 2 and abs(ref[-1] - ref[0]) > h:
                prev = int(np.sign(ref[-1] - ref[0]))
        if e >= n:
            break
        d = int(np.sign(mv[e] - level))
        if d == 0:
            continue
        k = e
        while (
            k + 1 < n
            and k + 1 - e < MAX_SLIP_SAMPLES
            and d * (mv[k + 1] - mv[k]) > h + max(0.0, d * (op[k + 1] - op[k]))
        ):
            k += 1
        slip_end = k + 1
        labels[e:slip_end] = LABEL_SLIP
        # Valve position after the slip: the next stuck level if it sticks at once,
        # else extrapolated from the moving phase's offset mv - op (constant, Eq. 4).
        nxt = stuck_idx[j + 1] if j + 1 < stuck_idx.size else None
        nxt_start = int(starts[nxt]) if nxt is not None else n
        if nxt is not None and nxt_start <= slip_end + 1:
            mv_after = float(run_level[nxt])
        else:
            w_end = min(nxt_start, slip_end + 20, n)
            offs = mv[slip_end - 1 : w_end] - op[slip_end - 1 : w_end]
            mv_after = float(op[e] + median_small(offs))
        seg = op[max(a - 1, 0) : e]
        op_stop = float(seg[np.argmin(d * seg)])
        run_max = np.maximum.accumulate(d * op[a : e + 1])
        mono = bool(np.max(run_max - d * op[a : e + 1]) <= pull_tol)
        ev["stuck"].append((a, e))
        ev["slip"].append((e, slip_end))
        ev["d"].append(d)
        ev["prev"].append(prev)
        ev["mono"].append(mono)
        ev["mv_stuck"].append(level)
        ev["mv_after"].append(mv_after)
        ev["op_stop"].append(op_stop)
        ev["op_break"].append(float(op[e]))
        last_dir = d
        last_end = slip_end
    return ev


def _mark_moving(op, mv, h, op_tol, runs, labels) -> None:
    """Label the moving phases: mv changes with op outside the stuck and slip phases."""
    starts, ends, run_stuck = runs
    dmv = np.abs(np.diff(mv, prepend=mv[0]))
    moving_mask = (labels == LABEL_REST) & (dmv > 0)
    for i in range(starts.size):
        a, e = int(starts[i]), int(ends[i])
        if not run_stuck[i] and np.ptp(mv[a:e]) <= h and np.ptp(op[a:e]) <= op_tol:
            moving_mask[a:e] = False  # valve and demand both at rest
    labels[moving_mask] = LABEL_MOVING


def segment_valve(op: np.ndarray, mv: np.ndarray, dt: float, deadband: float = 0.0) -> Segments:
    """Find the stuck, slip and moving phases of a valve and measure every slip.

    Parameters
    ----------
    op : ndarray
        Valve demand (controller output) [% of span].
    mv : ndarray
        Valve position [% of span], same length as ``op``.  Noise and a quantised
        signal are tolerated: mv counts as still within a band of
        ``max(4 sigma_mv, 1.01 q)`` around its mean, with ``sigma_mv`` the robust noise
        level and ``q`` the resolution
        (:func:`~stictiondiag.stiction.resolution.resolution`).
    dt : float
        Sampling time [s].
    deadband : float
        Deadband of the exception archive mv was rebuilt from [units of mv], 0 for a
        record of every sample.

    Returns
    -------
    Segments
        Phases and per-slip measurements (module docstring: how a slip gives S and J).

    Notes
    -----
    A run of still mv is a *stuck* interval only if op travels more than twice the
    band width and more than six op noise levels meanwhile (otherwise the valve is
    at rest with op, or the run is a slow part of a moving phase).  The slip is the
    first sample after the run, extended while mv keeps moving faster than op.
    """
    op, mv, dt = _check_pair(op, mv, dt)
    span = float(max(np.ptp(op), np.ptp(mv)))
    sig_mv = second_difference_noise_std(mv)
    sig_op = second_difference_noise_std(op)
    q_mv = resolution(mv, deadband)
    h = max(STILL_BAND_SIGMAS * sig_mv, 1.01 * q_mv, 1e-9 * span)
    op_tol = max(4.0 * h, 6.0 * sig_op, 1e-9 * span)
    pull_tol = max(6.0 * sig_op, 1e-9 * span)

    starts, ends, labels, run_stuck, run_level = _stuck_runs(op, mv, h, op_tol)
    ev = _measure_slips(op, mv, h, pull_tol, (starts, ends, run_stuck, run_level), labels)

    d = np.asarray(ev["d"], dtype=np.int8)
    prev = np.asarray(ev["prev"], dtype=np.int8)
    slips = np.asarray(ev["slip"], dtype=np.int64).reshape(-1, 2)
    mv_stuck = np.asarray(ev["mv_stuck"], dtype=float)
    mv_after = np.asarray(ev["mv_after"], dtype=float)
    op_break = np.asarray(ev["op_break"], dtype=float)
    op_stop = np.asarray(ev["op_stop"], dtype=float)
    if d.size:
        br = slips[:, 0]
        excess = 0.5 * np.maximum(0.0, d * (op[br] - op[np.maximum(br - 1, 0)]))
    else:
        excess = np.zeros(0)
    jump = d * (mv_after - mv_stuck) - excess
    band = 2.0 * (d * (op_break - mv_stuck) - excess) - jump
    travel = d * (op_break - op_stop) - excess

    _mark_moving(op, mv, h, op_tol, (starts, ends, run_stuck), labels)

    return Segments(
        stuck=np.asarray(ev["stuck"], dtype=np.int64).reshape(-1, 2),
        slip=slips,
        moving=_intervals(labels == LABEL_MOVING),
        labels=labels,
        direction=d,
        reversal=(prev != 0) & (d != prev),
        previous_direction=prev,
        monotone=np.asarray(ev["mono"], dtype=bool),
        mv_stuck=mv_stuck,
        mv_after=mv_after,
        op_stop=op_stop,
        op_break=op_break,
        jump=jump,
        band=band,
        travel=travel,
        still_band=float(h),
        noise_mv=float(sig_mv),
        noise_op=float(sig_op),
        quantum_mv=float(q_mv),
        dt=dt,
    )


# --------------------------------------------------------------------------------------
# S and J from mv
# --------------------------------------------------------------------------------------


def _grid_search(op, mv, sync, variant, S_max, J_max, seeds=(), n_grid=31, n_zoom=3, zoom=11):
    """Coarse-to-fine grid search of the mv cost over (S, J) for one valve model.

    With a noisy op the cost is rough in S (a small change of S moves a breakaway
    to another noise sample), so the fine grids are laid around several starting
    points: the three best cells of the coarse grid and the ``seeds`` (the segment
    estimate).  Each zoom keeps two steps of the previous grid either side.
    Returns all evaluated (S, J, cost) and the best pair with its cost.
    """
    S_all, J_all, C_all = [], [], []
    inputs: dict = {}

    def evaluate(Sg, Jg):
        SS, JJ = np.meshgrid(Sg, Jg, indexing="ij")
        SS, JJ = SS.ravel(), JJ.ravel()
        C = np.empty(SS.size)
        # A band narrower than the play operator runs on the raw op
        # (ValveVariant.band_parts): S = J = 0 is then the linear valve.
        for mask, v in variant.band_parts(SS):
            x = inputs.get(v.name)
            if x is None:
                x = inputs[v.name] = v.prepare(op)
            C[mask] = valve_sse_many(x, mv, v.model_S(SS[mask]), JJ[mask], v.kano, *sync)
        S_all.append(SS)
        J_all.append(JJ)
        C_all.append(C)
        return SS, JJ, C

    Sg = np.linspace(0.0, S_max, n_grid)
    Jg = np.linspace(0.0, J_max, n_grid)
    SS, JJ, C = evaluate(Sg, Jg)
    step_s, step_j = Sg[1] - Sg[0], Jg[1] - Jg[0]
    starts = [(SS[i], JJ[i]) for i in np.argsort(C)[:3]]
    starts += [(min(max(a, 0.0), S_max), min(max(b, 0.0), J_max)) for a, b in seeds]
    for sb, jb in starts:
        ds, dj = 2 * step_s, 2 * step_j
        for _ in range(n_zoom):
            Sz = np.linspace(max(0.0, sb - ds), min(S_max, sb + ds), zoom)
            Jz = np.linspace(max(0.0, jb - dj), min(J_max, jb + dj), zoom)
            SS, JJ, C = evaluate(Sz, Jz)
            i = int(np.argmin(C))
            sb, jb = SS[i], JJ[i]
            ds, dj = 2 * (Sz[1] - Sz[0]), 2 * (Jz[1] - Jz[0])
    S_all = np.concatenate(S_all)
    J_all = np.concatenate(J_all)
    C_all = np.concatenate(C_all)
    i = int(np.argmin(C_all))
    return S_all, J_all, C_all, float(S_all[i]), float(J_all[i]), float(C_all[i])


@dataclass(frozen=True)
class _SlipEvents:
    """Per-slip estimates used for the event statistics [% of span].

    Slips during which op travelled monotonically agree between the flowcharts;
    they are used when there are enough, else every slip.
    """

    use: np.ndarray
    band: np.ndarray
    jump: np.ndarray
    S: float | None
    J: float | None


def _slip_events(segs: Segments) -> _SlipEvents:
    use = (
        segs.monotone
        if segs.monotone.sum() >= MIN_EVENTS_FOR_INTERVAL
        else np.ones(segs.n_slips, dtype=bool)
    )
    band_ev = segs.band[use]
    jump_ev = segs.jump[use]
    S_seg = float(np.median(band_ev)) if band_ev.size else None
    J_seg = float(np.median(jump_ev)) if jump_ev.size else None
    return _SlipEvents(use, band_ev, jump_ev, S_seg, J_seg)


def _least_squares(op, mv, sync, S_max, seeds):
    """The grid search of every valve variant worth trying, and the best fit run.

    Returns the searches (name -> (variant, result of :func:`_grid_search`)), the
    name of the best, the variant that represents its band
    (:meth:`~stictiondiag.stiction.valvefit.ValveVariant.for_band`), and that model's
    valve position [% of span] and number of slips.
    """
    k0, k_start, d_start = sync
    variants = valve_variants(op)
    if any(v.play_width > 0 for v in variants):
        # On a noisy op the published flowchart re-arms at every noise reversal and
        # never slips, and behind the play operator it differs from Kano's variant
        # only in rare partial reversals: not worth their evaluations.
        variants = [v for v in variants if v.kano]
    searches = {}
    for variant in variants:
        res = _grid_search(op, mv, (k0, k_start, d_start, -1.0), variant, S_max, S_max, seeds=seeds)
        searches[variant.name] = (variant, res)
    best = min(searches, key=lambda k: searches[k][1][5])
    variant, (_, _, _, S_ls, J_ls, _) = searches[best]
    variant = variant.for_band(S_ls)
    S_model = float(variant.model_S(S_ls))
    y, n_slips = valve_run(variant.prepare(op), S_model, J_ls, variant.kano, k_start, d_start, -1.0)
    return searches, best, variant, y, n_slips


def _hull(a, b):
    """The interval spanning both ``a`` and ``b`` (``a`` alone when ``b`` is None)."""
    if b is None:
        return a
    return (max(0.0, min(a[0], b[0])), max(a[1], b[1]))


def _segments_details(segs: Segments, ev: _SlipEvents, cis, seg_cost) -> SegmentStatistics:
    """The event statistics of ``details.segments`` (``cis``: the bootstrap
    intervals of S and J)."""
    S_ci, J_ci = cis
    travel_rev = segs.travel[segs.reversal & ev.use]
    return SegmentStatistics(
        S=ev.S,
        J=ev.J,
        S_interval=None if S_ci is None else tuple(S_ci),
        J_interval=None if J_ci is None else tuple(J_ci),
        S_iqr=None if ev.band.size < 2 else _quartiles(ev.band),
        J_iqr=None if ev.jump.size < 2 else _quartiles(ev.jump),
        S_travel_at_reversals=None if travel_rev.size == 0 else float(np.median(travel_rev)),
        n_slips=segs.n_slips,
        n_used=int(ev.use.sum()),
        n_reversals=int(segs.reversal.sum()),
        cost=seg_cost,
        noise_mv=segs.noise_mv,
        noise_op=segs.noise_op,
        quantum_mv=segs.quantum_mv,
    )


def _quartiles(values: np.ndarray) -> tuple[float, float]:
    q1, q3 = np.percentile(values, [25, 75])
    return float(q1), float(q3)


def _synchronisation(segs: Segments, n: int) -> tuple[int, float]:
    """Where and in which direction the model valve starts moving.

    Right after the first recorded slip, in its direction, when it comes in the
    first half of the record; otherwise from the start, moving with op.
    """
    if segs.n_slips >= 1 and segs.slip[0, 1] < n // 2:
        return int(segs.slip[0, 1]) - 1, float(segs.direction[0])
    return 0, 0.0


def _mv_fit_details(
    variant, bias: float, searches: dict, best, intervals, hi_edges, segments, counts
) -> MvFitDetails:
    """:func:`estimate_from_mv`'s ``details``: the least-squares part, the segment
    statistics and the counts (``counts``: the first sample of the cost, the record's
    and the effective number of samples)."""
    S_all, J_all, C_all, S_ls, J_ls, cost = searches[best][1]
    (S_iv, J_iv), (S_hi_edge, J_hi_edge) = intervals, hi_edges
    k0, n, n_eff = counts
    least_squares = LeastSquaresEstimate(
        S=S_ls,
        J=J_ls,
        S_interval=tuple(S_iv),
        J_interval=tuple(J_iv),
        cost=cost,
        cost_by_valve_model={k: v[1][5] for k, v in searches.items()},
        effective_samples=n_eff,
        S_bounded=not S_hi_edge,
        J_bounded=not J_hi_edge,
    )
    return MvFitDetails(
        play_width=variant.play_width,
        bias=bias,
        least_squares=least_squares,
        segments=segments,
        burn_in_samples=k0,
        noise_cost=float(segments.noise_mv**2 * (n - k0)),
        n_parameters=ParameterCounts(stiction=3, linear=1),
        effective_samples=n_eff,
        n_samples=n - k0,
    )


def estimate_from_mv(
    op: np.ndarray,
    mv: np.ndarray,
    dt: float,
    segments: Segments | None = None,
    deadband: Mapping[str, float] | None = None,
) -> StictionFit:
    """S and J from the valve's recorded position (Sections 2.3 and 3, Fig. 2).

    Two estimates are made and both reported:

    1. *segments*: the median over slips of the per-slip ``S`` and ``J`` of
       :func:`segment_valve` (module docstring), with a 95 % bootstrap interval of
       the median over slips;
    2. *least squares*: the model of Fig. 10 fitted to mv (``mv = valve(op; S, J) +
       bias``) by a compiled coarse-to-fine grid search over (S, J) seeded with the
       segment estimate, for the valve variants of
       :func:`stictiondiag.stiction.valvefit.valve_variants` (the published flowchart and
       Kano's on a clean op; Kano's, raw and behind a play operator, on a noisy one;
       the best is kept), with a 95 % profile-cost interval (F test with the
       residual's effective sample size).

    The model is started moving right after the first recorded slip, in its
    direction, so it is in step with the valve from there (the samples before are
    left out of the cost).

    The reported ``S`` and ``J`` are the least-squares ones (they use every sample,
    not only the breakaway samples); the reported intervals span both the
    least-squares interval and the event interval, so that the spread of the valve's
    behaviour from one slip to the next is not hidden by a tight fit.

    Parameters
    ----------
    op : ndarray
        Valve demand [% of span].
    mv : ndarray
        Valve position [% of span].
    dt : float
        Sampling time [s].
    segments : Segments, optional
        ``segment_valve(op, mv, dt, deadband["mv"])`` when the caller has it already
        (it is then not computed again; the result is the same).
    deadband : mapping, optional
        Role -> deadband of the exception archive op and mv were rebuilt from [% of
        span] (:attr:`stictiondiag.io.tags.Tags.archive_deadband`).  S and J within
        what it can hide are marked in ``StictionFit.resolution``
        (:func:`~stictiondiag.stiction.resolution.hidden_by_resolution`), and the verdict
        does not call them stiction.

    Returns
    -------
    StictionFit
        ``method="mv_segments"``; ``details`` has both estimates, the segment
        statistics and the per-cycle costs used by :func:`stiction_verdict`.
    """
    op, mv, dt = _check_pair(op, mv, dt)
    n = op.size
    d_mv = float((deadband or {}).get("mv", 0.0))
    segs = segment_valve(op, mv, dt, d_mv) if segments is None else segments
    op_std = float(np.std(op))
    lo, hi = np.percentile(op, [0.5, 99.5])
    S_max = J_max = float(max(hi - lo, 1e-12))
    k_start, d_start = _synchronisation(segs, n)
    k0 = k_start + 1
    ev = _slip_events(segs)
    seeds = [] if ev.S is None else [(ev.S, ev.J)]
    searches, best, variant, y, n_slips = _least_squares(
        op, mv, (k0, k_start, d_start), S_max, seeds
    )
    S_all, J_all, C_all, S_ls, J_ls, cost = searches[best][1]
    bias = float(np.mean(mv[k0:] - y[k0:]))
    mv_model = y + bias
    resid = mv - mv_model
    lin_resid = mv - op - float(np.mean(mv[k0:] - op[k0:]))
    linear_cost = float(np.sum(lin_resid[k0:] ** 2))

    n_eff = effective_samples(resid[k0:])
    # The textbook threshold, not widened by the misfit: with mv, one (S, J) pair's
    # misfit is the valve varying from slip to slip, which the slips' interval reports.
    thr = cost_threshold(cost, n_eff, 3)
    S_iv, S_lo_edge, S_hi_edge = profile_interval(S_all, C_all, thr, 0.0, S_max)
    J_iv, J_lo_edge, J_hi_edge = profile_interval(J_all, C_all, thr, 0.0, J_max)
    # The model's cost [% of span]^2 with the event estimates of S and J, and the
    # per-cycle costs of the fit and of the linear valve that the verdict compares.
    seg_cost = None
    if ev.S is not None and ev.J is not None:
        S_ev, J_ev = max(ev.S, 0.0), max(ev.J, 0.0)
        seg_cost = searches[best][0].sse(op, mv, S_ev, J_ev, (k0, k_start, d_start))
    period = cycle_samples(op)
    blocks = BlockCosts(period, block_sse(resid, period, k0), block_sse(lin_resid, period, k0))

    S_ci = bootstrap_median_ci(ev.band, min_count=MIN_EVENTS_FOR_INTERVAL)
    J_ci = bootstrap_median_ci(ev.jump, min_count=MIN_EVENTS_FOR_INTERVAL)
    S_interval = _hull(S_iv, S_ci)
    J_interval = _hull(J_iv, J_ci)
    det = determinacy(S_ls, S_interval, S_hi_edge, J_ls, J_interval, J_hi_edge)
    stats = _segments_details(segs, ev, (S_ci, J_ci), seg_cost)
    details = _mv_fit_details(
        variant, bias, searches, best, (S_iv, J_iv), (S_hi_edge, J_hi_edge), stats, (k0, n, n_eff)
    )
    return StictionFit(
        S=S_ls,
        J=J_ls,
        S_scaled=S_ls / op_std,
        J_scaled=J_ls / op_std,
        S_interval=S_interval,
        J_interval=J_interval,
        method="mv_segments",
        mv_model=mv_model,
        n_slips=int(n_slips),
        cost=cost,
        linear_cost=linear_cost,
        details=details,
        S_determinacy=det["S"],
        J_determinacy=det["J"],
        valve_model=variant.name,
        interval_method=INTERVAL_METHOD,
        block_costs=blocks,
        resolution=archive_resolution(mv, deadband, S_ls, J_ls),
    )
