"""``stiction warm-up`` and the cold-cache detection behind "compiled once per node"."""

from __future__ import annotations

import importlib
import io
import sys

import pytest
from typer.testing import CliRunner

from stiction_cli.main import app
from stictiondiag.core import jit

KERNEL_SOURCE = """
from stictiondiag.core.jit import jit


@jit
def plus_one(x):
    return x + {k}
"""


@pytest.fixture
def fresh_kernel(tmp_path, monkeypatch):
    """A one-line kernel in a module of its own, so its cache starts empty."""
    monkeypatch.syspath_prepend(str(tmp_path))
    path = tmp_path / "warm_probe.py"

    def load(k: int):
        text = KERNEL_SOURCE.format(k=k)
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
        sys.modules.pop("warm_probe", None)
        return importlib.import_module("warm_probe").plus_one

    yield path, load
    sys.modules.pop("warm_probe", None)


def test_a_kernel_is_on_disk_once_compiled_and_stale_after_an_edit(fresh_kernel):
    path, load = fresh_kernel
    kernel = load(1)
    assert not jit.on_disk(kernel)
    assert kernel(1.0) == 2.0
    assert jit.on_disk(kernel)
    # Another process (a worker) sees the cache: a fresh import finds it.
    assert jit.on_disk(load(1))
    # An edited source makes the old entries stale (numba keeps a stamp of it).
    assert not jit.on_disk(load(2))


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_first_compilation_is_announced_once_on_a_terminal(monkeypatch):
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.setattr(jit._note_first_compile, "done", False)
    # Called by numba's compile event for each of this package's kernels.
    jit._note_first_compile("stictiondiag.x.kernel")
    jit._note_first_compile("stictiondiag.x.other")
    assert err.getvalue() == jit.FIRST_COMPILE_NOTE + "\n"
    # Output that is not a terminal (a pipe, a log file, a test) gets nothing.
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    monkeypatch.setattr(jit._note_first_compile, "done", False)
    jit._note_first_compile("stictiondiag.x.kernel")
    assert sys.stderr.getvalue() == ""


#: Kernels the package defines but no code path calls (``same_sign_fit_many`` took
#: their place in the Hammerstein fit); the warm-up cannot reach them.
UNCALLED = {
    "stictiondiag.stiction.hammerstein.kernels.same_sign_fit",
    "stictiondiag.stiction.hammerstein.kernels._solve_subset",
}


def test_warm_up_command_caches_every_kernel():
    result = CliRunner().invoke(app, ["warm-up"])
    assert result.exit_code == 0, result.output
    assert "kernels compiled in" in result.stdout
    assert "[3/3]" in result.stderr
    # Every kernel of the package the warm-up imported is in the cache afterwards,
    # but for those nothing calls: a kernel the warm-up does not reach compiles at
    # its first use, in every worker of a first scan.
    assert set(jit.cold_kernels()) <= UNCALLED
    assert not jit.cache_is_cold()


def test_an_uncalled_kernel_does_not_make_the_cache_cold(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    probes = {}
    for name in ("probe_a", "probe_b"):
        (tmp_path / f"{name}.py").write_text(KERNEL_SOURCE.format(k=1))
        sys.modules.pop(name, None)
        probes[name] = importlib.import_module(name).plus_one
    a, b = probes["probe_a"], probes["probe_b"]
    monkeypatch.setattr(jit, "kernels", lambda: [a, b])
    # Nothing ever compiled: a fresh installation, cold.
    assert jit.cache_is_cold()
    # One compiled, the other never called: warm (else every check says cold).
    a(1.0)
    assert not jit.cache_is_cold()
    # The compiled one's source edited since: stale, cold.
    (tmp_path / "probe_a.py").write_text(KERNEL_SOURCE.format(k=2))
    sys.modules.pop("probe_a")
    stale = importlib.import_module("probe_a").plus_one
    monkeypatch.setattr(jit, "kernels", lambda: [stale, b])
    assert jit.cache_is_cold()
    for name in probes:
        sys.modules.pop(name, None)


def test_a_command_on_a_cold_cache_says_so_at_once_and_shows_progress(monkeypatch):
    # Cold cache (a fresh installation): before "analysing ...", the command says
    # that it compiles the kernels (first run, about a minute) and prints the
    # warm-up's progress lines; the compilation itself is replaced by a stand-in.
    from pathlib import Path

    from stiction_cli.common import COMPILE_NOTE
    from stictiondiag.apps import warmup

    calls = []

    def fake_warm_up(progress=None):
        calls.append(1)
        progress("[1/3] valve models (0 s)")
        progress("  compiling stictiondiag.models.valve.choudhury_kernel")
        return warmup.WarmUp(("k",), 1, (), 0.5)

    monkeypatch.setattr(jit, "cache_is_cold", lambda: True)
    monkeypatch.setattr(warmup, "warm_up", fake_warm_up)
    sample = Path(__file__).resolve().parents[1] / "sample_data" / "healthy_flow.csv"
    result = CliRunner().invoke(app, ["analyze", str(sample), "--no-gap"])
    assert result.exit_code == 0, result.output
    err = result.stderr
    assert calls == [1]
    assert err.index(COMPILE_NOTE) < err.index("[1/3] valve models") < err.index("analysing")
    assert "1 kernels compiled in 0 s" in err
