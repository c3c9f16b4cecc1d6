"""Plant-wide oscillations: grouping, source ranking, roles, the generator and the scan step."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from stictiondiag.core.errors import DataError, UsageError
from stictiondiag.signals.plantwide import (
    cycle_lag,
    harmonic_ratio,
    plant_oscillations,
)
from stictiondiag.stiction.plantwide import diagnose_plant

DT = 1.0
N = 3000


def _square(period: float, n: int = N, phase: float = 0.0) -> np.ndarray:
    t = np.arange(n) * DT
    return np.sign(np.sin(2 * np.pi * (t / period) + phase))


def _lowpass(x: np.ndarray, tau: float, delay: int = 0) -> np.ndarray:
    a = np.exp(-DT / tau)
    y = np.empty_like(x)
    s = 0.0
    shifted = np.concatenate([np.full(delay, x[0]), x[: x.size - delay]]) if delay else x
    for k in range(x.size):
        s = a * s + (1 - a) * shifted[k]
        y[k] = s
    return y


def _plant(seed: int = 1) -> dict[str, np.ndarray]:
    """A sticky-like square cycle (period 100 s), two filtered and delayed copies of it,
    a loop with its own sinusoidal cycle (period 37 s) and a noise loop."""
    rng = np.random.default_rng(seed)
    src = _lowpass(_square(100.0), 3.0) + 0.1 * rng.normal(size=N)
    down1 = _lowpass(src, 10.0, 5) + 0.1 * rng.normal(size=N)
    down2 = _lowpass(down1, 8.0, 4) + 0.1 * rng.normal(size=N)
    own = np.sin(2 * np.pi * np.arange(N) * DT / 37.0) + 0.2 * rng.normal(size=N)
    noise = rng.normal(size=N)
    return {"SRC": src, "D1": down1, "D2": down2, "OWN": own, "NOISE": noise}


def test_group_of_a_propagated_cycle_and_nothing_else():
    res = plant_oscillations(_plant(), DT)
    assert len(res.groups) == 1
    g = res.groups[0]
    assert set(g.members) == {"SRC", "D1", "D2"}
    # Welch segments of 1500 samples resolve 1/1500 Hz: the power-weighted period
    # is within 3 % of the true 100 s.
    assert g.period_s == pytest.approx(100.0, rel=0.03)
    assert sum(g.shares) == pytest.approx(1.0, abs=1e-9)
    assert all(0.0 < f <= 1.0 for f in g.power_fractions)
    assert res.groups_of("OWN") == [] and res.groups_of("NOISE") == []


def test_the_harmonics_of_a_square_cycle_make_no_group_of_their_own():
    rng = np.random.default_rng(3)
    sq = _square(90.0) + 0.05 * rng.normal(size=N)
    copy = _square(90.0, phase=0.4) + 0.05 * rng.normal(size=N)
    res = plant_oscillations({"A": sq, "B": copy}, DT)
    assert [round(g.period_s / 90.0) for g in res.groups] == [1]


def test_two_loops_with_near_periods_but_no_common_cause_are_not_grouped():
    # Two independent narrow-band cycles 3 % apart in period: each peak passes, they
    # fall in one cluster, but they are not coherent.
    rng = np.random.default_rng(5)
    t = np.arange(N) * DT
    a = np.sin(2 * np.pi * t / 50.0 + np.cumsum(rng.normal(0, 0.05, N))) + 0.2 * rng.normal(size=N)
    b = np.sin(2 * np.pi * t / 51.5 + np.cumsum(rng.normal(0, 0.05, N))) + 0.2 * rng.normal(size=N)
    assert plant_oscillations({"A": a, "B": b}, DT).groups == ()


def test_cycle_lag_times_a_delayed_copy():
    x = _lowpass(_square(120.0), 2.0) + 0.01 * np.random.default_rng(0).normal(size=N)
    late = np.concatenate([np.full(7, x[0]), x[:-7]])
    # The lag is the peak of a sampled cross-correlation: exact to one sample.
    assert cycle_lag(late, x, DT, 120.0) == pytest.approx(7.0, abs=1.0)
    assert cycle_lag(x, late, DT, 120.0) == pytest.approx(-7.0, abs=1.0)


def test_harmonic_ratio_of_a_square_wave_and_a_sine():
    # Odd harmonics of a square wave: (1/9 + 1/25) of the fundamental's power up to the 5th.
    sq = _square(100.0)
    assert harmonic_ratio(sq, DT, 100.0) == pytest.approx(1 / 9 + 1 / 25, rel=0.1)
    sine = np.sin(2 * np.pi * np.arange(N) / 100.0)
    assert harmonic_ratio(sine, DT, 100.0) < 1e-3


def test_source_ranked_first_and_the_others_propagated():
    d = diagnose_plant(_plant(), DT, {"SRC": 0.6, "D1": 0.8, "D2": 0.9})
    (g,) = d.groups
    assert [e.loop for e in g.ranking] == ["SRC", "D1", "D2"]
    assert g.clear and g.candidates == ("SRC",)
    assert d.roles["SRC"].role == "source_candidate"
    assert d.roles["D2"].role == "propagated"
    assert d.roles["D2"].cause == "propagated: the cycle comes from SRC"
    assert d.roles["OWN"].role == "independent"
    json.dumps(d.to_dict())  # JSON-able


def test_simultaneous_cycles_are_no_single_source():
    # Two loops that see one cycle at the same instant: the timing cannot tell.
    rng = np.random.default_rng(8)
    base = _lowpass(_square(80.0), 3.0)
    sig = {"A": base + 0.05 * rng.normal(size=N), "B": base + 0.05 * rng.normal(size=N)}
    (g,) = diagnose_plant(sig, DT).groups
    assert not g.clear and set(g.candidates) == {"A", "B"}
    assert "no single source" in g.note


def test_bad_input_is_a_one_line_error():
    with pytest.raises(DataError, match="differ in length"):
        plant_oscillations({"A": np.zeros(500), "B": np.zeros(400)}, DT)
    with pytest.raises(UsageError, match="unknown grouping method"):
        plant_oscillations({"A": np.zeros(500)}, DT, method="pca")
    with pytest.raises(UsageError):
        plant_oscillations({"A": np.zeros(500)}, -1.0)


def test_generated_plant_truth_is_consistent():
    from stictiondiag.models.synthetic_plant import generate_plant

    p = generate_plant(4)
    assert 5 <= len(p.truth) <= 15
    assert list(p.frame.columns[:1]) == ["time"]
    for gid, g in p.groups.items():
        assert p.truth[g["source"]]["role"] == "source"
        assert all(p.truth[m]["group"] == gid for m in g["members"])
    again = generate_plant(4)
    pd.testing.assert_frame_equal(p.frame, again.frame)  # same seed, same plant


def test_scorer_counts_membership_sources_and_calls():
    from stictiondiag.apps.plant_benchmark import score_plant
    from stictiondiag.models.synthetic_plant import generate_plant

    p = generate_plant(4)
    (gid, g), *_ = p.groups.items()
    found = [
        {"group": 1, "period_s": 1.0, "members": g["members"], "ranking": [{"loop": g["source"]}]}
    ]
    prop = [m for m in g["members"] if m != g["source"]]
    verdicts = {m: "propagated" for m in prop}
    own = {m: "stiction" for m in prop[:1]}
    s = score_plant(p, found, verdicts, own)
    assert s.membership_right == s.n_loops - sum(
        len(t["members"]) for k, t in p.groups.items() if k != gid
    )
    assert s.sources_first == 1
    assert s.propagated_stiction == 0 and s.propagated_stiction_own == 1


def _wide(tmp_path, seed=11, n_loops=5, start=0.0):
    from stictiondiag.models.synthetic_plant import generate_plant

    p = generate_plant(seed, n_loops=n_loops, n_samples=2000)
    frame = p.frame.copy()
    frame["time"] = frame["time"] + start
    return p, frame


def test_scan_of_a_wide_plant_file_groups_and_relabels(tmp_path):
    from stictiondiag.apps.scan import scan

    p, frame = _wide(tmp_path)
    frame.to_csv(tmp_path / "plant.csv", index=False)
    res = scan(tmp_path / "plant.csv", out=tmp_path / "out", gap=False, workers=1)
    assert res.plantwide["status"] == "on"
    table = pd.read_parquet(tmp_path / "out" / "scan.parquet")
    assert {"plant_group", "plant_role", "plant_cause"} <= set(table.columns)
    record = json.loads((tmp_path / "out" / "plantwide.json").read_text())
    assert record["groups"], "the generated plant has a sticky source"
    src = p.groups[1]["source"]
    row = table.set_index("loop").loc
    # The source's cycle leads its downstream loops by their couplings' delays.
    assert record["groups"][0]["ranking"][0]["loop"] == src
    for m in p.groups[1]["members"]:
        if m != src:
            assert row[m, "plant_role"] == "propagated"
            assert row[m, "verdict"] == "propagated"
            assert row[m, "plant_cause"] == f"propagated: the cycle comes from {src}"
            assert row[m, "cause"] == f"propagated: the cycle comes from {src}"
    html = (tmp_path / "out" / "index.html").read_text()
    assert "Plant-wide oscillations" in html and "<svg" in html


def test_scan_of_files_recorded_at_different_times_says_grouping_is_off(tmp_path):
    from stictiondiag.apps.scan import scan

    _, frame = _wide(tmp_path, n_loops=5)
    loops = [c[:-3] for c in frame.columns if c.endswith(".PV")][:2]
    for i, loop in enumerate(loops):
        part = frame[["time", f"{loop}.PV", f"{loop}.OP"]].copy()
        part.columns = ["time", "pv", "op"]
        part["time"] += i * 1e6  # a million seconds apart
        part.to_csv(tmp_path / f"{loop}.csv", index=False)
    res = scan(tmp_path, out=tmp_path / "out", gap=False, workers=1)
    assert res.plantwide["status"] == "off"
    assert "do not overlap in time" in res.plantwide["reason"]
    assert "grouping off" in (tmp_path / "out" / "index.html").read_text()
    table = pd.read_parquet(tmp_path / "out" / "scan.parquet")
    assert table["plant_role"].isna().all()


def test_a_failing_plant_step_leaves_the_loops_results(monkeypatch):
    from stictiondiag.apps import plantwide
    from stictiondiag.apps.scan import LoopSource

    def broken(*args, **kwargs):
        raise ValueError("boom")

    monkeypatch.setattr(plantwide, "_stamped_pv", broken)
    rows = [{"loop": "A", "verdict": "stiction"}, {"loop": "B", "verdict": "no_stiction"}]
    out = plantwide.plantwide_step([LoopSource("A", "a.csv"), LoopSource("B", "b.csv")], rows, {})
    assert out["status"] == "off" and "internal error: ValueError: boom" in out["reason"]
    assert [r["verdict"] for r in rows] == ["stiction", "no_stiction"]
    assert all(r["plant_role"] is None for r in rows)


def test_benchmark_plant_command(tmp_path, monkeypatch):
    # The plants are generated for real; the scan is replaced by the plant-wide step
    # alone on the exported file (no per-loop analysis), so the test checks the
    # plumbing and scores in seconds.
    import types

    from typer.testing import CliRunner

    import stictiondiag.apps.scan as scan_module
    from stiction_cli.main import app

    def fake_scan(path, *, out, gap, workers):
        frame = pd.read_csv(path)
        loops = [c[:-3] for c in frame.columns if c.endswith(".PV")]
        d = diagnose_plant({k: frame[f"{k}.PV"].to_numpy() for k in loops}, 1.0)
        verdicts = [
            "propagated" if d.roles[k].role == "propagated" else "inconclusive" for k in loops
        ]
        table = pd.DataFrame({"loop": loops, "verdict": verdicts})
        return types.SimpleNamespace(table=table, plantwide=d.to_dict())

    monkeypatch.setattr(scan_module, "scan", fake_scan)
    res = CliRunner().invoke(
        app, ["benchmark", "--plant", "--cases", "2", "--seed", "0", "--out", str(tmp_path)]
    )
    assert res.exit_code == 0, res.output
    assert "loops in the right group" in res.stdout
    assert "[2/2] plant 1" in res.stderr
    d = json.loads((tmp_path / "plant_results.json").read_text())
    assert d["totals"]["plants"] == 2 and d["totals"]["seeds"] == [0, 1]
    # Seeds 0 and 1 are development plants (14 + 10 loops) whose loops all land in
    # the right group (measured while developing): a scoring slip would show here.
    assert d["totals"]["membership_pct"] == pytest.approx(100.0)


def test_scan_of_a_long_plant_export_groups_as_the_wide_one(tmp_path):
    from stictiondiag.apps.scan import scan

    p, frame = _wide(tmp_path)
    long = frame.melt(id_vars="time", var_name="tag", value_name="value")
    long["time"] = pd.to_datetime(long["time"], unit="s", origin="2024-01-01")
    long.to_csv(tmp_path / "plant_long.csv", index=False)
    res = scan(tmp_path / "plant_long.csv", out=tmp_path / "out", gap=False, workers=1)
    assert res.plantwide["status"] == "on", res.plantwide.get("reason")
    (found,) = [g for g in res.plantwide["groups"] if p.groups[1]["source"] in g["members"]]
    assert set(found["members"]) == set(p.groups[1]["members"])
    assert found["ranking"][0]["loop"] == p.groups[1]["source"]
