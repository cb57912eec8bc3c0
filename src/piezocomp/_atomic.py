"""Atomic file writing: a temporary file in the target folder, flushed, then renamed.

A crash or an interruption while writing never leaves a half-written file where the user's
file was, nor the temporary file: it is removed on any exception, ``KeyboardInterrupt``
included (the command line turns ``SIGTERM`` into one).

Inside :func:`output_group` (every command runs in one) the files are written to their
temporary names and put in place together when the group ends, in the order they were
written, with ``SIGINT`` and ``SIGTERM`` held back meanwhile; a group that fails or is
interrupted removes its temporary files and changes nothing. A folder of results is then
complete or untouched, never half written.

An output that is a symbolic link is written through (the file it points to is replaced,
the link kept); one that is a device or a pipe (``/dev/null``) is written into directly.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import stat
import tempfile
import time
from collections.abc import Iterator
from contextvars import ContextVar
from pathlib import Path
from typing import IO, Any

__all__ = [
    "OutputGroup",
    "atomic_open",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output",
    "check_outputs",
    "commit_so_far",
    "make_folder",
    "output_group",
    "signals_held",
    "staged_path",
]

_HELD = (signal.SIGINT, signal.SIGTERM)


class OutputGroup:
    """Files written inside :func:`output_group`, put in place when it ends.

    Attributes
    ----------
    written : list of Path
        The files put in place so far (written through at once, or renamed at the end).
    """

    def __init__(self) -> None:
        self.written: list[Path] = []
        self._staged: dict[Path, str] = {}  # target -> its temporary file, in writing order
        self._temps: list[str] = []  # every temporary file made, to remove on failure
        self._folders: list[Path] = []  # folders created for the files, deepest first

    def staged(self, target: Path) -> Path | None:
        """The temporary file holding what was written to ``target``, if any."""
        tmp = self._staged.get(target)
        return None if tmp is None else Path(tmp)

    def _stage(self, target: Path, tmp: str) -> None:
        old = self._staged.pop(target, None)  # written twice: the last one counts
        if old is not None:
            with contextlib.suppress(OSError):
                os.unlink(old)
        self._staged[target] = tmp

    def _commit(self) -> None:
        with signals_held():
            try:
                for target, tmp in list(self._staged.items()):
                    try:
                        os.replace(tmp, target)
                    except OSError as exc:
                        raise _renamed(exc, target) from None
                    del self._staged[target]
                    self.written.append(target)
            finally:
                self._discard()

    def _discard(self) -> None:
        for tmp in self._temps:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        self._temps.clear()
        self._staged.clear()
        _remove_empty(self._folders)


_GROUP: ContextVar[OutputGroup | None] = ContextVar("piezocomp_output_group", default=None)


@contextlib.contextmanager
def output_group() -> Iterator[OutputGroup]:
    """Write every file of the block together at its end, or none if it fails.

    Files written through :func:`atomic_open` inside the block go to temporary files beside
    their targets; when the block ends normally they are renamed into place in the order
    they were written (signals held back meanwhile, so an interrupted run leaves all or
    nothing). If the block raises (``KeyboardInterrupt`` included) the temporary files and
    the folders made for them are removed. Read a file written earlier in the block with
    :func:`staged_path`. Inside a group, a nested group joins it.
    """
    outer = _GROUP.get()
    if outer is not None:
        yield outer
        return
    group = OutputGroup()
    token = _GROUP.set(group)
    try:
        yield group
        _pause_for_tests()
    except BaseException:
        group._discard()
        raise
    finally:
        _GROUP.reset(token)
    group._commit()


def commit_so_far() -> None:
    """Put in place every file written so far in the current :func:`output_group` (none:
    nothing to do). A checkpoint for a run of independent parts (``reproduce --seeds``): the
    parts done stay when a later one is interrupted or fails; each part is still all or
    nothing."""
    group = _GROUP.get()
    if group is not None:
        group._commit()


PAUSE_ENV = "PIEZOCOMP_TEST_PAUSE_BEFORE_COMMIT_S"
"""Environment variable of the interrupt tests: seconds an output group waits, its files
staged, before it puts them in place (so that a signal sent once a file is staged surely
arrives before the commit, however loaded the machine)."""


def _pause_for_tests() -> None:
    value = os.environ.get(PAUSE_ENV)
    if value:
        time.sleep(float(value))


def make_folder(path: str | os.PathLike[str]) -> list[Path]:
    """Create the folder ``path`` with its missing parents; return those created, deepest
    first. Inside :func:`output_group` they are removed again, while empty, if the group
    fails."""
    p = Path(path)
    created = [d for d in (p, *p.parents) if not d.exists()]
    group = _GROUP.get()
    with signals_held():
        p.mkdir(parents=True, exist_ok=True)
        if group is not None:
            group._folders.extend(d for d in created if d not in group._folders)
    return created


def staged_path(path: str | os.PathLike[str]) -> Path:
    """Where to read ``path`` now: its temporary file if the current :func:`output_group` has
    written it but not yet put it in place, else ``path`` itself."""
    group = _GROUP.get()
    p = Path(path)
    if group is not None:
        target, _ = _destination(p)
        staged = group.staged(target)
        if staged is not None:
            return staged
    return p


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold ``SIGINT`` and ``SIGTERM`` back during the block; they arrive when it ends."""
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - not POSIX
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _destination(target: Path) -> tuple[Path, bool]:
    """Where writing ``target`` lands: the file itself, or the one a symbolic link points to;
    and whether it is written through (a device or a pipe, not replaced)."""
    try:
        st = os.stat(target)  # follows links
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise NotADirectoryError(errno.ENOTDIR, "Not a directory", str(target)) from None
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(errno.EISDIR, "Is a directory", str(target))
    if st is not None and not stat.S_ISREG(st.st_mode):
        return target, True
    if target.is_symlink():
        return Path(os.path.realpath(target)), False
    return target, False


def check_output(path: str | os.PathLike[str]) -> None:
    """Refuse an output that cannot be written, before anything is: a folder, a path through
    a file, a folder that cannot be written into (errors name ``path``)."""
    target, through = _destination(Path(path))
    if through:
        if not os.access(target, os.W_OK):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return
    for folder in (target.parent, *target.parent.parents):
        if not folder.exists():
            continue
        if not folder.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "Not a directory", str(path))
        if not os.access(folder, os.W_OK | os.X_OK):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return


def check_outputs(*paths: str | os.PathLike[str] | None) -> None:
    """:func:`check_output` on each path given (``None`` skipped); two outputs naming the same
    file are refused too."""
    seen: dict[Path, str] = {}
    for path in paths:
        if path is None:
            continue
        check_output(path)
        key = Path(os.path.realpath(path))
        if key in seen and not _destination(Path(path))[1]:
            raise ValueError(f"{path}: names the same file as {seen[key]}; give two files.")
        seen[key] = str(path)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", **kwargs: Any) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path``; on success it replaces ``path``.

    Parameters
    ----------
    path : path-like
        Final destination; missing parent folders are created. A folder there is refused
        (``IsADirectoryError`` naming ``path``); a symbolic link is written through, a device
        or a pipe written into directly. Inside :func:`output_group` the file is put in place
        when the group ends.
    mode : {"w", "wb"}
        Text or binary writing.
    **kwargs
        Passed to :func:`open` (e.g. ``newline=""``, ``encoding``).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb'. Got {mode!r}.")
    if mode == "w":
        kwargs.setdefault("encoding", "utf-8")
    user = Path(path)
    target, through = _destination(user)
    group = _GROUP.get()
    if through:
        try:
            with open(target, mode, **kwargs) as fh:
                yield fh
        except OSError as exc:
            raise _renamed(exc, user) from None
        if group is not None:
            group.written.append(user)
        return
    check_output(target)
    folder = target.parent
    created: list[Path] = []
    tmp = None
    try:
        created = make_folder(folder)  # every command creates missing folders
        with signals_held():  # the temporary file is always known to be removed
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
            if group is not None:
                group._temps.append(tmp)
        _set_mode(fd, target)
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        if group is None:
            os.replace(tmp, target)
            tmp = None
        else:
            group._stage(target, tmp)
            tmp = None
    except BaseException as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        if group is None:
            _remove_empty(created)
        if isinstance(exc, OSError):  # name the user's file, not the temporary one
            raise _renamed(exc, user) from None
        raise


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders (deepest first) that are still empty."""
    for d in sorted(folders, key=lambda p: len(p.parts), reverse=True):
        with contextlib.suppress(OSError):
            d.rmdir()


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
