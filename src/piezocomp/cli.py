"""The ``piezocomp`` command line.

Every module in :mod:`piezocomp.commands` that defines ``register(subparsers)`` adds one
subcommand; ``register`` must call ``parser.set_defaults(func=...)`` with a function
``func(args) -> int``. Errors a user can cause (``ValueError``, ``TypeError``, ``OSError``)
print one line and exit 2; nothing prints a traceback unless ``PIEZOCOMP_DEBUG`` is set.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with every subcommand of :mod:`piezocomp.commands`."""
    from piezocomp import __version__, commands

    parser = argparse.ArgumentParser(
        prog="piezocomp",
        description="Sensorless creep and hysteresis compensation for AFM piezo scanners.",
    )
    parser.add_argument("--version", action="version", version=f"piezocomp {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"piezocomp.commands.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(list(argv) if argv is not None else None)
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 2
    try:
        return int(func(args) or 0)
    except (ValueError, TypeError, OSError, KeyError) as exc:
        if os.environ.get("PIEZOCOMP_DEBUG"):
            raise
        message = str(exc) if not isinstance(exc, KeyError) else f"missing key {exc}"
        print(f"piezocomp {args.command}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
