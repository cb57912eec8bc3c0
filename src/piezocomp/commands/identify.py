"""``piezocomp identify``: sensorless identification on the virtual AFM, offline
on a recorded run (``--record``, :mod:`.identify_record`) or on a real instrument
(``--instrument``, :mod:`.identify_instrument`): the three choose where the record comes
from; the configuration (:func:`~.identify_outputs.config_of`: the defaults, ``--config``,
the flags) and each axis' summary
(:meth:`~piezocomp.identification.result.AxisIdentification.summary`) are the same.

On the virtual AFM the whole procedure of Sections III.C-V runs through the instrument
interface only (:func:`piezocomp.identification.sensorless.identify_axis`), with the length
reference of a virtual calibration grating under the same scanner; the command writes the
model file(s), the figures, ``config.toml`` and ``summary.json``, with the models' validation
against the simulator's ground truth from the experiments
(:func:`~piezocomp.experiments.virtual_identification.scored_summary`), the only use of the
ground truth.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

from piezocomp._atomic import atomic_write_text
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import output_folder
from piezocomp.commands.identify_outputs import (
    budget_seconds,
    config_of,
    drift_lines,
    figures,
    instrument_time_line,
    plan_summary,
    refused,
    save_config,
    save_models,
    warn,
)
from piezocomp.commands.identify_record import run_record
from piezocomp.commands.instrument_options import (
    add_instrument_options,
    refuse_instrument_options,
)
from piezocomp.experiments.virtual_identification import (
    VIRTUAL_PITCH_NM,
    calibrated,
    identify_virtual,
    scored_summary,
)
from piezocomp.identification.acquisition.diagnostics import ExcitationWarning
from piezocomp.identification.config import write_config
from piezocomp.identification.planning import within_budget
from piezocomp.instrument import RunValueError

if TYPE_CHECKING:
    from piezocomp.virtual_afm import VirtualAFM

NAME = "identify"

VIRTUAL_AFM_DEFAULTS: dict[str, Any] = {"seed": 1, "sample_period_s": 0.008}
"""The virtual AFM's own options and their defaults (the identification's settings are the
configuration's, :class:`~piezocomp.identification.config.IdentifyConfig`)."""

VIRTUAL_ONLY = (
    "seed", "span_nm", "speed_nm_per_s", "sample_period_s", "calibrate", "reference",
    "extra_lines", "overview_speed_nm_per_s", "speed_factors", "budget_min",
)  # fmt: skip
"""Options refused with ``--record`` (the waveform file fixes the acquisition)."""


def _calibration(text: str) -> str | float:
    """``--calibrate``: 'full-range', 'span' or a span in nm > 0."""
    if text in ("full-range", "span"):
        return text
    try:
        span = float(text)
    except ValueError:
        span = float("nan")
    if not (span > 0 and math.isfinite(span)):
        raise argparse.ArgumentTypeError(
            f"must be 'full-range', 'span' or a span in nm > 0. Got {text!r}."
        )
    return span


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        NAME,
        help=COMMANDS[NAME][1],
        description=(
            "Sensorless identification (Mokaberi & Requicha, Secs. III.C-V) on the virtual AFM: "
            "overview image, line choice, steady cycles, loop fit (eqs 21-23), h(y), RLS "
            "(eqs 16-20), batch refinement; orders chosen on a held-out part of the record; "
            "the models scaled by a calibration grating of known pitch scanned first with the "
            "same scanner (--reference none: without it). "
            "Writes DIR/model.json (the batch models), DIR/model_rls.json, figures and "
            "DIR/summary.json with the validation errors against the simulator's ground truth. "
            "Offline (--record): the same estimation on a run of 'piezocomp waveform' recorded "
            "with any instrument (--grating-record for the scale); the waveform file fixes "
            "span, speed and sample period, and there is no ground truth to score against."
        ),
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument("--preset", default="cpr5", help="virtual AFM preset (default cpr5)")
    src.add_argument("--scanner", help="virtual AFM configuration file (TOML)")
    src.add_argument(
        "--record",
        help="offline: a recorded run (CSV/NPZ with t_s, u_nm, height_nm) of the waveform "
        "written by 'piezocomp waveform', from any instrument; no ground truth, no scoring",
    )
    add_instrument_options(p, src, sample_period=False, range_nm=False)
    p.add_argument(
        "--calibration-speed-nm-per-s",
        type=float,
        help="with --instrument: the speed of the full-range scan the scanner's calibration "
        "was made at (from the lab's calibration record; 'piezocomp emulate' prints its "
        "own); the calibration cycles run over the whole range at it (--calibrate "
        "full-range, then the default); without it --calibrate span",
    )
    p.add_argument(
        "--out", help="output folder (it receives config.toml, the configuration the run used)"
    )
    p.add_argument(
        "--config",
        metavar="FILE",
        help="the identification's configuration (TOML, as --write-config writes it): its "
        "settings over the defaults (--quick: the reduced ones); the flags override it",
    )
    p.add_argument(
        "--write-config",
        metavar="FILE",
        help="write the configuration the other options describe (the packaged default "
        "without them) to FILE as TOML, and stop; edit it and run with --config FILE",
    )
    p.add_argument(
        "--no-progress", action="store_true", help="no progress bar (none off a terminal either)"
    )
    p.add_argument("--seed", type=int, help="sample seed of the virtual AFM (default 1)")
    p.add_argument(
        "--axis",
        choices=("x", "y", "both"),
        help="axis (default: both, one 2-D model file; x with --record)",
    )
    p.add_argument("--n-play", type=int, help="fix N_H (needs --n-creep)")
    p.add_argument("--n-creep", type=int, help="fix N_c (needs --n-play)")
    p.add_argument(
        "--span-nm",
        type=float,
        help="working span, nm of command (default 2000: about +-800 true nm on cpr5, the "
        "area the positioning examples work in)",
    )
    p.add_argument("--speed-nm-per-s", type=float, help="ramp speed (default 250 nm/s)")
    p.add_argument("--sample-period-s", type=float, help="T (default 0.008 s)")
    _add_procedure_options(p)
    p.add_argument("--quick", action="store_true", help="reduced waveform and orders (tests)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.set_defaults(func=run)


def _add_procedure_options(p: argparse.ArgumentParser) -> None:
    """The options of the procedure: calibration frame, length reference, lines, speeds,
    and what an offline record needs."""
    p.add_argument(
        "--calibrate",
        type=_calibration,
        metavar="{full-range,span,NM}",
        help="scale of the position frame: 'span' is the paper's calibration condition on the "
        "working span; 'full-range' (default) adds steady cycles over the scanner's whole range, "
        "where the nominal sensitivity holds, and maps the model onto that frame; a number: "
        "the cycles' span in nm",
    )
    p.add_argument(
        "--reference",
        choices=("grating", "none"),
        help="length reference: 'grating' (default) first scans a calibration grating of "
        "known pitch with the same scanner (over the working span) and scales the models to "
        "it; 'none' leaves the scale to the calibration cycles",
    )
    p.add_argument(
        "--grating-path",
        choices=("auto", "minor_loops", "steady"),
        help="what the grating's scan does along the axis: 'minor_loops', long sweeps after "
        "minor loops and rests, the scale of positioning's paths; 'steady', the paper's "
        "steady cycles; 'auto' (default), minor loops where 70%% of the span holds three "
        "pitches, else steady (with --grating-record the files say which)",
    )
    p.add_argument(
        "--grating-pitch-nm",
        type=float,
        help="pitch of the calibration grating: the virtual one's (default 278 nm, like "
        "NT-MDT TDG01), or, required with --grating-record, the certified pitch of yours",
    )
    p.add_argument(
        "--grating-record",
        nargs="+",
        metavar="FILE",
        help="with --record or --instrument: recorded runs (one per grating line, "
        "t_s,x_nm,y_nm,height_nm with the waveform line; t_s,u_nm,height_nm works but cannot "
        "measure the grating's angle) of 'piezocomp waveform --grating-line I' (the "
        "minor-loop grating path; steady cycles, '--n-decaying 0 --n-random 0 --n-steady 6', "
        "are read too) over a grating of known pitch, same span, centre and speed; scales "
        "the models",
    )
    p.add_argument(
        "--extra-lines",
        type=int,
        help="further particle lines refining the batch model with the first (default 1; 0 "
        "is the paper's single line); each costs its own line search, settling and record",
    )
    p.add_argument(
        "--overview-speed-nm-per-s",
        type=float,
        help="fast-axis speed of the overviews that choose the lines (default: the waveform's "
        "speed, --speed-nm-per-s); the overviews are most of the instrument time at that "
        "speed, but after a faster one the slow axis crept across the line during the record "
        "on 3 of 6 design seeds of cpr5 at 1 um/s, and the model failed its validation "
        "(docs/identification.md, Instrument time)",
    )
    p.add_argument(
        "--budget-min",
        type=float,
        help="instrument time to fit the identification into, minutes for all its axes: "
        "the protocol is shortened, one step at a time (no extra line, 64-line overviews, "
        "overviews at 1 um/s, 2 minutes of settling), until its plan fits; refused if even "
        "the shortest does not. The line searches and the virtual AFM's grating come on top; "
        "the steps after the first often give a model that fails its own validation "
        "(docs/identification.md, Instrument time)",
    )
    p.add_argument(
        "--speed-factors",
        type=float,
        nargs="+",
        metavar="F",
        help="virtual AFM: part B's ramps at these multiples of the speed in turn (default "
        "0.5 1 2 4 8: 125 nm/s to 2 um/s, the speeds the compensator is then used at; "
        "several speeds separate fast creep from narrow play, 1 alone is the paper's one "
        "speed; see docs/identification-design.md 'Three ramp speeds')",
    )
    p.add_argument(
        "--command-tolerance-nm",
        type=float,
        help="with --record: largest difference allowed between the recorded command and the "
        "waveform (default 0.001 nm; raise it to the step of a recorder that rounds)",
    )
    p.add_argument(
        "--range-nm",
        type=float,
        help="with --record: the scanner's full travel, stored in the model files (default: "
        "the range the waveform was written for, or the record's range_nm metadata); with "
        "--instrument: the travel to use, at most the controller's",
    )


def _progress(total: int, args: argparse.Namespace) -> Any:
    """A progress bar on the terminal (none when stderr is not one, or with
    ``--no-progress``)."""
    from tqdm.auto import tqdm

    quiet = bool(getattr(args, "no_progress", False)) or not sys.stderr.isatty()
    return tqdm(total=total, disable=quiet, leave=False)


def _pair(orders: dict[str, Any]) -> str:
    """``N_H x N_c`` of an orders entry of ``summary.json``."""
    return f"{orders['n_play']} x {orders['n_creep']}"


def _worst_axis(per_axis: dict[str, Any], section: str) -> dict[str, dict[str, float]]:
    """Each ``validation_*`` figure of ``rls`` and ``batch``, the largest over the axes."""
    axes = list(per_axis)
    return {
        m: {
            k: max(per_axis[a][section][m][k] for a in axes)
            for k in per_axis[axes[0]][section][m]
            if k.startswith("validation_")
        }
        for m in ("rls", "batch")
    }


def _record_options(args: argparse.Namespace) -> None:
    """With ``--record``: one axis (x unless given), and none of the virtual AFM's options."""
    if args.axis == "both":
        raise ValueError("--record holds one axis' run: use --axis x or --axis y.")
    if args.axis is None:
        args.axis = "x"
    given = [f"--{k.replace('_', '-')}" for k in VIRTUAL_ONLY if getattr(args, k) is not None]
    if given:
        raise ValueError(
            f"{', '.join(given)}: virtual AFM option(s); with --record the waveform file "
            "fixes span, speed and sample period (piezocomp waveform), and the grating "
            "records give the scale (--grating-record)."
        )


def run(args: argparse.Namespace) -> int:
    """Run the command in its output folder (removed again if it fails while empty), or
    write the configuration (``--write-config``)."""
    if args.write_config:
        cfg = config_of(args)
        write_config(
            Path(args.write_config),
            cfg,
            'piezocomp identify\'s configuration (lengths nm of command, times s; "none": '
            "None)\nrun it: piezocomp identify --config FILE --out DIR",
        )
        print(f"wrote the configuration to {args.write_config}")
        return 0
    if args.out is None:
        raise ValueError("--out is required (the output folder), unless --write-config.")
    with output_folder(args.out) as out:
        return _run(args, out)


def _virtual_afm(args: argparse.Namespace) -> tuple[VirtualAFM, str]:
    """The virtual AFM the options describe, and its name."""
    from piezocomp.virtual_afm import VirtualAFM

    if args.command_tolerance_nm is not None:
        raise ValueError("--command-tolerance-nm goes with --record.")
    if args.range_nm is not None:
        raise ValueError(
            "--range-nm goes with --record or --instrument; the virtual AFM states its own range."
        )
    seed, period = (
        VIRTUAL_AFM_DEFAULTS[k] if getattr(args, k) is None else getattr(args, k)
        for k in ("seed", "sample_period_s")
    )
    source = args.scanner if args.scanner else args.preset
    if args.scanner:
        afm = VirtualAFM.from_config(args.scanner, seed=seed, sample_period_s=period)
    else:
        afm = VirtualAFM.from_preset(args.preset, seed=seed, sample_period_s=period)
    return afm, str(source)


def _on_a_line_that_works(
    afm: VirtualAFM, cfg: Any, axis: str, name_axis: bool, quick: bool
) -> tuple[Any, list[dict[str, Any]]]:
    """One axis identified on its line, or, when that record fails (an error, or a batch
    model that fails its own validation), recorded again on lines
    :func:`~piezocomp.experiments.methods.retry_lines` across it on the slow axis,
    in turn, as a user records again elsewhere on the sample: on the same instrument, its
    clock, drift and scanner state carried on (``reproduce`` does the same on a fresh virtual
    AFM for each line). Each attempt is said on the terminal with its instrument time and
    listed (the one kept marked ``kept``); the others' time is the axis' ``instrument_s``
    stage ``lines recorded again``, beyond the plan and in its total. ``--quick``'s small
    orders usually fail the validation, so it records again only after an error. The last
    model that failed its validation is returned when no line gave a better one (written for
    inspection; the command exits 1); :class:`RunValueError` when every line failed with an
    error."""
    from piezocomp.experiments.methods import retry_lines

    lines = retry_lines(cfg, axis)
    attempts: list[dict[str, Any]] = []
    kept: Any = None
    kept_at = 0
    for k, (line, here) in enumerate(lines):
        where = f"the {line}"
        again = (
            f"; recording again on the {lines[k + 1][0]} (instrument time beyond the plan)"
            if k + 1 < len(lines)
            else ""
        )
        t0 = float(afm.time_s)
        error: ValueError | None = None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ExcitationWarning)
            try:  # the settings were checked when planned: what fails now, fails the line
                ident = identify_virtual(afm, here, axis)
            except ValueError as exc:
                error = exc
        warn(axis if name_axis else None, [str(w.message) for w in caught])
        took_s = float(afm.time_s) - t0
        took = f" ({took_s / 60:.0f} min of instrument time)"
        if error is not None:
            attempts.append({"line": where, "error": str(error), "instrument_s": took_s})
            if again:
                warn(axis if name_axis else None, [f"{where}{took}: {error}{again}"])
                continue
            if kept is not None:  # an earlier line's model, for inspection
                warn(axis if name_axis else None, [f"{where}{took}: {error}"])
                attempts[kept_at]["kept"] = True
                return kept, attempts
            first = attempts[0]["error"]
            raise RunValueError(
                f"axis {axis}: no line gave a model ({len(attempts)} tried; the first: "
                f"{first}; the last, {where}: {error})"
                if len(attempts) > 1
                else f"axis {axis}: {where}: {error}"
            ) from error
        failed = ident.validation_failures()
        attempts.append({"line": where, "validation_failures": failed, "instrument_s": took_s})
        if failed and again and not quick:
            why = "; ".join(failed)
            warn(axis if name_axis else None,
                 [f"{where}{took}: the model fails its own validation ({why}){again}"])  # fmt: skip
            kept, kept_at = ident, len(attempts) - 1
            continue
        attempts[-1]["kept"] = True
        return ident, attempts
    raise AssertionError("unreachable: the last line returns or raises")


def _run(args: argparse.Namespace, out: Path) -> int:
    if args.instrument:
        from piezocomp.commands.identify_instrument import run_instrument

        return run_instrument(args, out)
    refuse_instrument_options(args, also=("calibration_speed_nm_per_s",))
    if args.record:
        _record_options(args)
        return run_record(args, out)
    if args.grating_pitch_nm is not None and not args.grating_pitch_nm > 0:
        raise ValueError(f"--grating-pitch-nm must be > 0. Got {args.grating_pitch_nm}.")
    afm, source = _virtual_afm(args)
    axes = ("x", "y") if args.axis in (None, "both") else (args.axis,)
    # the lab's calibration record, measured before the plan that times its cycles
    plan = within_budget(afm, calibrated(afm, config_of(args)), axes, budget_seconds(args))
    cfg = plan.config
    if args.grating_record:
        raise ValueError(
            "--grating-record goes with --record or --instrument; the virtual AFM scans its "
            "own grating "
            "(--reference grating, --grating-pitch-nm)."
        )
    grating = cfg.reference.grating
    pitch = cfg.reference.grating_pitch_nm
    pitch = VIRTUAL_PITCH_NM if pitch is None else pitch
    print(f"piezocomp identify: {plan.describe()}", flush=True)
    summary: dict[str, Any] = {
        "source": str(source),
        "seed": VIRTUAL_AFM_DEFAULTS["seed"] if args.seed is None else args.seed,
        "calibration": cfg.acquisition.calibrate,
        "reference": "grating" if grating else "none",
        "axes": {},
        "settings": cfg.as_dict(),
        **plan_summary(plan, args.budget_min),
    }
    idents = {}
    t0 = time.perf_counter()
    bar = _progress(3 * len(axes), args)
    for axis in axes:
        bar.set_description(f"identify {axis}")
        ident, attempts = _on_a_line_that_works(afm, cfg, axis, len(axes) > 1, args.quick)
        bar.update()
        bar.set_description(f"validate {axis}")
        idents[axis] = ident
        summary["axes"][axis] = {**ident.summary(), **scored_summary(afm, ident, cfg)}
        summary["axes"][axis]["attempts"] = attempts
        again_s = sum(a["instrument_s"] for a in attempts if not a.get("kept"))
        if again_s > 0:  # the lines recorded and not kept are instrument time too
            stages = summary["axes"][axis]["instrument_s"]
            stages["lines recorded again"] = again_s
            stages["total"] = stages["total"] + again_s
        bar.update()
        if not args.no_figures:
            bar.set_description(f"figures {axis}")
            summary["axes"][axis]["figures"] = figures(ident, out)
        bar.update()
    bar.close()
    # Top level: the worst axis, so one number answers "how good is the model".
    summary["methods"] = _worst_axis(summary["axes"], "methods")
    if grating:
        summary["methods_without_reference"] = _worst_axis(summary["axes"], "without_reference")
    summary["orders"] = {a: summary["axes"][a]["orders"] for a in axes}
    summary["timing_s"] = {
        "identification_computing_per_axis": {
            a: summary["axes"][a]["timing_s"]["total_computing"] for a in axes
        },
        "total_wall": time.perf_counter() - t0,
    }
    summary["instrument_s"] = float(sum(summary["axes"][a]["instrument_s"]["total"] for a in axes))
    save_models(out, idents, axes, str(source), f"the virtual AFM's configuration ({source})")
    save_config(out / "config.toml", cfg, str(source))
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    meth = summary["methods"]
    rls_e, bat_e = (meth[m]["validation_max_error_nm"] for m in ("rls", "batch"))
    rls_s, bat_s = (meth[m]["validation_max_error_after_scale_nm"] for m in ("rls", "batch"))
    if grating:
        wo = summary["methods_without_reference"]
        scale_note = (
            f"scaled by a {pitch:g} nm grating; without it "
            f"{wo['rls']['validation_max_error_nm']:.2f} and "
            f"{wo['batch']['validation_max_error_nm']:.2f} nm"
        )
    else:
        scale_note = f"no length reference; after removing the scale {rls_s:.2f} and {bat_s:.2f} nm"
    ax = summary["axes"]
    orders = "; ".join(
        f"{a}: batch {_pair(ax[a]['orders'])}, RLS {_pair(ax[a]['rls_orders'])}" for a in axes
    )
    print(
        f"identified axis {','.join(axes)} of {source}: orders N_H x N_c ({orders}); "
        f"validation max error RLS {rls_e:.2f} nm, "
        f"batch {bat_e:.2f} nm ({scale_note}); wrote {out / 'model.json'} and "
        f"{out / 'summary.json'}"
    )
    for line in drift_lines(summary):
        print(line)
    print(instrument_time_line(summary))
    if args.quick:
        print(
            "--quick: a reduced record and orders, to try the command; its models are far "
            "from what the default run gives, not for positioning"
        )
    return refused(idents, quick=args.quick)
