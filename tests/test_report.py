"""Reports: escaping, self-contained HTML, and rendering in a real headless browser."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from stictiondiag.report import md_escape, render_index_html, render_loop_html, render_markdown

EVIL = "<script>alert('x')</script>"


def _analysis_dict(name=EVIL):
    return {
        "loop": name,
        "source": f"/data/{name}.csv",
        "tags": {
            "names": {"pv": EVIL, "op": "FIC101.OP"},
            "n_samples": 1000,
            "ts_s": 1.0,
            "loop_type": "flow",
            "integrating": False,
        },
        "stiction": {
            "status": "stiction",
            "confidence": 0.8,
            "S": 3.0,
            "J": 1.0,
            "S_interval": [2.5, 3.5],
            "J_interval": [0.5, 1.5],
            "method": "mv_segments",
            "reasons": [f"comment {EVIL}"],
        },
        "replay": None,
        "gap": {
            "metric": "nrmse",
            "before": 0.5,
            "after": 0.2,
            "shrink_pct": 60.0,
            "effect": "quantization",
            "runner_up": "none",
            "candidates": [
                {"effect": EVIL, "after": 0.3, "shrink_pct": 40.0, "params": {"q": EVIL}}
            ],
        },
        "warnings": [f"gap at {EVIL}"],
    }


def test_html_escapes_everything_from_the_data():
    html = render_loop_html(_analysis_dict(), {})
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


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.mark.browser
def test_report_renders_in_headless_browser(tmp_path):
    chromium = _chromium()
    if chromium is None:
        pytest.skip("no chromium on this machine (.ci/run installs it)")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stictiondiag.plotting import figure_png

    fig, ax = plt.subplots()
    ax.plot(np.sin(np.linspace(0, 10, 200)))
    page = tmp_path / "loop.html"
    page.write_text(render_loop_html(_analysis_dict("FIC101"), {"phase": figure_png(fig)}))
    flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}",
    ]
    dom = subprocess.run(
        [
            chromium,
            *flags,
            "--enable-logging=stderr",
            "--v=0",
            "--virtual-time-budget=3000",
            "--dump-dom",
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert dom.returncode == 0, dom.stderr[-2000:]
    # The page's load handler counts decoded images: all of them must have loaded.
    m = re.search(r'data-images-loaded="(\d+)/(\d+)"', dom.stdout)
    assert m is not None, "load handler did not run"
    assert m.group(1) == m.group(2) and int(m.group(2)) >= 1
    assert "CONSOLE" not in dom.stderr, "console messages: " + dom.stderr[-1000:]
    shot = tmp_path / "shot.png"
    subprocess.run(
        [chromium, *flags, "--window-size=1200,1600", f"--screenshot={shot}", page.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    # A blank page compresses to a few KB; a rendered page with a plot is far larger.
    assert shot.stat().st_size > 20_000
