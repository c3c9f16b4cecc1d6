"""Each layer imports only from the layers below it (README, "Layers").

Function-level imports count too: a lazy import that runs upward is still a
dependency upward.  The order, from the ground: core; io, signals and plotting
(plotting draws results read by attribute and imports nothing above core);
models; identification; stiction; replay; row; gap; result; analysis; apps; the
package's face.  Modules of one layer may import each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

import stictiondiag

ORDER = [
    ("core",),
    ("io", "signals", "plotting"),
    ("models",),
    ("identification",),
    ("stiction",),
    ("replay", "row"),
    ("gap",),
    ("result",),
    ("analysis",),
    ("apps",),
    ("__init__",),
]
RANK = {name: k for k, names in enumerate(ORDER) for name in names}
ROOT = Path(stictiondiag.__file__).parent


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found.extend((node.lineno, a.name) for a in node.names)
    return [(line, m) for line, m in found if m == "stictiondiag" or m.startswith("stictiondiag.")]


def test_every_import_points_down():
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        own = _layer(".".join(rel.parts))
        assert own in RANK, f"{rel}: a layer the README does not name"
        for line, module in _imports(path):
            if module == "stictiondiag":
                continue
            if RANK[_layer(module)] > RANK[own]:
                upward.append(f"{rel}:{line} imports {module}")
    assert upward == []


def test_the_order_names_every_layer():
    layers = {
        p.stem if p.is_file() else p.name
        for p in ROOT.iterdir()
        if not p.name.startswith("_") or p.name == "__init__.py"
    }
    layers = {x for x in layers if x != "__pycache__" and not x.endswith(".typed")}
    assert layers <= set(RANK)
