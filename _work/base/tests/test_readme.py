"""The project's front door: the README's library example runs as pasted and prints
what the README says; every sub-package is installed."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _blocks(text: str, language: str) -> list[tuple[int, str]]:
    """(offset, body) of every fenced block in ``language``."""
    pattern = re.compile(rf"^```{language}\n(.*?)^```", re.S | re.M)
    return [(m.start(), m.group(1)) for m in pattern.finditer(text)]


def test_readme_library_example_runs_and_prints_what_it_says(monkeypatch, capsys):
    import matplotlib.pyplot as plt

    readme = (ROOT / "README.md").read_text()
    (start, code), *others = _blocks(readme, "python")
    assert not others, "one library example in the README"
    # The output the README shows is the first text block after the example.
    shown = next(body for offset, body in _blocks(readme, "text") if offset > start)
    monkeypatch.chdir(ROOT)  # the example reads sample_data/ from the repository root
    before = set(plt.get_fignums())
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)
    printed = capsys.readouterr().out
    # Exact text: the example prints S and J rounded to 0.01 % of span, well above
    # the differences between platforms' floating point (the estimate is 5.00 and
    # 2.50 with its 95 % interval within +-0.02, docs/performance.md).
    assert printed == shown
    assert set(plt.get_fignums()) == before  # the figure is not left in pyplot


def test_every_subpackage_is_installed():
    # setuptools lists the packages one by one: a sub-package missing from the list
    # would work from the source tree (and an editable install) but not from a wheel.
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for init in (ROOT / "stictiondiag").rglob("__init__.py")
    }
    assert found <= listed, sorted(found - listed)
