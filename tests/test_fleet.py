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

from stictiondiag.apps.history import HistoryEntry, merge_entry, trend_sentence
from stictiondiag.apps.pages import RANKING_RULE, rank_key
from stictiondiag.apps.scan import rank, scan


def test_trend_sentence_says_rise_fall_or_no_change():
    def e(s, lo, hi, start):
        return HistoryEntry(key=str(start), record_start_s=start, S=s, S_lo=lo, S_hi=hi)

    entries = []
    for k, (s, lo, hi) in enumerate([(1.2, 1.1, 1.3), (2.0, 1.9, 2.1), (3.4, 3.3, 3.5)]):
        entries = merge_entry(entries, e(s, lo, hi, 1e9 + k * 86400))
    assert trend_sentence(entries) == "S rose from 1.2 % to 3.4 % over 3 exports"
    # The same record analysed again replaces its entry (keyed by the record period).
    again = merge_entry(entries, e(3.5, 3.3, 3.6, 1e9 + 2 * 86400))
    assert len(again) == 3 and again[-1].S == 3.5
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
    # P(valve) first within a verdict, severity only after it.
    assert [r["loop"] for r in sorted(rows, key=rank_key)] == ["a", "b", "c", "d"]
    assert list(rank(rows)["loop"]) == ["a", "b", "c", "d"]
    assert "then P(valve)" in RANKING_RULE


def _export(path: Path, S: float, day: int, tag: str = "QIC7") -> None:
    """A long export of a sticky concentration loop (Table 3) recorded on ``day``."""
    from stictiondiag.models.loops import simulate_paper_loop

    sim = simulate_paper_loop("concentration", S, 0.5 * S, duration=2400.0, dt=1.0)
    start = pd.Timestamp("2024-01-01") + pd.Timedelta(days=day)
    stamps = start + pd.to_timedelta(sim.time, unit="s")
    frame = pd.concat(
        pd.DataFrame({"timestamp": stamps, "tag": f"{tag}.{role.upper()}", "value": values})
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
def test_a_loop_left_out_of_the_next_export_keeps_its_last_result_in_view(three_scans, tmp_path):
    # A fourth export holds another loop only: QIC7's history stays, and the fleet
    # page lists it as not in this export, with its last S (true 4 %, within 0.3 % of
    # span as above), its trend and its earlier page; the ranked table has QIC8 alone.
    out = tmp_path / "scan"
    shutil.copytree(three_scans, out)
    export = tmp_path / "export3" / "plant.csv"
    _export(export, 3.0, day=90, tag="QIC8")
    scan(export.parent, out=out, workers=1, gap=False)
    assert list(pd.read_csv(out / "scan.csv")["loop"]) == ["QIC8"]
    assert len(json.loads((out / "history" / "QIC7.json").read_text())["entries"]) == 3
    index = (out / "index.html").read_text()
    section = index[index.index('<h2 id="absent">') :]
    assert "Not in this export (1 loop)" in section
    assert '<a href="loops/QIC7.html">QIC7</a>' in section and "QIC8" not in section
    S = float(re.search(r"<td class='num'>([\d.]+) \[", section).group(1))
    assert S == pytest.approx(4.0, abs=0.3)
    assert re.search(r"S rose from 2(\.\d+)? % to 4(\.\d+)? % over 3 exports", section)


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


def test_the_cause_column_says_undecided_not_the_gap_effect_for_an_inconclusive_loop():
    """An inconclusive verdict names no cause of the cycle; the cell used to fall back
    to the gap's effect, so a loop with a plain cycle read "none" (as if it did not
    oscillate).  A loop without a cycle reads "no cycle"."""
    from stictiondiag.apps.scan_page import scan_html

    rows = [
        {"loop": "osc", "verdict": "inconclusive", "probability": 0.5, "gap_effect": "none"},
        {"loop": "flat", "verdict": "no_stiction", "probability": 0.0, "cause": "none"},
        {"loop": "sticky", "verdict": "stiction", "probability": 0.9, "cause": "valve"},
    ]
    page = scan_html(rank(rows))
    cells = {
        name: page.split(f">{name}</a>")[1].split("</tr>")[0] for name in ("osc", "flat", "sticky")
    }
    assert "<td>undecided</td>" in cells["osc"] and "<td>none</td>" not in cells["osc"]
    assert "<td>no cycle</td>" in cells["flat"]
    assert "<td>valve</td>" in cells["sticky"]
    # The probability column is P(valve), and the page says what it is.
    assert "<th>P(valve)</th>" in page
    assert "P(valve): the probability that the valve causes the loop&#x27;s cycle" in page
