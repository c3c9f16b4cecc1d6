"""CLI tests of ``stiction gap`` and ``stiction benchmark``: exit codes, streams, files."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from stiction_cli.main import app
from stictiondiag.apps import benchmark as bm
from stictiondiag.models.synthetic import generate_case

runner = CliRunner()


@pytest.fixture(scope="module")
def loop_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("gap") / "loop.csv"
    generate_case("miscalibration", 3, n_samples=2000).data.to_csv(path, index=False)
    return path


def test_gap_command_writes_json_and_plots(loop_csv, tmp_path):
    out_json = tmp_path / "gap.json"
    out_png = tmp_path / "gap.png"
    res = runner.invoke(
        app, ["gap", str(loop_csv), "--json", str(out_json), "--plot", str(out_png)]
    )
    assert res.exit_code == 0, res.output
    assert "Traceback" not in res.output
    assert "effect      miscalibration" in res.stdout
    d = json.loads(out_json.read_text())
    assert d["effect"] == "miscalibration"
    assert {"metric", "before", "after", "shrink_pct", "candidates"} <= set(d)
    assert out_png.stat().st_size > 0
    assert (tmp_path / "gap_replay.png").stat().st_size > 0


def test_gap_json_to_stdout(loop_csv):
    res = runner.invoke(app, ["gap", str(loop_csv), "--json", "-"])
    assert res.exit_code == 0
    d = json.loads(res.stdout)
    assert d["metric"] == "excess_nrmse"


def test_gap_missing_file_is_a_data_error(tmp_path):
    res = runner.invoke(app, ["gap", str(tmp_path / "nope.csv")])
    assert res.exit_code == 3
    assert "Traceback" not in res.output
    assert "stiction: error: file not found" in res.output


def test_gap_plot_to_a_directory_is_a_usage_error(loop_csv, tmp_path):
    res = runner.invoke(app, ["gap", str(loop_csv), "--plot", str(tmp_path)])
    assert res.exit_code == 2
    assert "directory" in res.output


def test_benchmark_command(tmp_path, monkeypatch):
    # The generator runs for real; the diagnosis is replaced by one that names the
    # hidden effect except for one case, so the test checks the plumbing and scores
    # in seconds (the real benchmark is run by the command itself, see the README).
    import stictiondiag.models.synthetic as syn
    from stictiondiag.gap.diagnose import GapDiagnosis

    truths = {}

    def fake_diagnose(path):
        effect = truths[path.name]
        named = "none" if effect == "quantization" else effect
        g = GapDiagnosis("excess_nrmse", "", 10.0, 3.0, 70.0, named, None, 5.0, ())
        return g, "test"

    orig = syn.iter_benchmark

    def spy(out_dir, n_cases, seed):
        for p, t in orig(out_dir, n_cases, seed):
            truths[p.name] = t["effect"]
            yield p, t

    monkeypatch.setattr(syn, "iter_benchmark", spy)
    monkeypatch.setattr(bm, "_diagnose_path", fake_diagnose)
    res = runner.invoke(app, ["benchmark", "--cases", "8", "--seed", "3", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "| 8 | 3 | 0.875 |" in res.stdout
    assert "[8/8]" in res.stderr
    d = json.loads((tmp_path / "results.json").read_text())
    assert d["accuracy"] == pytest.approx(7 / 8)
    assert (tmp_path / "results.csv").exists()


def test_benchmark_bad_cases_is_a_usage_error(tmp_path):
    res = runner.invoke(app, ["benchmark", "--cases", "0", "--out", str(tmp_path)])
    assert res.exit_code == 2
    assert "Traceback" not in res.output


@pytest.mark.parametrize(
    "args",
    [["--seed", "-1"], ["--cases", "1000000000"], ["--seed", str(2**32)]],
)
def test_benchmark_out_of_range_options_are_usage_errors(tmp_path, args):
    # Issue 31: --seed -1 was a ValueError shown as a data error (exit 3), and
    # --cases 1000000000 allocated gigabytes before the first case.
    res = runner.invoke(app, ["benchmark", *args, "--out", str(tmp_path / "b")])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "b").exists()


def test_benchmark_cases_are_drawn_one_at_a_time(tmp_path):
    import stictiondiag.models.synthetic as syn

    cases = syn.iter_benchmark(tmp_path / "a", 5, 11)
    first, truth = next(cases)  # one case simulated and written, the others not yet
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == [first.name]
    # The same cases as the eager writer, in the same order.
    lazy = [truth, *(t for _, t in cases)]
    eager = [t for _, t in syn.write_benchmark(tmp_path / "b", 5, 11)]
    assert lazy == eager
    assert (tmp_path / "a" / first.name).read_bytes() == (tmp_path / "b" / first.name).read_bytes()
    with pytest.raises(syn.UsageError, match="seed"):
        next(syn.iter_benchmark(tmp_path, 5, -1))
