"""Whole-or-nothing file output: write to a temporary file, then rename.

A report, figure or JSON file that is interrupted half-way (disk full, Ctrl-C, an
exception inside a plotting library) must not leave a truncated file behind that
looks like a result. Every output of the library and the CLI therefore goes through
one of two functions:

* :func:`write_atomic` for text or bytes already in memory;
* :func:`atomic_path` for libraries that insist on writing by file name
  (``Figure.savefig``, ``DataFrame.to_parquet``).

Both write into a temporary file *in the destination directory* (so the final
``os.replace`` is a rename on one file system, atomic on POSIX and Windows), commit
only on success and remove the temporary file on failure. Missing parent
directories are created. An output location that cannot be written raises
:class:`~stictiondiag.core.errors.UsageError` with one line naming the path and the fix.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from stictiondiag.core.errors import UsageError

__all__ = ["TEMP_MARK", "atomic_path", "write_atomic"]

#: Marks the temporary files of this module (``.<name>.stiction-XXXXXXXX.tmp<ext>``),
#: so that a run can sweep the ones a killed run left behind
#: (:mod:`stictiondiag.apps.outdir`) and nothing else.
TEMP_MARK = "stiction-"

#: Longest part of the destination's name kept in a temporary file's name [characters]:
#: the temporary name stays within the file system's 255 bytes whatever the name.
_TEMP_STEM_CHARS = 40


def _current_umask() -> int:
    # os.umask can only be read by setting it; done once at import, before any
    # threads of this library exist, and restored immediately.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: Permission bits for new files, as ``open()`` would create them (0o666 minus umask).
_NEW_FILE_MODE = 0o666 & ~_current_umask()


def _fail(path: Path, exc: OSError) -> UsageError:
    reason = exc.strerror or type(exc).__name__
    return UsageError(f"cannot write {path}: {reason.lower()}; choose a writable output path")


def _prepare(path: str | os.PathLike[str]) -> Path:
    """Check the destination, create its parent directories, return it as a Path."""
    target = Path(path)
    if target.name in ("", ".", ".."):
        raise UsageError(
            f"cannot write {target}: not a file name; give a path ending in a file name"
        )
    if target.is_dir():
        raise UsageError(f"cannot write {target}: it is a directory; give a file name inside it")
    for parent in target.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UsageError(
                    f"cannot write {target}: {parent} is a file, not a directory; "
                    f"choose another output path"
                )
            break
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _fail(target, exc) from None
    return target


def _final_mode(target: Path) -> int:
    # Replacing a file keeps its permissions; a new file gets the usual umask
    # permissions instead of mkstemp's private 0o600.
    try:
        return target.stat().st_mode & 0o7777
    except OSError:
        return _NEW_FILE_MODE


def _temp_file(target: Path) -> tuple[int, Path]:
    # The temporary name keeps the real extension last, so libraries that infer
    # the format from the name (savefig: .png/.svg/.pdf) write the right format.
    try:
        suffix = target.suffix if len(target.suffix.encode()) <= 16 else ""
        fd, name = tempfile.mkstemp(
            prefix=f".{target.stem[:_TEMP_STEM_CHARS]}.{TEMP_MARK}",
            suffix=f".tmp{suffix}",
            dir=target.parent,
        )
    except OSError as exc:
        raise _fail(target, exc) from None
    return fd, Path(name)


def _fsync_directory(directory: Path) -> None:
    # Makes the rename itself durable; not possible on every platform (Windows).
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _commit(temp: Path, target: Path) -> None:
    try:
        os.chmod(temp, _final_mode(target))
        os.replace(temp, target)
    except OSError as exc:
        raise _fail(target, exc) from None
    _fsync_directory(target.parent)


def write_atomic(
    path: str | os.PathLike[str], data: str | bytes, *, encoding: str = "utf-8"
) -> Path:
    """Write ``data`` to ``path`` whole or not at all.

    Parameters
    ----------
    path : str or path-like
        Destination file. Parent directories are created. An existing file is
        replaced only once the new content is completely on disk.
    data : str or bytes
        Content; ``str`` is encoded with ``encoding``.
    encoding : str
        Text encoding for ``str`` data (default UTF-8).

    Returns
    -------
    Path
        The destination path.

    Raises
    ------
    UsageError
        The destination cannot be written (read-only or missing directory that
        cannot be created, a file in the way of a parent directory, a directory
        at ``path``).
    TypeError
        ``data`` is neither ``str`` nor ``bytes``.
    """
    if isinstance(data, str):
        payload = data.encode(encoding)
    elif isinstance(data, bytes | bytearray | memoryview):
        payload = bytes(data)
    else:
        raise TypeError(f"write_atomic needs str or bytes, not {type(data).__name__}")
    target = _prepare(path)
    fd, temp = _temp_file(target)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(payload)
            handle.flush()
            os.fsync(handle.fileno())
        _commit(temp, target)
    except BaseException as exc:
        temp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise _fail(target, exc) from None
        raise
    return target


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path to write to; rename it to ``path`` on success only.

    For libraries that write by file name::

        with atomic_path("out/fig.png") as tmp:
            fig.savefig(tmp)
        with atomic_path("out/data.parquet") as tmp:
            frame.to_parquet(tmp)

    The temporary file lives in the destination directory and ends in the same
    extension as ``path``, so format inference by extension still works. If the
    block raises, the temporary file is removed, ``path`` is left untouched and
    the exception propagates unchanged, except an ``OSError`` of the writing
    library (a full disk), which becomes a UsageError naming ``path``. If the block writes nothing, ``path``
    becomes an empty file.

    Raises
    ------
    UsageError
        The destination cannot be written (see :func:`write_atomic`).
    """
    target = _prepare(path)
    fd, temp = _temp_file(target)
    os.close(fd)
    try:
        try:
            yield temp
        except OSError as exc:
            # The library writing by name (savefig, to_parquet) hit a full disk or a
            # lost folder: an output error naming the destination, not a data error.
            raise _fail(target, exc) from None
        if not temp.exists():
            raise UsageError(
                f"cannot write {target}: the temporary file {temp.name} disappeared before commit"
            )
        _commit(temp, target)
    finally:
        temp.unlink(missing_ok=True)
