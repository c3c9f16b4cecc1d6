"""Reports: escaping, self-contained HTML, and rendering in a real headless browser."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from typed_results import make_analysis, make_candidate, make_gap

from stictiondiag.apps.loop_page import render_loop_html
from stictiondiag.apps.report import (
    build_report,
    md_escape,
    render_index_html,
    render_markdown,
)
from stictiondiag.gap.effects.base import EffectParams

ROOT = Path(__file__).resolve().parents[1]

EVIL = "<script>alert('x')</script>"


@dataclasses.dataclass(frozen=True)
class _TextParams(EffectParams):
    """Effect parameters holding a text, to check it is escaped."""

    q: str


def _analysis(name=EVIL, **fields):
    values = {
        "status": "stiction",
        "p": 0.8,
        "S": 3.0,
        "J": 1.0,
        "S_interval": (2.5, 3.5),
        "J_interval": (0.5, 1.5),
        "determinacy": (None, None),
        "names": {"pv": EVIL, "op": "FIC101.OP"},
        "loop_type": "flow",
        "reasons": [f"comment {EVIL}"],
        "gap": make_gap(candidates=[make_candidate(EVIL, params=_TextParams(EVIL))]),
        "warnings": [f"gap at {EVIL}"],
    }
    return make_analysis(name, **{**values, **fields})


def test_html_escapes_everything_from_the_data():
    html = render_loop_html(_analysis(), {})
    # The only <script> allowed is the page's own load marker.
    assert html.count("<script>") == 1
    assert "alert(" not in html.split("<script>")[1].split("</script>")[0]
    assert "&lt;script&gt;alert" in html


def test_index_and_markdown_escape_loop_names():
    rows = [
        {
            "loop": EVIL,
            "verdict": "stiction",
            "confidence": 0.9,
            "S": 2.0,
            "J": 1.0,
            "gap_effect": "none|x",
        }
    ]
    html = render_index_html(rows)
    assert html.count("<script>") == 1 and "&lt;script&gt;" in html
    md = render_markdown(rows)
    assert "<script>" not in md
    # A pipe inside a cell must not split the Markdown table row: the row has as many
    # cell separators as the header.
    lines = md.splitlines()
    header = next(ln for ln in lines if ln.startswith("| loop"))
    row = next(ln for ln in lines if "alert" in ln)
    assert len(_cell_separators(row)) == len(_cell_separators(header))


def _cell_separators(line: str) -> list[int]:
    """Positions of the pipes that end a GFM table cell (not escaped by a backslash).

    A pipe after an even run of backslashes is a separator: ``\\\\|`` is an escaped
    backslash followed by a bare pipe.
    """
    return [
        m.start()
        for m in re.finditer(r"\|", line)
        if (len(line[: m.start()]) - len(line[: m.start()].rstrip("\\"))) % 2 == 0
    ]


def test_md_escape_neutralises_markdown():
    assert md_escape("a*b_c[d](e)") == r"a\*b\_c\[d\]\(e\)"
    assert "<" not in md_escape("<b>")
    # A backslash before a pipe must not un-escape the pipe, and a newline must not
    # end the table row.
    cell = md_escape("a\\|b\nc")
    assert _cell_separators(cell) == [] and "\n" not in cell


def _poorly_determined(status="inconclusive", p=0.55):
    return _analysis(
        "LIC200",
        status=status,
        p=p,
        S=0.48,
        J=5.78,
        S_interval=(0.0, 1.7),
        J_interval=(2.89, 5.78),
        determinacy=(
            "poorly determined",
            "poorly determined (interval reaches the search limit)",
        ),
        has_mv=False,
    )


def test_loop_page_shows_probability_and_marks_poorly_determined_parameters():
    """Issue 18: no "confidence 1.00" on an undecided verdict; a poorly determined
    J is marked where it is shown, with its interval and the search edge."""
    html = render_loop_html(_poorly_determined(), {})
    assert "P(stiction) = 0.55 (decision levels 0.3 and 0.7)" in html
    assert "confidence" not in html.split("verdict evidence")[0]
    assert "J = 5.78 % of travel (poorly determined: interval 2.89–5.78 at the search edge)" in html
    assert html.count('class="poor"') >= 4  # two cards and two table cells
    assert "mv is not recorded" in html  # what the data cannot tell
    assert 'id="loop-type">flow</span> <span class="muted">from user/default' in html


def test_loop_type_source_is_shown_when_recorded():
    html = render_loop_html(_analysis("FIC101", loop_type_source="tag prefix FIC"), {})
    assert "from tag prefix FIC" in html


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
]


def _browser_load(chromium: str, page: Path, profile: Path) -> tuple[str, str]:
    """DOM after load and chromium's log (console messages appear as ``CONSOLE``)."""
    run = subprocess.run(
        [
            chromium,
            *_FLAGS,
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


@pytest.mark.browser
@pytest.mark.slow
def test_real_report_renders_in_headless_browser(tmp_path):
    """End to end: a report over a sample loop, gap diagnosis included, in chromium."""
    chromium = _chromium()
    if chromium is None:
        pytest.skip("no chromium on this machine (.ci/run installs it)")
    sample = ROOT / "sample_data" / "slave_flow_stickslip.csv"
    out = tmp_path / "report"
    result = build_report([sample], out, gap=True)
    assert result.failed == []
    d = json.loads((out / "loops" / f"{sample.stem}.json").read_text())
    # Figures expected on the page: phase plots, reconstruction, and the gap's own.
    n_figures = 1 + (d["replay"] is not None) * (1 + (d["gap"] is not None))
    loop_page = out / "loops" / f"{sample.stem}.html"
    # The new elements: findings in words, data span and analysis date, the loop type
    # and its source, the Fig. 10 valve signature, P(stiction) instead of a confidence.
    dom, _ = _browser_load(chromium, loop_page, tmp_path / "profile")
    for marker in (
        'id="findings"',
        'id="data-span"',
        'id="analysed-at"',
        'id="loop-type"',
        'id="valve-signature"',
        'alt="valve_zoom"',
        "P(stiction) = ",
        "decision levels 0.3 and 0.7",
        "waveform agreement",
    ):
        assert marker in dom, marker
    assert "confidence" not in dom.split('id="findings"')[0]  # not in the header cards
    assert re.search(r'id="analysed-at">\d{4}-\d\d-\d\dT', dom)
    for page, min_images in ((loop_page, n_figures + 1), (out / "index.html", 0)):
        dom, log = _browser_load(chromium, page, tmp_path / "profile")
        # The page's load handler counts decoded images: all of them must have loaded.
        m = re.search(r'data-images-loaded="(\d+)/(\d+)"', dom)
        assert m is not None, f"{page.name}: load handler did not run"
        assert m.group(1) == m.group(2) and int(m.group(2)) >= min_images, page.name
        # Console output would be a script error, a blocked (external) asset or a
        # Content-Security-Policy violation: a clean page logs nothing.
        assert "CONSOLE" not in log, f"{page.name}: " + log[-1500:]
    shot = tmp_path / "shot.png"
    subprocess.run(
        [
            chromium,
            *_FLAGS,
            f"--user-data-dir={tmp_path / 'profile'}",
            "--window-size=1200,2400",
            f"--screenshot={shot}",
            loop_page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    # A blank 1200 x 2400 page compresses to about 10 KB; with the summary, tables and
    # plots the screenshot is far larger.
    assert shot.stat().st_size > 100_000
    assert _png_size(shot.read_bytes()) == (1200, 2400)


def _png_size(png: bytes) -> tuple[int, int]:
    """Width and height from a PNG's IHDR chunk."""
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")


def test_index_and_markdown_mark_poorly_determined_parameters():
    rows = [
        {
            "loop": "LIC200",
            "verdict": "inconclusive",
            "probability": 0.55,
            "confidence": 0.55,
            "S": 0.5,
            "S_lo": 0.0,
            "S_hi": 1.7,
            "S_determinacy": "moderately determined",
            "J": 5.78,
            "J_lo": 2.89,
            "J_hi": 5.78,
            "J_determinacy": "poorly determined (interval reaches the search limit)",
        }
    ]
    html = render_index_html(rows)
    assert '5.78 (2.89&ndash;5.78) <span class="poor"' in html
    assert html.count('class="poor"') == 1  # J only
    assert "<th>P(valve)</th>" in html and "0.55" in html
    md = render_markdown(rows)
    assert r"5.78 \(2.89-5.78\) poorly determined" in md and "| P(valve) |" in md


def test_index_names_each_loop_type_and_what_decided_it():
    base = {"verdict": "stiction", "probability": 0.9, "S": 3.0, "J": 1.0}
    rows = [
        {**base, "loop": "LIC101", "loop_type": "level", "loop_type_source": "tag"},
        {
            **base,
            "loop": "A",
            "loop_type": "other",
            "integrating": True,
            "loop_type_source": "data",
        },
        {**base, "loop": "B", "loop_type": "other", "integrating": False},
        {**base, "loop": "C"},  # a row of an older report: no loop type recorded
    ]
    html = render_index_html(rows)
    assert "<th>loop type</th>" in html
    assert "<td>level (tag)</td>" in html
    assert "<td>integrating (data)</td>" in html
    assert "<td>self-regulating</td>" in html
    assert "<tr><td>C</td><td></td>" in html  # nothing recorded, nothing claimed
