"""Tests of the describing function (Section 6, Eqs. 7-10) and limit-cycle prediction."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from stictiondiag import UsageError
from stictiondiag.models.describing import (
    describing_function,
    describing_function_numeric,
    predict_limit_cycle,
)
from stictiondiag.models.processes import (
    FOPTD,
    LOOP_PARAMETERS,
    PI,
    Integrating,
)

# REFERENCE.md, "Describing function": (S, J, Xm, Re N, Im N), printed to 4 decimals.
N_TABLE = [
    (5, 2, 3.75, 0.6119, -0.3961),
    (5, 2, 10, 0.9148, -0.1751),
    (5, 0, 10, 0.8045, -0.2387),
    (5, 5, 5, 1.1366, -0.3183),
    (3, 4.5, 6, 1.2180, 0.0000),
    (5, 5, 50, 1.0091, -0.0032),
]

# REFERENCE.md, "Closed loops": (loop, S, J, DF period [s], DF op amplitude [%]).
LIMIT_CYCLES = [
    ("concentration", 5, 2, 198.0, 2.57),
    ("concentration", 5, 5, 82.9, 2.95),
    ("concentration", 5, 7, 64.2, 3.33),
    ("level", 3, 0, 17.3, 2.71),
    ("level", 3, 3, 9.8, 1.69),
    ("level", 3, 3.5, 8.8, 1.66),
    ("level", 3, 4.5, 7.3, 1.61),
]


@pytest.mark.parametrize(("S", "J", "Xm", "re", "im"), N_TABLE)
def test_closed_form_matches_reference_table(S, J, Xm, re, im):
    N = describing_function(Xm, S, J)
    # The table is printed to 4 decimals: half a unit of the last digit.
    assert N.real == pytest.approx(re, abs=5e-5)
    assert N.imag == pytest.approx(im, abs=5e-5)


@pytest.mark.parametrize(("S", "J", "Xm", "re", "im"), N_TABLE)
def test_closed_form_against_simulated_first_harmonic(S, J, Xm, re, im):
    P = 20000
    numeric = describing_function_numeric(Xm, S, J, samples_per_period=P)
    analytic = describing_function(Xm, S, J)
    # The simulated valve slips at the first sample past the threshold, so each
    # slip is late by up to one sample (2 pi / P rad): the harmonic is off by at
    # most about 2 J / (P Xm) = 1e-4 for S = J = Xm (the worst row here).
    assert abs(numeric - analytic) <= 2 * J / (P * Xm) + 1e-6
    assert abs(numeric - analytic) < 1e-3


def test_numeric_converges_with_sampling():
    coarse = describing_function_numeric(4.0, 5, 3, samples_per_period=2000)
    fine = describing_function_numeric(4.0, 5, 3, samples_per_period=40000)
    exact = describing_function(4.0, 5, 3)
    # Slip-timing error is first order in the sample time: 20 times finer sampling
    # shrinks it by about 20 (at least 5 allowing for where the samples fall).
    assert abs(fine - exact) < abs(coarse - exact) / 5
    assert abs(fine - exact) < 1e-4


def test_numeric_large_amplitude_uses_homogeneity():
    # Xm = 200 % cannot be simulated around 50 %; the model is homogeneous in
    # (op - 50, S, J), so it is simulated scaled down.  Same tolerance as above.
    n = describing_function_numeric(200.0, 20.0, 10.0)
    assert abs(n - describing_function(200.0, 20.0, 10.0)) < 1e-3


def test_vectorised_and_shape():
    Xm = np.array([[3.0, 4.0], [10.0, 100.0]])
    N = describing_function(Xm, 5, 2)
    assert N.shape == (2, 2) and np.iscomplexobj(N)
    for idx, x in np.ndenumerate(Xm):
        assert N[idx] == describing_function(float(x), 5, 2)


def test_no_output_below_half_S():
    N = describing_function(np.array([0.0, 1.0, 2.4999, 2.5]), 5, 2)
    assert np.isnan(N[:3]).all()
    assert np.isfinite(N[3])


def test_large_amplitude_asymptote():
    # Section 6.3: N -> 1 for Xm >> S; the leading correction is O(S / Xm).
    for S, J in [(5, 0), (5, 2), (5, 5), (3, 4.5)]:
        Xm = np.array([1e2, 1e3, 1e4])
        err = np.abs(describing_function(Xm, S, J) - 1.0)
        assert (err < 3 * S / Xm).all()
        assert err[-1] < 1e-3


@pytest.mark.parametrize(("S", "J"), [(5, 5), (5, 2), (3, 4.5), (5, 0), (4, 1)])
def test_half_S_limit(S, J):
    Xm = S / 2
    N = describing_function(Xm, S, J)
    expected = 2 * J / (math.pi * Xm) * np.exp(-1j * math.pi / 2)
    # Exact formula at phi = -pi/2; rounding only.
    assert N == pytest.approx(expected, abs=1e-12)
    # Approaching from above is continuous (phi ~ sqrt of the excess).
    assert describing_function(Xm * (1 + 1e-10), S, J) == pytest.approx(expected, abs=1e-4)


def test_half_S_limit_special_cases():
    # S = J: square wave of amplitude Xm lagging by a quarter cycle, N = 4/pi e^{-i pi/2}.
    assert describing_function(2.5, 5, 5) == pytest.approx(-4j / math.pi, abs=1e-12)
    # J = S/2: N = 2/pi e^{-i pi/2} (Appendix A.3).
    assert describing_function(2.5, 5, 2.5) == pytest.approx(-2j / math.pi, abs=1e-12)
    # Pure deadband: N -> 0.
    assert abs(describing_function(2.5, 5, 0)) < 1e-12


def test_phase_lag_for_undershoot_and_deadband():
    # The stuck phases delay the output: Im N <= 0 whenever J <= S.
    Xm = np.linspace(2.5, 100, 500)
    for J in (0, 1, 2.5, 5):
        assert (describing_function(Xm, 5, J).imag <= 1e-12).all()


@pytest.mark.parametrize(("S", "J"), [(-1, 0), (1, -1), ("a", 1), (float("nan"), 1)])
def test_bad_parameters(S, J):
    with pytest.raises(UsageError):
        describing_function(3.0, S, J)


@pytest.mark.parametrize(("loop", "S", "J", "period", "amplitude"), LIMIT_CYCLES)
def test_limit_cycle_predictions_match_reference(loop, S, J, period, amplitude):
    params = LOOP_PARAMETERS[loop]
    pred = predict_limit_cycle(params["process"], params["controller"], S, J)
    assert pred.limit_cycle and pred.stable
    # The reference is printed to three significant figures; the root finder
    # converges to ~1e-10, so the rounding of the table (0.5 in the last digit,
    # at most 0.3 % of the period here) sets the tolerance.  The amplitude gets
    # 1e-4 more: 2.94493 (S = J = 5) sits on a rounding boundary and the table
    # says 2.95, i.e. its own solution was about 2.9450.
    assert pred.period_s == pytest.approx(period, rel=3e-3)
    assert pred.amplitude_op == pytest.approx(amplitude, abs=0.005 + 1e-4)
    assert pred.frequency_rad_s == pytest.approx(2 * math.pi / pred.period_s)
    # The solution satisfies Eq. 5 itself.
    G0 = params["process"].frequency_response(pred.frequency_rad_s) * params[
        "controller"
    ].frequency_response(pred.frequency_rad_s)
    N = describing_function(pred.amplitude_op, S, J)
    assert abs(1 + N * G0) < 1e-8


def test_pure_deadband_concentration_loop_has_no_limit_cycle():
    params = LOOP_PARAMETERS["concentration"]
    pred = predict_limit_cycle(params["process"], params["controller"], 5, 0)
    assert not pred.limit_cycle
    assert pred.period_s is None and pred.amplitude_op is None and pred.solutions == ()
    d = pred.to_dict()
    assert d["limit_cycle"] is False and d["period_s"] is None
    json.dumps(d)


def test_pure_deadband_level_loop_has_a_limit_cycle():
    # Section 6.4: the integrator makes even a pure deadband cycle.
    params = LOOP_PARAMETERS["level"]
    assert predict_limit_cycle(params["process"], params["controller"], 3, 0).limit_cycle


@pytest.mark.parametrize("J", [0.05, 0.5, 1.0, 3.0, 10.0])
def test_any_slip_jump_cycles_in_the_concentration_loop(J):
    # Section 6.4: the -1/N curve reaches the negative imaginary axis when J > 0, and
    # the PI + FOPTD response crosses it: a limit cycle for any slip jump.
    params = LOOP_PARAMETERS["concentration"]
    pred = predict_limit_cycle(params["process"], params["controller"], 5, J)
    assert pred.limit_cycle and pred.stable


def test_period_shortens_with_slip_jump():
    # Section 6.4: slip-jump curves intersect at higher frequency.
    params = LOOP_PARAMETERS["level"]
    periods = [
        predict_limit_cycle(params["process"], params["controller"], 3, J).period_s
        for J in (0, 3, 3.5, 4.5)
    ]
    assert periods == sorted(periods, reverse=True)


def test_linear_valve_has_no_limit_cycle():
    params = LOOP_PARAMETERS["concentration"]
    assert not predict_limit_cycle(params["process"], params["controller"], 0, 0).limit_cycle


def test_loeb_criterion_marks_an_unstable_cycle():
    # Concentration loop with the gain raised past the linear stability limit
    # (Kc = 0.524): the linear loop diverges, a deadband only holds small signals.
    # The single intersection separates decay (small) from divergence (large): an
    # unstable limit cycle.  With a slip jump a stable small cycle appears below it.
    process, kc = FOPTD(3.0, 10.0, 10.0), 0.55
    dead = predict_limit_cycle(process, PI(kc, 10.0), 5, 0)
    assert dead.limit_cycle and len(dead.solutions) == 1 and dead.stable is False
    slip = predict_limit_cycle(process, PI(kc, 10.0), 5, 1)
    stable = [s for s in slip.solutions if s.stable]
    unstable = [s for s in slip.solutions if not s.stable]
    assert len(stable) == 1 and len(unstable) == 1
    assert stable[0].amplitude_op < unstable[0].amplitude_op
    assert slip.amplitude_op == stable[0].amplitude_op


def test_fold_in_the_phase_is_found():
    # Level loop with a dead time: the open-loop phase rises then falls, so the
    # phase condition has two branches that meet in a fold; the intersection lies
    # next to the fold.  Checked against a brute-force grid minimum of |1 + N G0|.
    process, controller = Integrating(1.0, 1.0), PI(0.4, 2.0)
    pred = predict_limit_cycle(process, controller, 3, 0)
    assert pred.limit_cycle
    Xm = pred.amplitude_op + np.linspace(-0.05, 0.05, 201)
    w = pred.frequency_rad_s * np.linspace(0.95, 1.05, 201)
    F = 1 + describing_function(Xm[:, None], 3, 0) * (
        process.frequency_response(w[None, :]) * controller.frequency_response(w[None, :])
    )
    i, j = np.unravel_index(np.argmin(np.abs(F)), F.shape)
    # The grid steps are 5e-4 in Xm and 5e-4 relative in w.
    assert Xm[i] == pytest.approx(pred.amplitude_op, abs=1e-3)
    assert w[j] == pytest.approx(pred.frequency_rad_s, rel=1e-3)


def test_to_dict_plain_types():
    params = LOOP_PARAMETERS["level"]
    d = predict_limit_cycle(params["process"], params["controller"], 3, 3).to_dict()
    text = json.dumps(d)
    assert "NaN" not in text
    assert isinstance(d["period_s"], float) and d["solutions"][0]["stable"] is True


def test_plot_nyquist_df_marks_the_intersections():
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    from stictiondiag.models.describing import limit_cycle_diagram

    params = LOOP_PARAMETERS["concentration"]
    fig = limit_cycle_diagram(
        params["process"], params["controller"], {"deadband": (5, 0), "J=2": (5, 2)}
    ).plot()
    try:
        assert isinstance(fig, Figure)
        ax = fig.axes[0]
        markers = [ln for ln in ax.lines if ln.get_marker() in ("o", "x")]
        # Deadband: no intersection; J = 2: one stable cycle marked on G0.
        assert len(markers) == 1
        x, y = markers[0].get_xdata()[0], markers[0].get_ydata()[0]
        pred = predict_limit_cycle(params["process"], params["controller"], 5, 2)
        g = params["process"].frequency_response(pred.frequency_rad_s) * params[
            "controller"
        ].frequency_response(pred.frequency_rad_s)
        assert complex(x, y) == pytest.approx(g, abs=1e-12)
        assert len(ax.texts) == 1 and "198" in ax.texts[0].get_text()
    finally:
        plt.close(fig)
