"""Why a held deadband archive of op biases S, and what the banded reading of op does.

    python scripts/compressed_op.py

Each bundled sample with mv has its op and mv put through exception (deadband)
compression at 0.05 to 0.5 % of span and rebuilt on the scan grid held, as the reader
did before op was read banded, and as the reader does now: op banded (the straight
line between archived values within the deadband, :func:`stictiondiag.io.compression.banded`),
mv held (:func:`stictiondiag.io.compression.reconstruct`).  S and J come from the mv-op estimator
(:func:`stictiondiag.stiction.segments.estimate_from_mv`); one line per sample and
deadband, with the deadbands the reader finds in the archives
(:func:`stictiondiag.io.compression.archive_deadbands`); ``*`` marks S and J within
what they can hide (:func:`stictiondiag.stiction.resolution.hidden_by_resolution`).
Then the healthy loop (linear valve) is analysed whole (``analyze``, no gap) for both
readings and for op and mv archived with different deadbands, with the deadbands
carried as the reader carries them and without (docs/historian_exports.md).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stictiondiag import AnalysisConfig, analyze  # noqa: E402
from stictiondiag.io.compression import (  # noqa: E402
    archive_deadbands,
    exception_compress,
    reconstruct,
)
from stictiondiag.io.tags import Tags, read_tags  # noqa: E402
from stictiondiag.stiction.segments import estimate_from_mv  # noqa: E402

SAMPLES = ("level_undershoot", "flow_mixed", "slave_flow_stickslip", "temperature_quantised",
           "healthy_flow")  # fmt: skip
DEADBANDS = (0.05, 0.1, 0.2, 0.5)


def _rebuilt(t, op, mv, deadband_op, deadband_mv, band):
    """op and mv rebuilt from their archives (every tag held, or as the reader does),
    and the deadbands the reader finds in them."""
    i, j = exception_compress(op, deadband_op), exception_compress(mv, deadband_mv)
    series = {"pv": (t, np.zeros(t.size)), "op": (t[i], op[i]), "mv": (t[j], mv[j])}
    how = None if band else "hold"
    arrays, *_ = reconstruct(series, "x", how)
    found = archive_deadbands(series, "x", how)
    return arrays["op"], arrays["mv"], found


def _verdicts() -> None:
    tags = read_tags(ROOT / "sample_data" / "healthy_flow.csv")
    t = np.arange(tags.n) * tags.ts
    print("healthy_flow, whole analysis (no gap): op / mv deadband, reading, verdict, S, J")
    for deadbands in ((0.1, 0.1), (0.05, 0.2), (0.2, 0.05)):
        for band in (False, True):
            op, mv, found = _rebuilt(t, tags.op, tags.mv, *deadbands, band)
            rebuilt = Tags.from_arrays(tags.pv, op, mv=mv, sp=tags.sp, ts=tags.ts,
                                       loop_type="flow")  # fmt: skip
            # As the reader carries them (io.tags.Tags.archive_deadband) ...
            result = analyze(replace(rebuilt, archive_deadband=found),
                             config=AnalysisConfig(gap=False))  # fmt: skip
            # ... and without them, as before the valve fit knew the archive.
            blind = analyze(rebuilt, config=AnalysisConfig(gap=False))
            print(f"  {deadbands[0]:.2f} / {deadbands[1]:.2f}  {'op banded' if band else 'held':9s}"
                  f"  {result.verdict.status:12s} S {result.fit.S:.3f}  J {result.fit.J:.3f}"
                  f"  P {result.verdict.evidence.p_friction:.2f}"
                  f"  (deadbands not known: {blind.verdict.status}, S {blind.fit.S:.3f})",
                  flush=True)  # fmt: skip


def main() -> None:
    print("sample                 deadband  plain S / J    op held S / J   op banded S / J"
          "   (* within what the archive can hide)")  # fmt: skip
    for name in SAMPLES:
        tags = read_tags(ROOT / "sample_data" / f"{name}.csv")
        op, mv, ts = np.asarray(tags.op), np.asarray(tags.mv), tags.ts
        t = np.arange(op.size) * ts
        plain = estimate_from_mv(op, mv, ts)
        for deadband in DEADBANDS:
            cells = []
            for band in (False, True):
                op_r, mv_r, found = _rebuilt(t, op, mv, deadband, deadband, band)
                fit = estimate_from_mv(op_r, mv_r, ts, deadband=found)
                hidden = fit.resolution is not None and fit.resolution.within
                cells.append(f"{fit.S:5.2f} / {fit.J:4.2f}{'*' if hidden else ' '}")
            print(f"{name:22s} {deadband:8.2f}  {plain.S:5.2f} / {plain.J:4.2f}  "
                  f"{cells[0]:>14s}  {cells[1]:>14s}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
    _verdicts()
