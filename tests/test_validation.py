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
    default_isdb_dir,
    expert_label,
    load_manifest,
    render_markdown,
    score,
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
    for method in ("ours", "horch", "bicoherence"):
        assert result.scores[method]["stated"]["n"] == 2
        assert result.scores[method]["none"]["n"] == 1
    page = render_markdown(result, command="stiction validate")
    assert "CHEM8" in page and "BAS1" in page
    assert "stiction validate" in page


def test_validate_cli_missing_isdb_is_a_data_error(tmp_path):
    result = CliRunner().invoke(app, ["validate", "--isdb", str(tmp_path / "nowhere")])
    assert result.exit_code == 3
    assert "stiction: error:" in result.output
    assert "Traceback" not in result.output
