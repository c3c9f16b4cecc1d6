"""The gap's base process replay does not take a flat forecast for the process."""

from __future__ import annotations

from types import SimpleNamespace

from stictiondiag.gap.context import build_context, signals_of
from stictiondiag.gap.effects.base import fit_process
from stictiondiag.models.synthetic import generate_case


def test_first_order_process_is_not_replayed_by_a_gainless_integrator():
    # Case 33 of `stiction benchmark --cases 40 --seed 7`: a first-order process (gain
    # 0.87, time constant 238 s) with an external oscillation at its output.  With an
    # integrator's load tracking searched down to 1e-10, the base replay was an
    # integrator of gain 2.9e-4 /s, thirteen times below the lag's gain over its time
    # constant (0.0037 /s): pv forecast at its level, the valve left out.
    case = generate_case("external_disturbance", 4214880232)
    truth = case.truth["process"]
    assert truth["type"] == "foptd"
    df = case.data.round(6)  # as the benchmark's case file holds it
    tags = SimpleNamespace(
        op=df.op.to_numpy(),
        pv=df.pv.to_numpy(),
        mv=df.mv.to_numpy(),
        sp=df.sp.to_numpy(),
        ts=float(df.time[1] - df.time[0]),
    )
    sig = signals_of(tags)
    ctx = build_context(sig)
    fit = fit_process(sig.mv, ctx, ctx.w_eval)
    assert not fit.integrating
    # The steady-state gain within 25 %: the oscillation at the output leaves the
    # lag's gain free to within a few per cent here (0.86 against 0.87); 25 % allows
    # for the time constant, which the load tracking leaves less well determined
    # (446 s against 238 s) and which the gain trades against.
    assert abs(fit.process.gain / truth["gain"] - 1.0) < 0.25
