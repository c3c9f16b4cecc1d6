"""The before/after comparison script (scripts/compare_analyses.py) finds differences."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "compare_analyses.py"
spec = importlib.util.spec_from_file_location("compare_analyses", SCRIPT)
compare = importlib.util.module_from_spec(spec)
spec.loader.exec_module(compare)


def test_numbers_within_tolerance_are_the_same():
    a = {"stiction": {"S": 5.0, "J": [1.0, 2.0]}, "source": "a.csv"}
    b = {"stiction": {"S": 5.0 * (1 + 1e-12), "J": [1.0, 2.0]}, "source": "b.csv"}
    assert compare.differences(a, b, rtol=1e-9, atol=0.0) == []


def test_every_kind_of_difference_is_listed():
    a = {"S": 5.0, "verdict": "stiction", "J": [1.0, 2.0], "only_a": 1, "flag": True}
    b = {"S": 5.1, "verdict": "inconclusive", "J": [1.0], "flag": False}
    diff = compare.differences(a, b, rtol=1e-9, atol=0.0)
    assert diff == [
        ".J: length 2 != 1",
        ".S: 5.0 != 5.1",
        ".flag: True != False",
        ".only_a: only in base",
        ".verdict: 'stiction' != 'inconclusive'",
    ]
