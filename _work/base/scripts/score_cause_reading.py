"""Score the cause model's reading on a validation run, as if it decided.

    python scripts/score_cause_reading.py validation.json

Reads the per-loop table that ``stiction validate --json`` writes and prints, for
the stated and the likely labels, the area under the ROC curve of the cause model's
P(the valve causes the cycle) (0 for a loop without a cycle) and the accuracy the
verdict would have if the cause model decided loops with a cycle (``stiction`` at
P(valve) >= 0.6, ``no_stiction`` at <= 0.4, ``inconclusive`` between:
``stictiondiag.stiction.verdict.VALVE_LEVEL``), the loops without a cycle keeping their
verdict.  It reads a finished run's results; it fits and chooses nothing.
"""

from __future__ import annotations

import json
import sys

import numpy as np

LEVEL = 0.6


def auc(y: np.ndarray, s: np.ndarray) -> float:
    """Area under the ROC curve (Mann-Whitney count, ties half)."""
    p, n = s[y], s[~y]
    gt = (p[:, None] > n[None, :]).sum() + 0.5 * (p[:, None] == n[None, :]).sum()
    return float(gt / (p.size * n.size))


def call(r: dict) -> str:
    p = r["p_valve_cause"]
    if p is None:
        return r["verdict"]
    return "stiction" if p >= LEVEL else ("no_stiction" if p <= 1 - LEVEL else "inconclusive")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print(__doc__.splitlines()[2].strip(), file=sys.stderr)
        return 2
    with open(argv[0]) as fh:
        loops = json.load(fh)["loops"]
    for group in ("stated", "likely"):
        rows = [r for r in loops if r["label_group"] == group]
        y = np.array([r["label"] == "stiction" for r in rows])
        pv = np.array([r["p_valve_cause"] or 0.0 for r in rows])
        calls = [call(r) for r in rows]
        acc = np.mean([(c == "stiction") == t for c, t in zip(calls, y, strict=True)])
        healthy = sum(c == "stiction" and not t for c, t in zip(calls, y, strict=True))
        print(
            f"{group}: {len(rows)} loops; area under the ROC curve of P(valve) {auc(y, pv):.2f};"
            f" had the cause model decided: accuracy {acc:.2f}, healthy loops called"
            f" stiction {healthy}, inconclusive {calls.count('inconclusive')}"
        )
    n_inc = sum(call(r) == "inconclusive" for r in loops)
    print(f"all loops: {len(loops)}; inconclusive had the cause model decided: {n_inc}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
