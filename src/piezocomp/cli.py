"""The ``piezocomp`` command line.

Every module in :mod:`piezocomp.commands` that defines ``register(subparsers)`` adds one
subcommand; ``register`` must call ``parser.set_defaults(func=...)`` with a function
``func(args) -> int``. Errors a user can cause (usage errors, ``ValueError``,
``TypeError``, ``OSError``) print one line, ``piezocomp COMMAND: error: ...``, and exit 2;
file errors name the file the user gave (``PATH: no such file``, ``PATH: is a directory``).
Nothing prints a traceback unless ``PIEZOCOMP_DEBUG`` is set.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence
from typing import NoReturn

__all__ = ["UsageError", "build_parser", "main"]


class UsageError(Exception):
    """A command line the parser cannot take (unknown flag, missing or malformed value)."""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are exceptions, reported in one line by :func:`main`
    (argparse's own prints the usage and the error on two)."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see {self.prog} --help)")


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with every subcommand of :mod:`piezocomp.commands`."""
    from piezocomp import __version__, commands

    parser = _Parser(
        prog="piezocomp",
        description="Sensorless creep and hysteresis compensation for AFM piezo scanners.",
    )
    parser.add_argument("--version", action="version", version=f"piezocomp {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"piezocomp.commands.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
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
    return " ".join(str(exc).split())  # one line, whatever the message held


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    arglist = list(argv) if argv is not None else sys.argv[1:]
    try:
        args = parser.parse_args(arglist)
    except UsageError as exc:
        command = next((a for a in arglist if not a.startswith("-")), "")
        prog = f"piezocomp {command}".strip()
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 2
    try:
        return int(func(args) or 0)
    except (ValueError, TypeError, OSError, KeyError, OverflowError, MemoryError) as exc:
        if os.environ.get("PIEZOCOMP_DEBUG"):
            raise
        print(f"piezocomp {args.command}: error: {_message(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
