"""``piezocomp compensate``: desired trajectory -> command (eqs 9-13)."""

from __future__ import annotations

import argparse
import sys

from piezocomp.commands._common import load_axis_model, read_uniform_series, write_series
from piezocomp.inverse import compensate
from piezocomp.limits import CommandLimits


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "compensate",
        help="turn a desired trajectory into the command that produces it",
        description=(
            "Read a desired extension (CSV with header t_s,y_nm, uniform sampling), run the "
            "inverse model (Mokaberi & Requicha eqs 9-13) from the zero state, and write the "
            "command (t_s,u_nm)."
        ),
    )
    p.add_argument("--model", required=True, help="model file (JSON)")
    p.add_argument("--input", required=True, help="desired trajectory CSV (t_s, y_nm)")
    p.add_argument("--output", required=True, help="command CSV to write (t_s, u_nm)")
    p.add_argument("--axis", choices=("x", "y"), help="axis of a 2-D model file")
    p.add_argument("--range-nm", type=float, help="scanner full travel; commands in +-range/2")
    p.add_argument("--max-slew-nm-per-s", type=float, default=float("inf"), help="slew limit")
    p.add_argument(
        "--clip",
        action="store_true",
        help="clip commands to the limits instead of refusing (clipped samples are listed)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    model = load_axis_model(args.model, args.axis)
    t, yd, T = read_uniform_series(args.input, "t_s", "y_nm")
    limits = None
    if args.range_nm is not None or args.max_slew_nm_per_s != float("inf"):
        half = args.range_nm / 2 if args.range_nm is not None else float("inf")
        limits = CommandLimits(-half, half, args.max_slew_nm_per_s)
    result = compensate(model, yd, T, limits=limits, clip=args.clip)
    write_series(args.output, {"t_s": t, "u_nm": result.command_nm})
    n = result.report.n_clipped
    if n:
        print(
            f"clipped {n} samples to the limits (range: {result.report.range_clipped.tolist()}, "
            f"slew: {result.report.slew_clipped.tolist()})",
            file=sys.stderr,
        )
    print(f"wrote {t.size} commands to {args.output}")
    return 0
