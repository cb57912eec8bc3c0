"""``piezocomp waveform``: the identification waveform of Fig. 7a, to run on any instrument."""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from piezocomp._atomic import check_output
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import write_series


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "waveform",
        help=COMMANDS["waveform"][1],
        description=(
            "Write the identification waveform of Fig. 7a (part A: steady full cycles; part B: "
            "varied amplitudes) as CSV (t_s, u_nm) with its parameters in a '# "
            "piezocomp_waveform: {...}' line. Run it along one line with the instrument's own "
            "software, record the topography, save t_s,u_nm,height_nm with that line kept, and "
            "identify offline with: piezocomp identify --record FILE --out DIR."
        ),
    )
    p.add_argument("--out", required=True, help="CSV to write")
    p.add_argument("--center-nm", type=float, default=0.0, help="line centre (command nm)")
    p.add_argument(
        "--span-nm", type=float, default=1000.0,
        help="span of the line, nm of command (default 1000; piezocomp identify's default is "
        "2000: give --span-nm 2000 for its area)",
    )  # fmt: skip
    p.add_argument(
        "--speed-nm-per-s", type=float, default=250.0, help="ramp speed, nm/s (default 250)"
    )
    p.add_argument("--sample-period-s", type=float, default=0.008, help="T, s (default 0.008)")
    p.add_argument("--n-steady", type=int, default=None, help="steady cycles of part A (4)")
    p.add_argument("--n-decaying", type=int, default=None, help="decaying reversals of part B (12)")
    p.add_argument(
        "--n-random", type=int, default=None, help="random turning points of part B (30)"
    )
    p.add_argument("--max-dwell-s", type=float, default=None, help="longest dwell (s, 4)")
    p.add_argument("--seed", type=int, default=None, help="randomness of part B (0)")
    p.add_argument(
        "--grating-line", type=int, default=None, metavar="I",
        help="write line I (0, 1, ...) of the minor-loop grating path instead: long sweeps "
        "after minor loops and rests, one file per grating line, the same span, centre and "
        "speed as the identification (its files go to --grating-record)",
    )  # fmt: skip
    p.add_argument(
        "--n-sweeps", type=int, default=None,
        help="with --grating-line: sweeps per line, an even number (4)",
    )  # fmt: skip
    p.add_argument(
        "--range-nm", type=float, default=5000.0,
        help="the scanner's full travel: the line must lie within +-range/2 (default 5000)",
    )  # fmt: skip
    p.add_argument(
        "--max-speed-nm-per-s", type=float, default=20000.0,
        help="the scanner's speed limit (default 20000)",
    )  # fmt: skip
    p.add_argument(
        "--speed-factors",
        type=float,
        nargs="+",
        default=None,
        help="part B's ramps at these multiples of the speed in turn (default that of "
        "piezocomp identify); keep them within the instrument's speed limit",
    )
    p.set_defaults(func=run)


PART_OPTIONS: dict[str, Any] = {
    "n_steady": 4,
    "n_decaying": 12,
    "n_random": 30,
    "max_dwell_s": 4.0,
    "seed": 0,
    "speed_factors": None,
}
"""The identification waveform's own options and their defaults (``None``: the identify
default's speed factors)."""


def run(args: argparse.Namespace) -> int:
    from piezocomp.identification.config import WaveformConfig
    from piezocomp.identification.offline import waveform_from_metadata, waveform_metadata

    if not (math.isfinite(args.span_nm) and args.span_nm > 0):
        raise ValueError(f"--span-nm must be a finite number > 0. Got {args.span_nm}.")
    if args.grating_line is not None:
        return _grating_line(args)
    if args.n_sweeps is not None:
        raise ValueError("--n-sweeps is for a grating line: give --grating-line I with it.")
    opt = {k: d if getattr(args, k) is None else getattr(args, k) for k, d in PART_OPTIONS.items()}
    factors = opt["speed_factors"] or list(WaveformConfig().speed_factors)
    _check_line(args, args.speed_nm_per_s * max(factors))

    params = {
        "center_nm": args.center_nm,
        "span_nm": args.span_nm,
        "speed_nm_per_s": args.speed_nm_per_s,
        "sample_period_s": args.sample_period_s,
        "n_steady": opt["n_steady"],
        "n_decaying": opt["n_decaying"],
        "n_random": opt["n_random"],
        "max_dwell_s": opt["max_dwell_s"],
        "seed": opt["seed"],
        "speed_factors": [float(v) for v in factors],
        "range_nm": float(args.range_nm),  # the models identified from it carry it
    }
    check_output(args.out)
    meta = waveform_metadata(params)
    wf, _ = waveform_from_metadata(meta, "waveform")
    t = np.arange(wf.u_nm.size, dtype=np.float64) * wf.sample_period_s
    write_series(args.out, {"t_s": t, "u_nm": wf.u_nm}, metadata=meta)
    print(
        f"wrote {wf.u_nm.size} samples ({wf.duration_s:.1f} s; part A {wf.part_a.stop} samples) "
        f"to {args.out}"
    )
    return 0


def _check_line(args: argparse.Namespace, fastest: float) -> None:
    """The line within the range and the fastest ramp within the speed limit."""
    half = args.range_nm / 2
    if not (math.isfinite(half) and half > 0):
        raise ValueError(f"--range-nm must be a finite number > 0. Got {args.range_nm}.")
    if not (math.isfinite(args.center_nm) and math.isfinite(args.span_nm)):
        raise ValueError("--center-nm and --span-nm must be finite.")
    if abs(args.center_nm) + args.span_nm / 2 > half:
        raise ValueError(
            f"the line {args.center_nm:g} +- {args.span_nm / 2:g} nm leaves the scanner's "
            f"range +-{half:g} nm (--range-nm)."
        )
    if fastest > args.max_speed_nm_per_s:
        raise ValueError(
            f"the fastest ramp ({fastest:g} nm/s) exceeds --max-speed-nm-per-s "
            f"{args.max_speed_nm_per_s:g}."
        )


def _grating_line(args: argparse.Namespace) -> int:
    """``--grating-line I``: line I of the minor-loop grating path, with its metadata."""
    from piezocomp.identification.offline import grating_path_from_metadata, grating_path_metadata
    from piezocomp.identification.reference.grating import MIN_PASS_PITCHES, SWEEP_FRACTION

    given = [f"--{k.replace('_', '-')}" for k in PART_OPTIONS if getattr(args, k) is not None]
    if given:
        raise ValueError(
            f"--grating-line writes a grating line, not the identification waveform: "
            f"{', '.join(given)} cannot go with it."
        )
    if args.grating_line < 0:
        raise ValueError(f"--grating-line must be >= 0. Got {args.grating_line}.")
    n = 4 if args.n_sweeps is None else args.n_sweeps
    if n < 2 or n % 2:
        raise ValueError(f"--n-sweeps must be an even integer >= 2. Got {n}.")
    _check_line(args, args.speed_nm_per_s)
    if not args.span_nm > 0:
        raise ValueError(f"--span-nm must be > 0. Got {args.span_nm}.")
    params = {
        "center_nm": args.center_nm,
        "span_nm": args.span_nm,
        "speed_nm_per_s": args.speed_nm_per_s,
        "sample_period_s": args.sample_period_s,
        "n_sweeps": n,
        "line": args.grating_line,
    }
    check_output(args.out)
    meta = grating_path_metadata(params)
    u, _ = grating_path_from_metadata(meta, "grating line")
    t = np.arange(u.size, dtype=np.float64) * args.sample_period_s
    write_series(args.out, {"t_s": t, "u_nm": u}, metadata=meta)
    print(
        f"wrote grating line {args.grating_line}: {u.size} samples "
        f"({u.size * args.sample_period_s:.1f} s, "
        f"{n} sweeps over {SWEEP_FRACTION:.0%} of the span or more; a grating of pitch up to "
        f"{SWEEP_FRACTION * args.span_nm / MIN_PASS_PITCHES:.0f} nm) to {args.out}"
    )
    return 0
