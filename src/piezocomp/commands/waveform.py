"""``piezocomp waveform``: the identification waveform of Fig. 7a, to run on any instrument."""

from __future__ import annotations

import argparse
import math

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
    p.add_argument("--span-nm", type=float, default=1000.0, help="span of the line (nm)")
    p.add_argument("--speed-nm-per-s", type=float, default=250.0, help="ramp speed (nm/s)")
    p.add_argument("--sample-period-s", type=float, default=0.008, help="T (s)")
    p.add_argument("--n-steady", type=int, default=4, help="steady cycles of part A")
    p.add_argument("--n-decaying", type=int, default=12, help="decaying reversals of part B")
    p.add_argument("--n-random", type=int, default=30, help="random turning points of part B")
    p.add_argument("--max-dwell-s", type=float, default=4.0, help="longest dwell (s)")
    p.add_argument("--seed", type=int, default=0, help="randomness of part B")
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


def run(args: argparse.Namespace) -> int:
    from piezocomp.identification.config import WaveformConfig
    from piezocomp.identification.offline import waveform_from_metadata, waveform_metadata

    factors = args.speed_factors or list(WaveformConfig().speed_factors)
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
    fastest = args.speed_nm_per_s * max(factors)
    if fastest > args.max_speed_nm_per_s:
        raise ValueError(
            f"the fastest ramp ({args.speed_nm_per_s:g} nm/s x {max(factors):g}) exceeds "
            f"--max-speed-nm-per-s {args.max_speed_nm_per_s:g}."
        )

    params = {
        "center_nm": args.center_nm,
        "span_nm": args.span_nm,
        "speed_nm_per_s": args.speed_nm_per_s,
        "sample_period_s": args.sample_period_s,
        "n_steady": args.n_steady,
        "n_decaying": args.n_decaying,
        "n_random": args.n_random,
        "max_dwell_s": args.max_dwell_s,
        "seed": args.seed,
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
