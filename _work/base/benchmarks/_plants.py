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


def run_in_checkout(code: Path, child: str, *args: str) -> dict:
    """Run the Python source ``child`` with the package of checkout ``code`` in a
    fresh process, one BLAS thread and one kernel thread (as in a scan's worker);
    the JSON object its last line of output prints.

    The process runs in the checkout: ``python -c`` puts the working directory first
    on the path, before ``PYTHONPATH``, so from another checkout it would import
    that one.  Stops when the child fails or imported the package from elsewhere
    (the child prints the package's file as ``"package"``).
    """
    import json
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(code))
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.setdefault("MKL_NUM_THREADS", "1")
    env.pop("STICTION_KERNEL_THREADS", None)
    done = subprocess.run(
        [sys.executable, "-c", child, *args],
        cwd=str(code),
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise SystemExit(f"the run with {code} failed:\n{done.stderr[-2000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if not Path(result["package"]).resolve().is_relative_to(Path(code).resolve()):
        raise SystemExit(f"the run of {code} imported {result['package']}")
    return result
