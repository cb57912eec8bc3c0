"""The options of every command that can drive a real instrument (``--instrument``).

``identify``, ``drift`` and ``reproduce`` take ``--instrument nanonis://HOST:PORT`` beside
their virtual AFM (``--preset``/``--scanner``); what cannot be read from the controller is
given by the flags added here (:func:`add_instrument_options`), checked in one line each
before anything connects (:func:`connect_instrument`), and refused without ``--instrument``
(:func:`refuse_instrument_options`). Not a subcommand (no ``register``).
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

__all__ = [
    "INSTRUMENT_OPTIONS",
    "add_instrument_options",
    "connect_instrument",
    "instrument_settings",
    "refuse_instrument_options",
]

INSTRUMENT_OPTIONS = (
    "emulator",
    "max_speed_nm_per_s",
    "speedup",
    "timeout_s",
    "timing_tolerance",
    "timing",
    "drift_ramp",
)
"""The options that go with ``--instrument`` only (``--sample-period-s`` and ``--range-nm``
are added too, unless the command has its own)."""


def add_instrument_options(
    parser: argparse.ArgumentParser,
    source: Any,
    *,
    sample_period: bool = True,
    range_nm: bool = True,
) -> None:
    """Add ``--instrument`` to the ``source`` group (mutually exclusive with the virtual AFM)
    and the instrument's options to ``parser``; ``sample_period``/``range_nm``: add
    ``--sample-period-s``/``--range-nm`` too (False where the command has its own)."""
    source.add_argument(
        "--instrument",
        metavar="nanonis://HOST:PORT",
        help="a real instrument: a Nanonis controller over TCP (or 'piezocomp emulate'); "
        "needs --max-speed-nm-per-s (docs/instruments.md)",
    )
    g = parser.add_argument_group("with --instrument")
    g.add_argument(
        "--max-speed-nm-per-s",
        type=float,
        help="the scanner's slew limit, nm/s (not readable from the controller)",
    )
    if sample_period:
        g.add_argument("--sample-period-s", type=float, help="T, s (default 0.008)")
    if range_nm:
        g.add_argument(
            "--range-nm",
            type=float,
            help="travel to use, nm: at most the controller's (default the controller's); a "
            "smaller one keeps a first session small",
        )
    g.add_argument(
        "--emulator",
        action="store_true",
        help="the instrument is 'piezocomp emulate': declare each path's sample period to it "
        "(never for a controller)",
    )
    g.add_argument(
        "--speedup",
        type=float,
        help="with --emulator: pace set-points this many times faster than T (default 1)",
    )
    g.add_argument("--timeout-s", type=float, help="longest wait for a reply, s (default 2)")
    g.add_argument(
        "--timing-tolerance",
        type=float,
        help="largest distance of a sample from its slot, in sample periods (default 0.5); a "
        "path beyond it stops the command",
    )
    g.add_argument(
        "--timing",
        choices=("raise", "flag"),
        help="a path beyond the tolerance stops the command (raise, the default) or, with "
        "--emulator only, is used and counted (flag: the emulator's clock is the set-point "
        "stream, so a late set-point changes nothing it measures)",
    )
    g.add_argument(
        "--drift-ramp",
        choices=("off", "keep"),
        help="the controller's drift ramp: switched off at connection (default) or kept "
        "(and reported: no piezocomp drift correction may then run on top)",
    )


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def refuse_instrument_options(args: argparse.Namespace, *, also: tuple[str, ...] = ()) -> None:
    """Without ``--instrument``: refuse any of its options that was given (``also``: the
    command's own names of ``--sample-period-s``/``--range-nm`` when it added them)."""
    for name in (*INSTRUMENT_OPTIONS, *also):
        value = getattr(args, name, None)
        if value is not None and value is not False:
            raise ValueError(f"{_flag(name)} goes with --instrument.")


def _positive(args: argparse.Namespace, name: str) -> float | None:
    """The option's value, checked finite and > 0; ``None`` if not given."""
    value = getattr(args, name, None)
    if value is None:
        return None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{_flag(name)} must be a finite number > 0. Got {value}.")
    return float(value)


def instrument_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The instrument's options checked, one line per problem, before anything connects:
    the keyword arguments of :meth:`NanonisInstrument.connect` (address apart)."""
    from piezocomp.drivers.nanonis import parse_address

    parse_address(args.instrument)  # the address first: the most likely typo
    vmax = _positive(args, "max_speed_nm_per_s")
    if vmax is None:
        raise ValueError(
            "--instrument needs --max-speed-nm-per-s (the scanner's slew limit, which the "
            "controller does not state)."
        )
    speedup = _positive(args, "speedup") or 1.0
    if speedup != 1.0 and not args.emulator:
        raise ValueError(
            "--speedup goes with --emulator (pacing faster than T breaks the model on a "
            "microscope)."
        )
    if args.timing == "flag" and not args.emulator:
        raise ValueError(
            "--timing flag goes with --emulator: on a microscope a path whose timing broke "
            "the model's assumption is not to be used."
        )
    tolerance = _positive(args, "timing_tolerance") or 0.5
    if tolerance > 10:
        raise ValueError(f"--timing-tolerance must be at most 10 sample periods. Got {tolerance}.")
    return {
        "timeout_s": _positive(args, "timeout_s") or 2.0,
        "sample_period_s": _positive(args, "sample_period_s") or 0.008,
        "max_speed_nm_per_s": vmax,
        "range_nm": _positive(args, "range_nm"),
        "speedup": speedup,
        "emulator": bool(args.emulator),
        "timing_tolerance": tolerance,
        "timing": args.timing or "raise",
        "drift_ramp": args.drift_ramp or "off",
    }


def connect_instrument(args: argparse.Namespace, command: str, **kwargs: Any) -> Any:
    """Check the instrument's options (:func:`instrument_settings`) and connect
    (:class:`NanonisInstrument`); the controller's state is printed on stderr, ``piezocomp
    COMMAND: ...``. ``kwargs`` go to the instrument."""
    from piezocomp.drivers.nanonis import NanonisInstrument

    inst = NanonisInstrument.connect(args.instrument, **instrument_settings(args), **kwargs)
    print(f"piezocomp {command}: {inst.address}: {inst.controller.summary()}", file=sys.stderr)
    return inst
