"""Validation against the International Stiction Database labels (stictiondiag.apps.validation).

The labels are read from the manifest's published comments, mechanically; the scores
count an ``inconclusive`` verdict as "not called stiction".  The ISDB has no open
licence: it is read from ``../shared/data/isdb`` and the tests that need it are
skipped where it is absent.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from stiction_cli.main import app
from stictiondiag.apps.validation import (
    CLASSIC_COLUMNS,
    SPLIT_MIN_CYCLES,
    default_isdb_dir,
    expert_label,
    load_manifest,
    render_markdown,
    score,
    split_half,
    split_summary,
    validate_isdb,
)

HAVE_ISDB = (default_isdb_dir() / "manifest.csv").is_file()
needs_isdb = pytest.mark.skipif(not HAVE_ISDB, reason="../shared/data/isdb not present")


@pytest.mark.parametrize(
    "published, other, expected",
    [
        ("yes", None, ("stiction", "stated")),
        ("yes_likely", None, ("stiction", "likely")),
        ("no", None, ("no_stiction", "stated")),
        ("", "quantisation", ("no_stiction", "stated")),
        ("", "external disturbance (likely)", ("no_stiction", "likely")),
        ("", None, (None, "none")),
        ("", float("nan"), (None, "none")),  # an empty CSV cell reads as NaN
    ],
)
def test_expert_label(published, other, expected):
    assert expert_label(published, other) == expected


def test_score_counts_inconclusive_as_not_called():
    table = pd.DataFrame(
        {
            "label_group": ["stated"] * 5 + ["likely", "none", "none"],
            "label": ["stiction", "stiction", "no_stiction", "no_stiction", "stiction"]
            + ["stiction", None, None],
            "verdict": ["stiction", "inconclusive", "stiction", "no_stiction", "no_stiction"]
            + ["stiction", "stiction", "inconclusive"],
        }
    )
    s = score(table, "verdict", lambda v: v == "stiction")
    assert s["stated"] == {
        "n": 5,
        "tp": 1,
        "fn": 2,  # the inconclusive stiction loop was not found
        "fp": 1,
        "tn": 1,
        "accuracy": 0.4,
        "inconclusive": 1,
    }
    assert s["likely"]["tp"] == 1 and s["likely"]["accuracy"] == 1.0
    assert s["none"] == {"n": 2, "called_stiction": 1}


def test_score_of_empty_groups():
    empty = pd.DataFrame({"label_group": [], "label": [], "verdict": []}, dtype=object)
    s = score(empty, "verdict", lambda v: v == "stiction")
    assert s["stated"]["n"] == 0 and s["stated"]["accuracy"] is None


def test_default_isdb_dir_is_beside_the_checkout(monkeypatch):
    # The data sits in ../shared next to the checkout, wherever the checkout is cloned
    # (CI clones it elsewhere); a wrong level here silently skips every ISDB test.
    monkeypatch.delenv("STICTION_ISDB", raising=False)
    checkout = Path(__file__).resolve().parents[1]
    assert default_isdb_dir() == checkout.parent / "shared" / "data" / "isdb"
    monkeypatch.setenv("STICTION_ISDB", "/elsewhere/isdb")
    assert default_isdb_dir() == Path("/elsewhere/isdb")


@needs_isdb
def test_manifest_labels():
    # The published comments give 28 stated labels (16 stiction, 12 not), 17 likely and
    # 32 loops without a diagnosis: the counts the results page states.
    m = load_manifest()
    assert len(m) == 77
    stated = m[m["label_group"] == "stated"]
    assert (stated["label"] == "stiction").sum() == 16
    assert (stated["label"] == "no_stiction").sum() == 12
    assert (m["label_group"] == "likely").sum() == 17
    assert (m["label_group"] == "none").sum() == 32
    assert m["path"].map(lambda p: Path(p).is_file()).all()  # every loop's file is there


@needs_isdb
@pytest.mark.isdb
def test_validate_a_few_loops_end_to_end():
    # One stiction loop with a textbook parallelogram (CHEM8), one stated healthy
    # loop (BAS1), one without a label (POW1 or the first such loop).
    m = load_manifest()
    unlabeled = m[m["label_group"] == "none"]["loop"].iloc[0]
    loops = ["CHEM8", "BAS1", unlabeled]
    result = validate_isdb(loops=loops, gap=False, workers=1)
    t = result.table.set_index("loop")
    assert set(t.index) == set(loops)
    assert set(t["verdict"]) <= {"stiction", "no_stiction", "inconclusive", "error"}
    for method in ("ours", *CLASSIC_COLUMNS):
        assert result.scores[method]["stated"]["n"] == 2
        assert result.scores[method]["none"]["n"] == 1
    # Every classic test's own call sits beside ours.
    for test in CLASSIC_COLUMNS:
        assert set(t[f"baseline_{test}"]) <= {"stiction", "no_stiction", "inconclusive", "n/a"}
    assert t["probability"].between(0.0, 1.0).all()
    page = render_markdown(result, command="stiction validate")
    assert "CHEM8" in page and "BAS1" in page
    assert "stiction validate" in page
    assert "## Split-half repeatability" in page and "## Targets" in page


def test_validate_cli_missing_isdb_is_a_data_error(tmp_path):
    result = CliRunner().invoke(app, ["validate", "--isdb", str(tmp_path / "nowhere")])
    assert result.exit_code == 3
    assert "stiction: error:" in result.output
    assert "Traceback" not in result.output


def _sticky_tags(duration: float):
    from stictiondiag.io.tags import Tags
    from stictiondiag.models.loops import simulate_paper_loop

    sim = simulate_paper_loop(
        "concentration", 5.0, 2.0, duration=duration, dt=0.5, noise_std=0.02, seed=3, kick=2.0
    )
    w = sim.n // 5
    return Tags.from_arrays(
        sim.pv[w:], sim.op[w:], sp=sim.sp[w:], ts=0.5, loop_type="other", integrating=False
    )


def test_split_half_of_a_sticky_loop_agrees():
    # The paper's concentration loop with S = 5, J = 2 cycles with a period of about
    # 140 s: the 2000 s kept hold about 14 cycles, so each half holds about seven
    # clear limit cycles of the same valve: both halves must say stiction, each with
    # S within 0.3 % of span of the true 5 % (the halves find 4.91 and 5.10).
    from stictiondiag.signals.oscillation import detect_oscillation

    tags = _sticky_tags(2500.0)
    period = detect_oscillation(tags.pv, tags.ts).period_s
    assert tags.duration > 2 * SPLIT_MIN_CYCLES * period
    out = split_half(tags, period)
    assert [h["verdict"] for h in out["halves"]] == ["stiction", "stiction"]
    assert out["agree"] is True
    for h in out["halves"]:
        assert h["S"] == pytest.approx(5.0, abs=0.3)
    # With little noise the profile intervals are a few hundredths wide, narrower than
    # the 0.2 % the two halves differ by: the check reports that, it does not hide it.
    lo_hi = [h["S_interval"] for h in out["halves"]]
    inside = all(
        iv[0] <= other["S"] <= iv[1] for iv, other in zip(lo_hi, out["halves"][::-1], strict=True)
    )
    assert out["S_within_intervals"] is inside
    # A record shorter than SPLIT_MIN_CYCLES periods is not split.
    assert split_half(tags, tags.duration / (SPLIT_MIN_CYCLES - 0.5)) is None
    assert split_half(tags, None) is None


def test_split_summary_counts():
    table = pd.DataFrame(
        {
            "split_agree": [True, False, True, None],
            "split_S_within": [True, None, False, None],
        }
    )
    s = split_summary(table)
    assert s == {
        "n": 3,
        "agree": 2,
        "agreement": pytest.approx(2 / 3),
        "n_S": 2,
        "S_within": 1,
        "S_within_share": 0.5,
    }


def test_stated_auc_and_per_cause_table():
    import pandas as pd

    from stictiondiag.apps.validation import cause_table, stated_auc

    t = pd.DataFrame(
        {
            "label_group": ["stated"] * 4 + ["likely"],
            "label": ["stiction", "stiction", "no_stiction", "no_stiction", "stiction"],
            "probability": [0.9, 0.4, 0.5, 0.1, 0.0],
            "stiction_published": ["yes", "yes", "not stated", "not stated", "yes_likely"],
            "other_fault_published": [None, "tight tuning", "quantisation", "no oscillation", None],
            "cause": ["valve", "tuning", "other", "none", "external"],
            "verdict": ["stiction", "no_stiction", "inconclusive", "no_stiction", "no_stiction"],
        }
    )
    # Pairs (stiction, other) on the stated loops: (0.9 > 0.5), (0.9 > 0.1),
    # (0.4 < 0.5), (0.4 > 0.1): 3 of 4; the likely loop is not counted.
    assert stated_auc(t) == pytest.approx(0.75, abs=1e-12)
    rows = {r.split(" | ")[0].lstrip("| "): r for r in cause_table(t)[2:]}
    assert set(rows) == {"stiction", "quantisation", "no oscillation", "stiction (likely)"}
    # stiction: 2 loops, one named valve, one tuning.
    assert rows["stiction"].startswith("| stiction | 2 | 1 | 1 | 0 | 0 | 0 | 0 | 0 |")
    assert rows["quantisation"].endswith("| 0 | 1 |")  # inconclusive, cause other
