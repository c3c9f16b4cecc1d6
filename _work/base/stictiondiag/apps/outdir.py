"""Output folders of ``report`` and ``scan``: they hold only what this tool wrote there.

An :class:`OutputFolder` keeps a manifest (a JSON file in the folder) of every file
the tool wrote, with the SHA-256 of what it wrote, and enforces four rules:

* **No foreign file is replaced.**  A file of the tool's (``index.html``, a loop's
  page) is written only where nothing stands, or where the manifest lists the name
  and the file still holds what the tool wrote.  Anything else (a file of the user, a
  file edited since, a symbolic link, a folder) is refused with a
  :class:`~stictiondiag.core.errors.UsageError` naming the path.
* **Clean removes only the tool's entries, as entries.**  :meth:`OutputFolder.clean`
  removes the files the manifest lists, each only while it holds what the tool wrote,
  and looks at every entry with ``lstat``: a listed name that has become a symbolic
  link is removed as a link (its target is never touched), a name below a linked
  folder is left alone.
* **One writer at a time.**  :meth:`OutputFolder.locked` takes an exclusive
  ``flock`` on the folder itself (no lock file is left behind); a second run waits
  for it, up to :data:`LOCK_WAIT_S` seconds (``STICTION_LOCK_WAIT``), then refuses.
* **Stale temporary files are swept.**  Temporary files of
  :mod:`stictiondiag.core.atomic` (``.<name>.stiction-XXXXXXXX.tmp<ext>``) older
  than the run, left by a run that was killed, are removed under the lock.

The manifest names every file *before* it is written (its digest is recorded once
the write is done), so a run killed in between can still be cleaned.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import stat
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

from stictiondiag.core.atomic import TEMP_MARK, write_atomic
from stictiondiag.core.errors import UsageError

__all__ = ["LOCK_WAIT_S", "OutputFolder", "file_digest", "is_stale_temp"]

#: Longest wait for another run's lock on the same folder [s]; ``STICTION_LOCK_WAIT``
#: overrides it (0: refuse at once).
LOCK_WAIT_S = 600.0

#: A temporary file of :mod:`stictiondiag.core.atomic`.
_TEMP_NAME = re.compile(r"^\..*\." + re.escape(TEMP_MARK) + r"[A-Za-z0-9_]{8}\.tmp(\.[^./]*)?$")


def is_stale_temp(name: str) -> bool:
    """Whether ``name`` is the name of one of this tool's temporary files."""
    return bool(_TEMP_NAME.match(name))


def file_digest(path: Path) -> str | None:
    """SHA-256 of a regular file (never through a link), None if it is not one."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return None
    digest = hashlib.sha256()
    with os.fdopen(fd, "rb") as handle:
        if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            return None
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _lstat(path: Path) -> os.stat_result | None:
    try:
        return path.lstat()
    except OSError:
        return None


class OutputFolder:
    """An output folder and the manifest of what the tool wrote in it.

    Parameters
    ----------
    out : path
        The folder.
    manifest : str
        File name of the manifest inside ``out``.
    tool : str
        Who writes here (``"stiction report"``); recorded in the manifest, and a
        manifest of another writer is a foreign file.
    adopt : callable, optional
        ``adopt(folder) -> names``: files of a folder written before manifests
        existed that are taken as the tool's (used once, when there is no manifest).
    """

    def __init__(
        self,
        out: str | os.PathLike,
        manifest: str,
        tool: str,
        adopt: Callable[[Path], Iterable[str]] | None = None,
    ) -> None:
        self.out = Path(out)
        self.manifest_name = manifest
        self.tool = tool
        self.files: list[str] = []
        self.digests: dict[str, str | None] = {}
        self._adopt = adopt
        self._dirty = False
        self._read()

    # ------------------------------------------------------------------ manifest

    def _read(self) -> None:
        path = self.out / self.manifest_name
        st = _lstat(path)
        if st is None:
            if self._adopt is not None and self.out.is_dir():
                for name in self._adopt(self.out):
                    self.files.append(name)
                    self.digests[name] = file_digest(self.out / name)
            return
        try:
            if not stat.S_ISREG(st.st_mode):
                raise ValueError("not a file")
            data = json.loads(path.read_text(encoding="utf-8"))
            if data.get("written_by") != self.tool:
                raise ValueError("another writer")
            files = [str(f) for f in data["files"] if isinstance(f, str)]
            digests = data.get("sha256") or {}
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            raise UsageError(
                f"{path} exists and was not written by {self.tool}: it would be overwritten; "
                "move it or choose another --out"
            ) from None
        self.files = files
        self.digests = {f: digests.get(f) if isinstance(digests, dict) else None for f in files}

    def _save(self) -> None:
        payload = {
            "written_by": self.tool,
            "files": self.files,
            "sha256": {f: self.digests.get(f) for f in self.files},
        }
        write_atomic(self.out / self.manifest_name, json.dumps(payload, indent=1) + "\n")
        self._dirty = False

    def flush(self) -> None:
        """Write the manifest if digests were recorded since it was last written."""
        if self._dirty:
            self._save()

    # ------------------------------------------------------------------ ownership

    def owns(self, name: str) -> bool:
        """Whether the tool may write ``name``: nothing stands there, or what it wrote.

        A listed file whose digest was never recorded (the run was killed between
        naming it and writing it) counts as the tool's.
        """
        path = self.out / name
        if not self._real_folders(name):
            return False
        st = _lstat(path)
        if st is None:
            return True
        if not stat.S_ISREG(st.st_mode) or name not in self.digests:
            return False
        recorded = self.digests[name]
        return recorded is None or recorded == file_digest(path)

    def _real_folders(self, name: str) -> bool:
        """Whether every folder between ``out`` and ``name`` is a real folder (or absent)."""
        folder = self.out
        for part in Path(name).parts[:-1]:
            folder = folder / part
            st = _lstat(folder)
            if st is None:
                return True
            if not stat.S_ISDIR(st.st_mode):
                return False
        return True

    def refuse_foreign(self, names: Sequence[str]) -> None:
        """Raise UsageError naming the first of ``names`` that is not the tool's to write."""
        for name in names:
            if not self.owns(name):
                raise UsageError(
                    f"{self.out / name} exists and was not written by {self.tool}: it would be "
                    "overwritten; move it or choose another --out"
                )

    def claim(self, *names: str) -> None:
        """List ``names`` in the manifest before they are written (refusing foreign files)."""
        self.refuse_foreign(names)
        new = [name for name in names if name not in self.digests]
        for name in new:
            self.files.append(name)
            self.digests[name] = None
        if new:
            # Digests recorded since the last save go along; without new names they
            # wait for the next save or flush (one manifest write per loop, not three).
            self._save()

    def write(self, files: dict[str, str | bytes]) -> None:
        """Write ``files`` (name -> content) whole, after claiming them; digests recorded."""
        self.claim(*files)
        for name, data in files.items():
            payload = data.encode("utf-8") if isinstance(data, str) else data
            write_atomic(self.out / name, payload)
            self.digests[name] = hashlib.sha256(payload).hexdigest()
            self._dirty = True

    def record(self, name: str) -> None:
        """Record the digest of ``name`` written by other means (``atomic_path``)."""
        self.digests[name] = file_digest(self.out / name)
        self._dirty = True

    # ------------------------------------------------------------------ clean, sweep

    def clean(self, keep: Sequence[str | os.PathLike] = ()) -> list[Path]:
        """Remove the files the manifest lists while they hold what the tool wrote.

        Each entry is looked at with ``lstat``: a link is removed as a link, a name
        below a linked folder is left alone, a file the user has replaced or edited
        stays.  Files in ``keep`` (the inputs) are never removed.  Folders are removed
        only when left empty; the manifest is removed last.

        Returns
        -------
        list of Path
            The entries removed.
        """
        keep_ids = set()
        for f in keep:
            with contextlib.suppress(OSError):
                kept = os.stat(f)
                keep_ids.add((kept.st_dev, kept.st_ino))
        removed: list[Path] = []
        folders: set[Path] = set()
        for name in list(self.files):
            path = self.out / name
            if Path(name).is_absolute() or ".." in Path(name).parts:
                continue
            if not self._real_folders(name):
                continue
            st = _lstat(path)
            if st is None:
                continue
            if (st.st_dev, st.st_ino) in keep_ids:
                continue
            if stat.S_ISLNK(st.st_mode) or (stat.S_ISREG(st.st_mode) and self.owns(name)):
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
                removed.append(path)
                if len(Path(name).parts) > 1:
                    folders.add(path.parent)
        for folder in sorted(folders, key=lambda p: len(p.parts), reverse=True):
            with contextlib.suppress(OSError):
                folder.rmdir()  # only when empty
        self.files = []
        self.digests = {}
        manifest = self.out / self.manifest_name
        mst = _lstat(manifest)
        if (
            mst is not None
            and stat.S_ISREG(mst.st_mode)
            and (mst.st_dev, mst.st_ino) not in keep_ids
        ):
            manifest.unlink()
        return removed

    def sweep(self, before: float, folders: Sequence[str] = ("",)) -> list[Path]:
        """Remove this tool's temporary files older than ``before`` (epoch s) in ``folders``."""
        swept: list[Path] = []
        for sub in folders:
            folder = self.out / sub
            try:
                entries = list(os.scandir(folder))
            except OSError:
                continue
            for entry in entries:
                if not is_stale_temp(entry.name):
                    continue
                with contextlib.suppress(OSError):
                    st = entry.stat(follow_symlinks=False)
                    if stat.S_ISREG(st.st_mode) and st.st_mtime < before:
                        os.unlink(entry.path)
                        swept.append(Path(entry.path))
        return swept

    # ------------------------------------------------------------------ lock

    @contextlib.contextmanager
    def locked(self, on_wait: Callable[[str], None] | None = None) -> Iterator[None]:
        """Hold an exclusive lock on the folder (which must exist) for the block.

        Raises
        ------
        UsageError
            Another run kept the folder locked for longer than the wait allowed.
        """
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not on Windows
            yield
            return
        try:
            wait = float(os.environ.get("STICTION_LOCK_WAIT", LOCK_WAIT_S))
        except ValueError:
            wait = LOCK_WAIT_S
        try:
            fd = os.open(self.out, os.O_RDONLY)
        except OSError as exc:
            reason = (exc.strerror or type(exc).__name__).lower()
            raise UsageError(
                f"cannot open the output folder {self.out}: {reason}; choose another --out"
            ) from None
        try:
            deadline = time.monotonic() + max(0.0, wait)
            told = False
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() >= deadline:
                        raise UsageError(
                            f"another stiction run is writing to {self.out}: wait for it to "
                            "finish, or choose another --out"
                        ) from None
                    if not told and on_wait is not None:
                        on_wait(f"waiting for another stiction run writing to {self.out}")
                        told = True
                    time.sleep(0.2)
                except OSError as exc:
                    # A file system without locks (some network mounts): run unlocked.
                    if on_wait is not None:
                        reason = (exc.strerror or type(exc).__name__).lower()
                        on_wait(
                            f"note: cannot lock {self.out} ({reason}): another run "
                            "writing there at the same time would not be held off"
                        )
                    break
            # Re-read: the other run may have changed the manifest while we waited.
            self.files, self.digests = [], {}
            self._read()
            try:
                yield
            finally:
                # The digests of what was written, also when the run stops midway.
                with contextlib.suppress(UsageError):
                    self.flush()
        finally:
            os.close(fd)  # releases the lock
