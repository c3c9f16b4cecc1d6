"""Does the closed-loop refit find the recorded limit cycle on simulated sticky loops?

Each case is a loop of the cause family with a sticky valve
(:func:`stictiondiag.apps.family_causes.cause_loop` with ``generator="valve"``),
analysed as plant data without mv (the refit then refines S and J as well as the
process) by the steps of ``analyze`` (:func:`stictiondiag.analysis.estimate_loop`,
then the replay with and without the refit).  Of the cases whose recorded pv
cycles regularly (Thornhill et al. 2003: regularity >= 1), the table counts the
replays that reproduce the cycle (:func:`stictiondiag.replay.metrics.cycle_reproduction`:
period within 20 %, amplitude within 35 %):

* the open-loop fit's replay (``refit=False``);
* the replay ``analyze`` reports (with the closed-loop refit);

and, apart, the cases whose open-loop replay does not cycle at all (the refit must
leave the no-cycle basin there).

Usage: ``python benchmarks/refit_reach.py [--cases 40] [--seed 0] [--csv rows.csv]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np


def _case(seed: int) -> dict | None:
    from stictiondiag.analysis import estimate_loop
    from stictiondiag.apps.family_causes import cause_loop
    from stictiondiag.core.errors import StictionError
    from stictiondiag.replay.closed_loop import replay
    from stictiondiag.replay.metrics import cycle_reproduction
    from stictiondiag.signals.oscillation import detect_oscillation

    loop = cause_loop(seed, generator="valve")
    try:
        tags = dataclasses.replace(loop.tags(), mv=None)
    except StictionError:
        return None
    osc = detect_oscillation(tags.pv, float(tags.ts))
    if osc.regularity is None or osc.regularity < 1.0:
        return None
    row: dict = {"seed": seed, "S_true": loop.truth.get("S"), "J_true": loop.truth.get("J")}
    try:
        est = estimate_loop(tags)
        reps = [
            replay(
                est.tags,
                est.fit,
                valve=est.fit.valve_family,
                integrating=est.tags.integrating,
                action=est.tags.action,
                known=est.structure,
                refit=refit,
            )
            for refit in (False, True)
        ]
    except StictionError as exc:
        row["error"] = str(exc)
        return row
    open_rep, rep = reps
    c0 = cycle_reproduction(open_rep.data.pv, open_rep.pv, float(open_rep.dt))
    c1 = cycle_reproduction(rep.data.pv, rep.pv, float(rep.dt))
    rf = rep.settings.refit
    row.update(
        S=float(est.fit.S),
        J=float(est.fit.J),
        open_cycles=c0.period_replay_s is not None,
        open_reproduced=bool(c0.reproduced),
        reproduced=bool(c1.reproduced),
        S_refit=float(rep.S),
        J_refit=float(rep.J),
        sims=None if rf is None else rf.simulations,
        refit_reason=None if rf is None else rf.reason,
    )
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=40, help="seeds drawn [-]")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--csv", default=None, help="write the rows to this CSV file")
    args = p.parse_args(argv)
    rows = []
    t0 = time.process_time()
    for s in range(args.seed, args.seed + args.cases):
        r = _case(s)
        if r is None:
            continue
        rows.append(r)
        if "error" in r:
            print(f"seed {s:4d}: {r['error']}", flush=True)
            continue
        print(
            f"seed {s:4d}: S/J true {r['S_true']:.2f}/{r['J_true']:.2f} "
            f"open-loop {r['S']:.2f}/{r['J']:.2f} "
            f"{'cycles' if r['open_cycles'] else 'NO CYCLE'} "
            f"{'R' if r['open_reproduced'] else '-'}  refit {r['S_refit']:.2f}/"
            f"{r['J_refit']:.2f} {'R' if r['reproduced'] else '-'}  sims {r['sims']}",
            flush=True,
        )
    ok = [r for r in rows if "error" not in r]
    nc = [r for r in ok if not r["open_cycles"]]
    print(f"regularly cycling cases: {len(rows)} ({len(rows) - len(ok)} without a replay)")
    print(
        f"reproduced: open-loop fit {sum(r['open_reproduced'] for r in ok)} of {len(ok)}, "
        f"with the refit {sum(r['reproduced'] for r in ok)} of {len(ok)}"
    )
    print(
        f"open-loop replay without a cycle: {len(nc)}; reproduced after the refit: "
        f"{sum(r['reproduced'] for r in nc)} of {len(nc)}"
    )
    sims = [r["sims"] for r in ok if r["sims"]]
    if sims:
        print(f"closed-loop simulations per refit: median {np.median(sims):.0f}, max {max(sims)}")
    print(f"cpu {time.process_time() - t0:.0f} s")
    if args.csv:
        import pandas as pd

        from stictiondiag.core.atomic import write_atomic

        write_atomic(args.csv, pd.DataFrame(rows).to_csv(index=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
