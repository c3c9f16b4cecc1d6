"""Does the open-loop stiction fit's process gain agree in sign with the controller?

    python scripts/gain_signs_isdb.py [--isdb DIR]

A loop under negative feedback has ``Kc * Kp > 0`` (``e = sp - pv``).  For every ISDB
loop analysed without mv (the Hammerstein fit of :mod:`stictiondiag.stiction.hammerstein`),
this prints S, J, the fit's process gain (the sum of its two input gains, in the
fit's scaled units: only its sign is compared) and the PI gain identified from sp, pv
and op (:func:`stictiondiag.identification.controller.identify_controller`), and
counts the loops whose signs would make the loop a positive-feedback one.  Since the
fit holds its gain to the controller's sign where that sign is well determined
(``StictionFit.gain_sign``), it also prints the sign held (0: free) and counts the
fits that found no valve output driving pv with that sign (a gain of zero).  The
labels are not read.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from stictiondiag.analysis import estimate_loop
from stictiondiag.apps.validation import LOOP_TYPE_MAP, load_manifest
from stictiondiag.core.errors import StictionError
from stictiondiag.identification.controller import identify_controller
from stictiondiag.io.tags import read_tags


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--isdb", default=None, help="ISDB folder (default ../shared/data/isdb)")
    args = p.parse_args(argv)
    m = load_manifest(args.isdb)
    n = opposite = held = inconsistent = 0
    for _, r in m.iterrows():
        lt = LOOP_TYPE_MAP.get(str(r["loop_type"]).lower(), "other")
        try:
            tags = read_tags(
                r["path"], ts=float(r["ts_s"]), loop_type=lt, integrating=bool(r["integrating"])
            )
            fit = estimate_loop(tags).fit
            if fit.method != "hammerstein":
                continue
            lp = fit.linear_part
            kp = 0.0 if lp is None else float(lp.direct_gain) + float(lp.lag_gain)
            kc = identify_controller(tags.sp, tags.pv, tags.op, float(tags.ts)).controller.gain
        except StictionError as exc:
            print(f"{r['loop']:8s} not analysed: {exc}")
            continue
        flip = bool(np.sign(kp) * np.sign(kc) < 0)
        signs = fit.gain_sign
        required = 0 if signs is None else int(signs.required)
        none_fits = signs is not None and not signs.consistent_fit
        n += 1
        opposite += flip
        held += required != 0
        inconsistent += none_fits
        print(
            f"{r['loop']:8s} S {fit.S:6.2f}  J {fit.J:6.2f}  Kp {kp:+9.3g}  Kc {kc:+9.3g}"
            f"  held {required:+d}"
            + ("  positive feedback" if flip else "")
            + ("  no fit of that sign" if none_fits else "")
        )
    print(f"{opposite} of {n} fits without mv have a process gain of the sign of positive feedback")
    print(f"sign held on {held} of {n}; {inconsistent} found no fit of the sign held")
    return 0


if __name__ == "__main__":
    sys.exit(main())
