"""The kernel-cache guard (stictiondiag.core.kernelcache): numba's caches of the package
are dropped as a whole when any of its source files changes, and only then."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from stictiondiag.core import kernelcache

#: numba's cache file names for a kernel ``run`` at line 5 of ``a.py``: the index and
#: two compiled versions (numba/core/caching.py, ``get_filename_base``).
A_CACHES = ("a.run-5.py311.nbi", "a.run-5.py311.1.nbc", "a.run-5.py311.2.nbc")
B_CACHES = ("b.step-12.py310.nbi", "b.step-12.py310.1.nbc")
#: Files in the same folders that are not numba's finished caches.
KEPT = ("a.cpython-311.pyc", "a.run-5.py311.nbi.tmp.0123abcd", "notes.txt")


def _touch(folder: Path, names) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / n for n in names]
    for p in paths:
        p.write_bytes(b"x")
    return paths


@pytest.fixture
def tree(tmp_path):
    """A package ``pkg`` (two folders) beside another package ``other``, each with
    cache files in its ``__pycache__``, and a user-wide cache folder."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("X = 1\n")
    (pkg / "sub" / "b.py").write_text("Y = 2\n")
    other = tmp_path / "other"
    other.mkdir()
    (other / "a.py").write_text("Z = 3\n")
    return tmp_path, pkg, other


def _plant(pkg: Path, other: Path, user: Path) -> tuple[list[Path], list[Path]]:
    """Cache files of ``pkg`` (to be removed) and files to keep; their paths."""
    ours = _touch(pkg / "__pycache__", A_CACHES) + _touch(pkg / "sub" / "__pycache__", B_CACHES)
    ours += _touch(user / kernelcache._subpath(str(pkg / "sub")), B_CACHES)
    keep = _touch(pkg / "__pycache__", KEPT) + _touch(other / "__pycache__", A_CACHES)
    keep += _touch(user / kernelcache._subpath(str(other)), A_CACHES)
    return ours, keep


def _stamp(pkg: Path) -> list[str]:
    return (pkg / "__pycache__" / kernelcache.STAMP_NAME).read_text().splitlines()


def test_a_changed_source_drops_exactly_the_packages_caches(tree):
    tmp, pkg, other = tree
    user = tmp / "user-cache"
    ours, keep = _plant(pkg, other, user)
    # No stamp yet (an installation from before the guard): the caches are of unknown
    # source, so every one of the package's is dropped, in-tree and user-wide.
    removed = kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user))
    assert sorted(removed) == sorted(str(p) for p in ours)
    assert [p for p in ours if p.exists()] == []
    assert [p for p in keep if not p.exists()] == []  # .pyc, numba's temp file, `other`
    first = _stamp(pkg)
    assert first[1] == kernelcache.source_fingerprint(str(pkg))

    # The caches are rebuilt; nothing changes: nothing is removed.
    ours, _ = _plant(pkg, other, user)
    assert kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user)) == []
    assert all(p.exists() for p in ours)

    # One file of another folder changes (a callee moved or edited): all go.
    (pkg / "sub" / "b.py").write_text("Y = 20\n")
    removed = kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user))
    assert sorted(removed) == sorted(str(p) for p in ours)
    assert all(p.exists() for p in keep)
    second = _stamp(pkg)
    assert second[1] == kernelcache.source_fingerprint(str(pkg)) != first[1]
    assert second[2] != first[2]  # the content digest moved with the content


def test_a_touched_but_unchanged_source_keeps_the_caches(tree):
    tmp, pkg, other = tree
    user = tmp / "user-cache"
    kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user))
    before = _stamp(pkg)
    ours, _ = _plant(pkg, other, user)
    # A new mtime, the same bytes (a checkout there and back): the stamp follows the
    # file's new stat, and no cache is dropped.
    st = os.stat(pkg / "a.py")
    os.utime(pkg / "a.py", ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))
    assert kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user)) == []
    assert all(p.exists() for p in ours)
    after = _stamp(pkg)
    assert after[1] != before[1] and after[2] == before[2]


def test_an_edit_above_every_kernel_layer_keeps_the_caches(tree):
    tmp, pkg, other = tree
    user = tmp / "user-cache"
    (pkg / "apps").mkdir()
    (pkg / "apps" / "report.py").write_text("R = 1\n")
    (pkg / "analysis.py").write_text("A = 1\n")
    kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user))
    ours, _ = _plant(pkg, other, user)
    # The orchestrator and the applications cannot reach into a kernel (the layers
    # import only downward): editing them costs no recompilation...
    (pkg / "apps" / "report.py").write_text("R = 10\n")
    (pkg / "analysis.py").write_text("A = 10\n")
    assert kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user)) == []
    assert all(p.exists() for p in ours)
    # ...unless the guard is told to count them.
    removed = kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user), above=())
    assert sorted(removed) == sorted(str(p) for p in ours)


def test_no_kernel_is_defined_above_the_kernel_layers():
    """What ABOVE_KERNELS leaves out of the fingerprint defines no kernel (else an
    edit there would leave its kernels' callers stale)."""
    import importlib
    import pkgutil

    from numba.core.dispatcher import Dispatcher

    import stictiondiag

    names = ["stictiondiag"]
    for top in kernelcache.ABOVE_KERNELS - {"__init__.py"}:
        name = f"stictiondiag.{top.removesuffix('.py')}"
        names.append(name)
        module = importlib.import_module(name)
        if hasattr(module, "__path__"):
            names += [m.name for m in pkgutil.walk_packages(module.__path__, name + ".")]
    assert len(names) > 5  # the applications' modules were found
    defined = [
        f"{name}.{attr}"
        for name in names
        for attr, obj in vars(importlib.import_module(name)).items()
        if isinstance(obj, Dispatcher) and obj.py_func.__module__ == name
    ]
    assert defined == []
    assert set(kernelcache.ABOVE_KERNELS) <= {
        p.name for p in Path(stictiondiag.__file__).parent.iterdir()
    }


def test_numba_cache_dir_is_cleaned_only_in_the_packages_folders(tree):
    tmp, pkg, other = tree
    cache_dir = tmp / "numba-cache"
    ours = _touch(cache_dir / kernelcache._subpath(str(pkg)), A_CACHES)
    ours += _touch(cache_dir / kernelcache._subpath(str(pkg / "sub")), B_CACHES)
    keep = _touch(cache_dir / kernelcache._subpath(str(other)), A_CACHES)
    keep += _touch(pkg / "__pycache__", A_CACHES)  # not where numba looks with the variable
    removed = kernelcache.guard(str(pkg), cache_dir=str(cache_dir), user_dir=str(tmp / "u"))
    assert sorted(removed) == sorted(str(p) for p in ours)
    assert all(p.exists() for p in keep)
    stamp = cache_dir / kernelcache._subpath(str(pkg)) / kernelcache.STAMP_NAME
    assert stamp.read_text().splitlines()[1] == kernelcache.source_fingerprint(str(pkg))


def test_a_missing_folder_does_not_raise(tmp_path):
    assert kernelcache.guard(str(tmp_path / "gone"), cache_dir="", user_dir=str(tmp_path)) is None


def test_a_read_only_installation_is_left_alone(tree, monkeypatch):
    tmp, pkg, other = tree
    user = tmp / "user-cache"
    ours, keep = _plant(pkg, other, user)

    def refuse(path, *args, **kwargs):
        raise PermissionError(13, "Permission denied", path)

    # Every folder read-only (faked: the tests may run as root, who writes anyway).
    monkeypatch.setattr(kernelcache, "_writable", lambda path: False)
    monkeypatch.setattr(os, "remove", refuse)
    monkeypatch.setattr(os, "replace", refuse)
    assert kernelcache.guard(str(pkg), cache_dir="", user_dir=str(user)) is None
    assert all(p.exists() for p in ours + keep)
    assert not (pkg / "__pycache__" / kernelcache.STAMP_NAME).exists()
    assert not (user / kernelcache._subpath(str(pkg)) / kernelcache.STAMP_NAME).exists()


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes anyway")
def test_a_read_only_folder_does_not_raise(tree):
    tmp, pkg, other = tree
    ours, _ = _plant(pkg, other, tmp / "user-cache")
    folders = [pkg / "__pycache__", pkg / "sub" / "__pycache__", pkg, pkg / "sub"]
    for f in folders:
        f.chmod(0o555)
    try:
        kernelcache.guard(str(pkg), cache_dir="", user_dir=str(tmp / "ro-user"))
        assert all(p.exists() for p in ours[: len(A_CACHES) + len(B_CACHES)])
    finally:
        for f in folders:
            f.chmod(0o755)


def test_the_guard_runs_when_the_kernels_module_is_imported(tmp_path):
    """Importing stictiondiag.core.jit (which every kernel module does first) drops a
    stale cache of the package before any kernel is defined."""
    import stictiondiag

    cache_dir = tmp_path / "numba-cache"
    core = os.path.join(os.path.dirname(os.path.abspath(stictiondiag.__file__)), "core")
    stale = _touch(cache_dir / kernelcache._subpath(core), ("filters.x-1.py311.nbi",))[0]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    subprocess.run([sys.executable, "-c", "import stictiondiag.core.jit"], env=env, check=True)
    assert not stale.exists()
    stamps = list(cache_dir.glob(f"*/{kernelcache.STAMP_NAME}"))
    assert len(stamps) == 1


KERNEL_A = """
from stictiondiag.core.jit import jit


@jit
def helper(x):
    return x + {k}
"""

KERNEL_B = """
from stictiondiag.core.jit import jit
from tinypkg.a import helper


@jit
def caller(x):
    return helper(x)
"""


def test_a_callers_cache_follows_an_edit_of_its_callees_file(tmp_path):
    """The failure the guard exists for, end to end: ``caller`` (b.py) calls
    ``helper`` (a.py); a.py is edited; ``caller`` must compute with the new helper."""
    pkg = tmp_path / "tinypkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(KERNEL_A.format(k=1))
    (pkg / "b.py").write_text(KERNEL_B)
    env = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache"),
        "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path]),
    }

    def run(guarded: bool) -> float:
        guard = f"kernelcache.guard({str(pkg)!r}); " if guarded else ""
        code = (
            "from stictiondiag.core import kernelcache; "
            f"{guard}from tinypkg.b import caller; print(caller(1.0))"
        )
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True
        )
        return float(out.stdout)

    assert run(guarded=True) == 2.0
    (pkg / "a.py").write_text(KERNEL_A.format(k=100))
    # Without the guard numba loads caller's stale code (helper + 1): the limitation.
    assert run(guarded=False) == 2.0
    assert run(guarded=True) == 101.0
    assert run(guarded=True) == 101.0  # and the new caches are kept
    assert list((tmp_path / "numba-cache").rglob("b.caller-*.nbi"))


def test_the_cache_file_pattern_is_numbas(tmp_path):
    """The names the guard removes are the names numba writes (checked on numba's
    own cache of a real kernel), so a numba that renamed them would show here."""
    text = textwrap.dedent(
        """
        from stictiondiag.core.jit import jit
        @jit
        def f(x):
            return x * 2
        print(f(2.0))
        """
    )
    (tmp_path / "probe29.py").write_text(text)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "nc")}
    subprocess.run([sys.executable, str(tmp_path / "probe29.py")], env=env, check=True)
    names = [p.name for p in (tmp_path / "nc").rglob("probe29.*")]
    assert any(n.endswith(".nbi") for n in names) and any(n.endswith(".nbc") for n in names)
    assert all(kernelcache._CACHE_FILE.match(n) for n in names)
