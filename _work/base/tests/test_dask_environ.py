"""A Dask scan leaves the caller's environment as it found it, and its workers run
without the allocator setting Dask's nanny adds (issue 19, docs/performance.md "Dask")."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

from stictiondiag.apps.scan import run_dask, scan

pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]

#: Set by Dask's nanny by default; it makes every numpy temporary of 128 KiB or more
#: a fresh mmap (1.4x the CPU per loop).
TRIM = "MALLOC_TRIM_THRESHOLD_"


def make_plant(*args, **kwargs):
    """scripts/make_plant.py, loaded on use (as in tests/test_scan.py)."""
    spec = importlib.util.spec_from_file_location("make_plant", ROOT / "scripts" / "make_plant.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make_plant(*args, **kwargs)


def _worker_environ(name: str) -> tuple[str, str | None]:
    """Run in a Dask worker: the value of ``name`` in its environment."""
    return name, os.environ.get(name)


def test_dask_scan_leaves_the_callers_environment_unchanged(tmp_path, monkeypatch):
    # Two small loops on a one-worker LocalCluster: the nanny runs in this process
    # and writes its worker settings into os.environ before it starts the worker.
    monkeypatch.delenv(TRIM, raising=False)
    plant = tmp_path / "plant"
    make_plant(plant, 2, n_samples=1500, seed=5, fmt="csv", sticky_model="simple")
    before = dict(os.environ)
    result = scan(plant, out=tmp_path / "out", engine="dask", workers=1, gap=False)
    assert (result.n_loops, result.n_failed) == (2, 0)
    # Exact equality: no key added, removed or changed (a diff names the culprit).
    added = {k: os.environ[k] for k in set(os.environ) - set(before)}
    removed = set(before) - set(os.environ)
    changed = {k for k in set(before) & set(os.environ) if before[k] != os.environ[k]}
    assert (added, removed, changed) == ({}, set(), set())


def test_dask_workers_run_without_the_trim_setting(monkeypatch):
    monkeypatch.delenv(TRIM, raising=False)
    before = dict(os.environ)
    got = dict(run_dask([TRIM, "OMP_NUM_THREADS"], _worker_environ, (), 1, None))
    # The allocator setting is gone; the nanny's thread settings are kept.
    assert got == {TRIM: None, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    assert dict(os.environ) == before
    # A value the user set is the one the workers see, and it stays in this process.
    monkeypatch.setenv(TRIM, "1048576")
    got = dict(run_dask([TRIM], _worker_environ, (), 1, None))
    assert got == {TRIM: "1048576"} and os.environ[TRIM] == "1048576"


def test_dask_engine_without_dask_says_which_extra_to_install(monkeypatch):
    """Dask is an optional extra: without it the engine refuses with one line
    naming the extra, not an ImportError."""
    import sys

    from stictiondiag.apps import workers
    from stictiondiag.core.errors import UsageError

    monkeypatch.setitem(sys.modules, "distributed", None)  # import fails as if absent
    with pytest.raises(UsageError, match=r"pip install 'stiction\[dask\]'"):
        workers._connect(1, None)
