"""Atomic file writing: a temporary file in the target folder, flushed, then renamed.

A crash while writing never leaves a half-written file where the user's file was.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_open", "atomic_write_bytes", "atomic_write_text"]


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", **kwargs: Any) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path``; on success it replaces ``path``.

    Parameters
    ----------
    path : path-like
        Final destination; missing parent folders are created. A folder there is refused
        (``IsADirectoryError`` naming ``path``).
    mode : {"w", "wb"}
        Text or binary writing.
    **kwargs
        Passed to :func:`open` (e.g. ``newline=""``, ``encoding``).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb'. Got {mode!r}.")
    target = Path(path)
    if target.is_dir():
        raise IsADirectoryError(21, "Is a directory", str(target))
    folder = target.parent if str(target.parent) else Path(".")
    folder.mkdir(parents=True, exist_ok=True)  # every command creates missing folders
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    except OSError as exc:  # name the user's file, not the temporary one
        raise _renamed(exc, target) from None
    _set_mode(fd, target)
    if mode == "w":
        kwargs.setdefault("encoding", "utf-8")
    try:
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise _renamed(exc, target) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _renamed(exc: OSError, target: Path) -> OSError:
    """The same error about ``target`` (the user's file), not about a temporary file."""
    if exc.errno is None:
        return type(exc)(f"{target}: {exc}")
    return type(exc)(exc.errno, exc.strerror, str(target))


def _set_mode(fd: int, target: Path) -> None:
    """Give the new file the mode the old one had, else the usual ``0o666 & ~umask``
    (mkstemp creates files readable by their owner only)."""
    try:
        mode = target.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    os.fchmod(fd, mode)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_open(path, "w") as fh:
        fh.write(text)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)
