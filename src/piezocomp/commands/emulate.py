"""``piezocomp emulate``: a Nanonis controller on loopback with the virtual AFM behind it.

Serves the Nanonis TCP protocol (:mod:`piezocomp.drivers.nanonis_emulator`) until Ctrl-C
(or ``SIGTERM``), so a session (``identify --instrument nanonis://127.0.0.1:PORT --emulator``
...) can be rehearsed over real sockets before a microscope is touched. Prints ``listening on
127.0.0.1:PORT`` first, then on stderr the flags to rehearse with, and when stopped how many
set-points it served and the virtual scanner's time.
"""

from __future__ import annotations

import argparse
import sys

from piezocomp.commands import COMMANDS

__all__ = ["register", "run"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``emulate`` subcommand."""
    p = subparsers.add_parser(
        "emulate",
        help=COMMANDS["emulate"][1],
        description=(
            "Emulate a Nanonis controller on 127.0.0.1 over the virtual AFM, for rehearsing a "
            "session with --instrument nanonis://127.0.0.1:PORT --emulator. Each streamed "
            "set-point is one sample period of the virtual scanner (the period the client "
            "declares with --emulator). Serves until Ctrl-C."
        ),
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument("--preset", default=None, help="virtual AFM preset (default cpr5)")
    src.add_argument("--scanner", default=None, metavar="FILE.toml", help="configuration file")
    p.add_argument("--port", type=int, default=6501, help="port (default 6501; 0: a free one)")
    p.add_argument("--seed", type=int, default=None, help="sample seed (overrides sample.seed)")
    p.add_argument("--sample-period-s", type=float, default=0.008, help="T (default 0.008 s)")
    p.add_argument(
        "--grating-pitch-nm",
        type=float,
        help="mount a calibration grating of this pitch instead of the particles (lines "
        "across --grating-axis), to rehearse a length-reference run",
    )
    p.add_argument("--grating-axis", choices=("x", "y"), help="with --grating-pitch-nm (default x)")
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND[@N][:COMMAND]",
        help="inject a fault once: slow, drop, malformed or error, on the N+1-th call of "
        "COMMAND (default FolMe.XYPosSet), e.g. drop@500; repeatable",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Build the virtual AFM, serve it until Ctrl-C."""
    from piezocomp.drivers.nanonis_emulator import Fault, NanonisEmulator
    from piezocomp.experiments.virtual_identification import calibration_record
    from piezocomp.virtual_afm import Grating, VirtualAFM

    if not 0 <= args.port < 65536:
        raise ValueError(f"--port must be in 0-65535. Got {args.port}.")
    faults = [Fault.parse(f) for f in args.fault]
    grating = None
    if args.grating_axis is not None and args.grating_pitch_nm is None:
        raise ValueError(
            f"--grating-axis {args.grating_axis} goes with --grating-pitch-nm (no grating is "
            "mounted without a pitch)."
        )
    if args.grating_pitch_nm is not None:
        if not args.grating_pitch_nm > 0:
            raise ValueError(f"--grating-pitch-nm must be > 0. Got {args.grating_pitch_nm}.")
        grating = Grating(args.grating_pitch_nm, axis=args.grating_axis or "x")
    source = args.scanner or args.preset or "cpr5"
    afm = VirtualAFM(source, seed=args.seed, sample_period_s=args.sample_period_s, grating=grating)
    emulator = NanonisEmulator(afm, port=args.port, faults=faults)
    emulator.warm_up()  # before the address is printed: a client's first samples keep time
    host, port = emulator.address
    sample = "a grating" if grating is not None else "particles"
    scan = calibration_record(afm)  # what the lab's calibration of this scanner states
    flags = (
        f"--instrument nanonis://{host}:{port} --emulator --timing flag "
        f"--max-speed-nm-per-s {afm.max_speed_nm_per_s:g} --sample-period-s {afm.sample_period_s:g}"
    )
    if scan is not None:  # what a lab's calibration record would state
        flags += f" (identify: --calibration-speed-nm-per-s {scan.speed_nm_per_s:.6g})"
    print(f"listening on {host}:{port}", flush=True)
    print(
        f"piezocomp emulate: nanonis://{host}:{port}, virtual AFM {source} over {sample}, "
        f"T = {afm.sample_period_s:g} s, range {afm.range_nm:g} nm, max speed "
        f"{afm.max_speed_nm_per_s:g} nm/s; rehearse with {flags} (--timing flag: on a busy "
        "computer set-points reach the emulator late, which changes nothing it simulates, so "
        "late paths are counted, not fatal; never use it on a microscope); Ctrl-C stops",
        file=sys.stderr,
        flush=True,
    )
    try:
        emulator.serve()
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
        print(
            f"piezocomp emulate: stopped; served {emulator.set_points} set-points "
            f"({emulator.streamed_s:.6g} s of scanner time streamed), virtual scanner time "
            f"{afm.time_s:.6g} s",
            file=sys.stderr,
            flush=True,
        )
    return 0
