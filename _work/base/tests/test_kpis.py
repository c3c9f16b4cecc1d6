"""Loop KPIs against values computed by hand on simulated signals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stictiondiag.signals.kpis import harris_index, loop_kpis, reversals

SAMPLES = Path(__file__).resolve().parents[1] / "sample_data"


def _triangle(cycles: int, low: float, high: float, half: int) -> np.ndarray:
    up = np.linspace(low, high, half + 1)[:-1]
    down = np.linspace(high, low, half + 1)[:-1]
    return np.concatenate([np.concatenate([up, down]) for _ in range(cycles)] + [[low]])


def test_travel_reversals_and_saturation_by_hand():
    # op: 10 triangles from 20 to 80 % (50 samples up, 50 down), ts = 2 s, then held at
    # 100 % for 333 samples.  By hand: travel 10 x 2 x 60 = 1200 % plus the step from 20
    # to 100 (80 %) = 1280 % over 1334 samples x 2 s = 2668 s, i.e. 1280 / 2668 x 86400
    # per day; reversals: 19 inside the triangles (the first move sets the direction)
    # and one more where the last fall turns into the step up, 20 in all; saturated
    # 333 of 1334 samples.
    op = np.concatenate([_triangle(10, 20.0, 80.0, 50), np.full(333, 100.0)])
    n = op.size
    assert n == 1334
    pv = np.sin(np.arange(n) / 10.0)
    k = loop_kpis(pv, op, np.zeros(n), 2.0)
    days = n * 2.0 / 86400.0
    assert k["op_travel_per_day"].value == pytest.approx(1280.0 / days, rel=1e-12)
    assert reversals(op, 1.0) == 20
    assert k["op_reversals_per_day"].value == pytest.approx(20 / days, rel=1e-12)
    assert k["time_at_op_limits"].value == pytest.approx(100.0 * 333 / n, rel=1e-12)
    # Error statistics: sp = 0, so the error is -pv.
    assert k["error_mean"].value == pytest.approx(-pv.mean(), abs=1e-12)
    assert k["error_std"].value == pytest.approx(pv.std(), rel=1e-12)
    assert k["service_factor"].value is None and "mode" in k["service_factor"].note
    assert k["harris_index"].value is None
    # Every indicator carries its definition and a citation.
    assert all(item.definition and item.citation for item in k.items)


def test_reversals_ignore_noise_below_the_hysteresis():
    rng = np.random.default_rng(1)
    flat = 50.0 + rng.uniform(-0.4, 0.4, 5000)
    assert reversals(flat, 1.0) == 0  # peak-to-peak 0.8 < 1: no reversal at all


@pytest.mark.parametrize(("phi", "d"), [(0.8, 1), (0.8, 2), (0.5, 3)])
def test_harris_index_of_an_ar1_error_is_the_closed_form(phi, d):
    # e[k] = phi e[k-1] + a[k]: var(e) = var(a) / (1 - phi^2) and the first d terms of
    # the impulse response are phi^i, so eta = (1 - phi^2) sum_{i<d} phi^(2i).
    # Tolerance 0.02: sampling error of two variances over 40 000 samples (~1 %).
    rng = np.random.default_rng(7)
    a = rng.normal(size=40_000)
    e = np.zeros_like(a)
    for i in range(1, a.size):
        e[i] = phi * e[i - 1] + a[i]
    expected = (1 - phi**2) * sum(phi ** (2 * i) for i in range(d))
    assert harris_index(e, d) == pytest.approx(expected, abs=0.02)


def test_harris_index_of_white_noise_is_one():
    # White error: nothing a controller could remove, eta = 1 (within sampling error).
    e = np.random.default_rng(3).normal(size=20_000)
    assert harris_index(e, 1) == pytest.approx(1.0, abs=0.01)


def test_op_not_in_percent_has_no_saturation_figure():
    op = _triangle(5, -2.0, 2.0, 40)
    k = loop_kpis(np.zeros(op.size) + 1.0, op, None, 1.0, op_in_percent=False)
    assert k["time_at_op_limits"].value is None
    assert "op units" in k["op_travel_per_day"].unit


@pytest.mark.slow
def test_analysis_reports_kpis_in_its_json_and_row():
    from stictiondiag import AnalysisConfig, analyze, read_tags

    tags = read_tags(SAMPLES / "level_undershoot.csv")
    result = analyze(tags, config=AnalysisConfig(gap=False, compensation=False))
    d = result.to_dict()
    days = tags.n * tags.ts / 86400.0
    travel = float(np.sum(np.abs(np.diff(tags.op)))) / days
    assert d["kpis"]["op_travel_per_day"]["value"] == pytest.approx(travel, rel=1e-12)
    # The replay identified the dead time, so the Harris index is given, in (0, 1].
    harris = d["kpis"]["harris_index"]["value"]
    assert harris is not None and 0 < harris <= 1
    row = result.summary_row(d)
    assert row["kpi_op_travel_per_day"] == pytest.approx(travel, rel=1e-12)
    # The oscillation KPI is the oscillation found for the verdict (about 1010 s).
    assert d["kpis"]["oscillation_period"]["value"] == pytest.approx(1010, rel=0.05)
