"""``stiction scan`` through Typer's CliRunner: table on stdout, progress on stderr, exit codes."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from stiction_cli.main import app
from stictiondiag.core.errors import (
    EXIT_DATA,
    EXIT_OK,
    EXIT_PARTIAL,
    EXIT_USAGE,
)

ROOT = Path(__file__).resolve().parents[1]
ISDB = ROOT.parent / "shared" / "data" / "isdb"

runner = CliRunner()


def make_plant(*args, **kwargs):
    """scripts/make_plant.py, loaded on use."""
    spec = importlib.util.spec_from_file_location("make_plant", ROOT / "scripts" / "make_plant.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make_plant(*args, **kwargs)


def _run(*args: str):
    result = runner.invoke(app, ["scan", *[str(a) for a in args]])
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


@pytest.fixture(scope="module")
def plant(tmp_path_factory) -> Path:
    """Four small loops (2 000 samples), two sticky."""
    folder = tmp_path_factory.mktemp("plant")
    make_plant(folder, 4, n_samples=2000, seed=5, fmt="csv", sticky_model="simple")
    return folder


def test_table_on_stdout_progress_on_stderr(plant, tmp_path):
    result = _run(plant, "--out", tmp_path / "out", "--workers", "2", "--no-gap")
    assert result.exit_code == EXIT_OK, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].split()[:3] == ["rank", "loop", "verdict"]
    assert sorted(line.split()[1] for line in lines[1:]) == ["L0000", "L0001", "L0002", "L0003"]
    # Progress bar with the count of loops done, then the summary, all on stderr.
    assert "scan" in result.stderr and "4/4" in result.stderr
    assert "4 loops:" in result.stderr and "0 failed" in result.stderr
    assert "scan" not in result.stdout.split("\n", 1)[0]
    table = pd.read_parquet(tmp_path / "out" / "scan.parquet")
    assert sorted(table["loop"]) == ["L0000", "L0001", "L0002", "L0003"]
    assert (tmp_path / "out" / "index.html").exists() and (tmp_path / "out" / "scan.csv").exists()


def test_broken_loop_exits_4_and_the_others_are_analysed(plant, tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    for f in sorted(plant.glob("*.csv"))[:2]:
        (folder / f.name).write_bytes(f.read_bytes())
    (folder / "broken.csv").write_text("time,pv,op\n0,1,abc\n1,2,def\n")
    result = _run(folder, "--out", tmp_path / "out", "--workers", "1", "--no-gap")
    assert result.exit_code == EXIT_PARTIAL
    assert "1 loop(s) failed" in result.stderr
    table = pd.read_csv(tmp_path / "out" / "scan.csv").set_index("loop")
    assert table.loc["broken", "verdict"] == "error"
    assert "\n" not in table.loc["broken", "error"]
    assert (table.drop(index="broken")["verdict"] != "error").all()
    # The failed loop is listed last on stdout too.
    assert result.stdout.splitlines()[-1].split()[1:3] == ["broken", "error"]


def test_resume_then_force(plant, tmp_path):
    out = tmp_path / "out"
    assert _run(plant, "--out", out, "--workers", "1", "--no-gap").exit_code == EXIT_OK
    again = _run(plant, "--out", out, "--workers", "1", "--no-gap")
    assert again.exit_code == EXIT_OK
    assert "4 resumed" in again.stderr
    forced = _run(plant, "--out", out, "--workers", "1", "--no-gap", "--force")
    assert forced.exit_code == EXIT_OK
    assert "0 resumed" in forced.stderr


def test_missing_path_is_a_data_error(tmp_path):
    result = _run(tmp_path / "absent", "--out", tmp_path / "out")
    assert result.exit_code == EXIT_DATA
    assert result.stderr.startswith("stiction: error:") and "no such file" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_bad_options_are_usage_errors(plant, tmp_path):
    assert _run(plant, "--workers", "0", "--out", tmp_path).exit_code == EXIT_USAGE
    assert _run(plant, "--engine", "spark", "--out", tmp_path).exit_code == EXIT_USAGE
    result = _run(plant, "--loop-column", "loop_id", "--out", tmp_path)
    assert result.exit_code == EXIT_USAGE
    assert "applies to a Parquet dataset" in result.stderr


@pytest.mark.isdb
@pytest.mark.slow
@pytest.mark.skipif(not (ISDB / "loops").is_dir(), reason="ISDB data not present")
def test_isdb_scan_end_to_end(tmp_path):
    manifest = pd.read_csv(ISDB / "manifest.csv")
    result = _run(ISDB / "loops", "--out", tmp_path, "--workers", "2", "--no-gap")
    assert result.exit_code in (EXIT_OK, EXIT_PARTIAL)
    table = pd.read_parquet(tmp_path / "scan.parquet")
    assert sorted(table["loop"]) == sorted(manifest["loop"])
    failed = table[table["verdict"] == "error"]
    assert (result.exit_code == EXIT_PARTIAL) == (len(failed) > 0)
    # Real data may be unusable (a record too short, a constant signal), but that is
    # a diagnosed data error, never a crash of the analysis.
    internal = failed[failed["error"].str.startswith("internal error")]
    assert internal.empty, internal[["loop", "error"]].to_string()
    assert (table["verdict"] == "stiction").any()
