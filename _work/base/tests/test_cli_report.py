"""``stiction report`` through Typer's CliRunner: exit codes, streams, updates, escaping.

The command is run the way the console script runs it (arguments through
:func:`stiction_cli.report.normalise_argv`, so a bare ``--fail-on-stiction`` works).
The report is built from the bundled sample loops: ``slave_flow_stickslip`` (a pure
stick-slip valve, Loop 3 of Section 3) and ``healthy_flow`` (a linear valve).
"""

from __future__ import annotations

import errno
import hashlib
import json
import re
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

import stictiondiag.analysis
import stictiondiag.core.atomic
from stiction_cli.main import app
from stiction_cli.report import DEFAULT_FAIL_THRESHOLD, normalise_argv
from stictiondiag.core.errors import (
    EXIT_DATA,
    EXIT_FINDING,
    EXIT_OK,
    EXIT_PARTIAL,
    EXIT_USAGE,
)

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_data"
STICKY = SAMPLES / "slave_flow_stickslip.csv"
HEALTHY = SAMPLES / "healthy_flow.csv"

runner = CliRunner()

_ANALYSES: dict = {}


@pytest.fixture(autouse=True)
def _analyse_each_file_once(monkeypatch):
    """Reuse one analysis per (file, options) across the many CLI runs of this module.

    The analysis itself is deterministic and tested in its own modules; what is under
    test here is the command around it (exit codes, streams, files), which needs a
    dozen runs over the same two loops. Figures and pages are still made every run.
    """
    original = stictiondiag.analysis.analyze_file

    def cached(path, *, config=None, **read_options):
        p = Path(path)
        stamp = p.stat().st_mtime_ns if p.exists() else None
        key = (str(p.resolve()), stamp, repr(config), repr(sorted(read_options.items())))
        if key not in _ANALYSES:
            _ANALYSES[key] = original(path, config=config, **read_options)
        return _ANALYSES[key]

    monkeypatch.setattr(stictiondiag.analysis, "analyze_file", cached)


def report(*args) -> object:
    """Run ``stiction report ARGS`` and check what must hold for every run."""
    argv = normalise_argv(["report", *[str(a) for a in args]])
    result = runner.invoke(app, argv)
    assert "Traceback" not in result.stdout and "Traceback" not in result.stderr, result.stderr
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception
    )
    return result


def temp_files(folder: Path) -> list[str]:
    """Files the atomic writer would leave behind had a write been interrupted."""
    return [p.name for p in folder.rglob("*") if p.name.startswith(".") or ".tmp" in p.name]


def loop_json(out: Path, loop: str) -> dict:
    return json.loads((out / "loops" / f"{loop}.json").read_text())


def index_loops(out: Path) -> list[str]:
    return [r["loop"] for r in json.loads((out / "rows.json").read_text())]


@pytest.fixture(scope="module")
def sticky_run(tmp_path_factory):
    """A report over the sticky sample loop with a bare ``--fail-on-stiction``."""
    out = tmp_path_factory.mktemp("sticky")
    result = report(STICKY, "--out", out, "--no-gap", "--fail-on-stiction")
    d = loop_json(out, STICKY.stem)
    # Precondition of the exit-1 tests: the sample was made with S = J (pure stick-slip).
    assert d["stiction"]["status"] == "stiction", d["stiction"].get("reasons")
    return result, out, float(d["stiction"]["confidence"])


@pytest.fixture(scope="module")
def sticky_confidence(sticky_run) -> float:
    """Verdict confidence of the sticky sample loop."""
    return sticky_run[2]


@pytest.fixture
def corrupt_csv(tmp_path) -> Path:
    path = tmp_path / "corrupt.csv"
    path.write_bytes(b"\x00\x01\x02 not a table \xff\xfe\n\x00\x00")
    return path


# -- exit 0 -------------------------------------------------------------------------


def test_clean_run_exits_0_and_writes_the_report(tmp_path):
    out = tmp_path / "report"
    md = tmp_path / "job" / "summary.md"
    result = report(HEALTHY, "--out", out, "--no-gap", "--markdown", md)
    assert result.exit_code == EXIT_OK, result.stderr
    # stdout carries only requested data: the Markdown went to a file.
    assert result.stdout == ""
    assert md.read_text() == (out / "summary.md").read_text()
    assert md.read_text().startswith("## Stiction report")
    assert temp_files(md.parent) == []
    assert f"[1/1] {HEALTHY.stem}" in result.stderr
    loop = HEALTHY.stem
    for name in (
        f"loops/{loop}.html",
        f"loops/{loop}.json",
        "index.html",
        "summary.md",
        "rows.json",
        "manifest.json",
    ):
        assert (out / name).is_file(), name
    d = loop_json(out, loop)
    assert d["loop"] == loop and d["stiction"]["status"] in ("no_stiction", "inconclusive")
    page = (out / "loops" / f"{loop}.html").read_text()
    # Self-contained: figures are embedded, nothing is fetched.
    assert page.count('src="data:image/png;base64,') >= 2  # phase plots + reconstruction
    assert not re.search(r'(src|href)="(https?:)?//', page)
    assert f'href="loops/{loop}.html"' in (out / "index.html").read_text()
    assert temp_files(out) == []


# -- exit 1 -------------------------------------------------------------------------


def test_bare_fail_on_stiction_exits_1_on_a_sticky_loop(sticky_run):
    result, out, confidence = sticky_run
    assert confidence >= DEFAULT_FAIL_THRESHOLD  # the bare flag's threshold
    assert result.exit_code == EXIT_FINDING, result.stderr
    assert "stiction found" in result.stderr and result.stdout == ""
    # The report is complete although the job fails.
    assert (out / "index.html").is_file() and (out / "loops" / f"{STICKY.stem}.html").is_file()


@pytest.mark.parametrize(
    "argv, expected",
    [
        (
            ["report", "a.csv", "--fail-on-stiction"],
            ["report", "a.csv", "--fail-on-stiction", "0.5"],
        ),
        (
            ["report", "--fail-on-stiction", "--no-gap"],
            ["report", "--fail-on-stiction", "0.5", "--no-gap"],
        ),
        (
            ["report", "--fail-on-stiction", "a.csv"],
            ["report", "--fail-on-stiction", "0.5", "a.csv"],
        ),
        (["report", "--fail-on-stiction", "0.7"], ["report", "--fail-on-stiction", "0.7"]),
        (["report", "--fail-on-stiction", "1.5"], ["report", "--fail-on-stiction", "1.5"]),
    ],
)
def test_bare_flag_gets_the_default_threshold(argv, expected):
    assert DEFAULT_FAIL_THRESHOLD == 0.5
    assert normalise_argv(argv) == expected


def test_fail_on_stiction_threshold_is_compared_with_the_confidence(tmp_path, sticky_confidence):
    below = max(0.0, sticky_confidence - 0.05)
    result = report(STICKY, "--out", tmp_path, "--no-gap", "--fail-on-stiction", f"{below:.4f}")
    assert result.exit_code == EXIT_FINDING, result.stderr
    if sticky_confidence < 0.95:
        above = sticky_confidence + 0.05
        result = report(STICKY, "--out", tmp_path, "--no-gap", "--fail-on-stiction", f"{above:.4f}")
        assert result.exit_code == EXIT_OK, result.stderr


def test_healthy_loop_with_the_flag_exits_0(tmp_path):
    result = report(HEALTHY, "--out", tmp_path, "--no-gap", "--fail-on-stiction")
    assert result.exit_code == EXIT_OK, result.stderr
    assert loop_json(tmp_path, HEALTHY.stem)["stiction"]["status"] != "stiction"


# -- exit 2 -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args, message",
    [
        (["--fail-on-stiction", "1.5"], "[0, 1]"),
        (["--fail-on-stiction", "-0.1"], "[0, 1]"),
        (["--no-such-option"], "No such option"),
        (["--op-units", "volts"], "volts"),
        (["--workers", "0"], "--workers"),
    ],
)
def test_usage_errors_exit_2(tmp_path, args, message):
    result = report(HEALTHY, "--out", tmp_path / "r", *args)
    assert result.exit_code == EXIT_USAGE, result.stderr
    assert message in result.stderr and result.stdout == ""
    # Rejected before any work: no report folder.
    assert not (tmp_path / "r").exists()


def test_no_input_file_exits_2(tmp_path):
    result = report("--out", tmp_path / "r")
    assert result.exit_code == EXIT_USAGE
    assert "Missing argument" in result.stderr


def test_out_is_a_file_exits_2(tmp_path):
    target = tmp_path / "report"
    target.write_text("not a folder")
    result = report(HEALTHY, "--out", target, "--no-gap")
    assert result.exit_code == EXIT_USAGE, result.stderr
    errors = [ln for ln in result.stderr.splitlines() if ln.startswith("stiction: error:")]
    assert len(errors) == 1 and "is a file" in errors[0]
    assert target.read_text() == "not a folder"


# -- exit 3 -------------------------------------------------------------------------


def test_unreadable_inputs_exit_3(tmp_path, corrupt_csv):
    out = tmp_path / "r"
    # Two worker processes: the pool path reports failures like the in-process one.
    result = report(tmp_path / "missing.csv", corrupt_csv, "--out", out, "--workers", "2")
    assert result.exit_code == EXIT_DATA, result.stderr
    assert result.stdout == ""
    # One line saying what is wrong, no traceback (checked in report()).
    errors = [ln for ln in result.stderr.splitlines() if ln.startswith("stiction: error:")]
    assert len(errors) == 1 and "missing.csv" in errors[0]
    # The index still lists what failed, so an artifact explains the red job.
    assert set(index_loops(out)) == {"missing", "corrupt"}
    assert "failed" in (out / "index.html").read_text()


# -- exit 4 -------------------------------------------------------------------------


def test_one_good_one_corrupt_file_exits_4(tmp_path, corrupt_csv):
    out = tmp_path / "r"
    result = report(
        HEALTHY, corrupt_csv, "--out", out, "--no-gap", "--fail-on-stiction", "--workers", "1"
    )
    assert result.exit_code == EXIT_PARTIAL, result.stderr
    assert "[1/2]" in result.stderr and "[2/2]" in result.stderr
    assert f"failed: {corrupt_csv}" in result.stderr
    assert (out / "loops" / f"{HEALTHY.stem}.html").is_file()
    assert not (out / "loops" / "corrupt.html").exists()
    rows = {r["loop"]: r for r in json.loads((out / "rows.json").read_text())}
    assert rows["corrupt"]["verdict"] == "error" and rows[HEALTHY.stem]["verdict"] != "error"
    assert "corrupt" in (out / "summary.md").read_text()


# -- streams and Markdown -------------------------------------------------------------


def test_markdown_dash_is_the_only_stdout(tmp_path, sticky_confidence):
    out = tmp_path / "r"
    result = report(STICKY, HEALTHY, "--out", out, "--no-gap", "--markdown", "-", "--workers", "1")
    assert result.exit_code == EXIT_OK, result.stderr
    assert result.stdout == (out / "summary.md").read_text()
    lines = result.stdout.splitlines()
    assert lines[0] == "## Stiction report"
    table = [ln for ln in lines if ln.startswith("| ")]
    # Header plus one row per loop, the sticky loop first (maintenance order).
    assert len(table) == 3 and table[1].startswith(f"| {STICKY.stem.replace('_', chr(92) + '_')} |")
    assert "[1/2]" in result.stderr and "[2/2]" in result.stderr


# -- updating, cleaning, atomic writes --------------------------------------------------


def test_existing_report_is_updated_not_wiped(tmp_path):
    out = tmp_path / "r"
    assert report(HEALTHY, "--out", out, "--no-gap").exit_code == EXIT_OK
    (out / "notes.txt").write_text("kept by the user")
    assert report(STICKY, "--out", out, "--no-gap").exit_code == EXIT_OK
    assert sorted(index_loops(out)) == sorted([HEALTHY.stem, STICKY.stem])
    index = (out / "index.html").read_text()
    assert f'href="loops/{HEALTHY.stem}.html"' in index
    assert f'href="loops/{STICKY.stem}.html"' in index
    assert (out / "loops" / f"{HEALTHY.stem}.html").is_file() and (out / "notes.txt").is_file()
    assert temp_files(out) == []

    # --clean starts afresh: the earlier loop is gone, the user's file is not (the
    # report removes only what its manifest says it wrote).
    assert report(STICKY, "--out", out, "--no-gap", "--clean").exit_code == EXIT_OK
    assert index_loops(out) == [STICKY.stem]
    assert HEALTHY.stem not in (out / "index.html").read_text()
    assert not (out / "loops" / f"{HEALTHY.stem}.html").exists()
    assert (out / "notes.txt").read_text() == "kept by the user"


def test_clean_of_a_folder_that_is_not_a_report_removes_nothing(tmp_path):
    folder = tmp_path / "home"
    folder.mkdir()
    (folder / "thesis.tex").write_text("precious")
    result = report(HEALTHY, "--out", folder, "--no-gap", "--clean")
    assert result.exit_code == EXIT_OK, result.stderr
    assert (folder / "thesis.tex").read_text() == "precious"


def test_clean_never_removes_the_input_it_reads(tmp_path):
    # Issue 20: `report rc/loop1.csv --out rc --clean` deleted rc and its input.
    folder = tmp_path / "rc"
    folder.mkdir()
    data = folder / "loop1.csv"
    data.write_bytes(HEALTHY.read_bytes())
    digest = hashlib.sha256(data.read_bytes()).hexdigest()
    for _ in range(2):  # the second run cleans the first run's report
        result = report(data, "--out", folder, "--no-gap", "--clean")
        assert result.exit_code == EXIT_OK, result.stderr
        assert hashlib.sha256(data.read_bytes()).hexdigest() == digest
    assert (folder / "loops" / "loop1.html").is_file()


def test_a_report_killed_midway_can_be_cleaned(tmp_path):
    out = tmp_path / "r"
    assert report(HEALTHY, "--out", out, "--no-gap").exit_code == EXIT_OK
    # As if killed after the loop's files and before the index: no index, no rows.
    (out / "index.html").unlink()
    (out / "rows.json").unlink()
    assert report(STICKY, "--out", out, "--no-gap", "--clean").exit_code == EXIT_OK
    assert not (out / "loops" / f"{HEALTHY.stem}.html").exists()
    assert index_loops(out) == [STICKY.stem]


def test_loop_names_never_replace_the_report_files(tmp_path):
    data = pd.read_csv(HEALTHY)
    files = []
    for name in ("index", "rows", "summary", "manifest"):
        files.append(tmp_path / f"{name}.csv")
        data.to_csv(files[-1], index=False)
    out = tmp_path / "r"
    assert report(*files, "--out", out, "--no-gap").exit_code == EXIT_OK
    assert sorted(index_loops(out)) == ["index", "manifest", "rows", "summary"]
    assert (out / "index.html").read_text().startswith("<!DOCTYPE html>")
    assert "Stiction report" in (out / "index.html").read_text()
    assert isinstance(json.loads((out / "rows.json").read_text()), list)


def test_two_inputs_with_one_stem_get_distinct_names_listed(tmp_path):
    data = pd.read_csv(HEALTHY)
    (tmp_path / "a").mkdir()
    first, second = tmp_path / "loop.csv", tmp_path / "a" / "loop.parquet"
    data.to_csv(first, index=False)
    data.to_parquet(second)
    out = tmp_path / "r"
    result = report(first, second, "--out", out, "--no-gap")
    assert result.exit_code == EXIT_OK, result.stderr
    assert sorted(index_loops(out)) == ["loop", "loop_parquet"]
    assert f"{second} -> loop_parquet" in result.stderr


@pytest.mark.parametrize("option", ["--markdown"])
def test_output_equal_to_an_input_is_a_usage_error(tmp_path, option):
    data = tmp_path / "loop.csv"
    data.write_bytes(HEALTHY.read_bytes())
    result = report(data, "--out", tmp_path / "r", "--no-gap", option, data)
    assert result.exit_code == EXIT_USAGE
    assert data.read_bytes() == HEALTHY.read_bytes()


def test_interrupted_write_leaves_the_old_file_whole(tmp_path, monkeypatch):
    out = tmp_path / "r"
    assert report(HEALTHY, "--out", out, "--no-gap").exit_code == EXIT_OK
    before = (out / "index.html").read_bytes()
    commit = stictiondiag.core.atomic._commit

    def disk_full_on_index(temp, target):
        if Path(target).name == "index.html":
            raise OSError(errno.ENOSPC, "No space left on device")
        commit(temp, target)

    monkeypatch.setattr(stictiondiag.core.atomic, "_commit", disk_full_on_index)
    result = report(STICKY, "--out", out, "--no-gap")
    assert result.exit_code != EXIT_OK
    assert "no space left on device" in result.stderr.lower()
    # The old index is untouched and no partial file is left beside it.
    assert (out / "index.html").read_bytes() == before
    assert temp_files(out) == []


# -- escaping ---------------------------------------------------------------------------

EVIL_PV = "<script>alert('pv')</script>"
EVIL_OP = "<img src=x onerror=alert(1)>"


def test_tag_and_file_names_are_escaped(tmp_path):
    data = pd.read_csv(HEALTHY).rename(columns={"pv": EVIL_PV, "op": EVIL_OP})
    evil = tmp_path / "in" / "FIC<script>alert(1)<!--.csv"
    evil.parent.mkdir()
    data.to_csv(evil, index=False)
    out = tmp_path / "r"
    result = report(
        evil, "--out", out, "--no-gap", "--pv", EVIL_PV, "--op", EVIL_OP, "--markdown", "-"
    )
    assert result.exit_code == EXIT_OK, result.stderr
    pages = list((out / "loops").glob("*.html"))
    assert len(pages) == 1 and "<" not in pages[0].name
    for page in (pages[0], out / "index.html"):
        html = page.read_text()
        # The page's own load marker is the only script; the names show as text.
        assert html.count("<script") == 1, page.name
        assert "<img src=x" not in html and "<!--" not in html
        assert "FIC&lt;script&gt;alert(1)&lt;!--" in html
    html = pages[0].read_text()
    assert "&lt;script&gt;alert(&#x27;pv&#x27;)&lt;/script&gt;" in html
    assert "&lt;img src=x onerror=alert(1)&gt;" in html
    # Markdown: no raw angle brackets, so no HTML in a rendered job summary.
    assert "<" not in result.stdout and "FIC&lt;script&gt;alert\\(1\\)&lt;\\!--" in result.stdout
    # The JSON keeps the names as they are: it is data, not markup.
    d = json.loads(pages[0].with_suffix(".json").read_text())
    assert d["tags"]["names"]["pv"] == EVIL_PV and d["tags"]["names"]["op"] == EVIL_OP
