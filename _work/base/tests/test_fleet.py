"""The fleet page and a valve's history: three scans of one loop whose valve gets stickier."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stictiondiag.apps.history import merge_entry, trend_sentence
from stictiondiag.apps.pages import RANKING_RULE, rank_key
from stictiondiag.apps.scan import rank, scan


def test_trend_sentence_says_rise_fall_or_no_change():
    def e(s, lo, hi, start):
        return {"key": str(start), "record_start_s": start, "S": s, "S_lo": lo, "S_hi": hi}

    entries = []
    for k, (s, lo, hi) in enumerate([(1.2, 1.1, 1.3), (2.0, 1.9, 2.1), (3.4, 3.3, 3.5)]):
        entries = merge_entry(entries, e(s, lo, hi, 1e9 + k * 86400))
    assert trend_sentence(entries) == "S rose from 1.2 % to 3.4 % over 3 exports"
    # The same record analysed again replaces its entry (keyed by the record period).
    again = merge_entry(entries, e(3.5, 3.3, 3.6, 1e9 + 2 * 86400))
    assert len(again) == 3 and again[-1]["S"] == 3.5
    flat = [e(2.0, 1.5, 2.5, 1e9), e(2.2, 1.8, 2.6, 2e9)]
    assert trend_sentence(flat) == "S stayed at about 2.2 % over 2 exports (intervals overlap)"
    assert trend_sentence(flat[:1]) is None


def test_one_ranking_rule_for_the_table_and_every_page():
    rows = [
        {"loop": "b", "verdict": "stiction", "probability": 0.8, "S": 9.0, "J": 1.0},
        {"loop": "a", "verdict": "stiction", "probability": 0.95, "S": 1.0, "J": 0.0},
        {"loop": "c", "verdict": "inconclusive", "probability": 0.6, "S": 20.0, "J": 5.0},
        {"loop": "d", "verdict": "error", "error": "bad"},
    ]
    # P(stiction) first within a verdict, severity only after it.
    assert [r["loop"] for r in sorted(rows, key=rank_key)] == ["a", "b", "c", "d"]
    assert list(rank(rows)["loop"]) == ["a", "b", "c", "d"]
    assert "then P(stiction)" in RANKING_RULE


def _export(path: Path, S: float, day: int) -> None:
    """A long export of a sticky concentration loop (Table 3) recorded on ``day``."""
    from stictiondiag.models.loops import simulate_paper_loop

    sim = simulate_paper_loop("concentration", S, 0.5 * S, duration=2400.0, dt=1.0)
    start = pd.Timestamp("2024-01-01") + pd.Timedelta(days=day)
    stamps = start + pd.to_timedelta(sim.time, unit="s")
    frame = pd.concat(
        pd.DataFrame({"timestamp": stamps, "tag": f"QIC7.{role.upper()}", "value": values})
        for role, values in (("pv", sim.pv), ("op", sim.op), ("mv", sim.mv), ("sp", sim.sp))
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_csv(path, index=False)


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def _dom(chromium: str, page: Path, profile: Path) -> tuple[str, str]:
    run = subprocess.run(
        [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            f"--user-data-dir={profile}",
            "--enable-logging=stderr",
            "--v=0",
            "--virtual-time-budget=5000",
            "--dump-dom",
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    return run.stdout, run.stderr


@pytest.fixture(scope="module")
def three_scans(tmp_path_factory):
    """Three exports of loop QIC7 (S = 2, 3, 4 % of span), scanned one after the other
    into one output folder, as a plant's monthly exports would be."""
    root = tmp_path_factory.mktemp("history")
    out = root / "scan"
    for k, S in enumerate((2.0, 3.0, 4.0)):
        export = root / f"export{k}" / "plant.csv"
        _export(export, S, day=30 * k)
        scan(export.parent, out=out, workers=1, gap=False)
    return out


@pytest.mark.slow
def test_history_of_three_scans_keeps_every_record_and_says_the_trend(three_scans):
    out = three_scans
    history = json.loads((out / "history" / "QIC7.json").read_text())
    entries = history["entries"]
    assert len(entries) == 3
    # One entry per record period, in record order, 30 days apart.
    starts = [e["record_start_s"] for e in entries]
    assert np.allclose(np.diff(starts), 30 * 86400.0)
    # The true S of the three records: 2, 3, 4 % (mv recorded: S within 0.3 % of span).
    assert [e["S"] for e in entries] == pytest.approx([2.0, 3.0, 4.0], abs=0.3)
    table = pd.read_csv(out / "scan.csv")
    trend = table.set_index("loop").loc["QIC7", "trend"]
    assert re.fullmatch(r"S rose from 2(\.\d+)? % to 4(\.\d+)? % over 3 exports", trend), trend
    page = (out / "loops" / "QIC7.html").read_text()
    assert 'id="history"' in page and "over 3 exports" in page
    assert page.count('alt="phase"') == 1  # the loop page carries its plots
    index = (out / "index.html").read_text()
    assert RANKING_RULE.split(",")[0] in index and "over 3 exports" in index
    assert "flags" not in index  # no internal notes on the overview


@pytest.mark.slow
@pytest.mark.browser
def test_fleet_and_loop_pages_render_in_a_real_browser(three_scans, tmp_path):
    chromium = _chromium()
    if chromium is None:
        pytest.skip("no chromium on this machine (.ci/run installs it)")
    out = three_scans
    dom, log = _dom(chromium, out / "index.html", tmp_path / "profile")
    # The page's own filter script ran (CSP allowed it by its hash): it counts the rows.
    assert re.search(r'id="f-count"[^>]*>1 shown<', dom), dom[:2000]
    assert 'id="ranking-rule"' in dom and '<svg class="spark"' in dom
    assert "Content Security Policy" not in log and "Uncaught" not in log
    dom, log = _dom(chromium, out / "loops" / "QIC7.html", tmp_path / "profile")
    m = re.search(r'data-images-loaded="(\d+)/(\d+)"', dom)
    assert m is not None and m.group(1) == m.group(2) and int(m.group(2)) >= 2
    assert '<svg class="history"' in dom and "Content Security Policy" not in log
