"""Atomic file writes: the one helper every result file of the package goes through.

``write_atomic(path, content)`` writes ``content`` to a temporary file in the destination folder, flushes it to
disk (fsync), then renames it over ``path`` (``os.replace``), so a reader, a crash or a SIGKILL sees either the
old file or the complete new one, never half a file. The temporary file is created with mode 0o666 filtered by
the process umask, exactly like ``open(path, "w")`` would (``tempfile.mkstemp`` would give 0600, which leaves
reports unreadable to the rest of the user's group). A failed write removes its temporary file.

``content`` is one of
    str                        written as UTF-8 (``newline`` is passed through untranslated),
    bytes / bytearray          written as is,
    callable(fh) -> None       called with the binary file object (``fig.savefig(fh, format="png")``,
                               ``np.savez(fh, **cols)``, ``model.save(fh)``...).
"""
from __future__ import annotations

import os
import secrets
from pathlib import Path
from typing import BinaryIO, Callable, Union

Content = Union[str, bytes, bytearray, Callable[[BinaryIO], object]]

__all__ = ["write_atomic", "temporary_name", "is_temporary"]

TMP_SUFFIX = ".tmp"


def temporary_name(path: Path) -> Path:
    """A fresh hidden name beside ``path``: ``.NAME.<random>.tmp``."""
    return path.with_name(f".{path.name}.{secrets.token_hex(4)}{TMP_SUFFIX}")


def is_temporary(path) -> bool:
    """True for a file name :func:`write_atomic` uses while writing (left behind only by a killed process)."""
    n = Path(path).name
    return n.startswith(".") and n.endswith(TMP_SUFFIX)


def _open_new(path: Path) -> tuple[int, Path]:
    for _ in range(100):
        tmp = temporary_name(path)
        try:
            # O_EXCL: never reuse someone else's file; 0o666 & ~umask is applied by the kernel, as for open(..., "w")
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"cannot create a temporary file beside {path}")


def write_atomic(path, content: Content, *, fsync: bool = True, mkdir: bool = True) -> Path:
    """Write ``content`` to ``path`` atomically, with the mode a plain ``open(path, "w")`` would give.

    Returns the path. The destination folder is created if ``mkdir``. See the module docstring for ``content``.
    """
    path = Path(path)
    if mkdir:
        path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(content, str):
        payload: bytes | None = content.encode("utf-8")
    elif isinstance(content, (bytes, bytearray, memoryview)):
        payload = bytes(content)
    elif callable(content):
        payload = None
    else:
        raise TypeError(f"write_atomic({path}): content must be str, bytes or a callable taking the file, "
                        f"got {type(content).__name__}")
    fd, tmp = _open_new(path)
    try:
        with os.fdopen(fd, "wb") as fh:
            if payload is None:
                content(fh)
            else:
                fh.write(payload)
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    if fsync:
        _fsync_dir(path.parent)
    return path


def _fsync_dir(d: Path) -> None:
    """Make the rename itself durable (POSIX); a no-op where folders cannot be opened."""
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
