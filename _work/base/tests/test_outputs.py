"""Output folders hold only what the tool wrote there (``report`` and ``scan``).

What is under test is the folder's handling, not the analysis: most tests replace the
per-loop analysis by a stand-in that returns a page at once
(:func:`_fake_report_loop`), so a report costs milliseconds.  The CLI tests that
must reach the analysis stop before it (a refusal) or use the real one once.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from pathlib import Path

import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

import stictiondiag.apps.report as report_module
import stictiondiag.apps.scan as scan_module
from stiction_cli.main import app
from stictiondiag.apps.outdir import OutputFolder, is_stale_temp
from stictiondiag.apps.pages import MAX_NAME_BYTES, safe_name
from stictiondiag.apps.report import build_report, clean_report
from stictiondiag.apps.scan import scan
from stictiondiag.core.errors import EXIT_USAGE, UsageError

ROOT = Path(__file__).resolve().parents[1]
HEALTHY = ROOT / "sample_data" / "healthy_flow.csv"
runner = CliRunner()


def _fake_report_loop(source, read_options, gap):
    """Stand-in for :func:`analyse_for_report`: a page and JSON without analysing."""
    path, name = source[0], source[1]
    loop = source[4] if len(source) > 4 else Path(path).stem
    return {
        "file": str(path),
        "loop": loop,
        "name": name,
        "page": f"<!DOCTYPE html><p>{name}</p>\n",
        "json": json.dumps({"loop": loop}) + "\n",
        "row": {
            "loop": loop,
            "source": str(path),
            "verdict": "no_stiction",
            "page": f"loops/{name}.html",
        },
    }


@pytest.fixture
def fast_report(monkeypatch):
    monkeypatch.setattr(report_module, "analyse_for_report", _fake_report_loop)


def _inputs(folder: Path, *stems: str) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for stem in stems:
        files.append(folder / f"{stem}.csv")
        files[-1].write_text("pv,op\n1,2\n")
    return files


def _snapshot(folder: Path) -> dict[str, tuple[str, bytes | str]]:
    """Every entry under ``folder`` (not followed through links): kind and content."""
    found: dict[str, tuple[str, bytes | str]] = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = Path(root) / name
            rel = str(p.relative_to(folder))
            if p.is_symlink():
                found[rel] = ("link", os.readlink(p))
            elif p.is_file():
                found[rel] = ("file", p.read_bytes())
    return found


# -- foreign files are never replaced -----------------------------------------------------


@pytest.mark.parametrize("name", ["index.html", "summary.md", "rows.json", "manifest.json"])
def test_report_refuses_to_replace_a_user_file(tmp_path, name):
    # Issue 31: `stiction report notes/loop1.csv --out notes` lost notes/index.html.
    notes = tmp_path / "notes"
    (data,) = _inputs(notes, "loop1")
    data.write_bytes(HEALTHY.read_bytes())
    (notes / name).write_text("my own notes")
    result = runner.invoke(app, ["report", str(data), "--out", str(notes), "--no-gap"])
    assert result.exit_code == EXIT_USAGE, result.stderr
    assert str(notes / name) in result.stderr and "not written by" in result.stderr
    assert (notes / name).read_text() == "my own notes"
    assert not (notes / "loops").exists()  # refused before anything was written


def test_scan_refuses_to_replace_a_user_index(tmp_path, monkeypatch):
    folder = tmp_path / "plant"
    folder.mkdir()
    (folder / "L1.csv").write_bytes(HEALTHY.read_bytes())
    (folder / "index.html").write_text("<p>my plant wiki</p>")
    result = runner.invoke(app, ["scan", str(folder), "--out", str(folder), "--no-gap"])
    assert result.exit_code == EXIT_USAGE, result.stderr
    assert str(folder / "index.html") in result.stderr
    assert (folder / "index.html").read_text() == "<p>my plant wiki</p>"


def test_a_foreign_file_at_a_loop_page_fails_that_row_only(tmp_path, fast_report):
    files = _inputs(tmp_path / "in", "a", "b")
    out = tmp_path / "r"
    (out / "loops").mkdir(parents=True)
    (out / "loops" / "a.html").write_text("the user's page")
    result = build_report(files, out, workers=1)
    assert [f for f, _ in result.failed] == [str(files[0])]
    assert "not written by stiction report" in result.failed[0][1]
    assert (out / "loops" / "a.html").read_text() == "the user's page"
    assert (out / "loops" / "b.html").is_file()


def test_a_page_edited_by_the_user_is_neither_replaced_nor_cleaned(tmp_path, fast_report):
    (data,) = _inputs(tmp_path / "in", "a")
    out = tmp_path / "r"
    build_report([data], out, workers=1)
    page = out / "loops" / "a.html"
    page.write_text("annotated by hand")
    with pytest.raises(UsageError, match="not written by stiction report"):
        build_report([data], out, workers=1)  # no page could be written: exit 2
    assert page.read_text() == "annotated by hand"
    clean_report(out)
    assert page.read_text() == "annotated by hand"
    assert not (out / "index.html").exists() and not (out / "manifest.json").exists()


def test_loop_names_index_and_rows_stay_in_their_folder(tmp_path, fast_report):
    files = _inputs(tmp_path / "in", "index", "rows", "manifest", "summary")
    out = tmp_path / "r"
    result = build_report(files, out, workers=1)
    assert not result.failed
    assert json.loads((out / "manifest.json").read_text())["written_by"] == "stiction report"
    assert isinstance(json.loads((out / "rows.json").read_text()), list)
    assert sorted(p.name for p in (out / "loops").glob("*.html")) == [
        "index.html",
        "manifest.html",
        "rows.html",
        "summary.html",
    ]


# -- clean: only the manifest's entries, as entries -------------------------------------


def test_clean_removes_a_link_not_its_target(tmp_path, fast_report):
    (data,) = _inputs(tmp_path / "in", "a")
    out = tmp_path / "r"
    build_report([data], out, workers=1)
    precious = tmp_path / "thesis.tex"
    precious.write_text("precious")
    page = out / "loops" / "a.html"
    page.unlink()
    page.symlink_to(precious)
    clean_report(out)
    assert not os.path.lexists(page)
    assert precious.read_text() == "precious"


def test_clean_never_follows_a_linked_loops_folder(tmp_path, fast_report):
    (data,) = _inputs(tmp_path / "in", "a")
    out = tmp_path / "r"
    build_report([data], out, workers=1)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "a.html").write_text("not the report's")
    for f in (out / "loops").iterdir():
        f.unlink()
    (out / "loops").rmdir()
    (out / "loops").symlink_to(elsewhere, target_is_directory=True)
    clean_report(out)
    assert (elsewhere / "a.html").read_text() == "not the report's"


# -- lock, long names, stale temporary files --------------------------------------------


def test_a_second_writer_waits_for_the_first(tmp_path, fast_report, monkeypatch):
    first, second = _inputs(tmp_path / "in", "a", "b")
    out = tmp_path / "r"
    build_report([first], out, workers=1)
    folder = OutputFolder(out, "manifest.json", "stiction report")
    notes: list[str] = []
    with folder.locked():
        # Another run holds the folder: with no wait allowed, the report refuses.
        monkeypatch.setenv("STICTION_LOCK_WAIT", "0")
        with pytest.raises(UsageError, match="another stiction run is writing"):
            build_report([second], out, workers=1)
        monkeypatch.setenv("STICTION_LOCK_WAIT", "30")
        result: dict = {}
        worker = threading.Thread(
            target=lambda: result.update(
                r=build_report([second], out, workers=1, on_note=notes.append)
            )
        )
        worker.start()
        time.sleep(0.6)
        assert worker.is_alive()  # waiting, not writing
    worker.join(timeout=30)
    assert any("waiting for another stiction run" in n for n in notes)
    # Both runs' loops are in the index: the second read the first's rows.
    rows = json.loads((out / "rows.json").read_text())
    assert sorted(r["loop"] for r in rows) == ["a", "b"]


def test_long_loop_names_are_capped_and_stay_distinct(tmp_path, fast_report):
    stem = "x" * 230  # a valid file name of 234 bytes; its page's name would not be
    files = _inputs(tmp_path / "in", stem + "1", stem + "2")
    out = tmp_path / "r"
    result = build_report(files, out, workers=1)
    assert not result.failed
    pages = sorted(p.name for p in (out / "loops").glob("*.html"))
    assert len(pages) == 2 and all(len(p.encode()) <= MAX_NAME_BYTES + 5 for p in pages)
    assert safe_name(stem + "1") != safe_name(stem + "2")


def test_stale_temporary_files_of_the_tool_are_swept(tmp_path, fast_report):
    (data,) = _inputs(tmp_path / "in", "a")
    out = tmp_path / "r"
    build_report([data], out, workers=1)
    stale = out / "loops" / ".a.stiction-abcd1234.tmp.html"
    stale.write_text("half a page")
    old = time.time() - 3600
    os.utime(stale, (old, old))
    users = out / ".a.tmp.html"  # looks temporary, is not the tool's
    users.write_text("mine")
    build_report([data], out, workers=1)
    assert not stale.exists() and users.read_text() == "mine"
    assert is_stale_temp(stale.name) and not is_stale_temp(users.name)


# -- the property: report then --clean keeps every file it did not write ------------------

_NAMES = st.sampled_from(
    [
        "index.html",
        "summary.md",
        "rows.json",
        "notes.txt",
        "a.csv",
        "loops/a.html",
        "loops/b.json",
        "loops/mine.txt",
        ".hidden",
        "sub/index.html",
    ]
)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    user_files=st.lists(_NAMES, max_size=5, unique=True),
    links=st.lists(st.tuples(_NAMES, st.booleans()), max_size=3),
    earlier=st.lists(st.sampled_from(["a", "b", "c"]), max_size=2),
    now=st.lists(st.sampled_from(["a", "b", "d"]), min_size=1, max_size=2, unique=True),
)
def test_report_then_clean_leaves_what_it_did_not_write(
    tmp_path_factory, monkeypatch, user_files, links, earlier, now
):
    monkeypatch.setattr(report_module, "analyse_for_report", _fake_report_loop)
    base = tmp_path_factory.mktemp("prop")
    out, inputs = base / "out", base / "in"
    outside = base / "outside.txt"
    outside.write_text("outside the folder")
    if earlier:
        build_report(_inputs(inputs, *earlier), out, workers=1)
    out.mkdir(exist_ok=True)
    for name in user_files:
        p = out / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if not os.path.lexists(p) or p.is_file():
            p.unlink(missing_ok=True)
            p.write_bytes(hashlib.sha256(name.encode()).digest())
    for name, to_outside in links:
        p = out / name
        if os.path.lexists(p) and not p.is_dir():
            p.unlink()
        if not os.path.lexists(p):
            p.parent.mkdir(parents=True, exist_ok=True)
            p.symlink_to(outside if to_outside else out / "notes.txt")
    before = _snapshot(out)
    manifest = out / "manifest.json"
    recorded = json.loads(manifest.read_text()).get("sha256", {}) if manifest.is_file() else {}
    # The user's files: all but those holding exactly what an earlier report wrote.
    users = {
        rel: entry
        for rel, entry in before.items()
        if entry[0] == "file"
        and rel != "manifest.json"
        and recorded.get(rel) != hashlib.sha256(entry[1]).hexdigest()
    }
    try:
        build_report(_inputs(inputs, *now), out, workers=1)
    except UsageError:
        pass  # a foreign file at one of the report's own names: refused whole
    clean_report(out, [str(f) for f in inputs.glob("*.csv")])
    after = _snapshot(out)
    for rel, entry in users.items():
        assert after.get(rel) == entry, rel
    assert outside.read_text() == "outside the folder"
    assert not any(is_stale_temp(Path(r).name) for r in after)
    # What the report wrote is gone: only the user's files (and links) are left.
    assert set(after) - set(users) <= {r for r, e in after.items() if e[0] == "link"}


# -- scan: CSV cells a spreadsheet would run are escaped ----------------------------------


def _fake_scan_loop(source, read_options, gap, plots=True):
    row = {
        "loop": source.loop,
        "source": source.path,
        "error": None,
        "verdict": "no_stiction",
        "S": -1.5,
    }
    return {"row": row, "analysis": {"loop": source.loop}}


def test_scan_csv_escapes_formulas_and_parquet_stays_raw(tmp_path, monkeypatch):
    monkeypatch.setattr(scan_module, "analyse_source", _fake_scan_loop)
    folder = tmp_path / "plant"
    folder.mkdir()
    names = ["=HYPERLINK(1)", "+1", "-cmd", "@SUM(A1)", "ok"]
    for name in names:
        (folder / f"{name}.csv").write_bytes(HEALTHY.read_bytes())
    out = tmp_path / "out"
    result = scan(folder, out=out, workers=1, gap=False)
    assert result.n_failed == 0
    csv_loops = pd.read_csv(out / "scan.csv")["loop"].tolist()
    assert sorted(csv_loops) == sorted(["'=HYPERLINK(1)", "'+1", "'-cmd", "'@SUM(A1)", "ok"])
    assert (pd.read_csv(out / "scan.csv")["S"] == -1.5).all()  # numbers stay numbers
    assert sorted(pd.read_parquet(out / "scan.parquet")["loop"]) == sorted(names)
    # A rerun resumes from the scan's own folder (its files are in its manifest).
    again = scan(folder, out=out, workers=1, gap=False)
    assert again.n_skipped == len(names)


def test_a_scan_folder_from_before_manifests_is_taken_over_once(tmp_path, monkeypatch):
    monkeypatch.setattr(scan_module, "analyse_source", _fake_scan_loop)
    folder = tmp_path / "plant"
    folder.mkdir()
    (folder / "L1.csv").write_bytes(HEALTHY.read_bytes())
    out = tmp_path / "out"
    scan(folder, out=out, workers=1, gap=False)
    (out / "scan-manifest.json").unlink()  # as an older scan left it
    again = scan(folder, out=out, workers=1, gap=False)
    assert again.n_loops == 1 and again.n_failed == 0
    assert "loops/L1.json" in json.loads((out / "scan-manifest.json").read_text())["files"]


def test_a_foreign_file_at_a_scan_record_fails_that_loop_only(tmp_path, monkeypatch):
    monkeypatch.setattr(scan_module, "analyse_source", _fake_scan_loop)
    folder = tmp_path / "plant"
    folder.mkdir()
    for name in ("L1", "L2"):
        (folder / f"{name}.csv").write_bytes(HEALTHY.read_bytes())
    out = tmp_path / "out"
    (out / "loops").mkdir(parents=True)
    (out / "loops" / "L1.html").write_text("my notes on L1")
    result = scan(folder, out=out, workers=1, gap=False)
    rows = result.table.set_index("loop")
    assert rows.loc["L1", "verdict"] == "error" and "not written by" in rows.loc["L1", "error"]
    assert rows.loc["L2", "verdict"] == "no_stiction"
    assert (out / "loops" / "L1.html").read_text() == "my notes on L1"
