"""``piezocomp simulate``: command -> extension through the forward model (eq 14)."""

from __future__ import annotations

import argparse

from piezocomp.commands._common import load_axis_model, read_uniform_series, write_series
from piezocomp.model import simulate


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "simulate",
        help="run the forward model on a command trajectory",
        description=(
            "Read a command (CSV with header t_s,u_nm, uniform sampling), run the forward "
            "model (eq 14) from the zero state, and write the extension (t_s,y_nm)."
        ),
    )
    p.add_argument("--model", required=True, help="model file (JSON)")
    p.add_argument("--input", required=True, help="command CSV (t_s, u_nm)")
    p.add_argument("--output", required=True, help="extension CSV to write (t_s, y_nm)")
    p.add_argument("--axis", choices=("x", "y"), help="axis of a 2-D model file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    model = load_axis_model(args.model, args.axis)
    t, u, T = read_uniform_series(args.input, "t_s", "u_nm")
    y, _ = simulate(model, u, T)
    write_series(args.output, {"t_s": t, "y_nm": y})
    print(f"wrote {t.size} samples to {args.output}")
    return 0
