"""The sign of the no-mv fit's process gain on simulated loops; prints tables.

A loop that runs under control has ``Kc Kp > 0`` (``e = sp - pv``).  The
Hammerstein fit (:mod:`stictiondiag.stiction.hammerstein`) can hold its process gain
to the sign of the identified controller's gain
(:func:`stictiondiag.identification.controller.loop_gain_sign`).  On loops of the
training family (:func:`stictiondiag.apps.family.family_loop`, mv removed; every
process gain and controller gain of the family is positive, so the truth is +1)
this prints:

1. how often the identified controller gain has the wrong sign, by the R^2 of its
   law, with the recorded set point and with the set point dropped (read against a
   constant one): what :data:`~stictiondiag.identification.controller.SIGN_MIN_R2`
   rests on;
2. how often the fit's process gain has the wrong sign with the sign free
   (``gain_sign=0``) and as the analysis fits it (the controller's sign when well
   determined), and the median and 90th percentile of ``|S - S_true|`` and
   ``|J - J_true|`` [% of span] of sticky and healthy loops for both, and the
   median improvement ``1 - C / C_linear``.

Both fits run on the record as the analysis reads it (:meth:`FamilyLoop.tags`, the
loop type settled by :func:`stictiondiag.analysis.estimate_loop`).  Labels of real
plants are not used.

Usage: ``python benchmarks/gain_sign_family.py [--seed0 20000] [--loops 300]``
(about 0.6 s per loop).
"""

from __future__ import annotations

import argparse
import dataclasses
import math

import numpy as np

R2_THRESHOLDS = (0.05, 0.1, 0.2, 0.3, 0.5)


def one_loop(seed: int) -> dict | None:
    from stictiondiag.analysis import FLOW_LIKE, estimate_loop
    from stictiondiag.apps.family import family_loop
    from stictiondiag.core.errors import StictionError
    from stictiondiag.identification.controller import identify_controller
    from stictiondiag.stiction.hammerstein import fit_hammerstein

    loop = dataclasses.replace(family_loop(seed), mv=None)
    try:
        est = estimate_loop(loop.tags())
        tags = est.tags
        free = fit_hammerstein(
            tags.op,
            tags.pv,
            float(tags.ts),
            integrating=bool(tags.integrating),
            flow_loop=tags.loop_type in FLOW_LIKE,
        )
    except StictionError:
        return None
    row = {"sticky": loop.sticky, "S": loop.truth["S"], "J": loop.truth["J"]}
    for name, fit in (("free", free), ("signed", est.fit)):
        lp = fit.linear_part
        row[name] = (float(lp.direct_gain + lp.lag_gain), fit.S, fit.J, fit.improvement or 0.0)
    row["required"] = 0 if est.fit.gain_sign is None else est.fit.gain_sign.required
    for key, sp in (("sp", loop.sp), ("no_sp", None)):
        try:
            cf = identify_controller(sp, loop.pv, loop.op, loop.ts)
            row[key] = (float(cf.controller.gain), float(cf.fit_r2))
        except StictionError:
            row[key] = None
    return row


def controller_table(rows: list[dict]) -> None:
    print("controller gain sign (truth +1), by the R^2 of the PI law")
    print(f"{'set point':10s} {'R^2 >=':>7s} {'kept':>9s} {'wrong kept':>11s} {'wrong below':>12s}")
    for key in ("sp", "no_sp"):
        got = [r[key] for r in rows if r[key] is not None and math.isfinite(r[key][1])]
        for thr in R2_THRESHOLDS:
            kept = [g for g in got if g[1] >= thr]
            below = [g for g in got if g[1] < thr]
            print(
                f"{key:10s} {thr:7.2f} {len(kept):4d}/{len(got):<4d} "
                f"{sum(g[0] <= 0 for g in kept):11d} {sum(g[0] <= 0 for g in below):12d}"
            )


def fit_table(rows: list[dict]) -> None:
    print("\nprocess gain of the fit (truth +1); errors in % of span")
    head = f"{'loops':14s} {'fit':7s} {'n':>4s} {'Kp<=0':>6s} {'|S err| med/p90':>16s}"
    print(head + f" {'|J err| med/p90':>16s} {'impr. med':>10s}")
    groups = (("sticky", lambda r: r["sticky"]), ("healthy", lambda r: not r["sticky"]))
    for label, keep in groups:
        sub = [r for r in rows if keep(r)]
        for name in ("free", "signed"):
            kp = np.array([r[name][0] for r in sub])
            es = np.array([abs(r[name][1] - r["S"]) for r in sub])
            ej = np.array([abs(r[name][2] - r["J"]) for r in sub])
            imp = np.array([r[name][3] for r in sub])
            print(
                f"{label:14s} {name:7s} {len(sub):4d} {int(np.sum(kp <= 0)):6d} "
                f"{np.median(es):7.2f}/{np.quantile(es, 0.9):<8.2f} "
                f"{np.median(ej):7.2f}/{np.quantile(ej, 0.9):<8.2f} {np.median(imp):10.3f}"
            )
    held = [r for r in rows if r["required"] != 0]
    print(
        f"\nsign held on {len(held)} of {len(rows)} loops; wrong sign held: "
        f"{sum(r['required'] < 0 for r in held)}; fits whose free sign was wrong and "
        f"held: {sum(r['free'][0] <= 0 for r in held)}"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed0", type=int, default=20000, help="first family seed")
    p.add_argument("--loops", type=int, default=300, help="number of family loops")
    args = p.parse_args(argv)
    rows = [r for s in range(args.seed0, args.seed0 + args.loops) if (r := one_loop(s))]
    print(f"{len(rows)} of {args.loops} family loops (seeds {args.seed0}-) fitted without mv\n")
    controller_table(rows)
    fit_table(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
