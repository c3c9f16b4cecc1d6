"""Accuracy of ``analyze`` on simulated closed loops; prints a table.

Each case is a PI loop of :func:`stictiondiag.models.loops.simulate_loop` with the
data-driven valve of Choudhury, Thornhill & Shah (2005), Section 5
(``valve="choudhury"``), drawn with a fixed seed:

* process and controller from :data:`TEMPLATES`: the concentration loop of Eq. 3 /
  Table 3, a faster FOPTD loop, and two integrating (level-like) loops;
* S uniform in 1-8 % of span, J uniform in 0-1.4 S (deadband, undershoot, no
  offset and overshoot cases of Section 5.1);
* white measurement noise on pv, its standard deviation a random 0.5-4 % of the
  noise-free pv's standard deviation (of ``gain * S / 2`` when there is no cycle);
* sampled at 1 s, the start-up transient of the kick (:data:`WARMUP_S`) dropped,
  then at least :data:`MIN_SAMPLES` samples or :data:`MIN_CYCLES` cycles.

Every case is analysed twice through :func:`stictiondiag.analysis.analyze` on
``Tags.from_arrays`` (sim-to-real gap off): with the recorded mv, and with mv
dropped (pv and op only, the plant-data situation). For each group of cases the
table gives the median and 90th percentile of ``|S - S_true|`` and ``|J - J_true|``
[% of span], the median replay period error ``|T_replay / T_data - 1|`` [%], the
share of cases whose replay period is within 5 %, and the share called stiction.

Targets (the issue's proof section): median |S error| and |J error| <= 0.3 % of span
with mv, <= 1 % without; replay period within 5 % of the data's.

Some draws hold no regular limit cycle: a FOPTD loop with a small slip jump has
none (pure deadband "only adds dead time", Section 5.3.1) or one too slow for the
record; and measurement noise passed to op by the controller can hold the published
flowchart's valve, which re-arms its stuck point at every reversal of its input
(Fig. 10; Section 5.1 asks for a filter in front of the model), so the cycle
becomes irregular. Cases whose noisy pv has no regular oscillation with at least
:data:`MIN_CYCLES_TARGET` cycles (:func:`stictiondiag.signals.oscillation.detect_oscillation`)
are drawn like the others but listed in their own row, outside the targets.

Usage: ``python benchmarks/accuracy_analyze.py [--cases 48] [--seed 1] [--workers 1]
[--csv results.csv]``.
"""

from __future__ import annotations

import argparse
import math
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

#: Sample time of every case [s].
TS = 1.0
#: Start-up transient dropped from every record [s].
WARMUP_S = 1000.0
#: Least and most samples analysed.
MIN_SAMPLES, MAX_SAMPLES = 3000, 10_000
#: Cycles a record should hold.
MIN_CYCLES = 12
#: Regular cycles of the noisy pv a case needs to count for the targets.
MIN_CYCLES_TARGET = 5
#: Noise standard deviation as a fraction of the noise-free pv's standard deviation.
NOISE_FRACTION = (0.005, 0.04)
#: Targets: median |error| [% of span] with and without mv, replay period [%].
TARGET_WITH_MV, TARGET_WITHOUT_MV, TARGET_PERIOD_PCT = 0.3, 1.0, 5.0


def templates():
    """Loop templates: name -> (kind, process, controller)."""
    from stictiondiag.models.processes import (
        FOPTD,
        LOOP_PARAMETERS,
        PI,
        Integrating,
    )

    conc = LOOP_PARAMETERS["concentration"]
    return {
        # Eq. 3 / Table 3: 3 e^{-10s}/(10s+1), 0.2 (10s+1)/(10s).
        "concentration": ("FOPTD", conc["process"], conc["controller"]),
        "foptd_fast": ("FOPTD", FOPTD(1.5, 20.0, 4.0), PI(0.6, 8.0)),
        # The level loop of Table 3 slowed ten times (1/(10 s), 0.4 (20s+1)/(20s)),
        # so that a 1 s sample holds the cycle.
        "level_slow": ("integrating", Integrating(0.1, 0.0), PI(0.4, 20.0)),
        "level_deadtime": ("integrating", Integrating(0.05, 3.0), PI(1.5, 40.0)),
    }


TEMPLATES = ("concentration", "foptd_fast", "level_slow", "level_deadtime")


def draw_cases(n_cases: int, seed: int) -> list[dict]:
    """Seeded case list: template, S, J, noise fraction, simulation seed."""
    rng = np.random.default_rng(seed)
    cases = []
    for i in range(n_cases):
        S = float(rng.uniform(1.0, 8.0))
        cases.append(
            {
                "case": i,
                "template": TEMPLATES[i % len(TEMPLATES)],
                "S": round(S, 3),
                "J": round(float(rng.uniform(0.0, 1.4)) * S, 3),
                "noise_fraction": float(rng.uniform(*NOISE_FRACTION)),
                "seed": int(rng.integers(0, 2**31 - 1)),
            }
        )
    return cases


def simulate_case(case: dict) -> dict:
    """The case's data: a noise-free run to size the record and noise, then the noisy run."""
    from stictiondiag.models.loops import simulate_loop
    from stictiondiag.signals.oscillation import detect_oscillation

    kind, process, controller = templates()[case["template"]]
    S, J = case["S"], case["J"]
    first = int(WARMUP_S / TS)
    clean = simulate_loop(
        process, controller, duration=WARMUP_S + MAX_SAMPLES * TS, dt=TS, S=S, J=J
    )
    pv_clean = clean.pv[first:]
    osc = detect_oscillation(pv_clean, TS)
    period = osc.period_s if osc.present else None
    n_cycles = 0.0 if period is None else pv_clean.size * TS / period
    if period is None:
        n = MIN_SAMPLES
    else:
        n = int(min(MAX_SAMPLES, max(MIN_SAMPLES, MIN_CYCLES * period / TS)))
    pv_std = float(np.std(pv_clean[:n]))
    if pv_std < 1e-6 * max(1.0, abs(process.gain)):
        pv_std = abs(process.gain) * S / 2
    noise_std = case["noise_fraction"] * pv_std
    sim = simulate_loop(
        process,
        controller,
        duration=WARMUP_S + n * TS,
        dt=TS,
        S=S,
        J=J,
        noise_std=noise_std,
        seed=case["seed"],
    )
    keep = slice(first, first + n)
    # Classified on the data analysed: the noisy loop must hold a regular cycle.
    osc_noisy = detect_oscillation(sim.pv[keep], TS)
    cycles_noisy = 0.0 if not osc_noisy.present else n * TS / osc_noisy.period_s
    return {
        "kind": kind,
        "integrating": kind == "integrating",
        "limit_cycle": bool(osc_noisy.present) and cycles_noisy >= MIN_CYCLES_TARGET,
        "cycles_clean": n_cycles,
        "period_clean_s": period,
        "noise_std": noise_std,
        "pv": sim.pv[keep],
        "op": sim.op[keep],
        "mv": sim.mv[keep],
        "sp": sim.sp[keep],
    }


def analyse_case(case: dict) -> list[dict]:
    """Both analyses of one case (with mv, without mv); one result row each."""
    from stictiondiag.analysis import (
        AnalysisConfig,
        analyze,
    )
    from stictiondiag.core.errors import StictionError
    from stictiondiag.io.tags import Tags

    data = simulate_case(case)
    rows = []
    for with_mv in (True, False):
        row = {
            **case,
            "kind": data["kind"],
            "limit_cycle": data["limit_cycle"],
            "with_mv": with_mv,
            "n": int(data["pv"].size),
            "noise_std": data["noise_std"],
        }
        tags = Tags.from_arrays(
            data["pv"],
            data["op"],
            mv=data["mv"] if with_mv else None,
            sp=data["sp"],
            ts=TS,
            loop_type="level" if data["integrating"] else "other",
            integrating=data["integrating"],
            source=f"case{case['case']}",
        )
        t0 = time.perf_counter()
        try:
            result = analyze(tags, config=AnalysisConfig(gap=False))
        except StictionError as exc:
            row.update(error=str(exc), seconds=time.perf_counter() - t0)
            rows.append(row)
            continue
        row["seconds"] = time.perf_counter() - t0
        fit, rep = result.fit, result.replay
        row.update(
            S_hat=float(fit.S),
            J_hat=float(fit.J),
            S_err=abs(float(fit.S) - case["S"]),
            J_err=abs(float(fit.J) - case["J"]),
            method=fit.method,
            verdict=result.verdict.status,
            period_data=None if rep is None else rep.period_s.get("data"),
            period_replay=None if rep is None else rep.period_s.get("replay"),
            warnings=len(result.warnings),
        )
        pd_, pr, pc = row["period_data"], row["period_replay"], data["period_clean_s"]
        row["period_clean"] = pc
        row["period_err_pct"] = _rel_pct(pr, pd_)
        # The same replay against the noise-free loop: separates what the replay
        # gets wrong from what the noise did to the data's cycle.
        row["period_err_clean_pct"] = _rel_pct(pr, pc)
        row["noise_shift_pct"] = _rel_pct(pd_, pc)
        rows.append(row)
    return rows


def _rel_pct(value, reference):
    """``100 |value / reference - 1|`` [%], None when either is missing."""
    if not value or not reference or not math.isfinite(value * reference):
        return None
    return abs(value / reference - 1.0) * 100


def _median(values):
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else None


def _p90(values):
    values = [v for v in values if v is not None]
    return float(np.percentile(values, 90)) if values else None


def summarise(rows: list[dict]) -> list[dict]:
    """One summary per group (kind x mv, and the no-limit-cycle cases apart)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        key = (r["with_mv"], r["kind"] if r["limit_cycle"] else "no regular limit cycle")
        groups.setdefault(key, []).append(r)
        if r["limit_cycle"]:
            groups.setdefault((r["with_mv"], "all with a limit cycle"), []).append(r)
    out = []
    order = ["FOPTD", "integrating", "all with a limit cycle", "no regular limit cycle"]
    for with_mv in (True, False):
        for kind in order:
            g = groups.get((with_mv, kind))
            if not g:
                continue
            ok = [r for r in g if "error" not in r]
            periods = [r["period_err_pct"] for r in ok]
            with_period = [p for p in periods if p is not None]
            out.append(
                {
                    "mv": "yes" if with_mv else "no",
                    "group": kind,
                    "n": len(g),
                    "errors": len(g) - len(ok),
                    "S_med": _median([r["S_err"] for r in ok]),
                    "S_p90": _p90([r["S_err"] for r in ok]),
                    "J_med": _median([r["J_err"] for r in ok]),
                    "J_p90": _p90([r["J_err"] for r in ok]),
                    "T_med": _median(periods),
                    "T_clean_med": _median([r["period_err_clean_pct"] for r in ok]),
                    "T_noise_med": _median([r["noise_shift_pct"] for r in ok]),
                    "T_within5": (
                        sum(p <= TARGET_PERIOD_PCT for p in with_period) / len(with_period)
                        if with_period
                        else None
                    ),
                    "T_n": len(with_period),
                    "stiction": sum(r.get("verdict") == "stiction" for r in ok) / max(1, len(ok)),
                    "seconds": _median([r["seconds"] for r in g]),
                }
            )
    return out


def _f(v, spec=".2f"):
    return "-" if v is None else format(v, spec)


def print_table(summary: list[dict]) -> None:
    print(
        "| mv  | group                  |  n | |S err| med | p90  | |J err| med | p90  "
        "| period err med [%] | within 5 % | vs noise-free [%] | noise shift [%] "
        "| stiction | s/case |"
    )
    print("|-----|------------------------|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for s in summary:
        within = "-" if s["T_within5"] is None else f"{s['T_within5']:.0%} of {s['T_n']}"
        errors = f" ({s['errors']} failed)" if s["errors"] else ""
        print(
            f"| {s['mv']:<3} | {s['group']:<22} | {s['n']:>2} | {_f(s['S_med']):>5} "
            f"| {_f(s['S_p90'])} | {_f(s['J_med']):>5} | {_f(s['J_p90'])} "
            f"| {_f(s['T_med'], '.1f'):>5} | {within} | {_f(s['T_clean_med'], '.1f')} "
            f"| {_f(s['T_noise_med'], '.1f')} | {s['stiction']:.0%}{errors} "
            f"| {_f(s['seconds'], '.1f')} |"
        )


def print_verdicts(summary: list[dict]) -> None:
    print()
    for s in summary:
        if s["group"] != "all with a limit cycle":
            continue
        target = TARGET_WITH_MV if s["mv"] == "yes" else TARGET_WITHOUT_MV
        for name, value in (("S", s["S_med"]), ("J", s["J_med"])):
            met = value is not None and value <= target
            print(
                f"mv {s['mv']:<3}: median |{name} error| {_f(value)} % of span, target <= "
                f"{target:g} % -> {'MET' if met else 'NOT MET'}"
            )
        t = s["T_med"]
        print(
            f"mv {s['mv']:<3}: median replay period error {_f(t, '.1f')} %, "
            f"{_f(s['T_within5'] * 100 if s['T_within5'] is not None else None, '.0f')} % of "
            f"cases within {TARGET_PERIOD_PCT:g} % -> "
            f"{'MET' if t is not None and t <= TARGET_PERIOD_PCT else 'NOT MET'} (median)"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=48, help="number of simulated loops")
    parser.add_argument("--seed", type=int, default=1, help="seed of the case draw")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--csv", help="also write the per-case rows to this CSV")
    parser.add_argument("--worst", type=int, default=8, help="list the N worst cases")
    args = parser.parse_args()

    cases = draw_cases(args.cases, args.seed)
    t0 = time.perf_counter()
    rows: list[dict] = []
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as pool:
            for case_rows in pool.map(analyse_case, cases):
                rows.extend(case_rows)
    else:
        for case in cases:
            rows.extend(analyse_case(case))
    elapsed = time.perf_counter() - t0

    print(
        f"analyze() on {args.cases} simulated loops (seed {args.seed}, valve choudhury, "
        f"ts {TS:g} s, noise {NOISE_FRACTION[0]:.1%}-{NOISE_FRACTION[1]:.0%} of pv std), "
        f"gap off; {elapsed:.0f} s"
    )
    print("errors |S - S_true|, |J - J_true| in % of span; period error |T_replay/T_data - 1|;")
    print(
        "vs noise-free |T_replay/T_clean - 1| and noise shift |T_data/T_clean - 1|, T_clean "
        "the pv period of the same loop without measurement noise"
    )
    print()
    summary = summarise(rows)
    print_table(summary)
    print_verdicts(summary)

    failed = [r for r in rows if "error" in r]
    for r in failed:
        print(f"FAILED case {r['case']} ({r['template']}, mv={r['with_mv']}): {r['error']}")
    if args.worst:
        print()
        print(f"worst {args.worst} cases by max(|S err|, |J err|):")
        ok = [r for r in rows if "error" not in r and r["limit_cycle"]]
        ok.sort(key=lambda r: -max(r["S_err"], r["J_err"]))
        for r in ok[: args.worst]:
            print(
                f"  case {r['case']:>2} {r['template']:<15} mv={'yes' if r['with_mv'] else 'no ':<3} "
                f"S {r['S']:.2f}->{r['S_hat']:.2f}  J {r['J']:.2f}->{r['J_hat']:.2f}  "
                f"noise {r['noise_fraction']:.1%}  T data/replay/noise-free "
                f"{_f(r['period_data'], '.0f')}/{_f(r['period_replay'], '.0f')}/"
                f"{_f(r['period_clean'], '.0f')} s  {r['verdict']}"
            )
        slow = [
            r
            for r in rows
            if "error" not in r
            and r["limit_cycle"]
            and (r["period_err_pct"] is None or r["period_err_pct"] > TARGET_PERIOD_PCT)
        ]
        print()
        print(f"cases with a limit cycle whose replay period is off by > {TARGET_PERIOD_PCT:g} %:")
        for r in sorted(slow, key=lambda r: -(r["period_err_pct"] or 1e9)):
            print(
                f"  case {r['case']:>2} {r['template']:<15} mv={'yes' if r['with_mv'] else 'no ':<3} "
                f"S {r['S']:.2f}->{r['S_hat']:.2f}  J {r['J']:.2f}->{r['J_hat']:.2f}  "
                f"noise {r['noise_fraction']:.1%}  T data/replay/noise-free "
                f"{_f(r['period_data'], '.0f')}/{_f(r['period_replay'], '.0f')}/"
                f"{_f(r['period_clean'], '.0f')} s"
            )
    if args.csv:
        import pandas as pd

        pd.DataFrame(rows).to_csv(args.csv, index=False)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
