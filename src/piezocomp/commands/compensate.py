"""``piezocomp compensate``: desired trajectory -> command (eqs 9-13), per axis."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from piezocomp._atomic import atomic_write_text, check_outputs
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import axis_jobs, read_columns, write_series
from piezocomp.inverse import compensate
from piezocomp.io.model_files import load_model, load_state, save_state
from piezocomp.limits import CommandLimits, LimitReport
from piezocomp.model import ModelState, simulate

DOMAIN_SLACK = 0.01
"""Commands may leave the model's domain by this fraction of its width (as the compensated
instrument allows)."""

SHOWN = 10
"""Clipped samples listed on the terminal (``--clip-report`` lists them all)."""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "compensate",
        help=COMMANDS["compensate"][1],
        description=(
            "Read a desired trajectory (CSV with a header: t_s and the position of each axis, "
            "x_nm and/or y_nm; position_nm for a 1-D model of an unnamed axis; uniform "
            "sampling), run the inverse model (Mokaberi & Requicha eqs 9-13) and write the "
            "command of each axis (ux_nm, uy_nm; u_nm for a 1-D model). A 2-D model "
            "compensates every axis the file holds. Commands outside the scanner's range "
            "(the model file's range_nm, or --range-nm) or the model's identified domain are "
            "refused. The state starts at zero (the initial loading curve) or where a "
            "previous run left it (--state-in)."
        ),
    )
    p.add_argument("--model", required=True, help="model file (JSON, 1-D or 2-D)")
    p.add_argument("--input", required=True, help="desired trajectory CSV")
    p.add_argument("--output", required=True, help="command CSV to write")
    p.add_argument("--axis", choices=("x", "y"), help="only this axis of a 2-D model")
    p.add_argument(
        "--range-nm", type=float, help="scanner full travel, commands in +-range/2 (default: "
        "the model file's range_nm)"
    )  # fmt: skip
    p.add_argument("--max-slew-nm-per-s", type=float, default=float("inf"), help="slew limit")
    p.add_argument(
        "--clip", action="store_true",
        help="clip commands to the range and slew limits instead of refusing",
    )  # fmt: skip
    p.add_argument("--clip-report", metavar="FILE", help="with --clip: every clipped sample (CSV)")
    p.add_argument(
        "--allow-extrapolation", action="store_true",
        help="send commands outside the model's identified domain (it extrapolates there)",
    )  # fmt: skip
    p.add_argument("--state-in", metavar="FILE", help="start from this state (state file)")
    p.add_argument("--state-out", metavar="FILE", help="write the state after the last sample")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_outputs(args.output, args.state_out, args.clip_report)
    model = load_model(args.model)
    t, cols, T = read_columns(args.input)
    jobs = axis_jobs(model, args.axis, cols, str(args.input), commands_in=False,
                     range_nm=args.range_nm)  # fmt: skip
    if args.clip_report and not args.clip:
        raise ValueError("--clip-report goes with --clip.")
    states = load_state(args.state_in) if args.state_in else {}
    out = {"t_s": t}
    ends: dict[str, ModelState] = {}
    reports: list[tuple[str, LimitReport]] = []
    for job in jobs:
        st = states.get(job.key)
        if args.state_in and st is None:
            raise ValueError(f"{args.state_in}: holds no state for {job.key!r}.")
        if st is not None:
            st.check_for(job.model)
        assert job.range_nm is not None  # axis_jobs refuses a missing range here
        half = job.range_nm / 2
        limits = CommandLimits(-half, half, args.max_slew_nm_per_s)
        try:
            result = compensate(job.model, cols[job.in_column], T, st)
            sent, report = limits.check(
                result.command_nm, T, previous_nm=None if st is None else st.u_prev_nm,
                clip=args.clip, name=f"{job.out_column}", clip_hint="Pass --clip to clip.",
            )  # fmt: skip
        except ValueError as exc:
            raise ValueError(f"{exc} (no file written)") from None
        if not args.allow_extrapolation:
            _domain_check(job.model.domain_nm, sent, job.out_column)
        end = result.state
        if report.n_clipped:  # the scanner follows what is sent
            _, end = simulate(job.model, sent, T, st)
            reports.append((job.out_column, report))
        out[job.out_column] = sent
        ends[job.key] = end
    write_series(args.output, out)
    if args.state_out:
        save_state(args.state_out, ends)
    for name, report in reports:
        _report_clipping(name, report, args.clip_report)
    print(f"wrote {t.size} commands of {', '.join(j.out_column for j in jobs)} to {args.output}")
    return 0


def _domain_check(domain: tuple[float, float] | None, u: np.ndarray, name: str) -> None:
    if domain is None:
        return
    lo, hi = domain
    slack = DOMAIN_SLACK * (hi - lo)
    bad = np.flatnonzero((u < lo - slack) | (u > hi + slack))
    if bad.size:
        k = int(bad[0])
        raise ValueError(
            f"{name}[{k}] = {u[k]:.6g} nm is outside the model's domain [{lo:g}, {hi:g}] nm "
            f"(where it was identified; {bad.size} samples outside); no file written. Pass "
            "--allow-extrapolation to send them anyway."
        )


def _report_clipping(name: str, report: LimitReport, path: str | None) -> None:
    idx = np.union1d(report.range_clipped, report.slew_clipped)
    first = ", ".join(str(int(i)) for i in idx[:SHOWN])
    more = f", ... (all {idx.size} in {path})" if path else (", ..." if idx.size > SHOWN else "")
    print(
        f"piezocomp compensate: warning: {name}: clipped {idx.size} samples to the limits "
        f"({report.range_clipped.size} to the range, {report.slew_clipped.size} to the slew "
        f"limit): samples {first}{more}",
        file=sys.stderr,
    )
    if path:
        rows = ["sample,limit"] + [
            f"{int(i)},{'range' if i in set(report.range_clipped.tolist()) else 'slew'}"
            for i in idx
        ]
        atomic_write_text(Path(path), "\n".join(rows) + "\n")
