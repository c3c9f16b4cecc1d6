"""The generated plants the scan benchmarks share (``scripts/make_plant.py``).

``make_plant`` loads the script as a module: the benchmarks run as scripts from a
checkout, where ``scripts`` is not a package.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def make_plant(*args, **kwargs):
    """:func:`make_plant` of ``scripts/make_plant.py`` (see there for the arguments)."""
    spec = importlib.util.spec_from_file_location("make_plant", ROOT / "scripts" / "make_plant.py")
    if spec is None or spec.loader is None:
        raise ImportError("scripts/make_plant.py not found beside benchmarks/")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make_plant(*args, **kwargs)
