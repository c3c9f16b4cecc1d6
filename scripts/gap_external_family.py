"""What the gap names on simulated loops that cycle because of an external oscillation.

    python scripts/gap_external_family.py [--first 100] [--last 170]

The cause family (:mod:`stictiondiag.apps.family_causes`, generator ``external``):
a linear valve (in a quarter of the loops a mildly sticky one) and a periodic load
that is mostly not a sinusoid (a triangle, a square wave, two tones, intermittent
bursts, or a sine); for cascade slaves the master's set point carries it.  A loop
counts when its counterfactual label is ``external`` (its twin without the load no
longer cycles).  Each is diagnosed as ``stiction gap`` does (no mv, as on the ISDB),
and the script prints the effect named per loop and how many are
``external_disturbance``.  Simulated loops only: no ISDB record or label is read.
"""

from __future__ import annotations

import argparse

from stictiondiag.analysis import diagnose_gap_tags
from stictiondiag.apps.family_causes import cause_label
from stictiondiag.core.errors import StictionError
from stictiondiag.io.tags import Tags


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first", type=int, default=100, help="first family seed")
    ap.add_argument("--last", type=int, default=170, help="last family seed (excluded)")
    args = ap.parse_args(argv)
    named = total = 0
    for seed in range(args.first, args.last):
        loop, label = cause_label(seed, generator="external")
        if label != "external":
            continue
        t = loop.truth
        tags = Tags.from_arrays(
            loop.pv,
            loop.op,
            sp=loop.sp,
            ts=loop.ts,
            loop_type=loop.loop_type,
            integrating=loop.integrating,
        )
        try:
            g = diagnose_gap_tags(tags)
        except StictionError as exc:
            print(f"{seed} {t['shape']} {t['kind']}: no gap diagnosis ({exc})")
            continue
        total += 1
        named += g.effect == "external_disturbance"
        print(
            f"{seed} {t['shape']:9s} {t['kind']:11s} valve {t['valve']:9s} n {t['n']:5d} "
            f"named {g.effect:21s} gap {g.before:6.2f} -> {g.after:6.2f} %",
            flush=True,
        )
    print(f"external_disturbance named on {named} of {total} loops labelled external")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
