"""``piezocomp calibrate``: the scanner's calibration record, measured on a grating.

The sensorless identification runs its calibration cycles at the speed at which a steady
full-range scan is as wide as commanded (Section IV's calibration condition). A controller
whose calibration record states it needs nothing; otherwise mount a grating of known pitch
(lines perpendicular to the axis) and run this once: it scans the grating over the whole
range at several speeds and finds that speed
(:func:`~piezocomp.identification.reference.calibration_scan.measure_calibration_scan`),
then ``piezocomp identify --calibration-speed-nm-per-s V`` uses it. On the virtual AFM the
grating is mounted instead of the particles and the speed the scanner's physics gives is
written beside it, for scoring only.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from piezocomp._atomic import atomic_write_text
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import output_folder
from piezocomp.commands.instrument_options import (
    add_instrument_options,
    connect_instrument,
    refuse_instrument_options,
)


def register(subparsers: Any) -> None:
    """Add the ``calibrate`` subcommand."""
    p = subparsers.add_parser(
        "calibrate",
        help=COMMANDS["calibrate"][1],
        description=(
            "Scan a grating of known pitch over the scanner's whole range in steady cycles at "
            "several speeds and find the speed at which the scan is as wide as commanded: the "
            "calibration record that 'piezocomp identify --calibration-speed-nm-per-s' takes. "
            "Writes calibration.json. On a real instrument (--instrument) mount the grating "
            "first, its lines perpendicular to --axis; on the virtual AFM (--preset, "
            "--scanner) the grating is mounted for you."
        ),
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--preset", help="virtual AFM preset (e.g. cpr5)")
    src.add_argument("--scanner", help="virtual AFM configuration file (TOML)")
    add_instrument_options(p, src)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument(
        "--grating-pitch-nm", type=float, required=True, help="the grating's certified pitch, nm"
    )
    p.add_argument("--axis", choices=("x", "y"), default="x", help="axis scanned (default x)")
    p.add_argument(
        "--speeds-nm-per-s",
        type=float,
        nargs=2,
        metavar=("LOW", "HIGH"),
        default=None,
        help="speeds searched, nm/s (default 100 10000)",
    )
    p.add_argument("--seed", type=int, help="virtual AFM seed (default 1)")
    p.set_defaults(func=run)


def _check(args: argparse.Namespace) -> None:
    pitch = args.grating_pitch_nm
    if not (math.isfinite(pitch) and pitch > 0):
        raise ValueError(f"--grating-pitch-nm must be a finite number > 0. Got {pitch}.")
    if args.speeds_nm_per_s is not None:
        lo, hi = args.speeds_nm_per_s
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            raise ValueError(f"--speeds-nm-per-s must satisfy 0 < LOW < HIGH. Got {lo} {hi}.")
    if args.instrument:
        if args.seed is not None:
            raise ValueError("--seed goes with the virtual AFM (--preset or --scanner).")
    else:
        refuse_instrument_options(args)


def run(args: argparse.Namespace) -> int:
    """Run ``piezocomp calibrate``; return the exit status."""
    from piezocomp.identification.reference.calibration_scan import (
        CALIBRATION_SPEEDS_NM_PER_S,
        measure_calibration_scan,
    )
    from piezocomp.instrument import RunValueError

    _check(args)
    speeds = tuple(args.speeds_nm_per_s or CALIBRATION_SPEEDS_NM_PER_S)
    kw = {"axis": args.axis, "speeds_nm_per_s": speeds}
    with output_folder(args.out) as out:
        truth: dict[str, Any] | None = None
        if args.instrument:
            with connect_instrument(args, "calibrate") as inst:
                found = measure_calibration_scan(inst, args.grating_pitch_nm, **kw)
                source = inst.address
        else:
            from piezocomp.experiments.virtual_identification import (
                lab_calibration,
                true_calibration_speed,
            )
            from piezocomp.virtual_afm import VirtualAFM

            seed = 1 if args.seed is None else args.seed
            afm = VirtualAFM(args.scanner or args.preset, seed=seed)
            found = lab_calibration(afm, args.axis, args.grating_pitch_nm, speeds)
            source = str(args.scanner or args.preset)
            truth = {"physics_speed_nm_per_s": true_calibration_speed(afm),
                     "note": "ground truth, for scoring only"}  # fmt: skip
        if found.scan is None:
            raise RunValueError(_no_crossing(speeds, found.width_ratios))
        body: dict[str, Any] = {
            "source": source,
            "axis": args.axis,
            "grating_pitch_nm": args.grating_pitch_nm,
            "span_nm": found.scan.span_nm,
            "speed_nm_per_s": found.scan.speed_nm_per_s,
            "width_ratios": [
                {"speed_nm_per_s": v, "width_over_command": r} for v, r in found.width_ratios
            ],
            "instrument_s": found.instrument_s,
        }
        if truth is not None:
            body["truth"] = truth
        atomic_write_text(out / "calibration.json", json.dumps(body, indent=2) + "\n")
    minutes = found.instrument_s / 60
    v = found.scan.speed_nm_per_s
    print(
        f"piezocomp calibrate: a steady scan over {found.scan.span_nm:g} nm is as wide as "
        f"commanded at {v:.4g} nm/s ({len(found.width_ratios)} speeds scanned, {minutes:.0f} "
        f"min of instrument time); {_use(args, v)}",
        file=sys.stderr,
    )
    if truth is not None and truth["physics_speed_nm_per_s"] is not None:
        exact = truth["physics_speed_nm_per_s"]
        print(
            f"piezocomp calibrate: the virtual scanner's physics gives {exact:.4g} nm/s for a "
            "scan from rest (ground truth, for scoring)",
            file=sys.stderr,
        )
    print(out / "calibration.json")
    return 0


def _use(args: argparse.Namespace, speed: float) -> str:
    """How the identification takes the record."""
    if args.instrument:
        return f"identify with --calibration-speed-nm-per-s {speed:.6g}"
    return (
        "the virtual lab's record, which 'piezocomp identify' on this sample measures for "
        "itself (to set another: acquisition.calibration_speed_nm_per_s in --config)"
    )


def _no_crossing(speeds: tuple[float, ...], widths: tuple[tuple[float, float], ...]) -> str:
    """The failure when no speed searched is as wide as commanded, and which way to go."""
    r = [w for _, w in widths]
    way = "lower LOW" if max(r) < 1 else "raise HIGH (if the slew limit allows)"
    listed = ", ".join(f"{w:.4f} at {v:.4g} nm/s" for v, w in widths)
    return (
        f"no speed in {speeds[0]:g}-{speeds[1]:g} nm/s makes a full-range scan as wide as "
        f"commanded (width over command: {listed}): {way} in --speeds-nm-per-s"
    )
