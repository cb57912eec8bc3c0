"""``piezocomp simulate``: command -> position through the forward model (eq 14), per axis."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from piezocomp._atomic import check_outputs
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import axis_jobs, read_columns, write_series
from piezocomp.io.model_files import load_model, load_state, save_state
from piezocomp.limits import CommandLimits
from piezocomp.model import ModelState, simulate


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "simulate",
        help=COMMANDS["simulate"][1],
        description=(
            "Read a command trajectory (CSV with a header: t_s and the command of each axis, "
            "ux_nm and/or uy_nm; u_nm for a 1-D model; uniform sampling), run the forward "
            "model (eq 14) and write the predicted position of each axis (x_nm, y_nm; "
            "position_nm for a 1-D model). Commands outside the scanner's range (--range-nm, "
            "or the model file's range_nm when it states one) are refused; commands outside "
            "the model's identified domain are predicted with a warning. The state starts at "
            "zero or where a previous run left it (--state-in)."
        ),
    )
    p.add_argument("--model", required=True, help="model file (JSON, 1-D or 2-D)")
    p.add_argument("--input", required=True, help="command CSV")
    p.add_argument("--output", required=True, help="position CSV to write")
    p.add_argument("--axis", choices=("x", "y"), help="only this axis of a 2-D model")
    p.add_argument(
        "--range-nm", type=float,
        help="scanner full travel: refuse commands outside +-range/2 (default: the model "
        "file's range_nm; with neither, no check)",
    )  # fmt: skip
    p.add_argument("--state-in", metavar="FILE", help="start from this state (state file)")
    p.add_argument("--state-out", metavar="FILE", help="write the state after the last sample")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_outputs(args.output, args.state_out)
    model = load_model(args.model)
    t, cols, T = read_columns(args.input)
    jobs = axis_jobs(model, args.axis, cols, str(args.input), commands_in=True,
                     range_nm=args.range_nm, need_range=False)  # fmt: skip
    states = load_state(args.state_in) if args.state_in else {}
    out = {"t_s": t}
    ends: dict[str, ModelState] = {}
    for job in jobs:
        st = states.get(job.key)
        if args.state_in and st is None:
            raise ValueError(f"{args.state_in}: holds no state for {job.key!r}.")
        if st is not None:
            st.check_for(job.model)
        u = cols[job.in_column]
        if job.range_nm is not None:  # a prediction needs no range; checked when known
            half = job.range_nm / 2
            try:
                CommandLimits(-half, half).check(u, T, name=job.in_column, clip_hint="")
            except ValueError as exc:
                raise ValueError(f"{args.input}: {exc} (no file written)") from None
        dom = job.model.domain_nm
        if dom is not None and (u.min() < dom[0] or u.max() > dom[1]):
            outside = int(np.sum((u < dom[0]) | (u > dom[1])))
            print(
                f"piezocomp simulate: warning: {job.in_column}: {outside} commands lie outside "
                f"the model's domain [{dom[0]:g}, {dom[1]:g}] nm: the prediction extrapolates "
                "there",
                file=sys.stderr,
            )
        out[job.out_column], ends[job.key] = simulate(job.model, u, T, st)
        if not np.all(np.isfinite(out[job.out_column])):
            raise ValueError(
                f"{args.input}: {job.in_column}: the prediction overflows (commands of "
                f"{np.max(np.abs(u)):.6g} nm); no file written."
            )
    write_series(args.output, out)
    if args.state_out:
        save_state(args.state_out, ends)
    print(f"wrote {t.size} samples of {', '.join(j.out_column for j in jobs)} to {args.output}")
    return 0
