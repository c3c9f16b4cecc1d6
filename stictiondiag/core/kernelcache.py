"""Keeping numba's on-disk kernel caches consistent with the package's source as a whole.

numba stamps each cached kernel with a hash of *its own* source file only.  A kernel
that calls, or compiles in (``inline="always"``), a kernel of another file keeps its
old machine code when only that other file changes: after a ``git pull`` in an
editable install, or an upgrade over an old installation, it may crash
(``SystemError: ... returned a result with an exception set``) or, worse, run the
old code silently.  :func:`guard` closes that gap: :mod:`stictiondiag.core.jit`
calls it on import, before any kernel of the package is defined or loaded.

How it works
------------
* A stamp file (:data:`STAMP_NAME`) in the cache directory of the package's top
  folder records a fingerprint of the package's source: the relative path, size and
  modification time [ns] of every ``.py`` file (one ``stat`` each), and a SHA-256 of
  their contents.  The layers above every kernel (:data:`ABOVE_KERNELS`: the
  orchestrator ``analysis.py``, ``result.py``, ``apps/``, the package's
  ``__init__.py``) are left out: imports only point down, so no kernel depends on
  them, and editing them costs no recompilation.
* Same stat fingerprint: nothing more is done (the common case).
* Different stat fingerprint, same content (a ``touch``, a ``git checkout`` there and
  back): the stamp is rewritten and no cache is dropped.
* Different content, or no stamp (an installation made before this guard): every
  numba cache file (``*.nbi`` index, ``*.nbc`` code) of every folder of the package is
  removed, then the new stamp is written.  The next run recompiles every kernel
  once (docs/performance.md, "First run").

Where numba caches (``numba/core/caching.py``, its locators, tried in this order):
``NUMBA_CACHE_DIR`` when set (``<dir>/<folder>_<sha1 of the folder's path>``); else
``__pycache__`` next to the source when writable; else numba's user-wide cache
directory (same sub-folder names).  Without ``NUMBA_CACHE_DIR`` both the in-tree and
the user-wide folders are cleaned, so a folder whose ``__pycache__`` is not writable
is covered too.  Only files named as numba names its cache files
(``<module>.<function>-<line>.py<version>[.<n>].nbi|nbc``), in the cache folders of
this package's own folders, are ever removed; numba's in-flight temporary files,
``.pyc`` files and other packages' caches are left alone.

Several processes at once (a scan's workers, two commands started together): a
file already removed is skipped; the stamp is written whole by a rename
(:func:`stictiondiag.core.atomic.write_atomic`), so a reader sees the old stamp or
the new one; removing a cache another process has just written costs only a
recompile.  Nothing here raises: an unwritable cache folder (a read-only
installation) or any unexpected error leaves the caches as they are.  A custom
``NUMBA_CACHE_LOCATOR_CLASSES`` or ``NUMBA_DISABLE_JIT`` turns the guard off.

Not covered: a process started *before* the source changed, that compiles a kernel
afterwards, writes machine code of the old source under the new stamp.  Finish
running commands before updating.

Cost, measured: 0.6 ms per call when nothing changed (112 of the package's 137
``.py`` files in 14 folders; ``python -m timeit -n 200 -s "from stictiondiag.core
import kernelcache; import numba" "kernelcache.guard()"``, best of 5, three runs
0.60-0.62 ms); the content hash after a changed stat fingerprint adds 2.3 ms.  The
``import stictiondiag.core.jit`` of a new process (0.34 s of CPU) did not change
measurably: the median ratio of whole-process CPU time with/without the guard was
0.99 and 1.01 in two series of 15 alternated pairs (ranges 0.84-1.12, 0.91-1.09).
``stiction --help`` and ``import stictiondiag`` do not import numba or this module
(``stiction --help``: ratio 0.99, 10 pairs).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
from collections.abc import Collection

from stictiondiag.core.atomic import write_atomic

__all__ = ["ABOVE_KERNELS", "STAMP_NAME", "guard", "source_fingerprint"]

#: Name of the stamp file in the package's top cache folder.
STAMP_NAME = "stictiondiag-kernel-sources.stamp"

#: First line of a stamp (a change of the format makes old stamps count as missing).
_STAMP_HEADER = "stictiondiag kernel-cache stamp 1"

#: The package's top folder (``stictiondiag/``), as its modules' ``__file__`` name it.
PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: Top-level modules and folders of the package above every layer that holds a kernel
#: (README, "Layers"; ``tests/test_layers.py`` holds every import to point down, and
#: ``tests/test_kernelcache.py`` that none of these defines a kernel): no kernel can
#: depend on them, so editing them does not drop the caches.
ABOVE_KERNELS = frozenset({"__init__.py", "result.py", "analysis.py", "apps"})

#: numba's cache file names: ``<module>.<qualname>-<line>.py<major><minor><abiflags>``
#: then ``.nbi`` (the index) or ``.<n>.nbc`` (one compiled version).
_CACHE_FILE = re.compile(r"^[^.]+\..+-\d+\.py\d+[a-z]*(\.nbi|\.\d+\.nbc)$")


def _sources(
    root: str, above: Collection[str] = ()
) -> tuple[list[str], list[tuple[str, int, int]]]:
    """The package's folders holding ``.py`` files, and (relative path, size [bytes],
    mtime [ns]) of each ``.py`` file outside the top-level names ``above``, sorted."""
    root = os.path.abspath(root)
    folders: list[str] = []
    files: list[tuple[str, int, int]] = []
    skip = len(root) + 1  # os.path.relpath costs more than the stat itself
    pending = [(root, False)]  # (folder, left out of the fingerprint)
    while pending:
        folder, outside = pending.pop()
        has_source = False
        with os.scandir(folder) as entries:
            for entry in entries:
                name = entry.name
                left_out = outside or (folder == root and name in above)
                if entry.is_dir(follow_symlinks=False):
                    if name != "__pycache__" and not name.startswith("."):
                        pending.append((entry.path, left_out))
                elif name.endswith(".py"):
                    has_source = True
                    if not left_out:
                        st = entry.stat()
                        files.append((entry.path[skip:], st.st_size, st.st_mtime_ns))
        if has_source:
            folders.append(folder)
    return sorted(folders), sorted(files)


def source_fingerprint(root: str = PACKAGE_ROOT, above: Collection[str] = ABOVE_KERNELS) -> str:
    """SHA-256 (hex) of (relative path, size, mtime [ns]) of every ``.py`` file under
    ``root`` but those of ``above``: changes when a source file any kernel may depend
    on is edited, added, removed or moved."""
    return _stat_digest(_sources(root, above)[1])


def _stat_digest(files: list[tuple[str, int, int]]) -> str:
    return hashlib.sha256(repr(files).encode()).hexdigest()


def _content_digest(root: str, files: list[tuple[str, int, int]]) -> str:
    digest = hashlib.sha256()
    for rel, _, _ in files:
        digest.update(rel.encode() + b"\0")
        with open(os.path.join(root, rel), "rb") as handle:
            digest.update(hashlib.sha256(handle.read()).digest())
    return digest.hexdigest()


def _subpath(folder: str) -> str:
    # numba's own rule (get_suitable_cache_subpath), for the same folder names.
    from numba.core.caching import _CacheLocator

    return _CacheLocator.get_suitable_cache_subpath(os.path.join(folder, "__init__.py"))


def _user_cache_root() -> str:
    from numba.misc.appdirs import AppDirs

    return AppDirs(appname="numba", appauthor=False).user_cache_dir


def _writable(path: str) -> bool:
    """Whether numba could cache in ``path`` (it creates the folder when missing)."""
    while not os.path.exists(path):
        parent = os.path.dirname(path)
        if parent == path:
            return False
        path = parent
    return os.path.isdir(path) and os.access(path, os.W_OK | os.X_OK)


def _cache_folders(folder: str, cache_dir: str, user_dir: str | None) -> list[str]:
    """Where numba may keep the caches of the kernels of the sources in ``folder``."""
    if cache_dir:
        return [os.path.join(cache_dir, _subpath(folder))]
    found = [os.path.join(folder, "__pycache__")]
    if user_dir:
        found.append(os.path.join(user_dir, _subpath(folder)))
    return found


def _stamp_folder(root: str, cache_dir: str, user_dir: str | None) -> str | None:
    """The cache folder of the package's top folder, as numba would choose it."""
    if cache_dir:
        return os.path.join(cache_dir, _subpath(root))
    in_tree = os.path.join(root, "__pycache__")
    if _writable(in_tree):
        return in_tree
    return os.path.join(user_dir, _subpath(root)) if user_dir else None


def _read_stamp(path: str) -> tuple[str, str] | None:
    try:
        with open(path, encoding="utf-8") as handle:
            lines = handle.read().splitlines()
    except (OSError, UnicodeDecodeError):
        return None
    if len(lines) != 3 or lines[0] != _STAMP_HEADER:
        return None
    return lines[1], lines[2]


def _remove_caches(folder: str) -> tuple[list[str], bool]:
    """Remove numba's cache files in ``folder``: (removed paths, all removed)."""
    removed: list[str] = []
    complete = True
    try:
        names = os.listdir(folder)
    except FileNotFoundError:
        return removed, True
    except OSError:
        return removed, not _writable(folder)
    for name in sorted(names):
        if not _CACHE_FILE.match(name):
            continue
        path = os.path.join(folder, name)
        try:
            os.remove(path)
        except FileNotFoundError:  # another process removed it first
            continue
        except OSError:
            # A folder this user cannot write is not one numba caches in for it.
            complete = complete and not _writable(folder)
            continue
        removed.append(path)
    return removed, complete


def guard(
    root: str = PACKAGE_ROOT,
    *,
    cache_dir: str | None = None,
    user_dir: str | None = None,
    above: Collection[str] = ABOVE_KERNELS,
) -> list[str] | None:
    """Drop the package's numba caches if its source changed since they were made.

    Parameters
    ----------
    root : str
        The package's top folder.
    cache_dir : str, optional
        numba's ``NUMBA_CACHE_DIR``; None reads numba's configuration.
    user_dir : str, optional
        numba's user-wide cache folder; None asks numba (only when needed).
    above : collection of str
        Top-level names of ``root`` left out of the fingerprint (:data:`ABOVE_KERNELS`).

    Returns
    -------
    list of str or None
        The cache files removed (empty when the caches were current), or None when
        the guard did not run to the end (turned off, an error, an unwritable
        stamp).  Never raises.
    """
    try:
        return _guard(root, cache_dir, user_dir, above)
    except Exception:  # a guard must never stop the program it guards
        return None


def _guard(
    root: str, cache_dir: str | None, user_dir: str | None, above: Collection[str]
) -> list[str] | None:
    if cache_dir is None:
        from numba.core import config  # its settings are set at run time: getattr

        if getattr(config, "CACHE_LOCATOR_CLASSES", "") or getattr(config, "DISABLE_JIT", 0):
            return None
        cache_dir = getattr(config, "CACHE_DIR", "") or ""
    root = os.path.abspath(root)
    folders, files = _sources(root, above)
    stat_digest = _stat_digest(files)
    in_tree = os.path.join(root, "__pycache__")
    if user_dir is None and not cache_dir and not _writable(in_tree):
        user_dir = _user_cache_root()
    stamp_folder = _stamp_folder(root, cache_dir, user_dir)
    if stamp_folder is None:
        return None
    stamp_path = os.path.join(stamp_folder, STAMP_NAME)
    recorded = _read_stamp(stamp_path)
    if recorded is not None and recorded[0] == stat_digest:
        return []
    content_digest = _content_digest(root, files)
    removed: list[str] = []
    complete = True
    if recorded is None or recorded[1] != content_digest:
        if user_dir is None and not cache_dir:
            with contextlib.suppress(Exception):
                user_dir = _user_cache_root()
        for folder in folders:
            for cache_folder in _cache_folders(folder, cache_dir, user_dir):
                gone, ok = _remove_caches(cache_folder)
                removed.extend(gone)
                complete = complete and ok
    if not complete or not _writable(stamp_folder):
        return None  # try again next time; nothing to record in a read-only folder
    write_atomic(stamp_path, f"{_STAMP_HEADER}\n{stat_digest}\n{content_digest}\n")
    return removed
