"""The ``piezocomp`` command line.

Each subcommand is a module of :mod:`piezocomp.commands` named in its ``COMMANDS`` (with
its one-line help) that defines ``register(subparsers)``; ``register`` must call
``parser.set_defaults(func=...)`` with a function ``func(args) -> int``. Only the module of
the command given is imported. Errors a user can cause (usage errors, ``ValueError``,
``TypeError``, ``OSError``) print one line, ``piezocomp COMMAND: error: ...``, and exit 2;
file errors name the file the user gave (``PATH: no such file``, ``PATH: is a directory``).
Nothing prints a traceback unless ``PIEZOCOMP_DEBUG`` is set.

A command runs inside one :func:`piezocomp._atomic.output_group`: its files are put in place
together when it ends, or not at all. Ctrl-C (``SIGINT``) or ``SIGTERM`` stops it with one
line, ``piezocomp COMMAND: interrupted; nothing written``, and exit status 128 + the signal
number (130 for Ctrl-C, 143 for ``SIGTERM``); temporary files are removed and earlier outputs
are left as they were.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import importlib
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import NoReturn

from piezocomp._atomic import OutputGroup, output_group
from piezocomp._validation import one_line

__all__ = ["Interrupted", "UsageError", "build_parser", "main"]


class UsageError(Exception):
    """A command line the parser cannot take (unknown flag, missing or malformed value)."""


class Interrupted(KeyboardInterrupt):
    """A command stopped by a signal (``SIGINT`` or ``SIGTERM``); ``signum`` names it.

    A ``KeyboardInterrupt``, so that every clean-up written for Ctrl-C runs for ``SIGTERM``.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_interrupted(signum: int, frame: FrameType | None) -> None:
    raise Interrupted(signum)


@contextlib.contextmanager
def _signals_interrupt() -> Iterator[None]:
    """Turn ``SIGTERM`` (and Ctrl-C) into :class:`Interrupted` during the block, unless the
    signal is ignored (a background job) or this is not the main thread; the handlers are
    restored afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {}
    for sig, default in ((signal.SIGINT, signal.default_int_handler),
                         (signal.SIGTERM, signal.SIG_DFL)):  # fmt: skip
        if signal.getsignal(sig) is default:
            old[sig] = signal.signal(sig, _raise_interrupted)
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are exceptions, reported in one line by :func:`main`
    (argparse's own prints the usage and the error on two)."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see {self.prog} --help)")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Build the argument parser: every subcommand of :data:`piezocomp.commands.COMMANDS`,
    ``command``'s in full (its module imported and its ``register`` called) and the others
    by name and help only, so that a command line loads the dependencies of its own command
    and no other (``None``: every one in full)."""
    from piezocomp import __version__
    from piezocomp.commands import COMMANDS

    parser = _Parser(
        prog="piezocomp",
        description="Sensorless creep and hysteresis compensation for AFM piezo scanners.",
    )
    parser.add_argument("--version", action="version", version=f"piezocomp {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (module_name, help_text) in sorted(COMMANDS.items()):
        if command is None or name == command:
            module = importlib.import_module(f"piezocomp.commands.{module_name}")
            module.register(sub)
        else:
            sub.add_parser(name, help=help_text, add_help=False)
    return parser


def _message(exc: BaseException) -> str:
    """One line for an error a user caused; file errors name the file, not the system call."""
    if isinstance(exc, OSError) and exc.filename is not None:
        name = exc.filename
        if isinstance(exc, FileNotFoundError):
            return f"{name}: no such file"
        if isinstance(exc, IsADirectoryError):
            return f"{name}: is a directory"
        if isinstance(exc, NotADirectoryError):
            return f"{name}: a folder in the path is a file"
        if isinstance(exc, PermissionError):
            return f"{name}: permission denied"
        return f"{name}: {exc.strerror or exc}"
    if isinstance(exc, KeyError):
        return f"missing key {exc}"
    if isinstance(exc, RecursionError):
        return "the input is nested too deeply to read"
    if isinstance(exc, csv.Error):
        return f"not a readable CSV file ({exc})"
    return str(exc)


def _interrupted(command: str, exc: KeyboardInterrupt, written: list[Path]) -> int:
    """Report an interrupted run in one line; the exit status, 128 + the signal number."""
    signum = getattr(exc, "signum", signal.SIGINT)
    name = signal.Signals(signum).name
    how = "interrupted" if signum == signal.SIGINT else f"interrupted ({name})"
    kept = f"kept {', '.join(map(str, written))}" if written else "nothing written"
    print(f"{f'piezocomp {command}'.strip()}: {how}; {kept}", file=sys.stderr)
    return 128 + int(signum)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    arglist = list(argv) if argv is not None else sys.argv[1:]
    command = _command_of(arglist)
    groups: list[OutputGroup] = []
    try:
        with _signals_interrupt():  # from the start: importing the commands takes a while
            return _run(arglist, groups)
    except KeyboardInterrupt as exc:
        if os.environ.get("PIEZOCOMP_DEBUG"):
            raise
        return _interrupted(command, exc, groups[0].written if groups else [])


def _command_of(arglist: list[str]) -> str:
    """The subcommand a command line names: its first word that is not an option (the
    top-level parser's only options, ``--help`` and ``--version``, take no value)."""
    return next((a for a in arglist if not a.startswith("-")), "")


def _run(arglist: list[str], groups: list[OutputGroup]) -> int:
    """Parse and run one command in an :func:`output_group` (appended to ``groups``)."""
    from piezocomp.commands import COMMANDS

    parser = build_parser(_command_of(arglist))
    try:
        args = parser.parse_args(arglist)
    except UsageError as exc:
        command = _command_of(arglist)
        prog = f"piezocomp {command}".strip() if command in COMMANDS else "piezocomp"
        message = str(exc)
        if command in COMMANDS:  # a flag the command does not take: point at its own help
            message = message.replace("(see piezocomp --help)", f"(see {prog} --help)")
        print(f"{prog}: error: {message}", file=sys.stderr)
        return 2
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 2
    try:
        with output_group() as group:
            groups.append(group)
            code = int(func(args) or 0)
        return code
    except (
        ValueError, TypeError, OSError, KeyError, OverflowError, MemoryError, RecursionError,
        csv.Error,
    ) as exc:  # fmt: skip
        if os.environ.get("PIEZOCOMP_DEBUG"):
            raise
        from piezocomp.instrument import RunFailure  # imported by now, if it was raised

        print(f"piezocomp {args.command}: error: {one_line(_message(exc))}", file=sys.stderr)
        return 1 if isinstance(exc, RunFailure) else 2  # found during the run, or usage


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
