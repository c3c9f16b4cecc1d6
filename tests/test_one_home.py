"""Shared helpers live in ``stictiondiag/core`` only: a copy elsewhere fails here.

The copies this test has found before (issue: one home per concept): the sample-time
check, the JSON converters of one number or a nested result, and the MAD factor
1.4826 written inline.  Each rule names the one home; a new copy of any of them
makes this test fail with the file and line.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "stictiondiag"

#: Function names that are shared helpers, and their one home.
HOMES = {
    "check_dt": "core/checks.py",
    "_check_dt": "core/checks.py",
    "_check_ts": "core/checks.py",
    "as_signal": "core/checks.py",
    "plain_float": "core/serialize.py",
    "to_plain": "core/serialize.py",
    "_plain": "core/serialize.py",
    "_clean": "core/serialize.py",
    "plain": "core/serialize.py",
    "mad": "core/robust.py",
    "robust_std": "core/robust.py",
    "second_difference_noise_std": "core/robust.py",
    "memo_by_content": "(nowhere: results are passed, not remembered)",
}

#: The MAD-to-standard-deviation factor, written only in its home.
MAD_FACTOR = 1.4826


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        yield path.relative_to(PACKAGE).as_posix(), ast.parse(path.read_text(encoding="utf-8"))


def test_shared_helpers_are_defined_in_core_only():
    copies = [
        f"{rel}:{node.lineno} defines {node.name} (home: {HOMES[node.name]})"
        for rel, tree in _modules()
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and node.name in HOMES
        and rel != HOMES[node.name]
    ]
    assert copies == []


def test_mad_factor_is_written_once():
    inline = [
        f"{rel}:{node.lineno}"
        for rel, tree in _modules()
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, float)
        and abs(node.value - MAD_FACTOR) < 1e-12
        and rel != "core/robust.py"
    ]
    assert inline == []


def test_the_rule_finds_a_copy(tmp_path):
    """The scan is not vacuous: a module with a copy of each is caught."""
    tree = ast.parse("def check_dt(dt):\n    return 1.4826 * dt\n")
    names = [n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
    consts = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)]
    assert "check_dt" in HOMES and names == ["check_dt"]
    assert any(isinstance(c, float) and abs(c - MAD_FACTOR) < 1e-12 for c in consts)


def test_the_benchmark_oracle_imports_nothing_of_the_models():
    """The withheld-effect benchmark's simulator is an independent oracle
    (:mod:`stictiondiag.models.synthetic_loop`): it imports no valve, loop or
    physical model, so a benchmark result cannot come from both sides sharing one
    mistake."""
    tree = ast.parse((PACKAGE / "models" / "synthetic_loop.py").read_text(encoding="utf-8"))
    imported = [
        node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module
    ] + [a.name for node in ast.walk(tree) if isinstance(node, ast.Import) for a in node.names]
    ours = [m for m in imported if m.startswith("stictiondiag")]
    assert ours == ["stictiondiag.core.jit"]
