"""``piezocomp fit``: identify the scanner model (14) from a sensor record ``(t, u, y)``."""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm.auto import tqdm

from piezocomp._atomic import atomic_write_text, check_outputs
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import read_uniform_series, record_range, uniform_sample_period
from piezocomp.identification.acquisition.diagnostics import ExcitationWarning
from piezocomp.io.model_files import save_model
from piezocomp.sensor.fit import (
    ASYMMETRY_TOLERANCE,
    DEAD_ZONES,
    DEFAULT_MIN_TIME_CONSTANT_S,
    REFERENCE_ORDERS,
    SensorFit,
    fit_sensor,
)
from piezocomp.sensor.orders import select_sensor_orders
from piezocomp.sensor.record import ErrorFigures, split_record

NAME = "fit"


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        NAME,
        help=COMMANDS[NAME][1],
        description=(
            "Fit the creep + Prandtl-Ishlinskii model (Mokaberi & Requicha eq 14) to a record "
            "of command u and sensor-measured extension y (CSV with a header, or NPZ with one "
            "array per column; uniform sampling): non-negative least squares with placed "
            "thresholds and time constants, then bounded nonlinear least squares, beside a "
            "reference of many placed operators, and with Kuhnen's one-sided dead zones "
            "added where the loop is asymmetric. The end of the record is held out for "
            "validation, and chooses among these."
        ),
    )
    p.add_argument("--input", required=True, help="record (.csv with header, or .npz)")
    p.add_argument("--output", required=True, help="model file to write (JSON)")
    p.add_argument("--time-column", default="t_s", help="time column, s (default t_s)")
    p.add_argument("--input-column", default="u_nm", help="command column, nm (default u_nm)")
    p.add_argument(
        "--output-column", default="y_nm", help="measured extension column, nm (default y_nm)"
    )
    p.add_argument("--n-play", type=int, help="number of play operators N_H (default 8)")
    p.add_argument("--n-creep", type=int, help="number of creep operators N_c (default 2)")
    p.add_argument(
        "--select-orders",
        action="store_true",
        help="choose N_H and N_c by held-out error within the fitted part",
    )
    p.add_argument(
        "--validation-fraction",
        type=float,
        default=0.25,
        help="fraction of the record, at its end, held out (default 0.25)",
    )
    p.add_argument(
        "--warmup-samples",
        type=int,
        default=0,
        help="first samples left out of the fit and the errors (unknown initial state)",
    )
    p.add_argument(
        "--initial-state",
        choices=("auto", "rest", "zero", "estimate"),
        default="auto",
        help="state before the first sample: held at the first command (rest), reset at "
        "zero command (zero), held at a command found from the record (estimate: for a "
        "record that starts after the scanner rested elsewhere), or the one of these the "
        "held-out part prefers (auto, default)",
    )
    p.add_argument(
        "--min-time-constant-s",
        type=float,
        default=DEFAULT_MIN_TIME_CONSTANT_S,
        help=f"shortest creep time constant, s (default {DEFAULT_MIN_TIME_CONSTANT_S:g}); "
        "faster operators would model the scanner's dynamics, not creep",
    )
    p.add_argument("--no-refine", action="store_true", help="skip the nonlinear refinement")
    p.add_argument(
        "--no-reference", action="store_true",
        help="do not fit the reference (the same family by plain NNLS, 16 plays x 19 creep "
        "operators), so the model written has the orders given or selected",
    )  # fmt: skip
    p.add_argument(
        "--creep-coupling", type=_coupling, default=0.0, metavar="BETA|fit",
        help="creep coupling beta of eq (2'): 0 (default) the paper's model; 'fit' searches "
        "it (the refinement with it) and keeps it only if better on the held-out part; a "
        "number > 0 holds it in both stages",
    )  # fmt: skip
    p.add_argument(
        "--dead-zones", type=int, default=DEAD_ZONES, metavar="N",
        help=f"one-sided dead zones of the asymmetric candidate (Kuhnen's modified PI, eq 8'; "
        f"even, default {DEAD_ZONES}): added to the best symmetric model and kept only if it "
        f"predicts the held-out part more than {100 * ASYMMETRY_TOLERANCE:g} %% better; 0: "
        "symmetric models only",
    )  # fmt: skip
    p.add_argument("--figures", help="folder to write fit.png into (created if missing)")
    p.add_argument(
        "--range-nm", type=float,
        help="the scanner's full travel, stored in the model file (commands in +-range/2); "
        "default: the record's 'range_nm' metadata, or that of its waveform",
    )  # fmt: skip
    p.add_argument("--summary", help="JSON file to write the figures into")
    p.set_defaults(func=run)


def _coupling(text: str) -> float | str:
    """``--creep-coupling``: ``fit`` or a finite number >= 0."""
    if text == "fit":
        return "fit"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be 'fit' or a number >= 0. Got {text!r}.") from None
    if not np.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be 'fit' or a number >= 0. Got {text!r}.")
    return value


def _read_npz(
    path: Path, time_column: str, input_column: str, output_column: str
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    try:
        with np.load(path, allow_pickle=False) as data:
            cols = {}
            for name in (time_column, input_column, output_column):
                if name not in data.files:
                    raise ValueError(f"{path}: no column {name!r}; the file has {data.files}.")
                a = np.asarray(data[name], dtype=float)
                if a.ndim != 1:
                    raise ValueError(f"{path}: column {name!r} must be 1-D. Got {a.shape}.")
                cols[name] = a
    except (zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({exc}).") from None
    t, u, y = cols[time_column], cols[input_column], cols[output_column]
    if not (t.size == u.size == y.size):
        raise ValueError(
            f"{path}: columns must have the same length. Got {t.size}, {u.size}, {y.size}."
        )
    for name, a in cols.items():
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise ValueError(f"{path}: column {name!r} holds {a[bad[0]]} at row {bad[0]}.")
    return t, u, y, uniform_sample_period(path, t, time_column)


def read_record(
    path: str, time_column: str, input_column: str, output_column: str
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    """``(t, u, y, T)`` from a CSV (header) or NPZ record; errors name the file and the fault."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: no such file.")
    suffix = p.suffix.lower()
    if suffix == ".npz":
        return _read_npz(p, time_column, input_column, output_column)
    if suffix != ".csv":
        raise ValueError(f"{p}: unsupported record type {suffix!r}; use .csv or .npz.")
    t, u, T = read_uniform_series(p, time_column, input_column)
    _, y, _ = read_uniform_series(p, time_column, output_column)
    return t, u, y, T


def _line(name: str, e: ErrorFigures | None) -> str:
    if e is None:
        return f"  {name:<11} (nothing held out)"
    return (
        f"  {name:<11} rms {e.rms_nm:.4g} nm ({e.rms_percent_of_range:.3g} % of range), "
        f"max {e.max_nm:.4g} nm, {e.n_samples} samples"
    )


_BASE_NAMES = {"linear": "NNLS", "refined": "refined", "reference": "reference"}


def _choice(fit: SensorFit) -> str:
    """Which model was written, and by how much it beat the others on the held-out part."""
    lin, ref = fit.nnls_validation_errors, fit.refined_validation_errors
    if fit.chosen == "asymmetric" and fit.asymmetry is not None:
        asym = fit.asymmetry
        base = 100.0 * asym.base_validation_rms_nm / fit.output_range_nm
        return (
            f"the {_BASE_NAMES[asym.base]} model with {asym.model.n_dead_zones} dead zones of "
            f"eq (8') (Kuhnen's modified PI: an asymmetric loop), which predicted the held-out "
            f"part better than the symmetric one (rms "
            f"{asym.validation_errors.rms_percent_of_range:.3g} % of range against {base:.3g} %)"
        )
    if fit.chosen == "reference" and fit.reference is not None:
        best = fit.reference.validation_errors
        # the model it displaced: the refined one unless the NNLS model had beaten it
        refined_won = ref is not None and lin is not None and ref.rms_nm <= lin.rms_nm
        other = ref if fit.refinement is not None and refined_won else lin
        assert best is not None and other is not None
        return (
            f"the reference fit (N_H={fit.model.n_play}, N_c={fit.model.n_creep}, plain "
            f"non-negative least squares): it predicted the held-out part better than the "
            f"{'refined' if other is ref else 'NNLS'} model (rms "
            f"{best.rms_percent_of_range:.3g} % of range against "
            f"{other.rms_percent_of_range:.3g} %)"
        )
    if fit.refinement is None:
        return "the NNLS model (--no-refine)"
    if lin is None or ref is None:
        return "the refined model (nothing held out to compare it with the NNLS model)"
    a, b = lin.rms_percent_of_range, ref.rms_percent_of_range
    if fit.chosen == "refined":
        against = ""
        if fit.reference is not None and fit.reference.validation_errors is not None:
            c = fit.reference.validation_errors.rms_percent_of_range
            against = f" and the reference's ({c:.3g} %)"
        return (
            f"the refined model, better on the held-out part than the NNLS model "
            f"(rms {b:.3g} % of range against {a:.3g} %){against}"
        )
    return (
        f"the NNLS model: the refinement predicted the held-out part worse "
        f"(rms {b:.3g} % of range against {a:.3g} %), so it was not kept"
    )


def _summary(
    args: argparse.Namespace,
    fit: SensorFit,
    T: float,
    n_samples: int,
    range_nm: float | None,
    range_from: str,
    figures: list[str],
) -> dict[str, Any]:
    """``summary.json`` (and the model file's metadata): the record, the choices, the fit."""
    return {
        "data_file": str(args.input),
        "columns": {
            "time": args.time_column,
            "input": args.input_column,
            "output": args.output_column,
        },
        "sample_period_s": T,
        "n_samples": n_samples,
        "orders_selected": bool(args.select_orders),
        "validation_fraction": args.validation_fraction,
        "min_time_constant_s": args.min_time_constant_s,
        "range_nm": range_nm,
        "range_nm_from": range_from if range_nm is not None else None,
        "figures": figures,
        **fit.summary(),
    }


def run(args: argparse.Namespace) -> int:
    if args.select_orders and (args.n_play is not None or args.n_creep is not None):
        raise ValueError("give either --n-play/--n-creep or --select-orders, not both.")
    for name in ("n_play", "n_creep"):
        v = getattr(args, name)
        if v is not None and v < 0:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 0. Got {v}.")
    f = args.validation_fraction
    if not (math.isfinite(f) and 0 <= f < 1):
        raise ValueError(f"--validation-fraction must be in [0, 1). Got {f}.")
    if args.warmup_samples < 0:
        raise ValueError(f"--warmup-samples must be >= 0. Got {args.warmup_samples}.")
    if args.dead_zones < 0 or args.dead_zones % 2:
        raise ValueError(
            f"--dead-zones must be an even number >= 0 (pairs about the loop's centre). "
            f"Got {args.dead_zones}."
        )
    if args.range_nm is not None and not (math.isfinite(args.range_nm) and args.range_nm > 0):
        raise ValueError(f"--range-nm must be a finite number > 0. Got {args.range_nm}.")
    fig_path = None if args.figures is None else Path(args.figures) / "fit.png"
    check_outputs(args.output, args.summary, fig_path)  # before the fit, not after
    _, u, y, T = read_record(args.input, args.time_column, args.input_column, args.output_column)
    range_nm, range_from = args.range_nm, "--range-nm"
    if range_nm is None:
        range_nm, range_from = record_range(args.input)
    if range_nm is not None and np.max(np.abs(u)) > range_nm / 2:
        raise ValueError(
            f"{args.input}: commands reach {np.max(np.abs(u)):.6g} nm, outside the range "
            f"{range_nm:g} nm ({range_from}; +-{range_nm / 2:g} nm)."
        )
    bar = tqdm(total=3, disable=not sys.stderr.isatty(), leave=False)
    bar.set_description("fit: orders" if args.select_orders else "fit")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ExcitationWarning)
        table = None
        if args.select_orders:
            n_fit = split_record(u.size, args.validation_fraction, None, args.warmup_samples)
            sel = select_sensor_orders(
                u[:n_fit],
                y[:n_fit],
                T,
                warmup_samples=args.warmup_samples,
                initial_state=args.initial_state,
                min_time_constant_s=args.min_time_constant_s,
            )
            n_play, n_creep, table = sel.n_play, sel.n_creep, sel.table()
            caught.clear()  # candidates' own warnings; the final fit re-checks its orders
            bar.update()
            bar.set_description(f"fit: N_H={n_play}, N_c={n_creep}")
        else:
            n_play = 8 if args.n_play is None else args.n_play
            n_creep = 2 if args.n_creep is None else args.n_creep
        fit: SensorFit = fit_sensor(
            u,
            y,
            T,
            n_play=n_play,
            n_creep=n_creep,
            validation_fraction=args.validation_fraction,
            warmup_samples=args.warmup_samples,
            initial_state=args.initial_state,
            refine=not args.no_refine,
            min_time_constant_s=args.min_time_constant_s,
            creep_coupling=args.creep_coupling,
            reference_orders=None if args.no_reference else REFERENCE_ORDERS,
            n_dead_zones=args.dead_zones,
        )
    bar.update()
    bar.close()
    # where the model was informed, and the scanner it describes
    fit = replace(
        fit, model=replace(fit.model, domain_nm=(float(u.min()), float(u.max())),
                           range_nm=range_nm)
    )  # fmt: skip
    for w in caught:
        if issubclass(w.category, ExcitationWarning):
            print(f"piezocomp {NAME}: warning: {w.message}", file=sys.stderr)
        else:  # pragma: no cover - anything else goes back to the warnings machinery
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    figures: list[str] = []
    if fig_path is not None:
        from piezocomp.plotting.fit import plot_sensor_fit

        plot_sensor_fit(fit, u, y, T, fig_path, title=f"piezocomp fit: {Path(args.input).name}")
        figures.append(str(fig_path))
    summary = _summary(args, fit, T, u.size, range_nm, range_from, figures)
    if table is not None:
        summary["order_trials"] = table
    save_model(args.output, fit.model, metadata={"identified_by": "piezocomp fit", **summary})
    if args.summary is not None:
        atomic_write_text(args.summary, json.dumps(summary, indent=2, allow_nan=False) + "\n")
    how = "selected" if args.select_orders else "given"
    if not args.select_orders and args.n_play is None and args.n_creep is None:
        how = "by default"
    asym = fit.asymmetry
    on_reference = fit.chosen == "asymmetric" and asym is not None and asym.base == "reference"
    if fit.chosen == "reference" or on_reference:
        how = f"the reference's; N_H={n_play}, N_c={n_creep} {how}"
    zones = f", {fit.model.n_dead_zones} dead zones" if fit.model.n_dead_zones else ""
    print(
        f"model N_H={fit.model.n_play}, N_c={fit.model.n_creep}{zones} ({how}) written to "
        f"{args.output}: {_choice(fit)}"
    )
    if fit.initial_state == "estimate" or fit.state_scores is not None:
        text = f"  initial state: {fit.initial_state}"
        if fit.initial_state == "estimate" and fit.rest_command_nm is not None:
            text += (
                f", held at {fit.rest_command_nm:.6g} nm before the record (found from the "
                f"fitted part; the record starts at {u[0]:.6g} nm)"
            )
        if fit.state_scores is not None:
            scores = ", ".join(f"{k} {v:.4g} nm" for k, v in fit.state_scores.items())
            part = "held-out" if fit.validation_errors is not None else "fitted part's"
            text += f"; chosen by the NNLS fits' {part} rms: {scores}"
        print(text)
    if fit.coupling is not None:
        c = fit.coupling
        if c.best_coupling == 0.0:
            print(
                "  creep coupling: the search found beta = 0 best on the fitted part: the "
                f"paper's family kept (the model written: beta = {fit.model.creep_coupling:.3g})"
            )
        else:
            print(
                f"  creep coupling: search found beta = {c.best_coupling:.3g}; the NNLS "
                f"model's held-out rms {c.validation_rms_nm[1]:.4g} nm against "
                f"{c.validation_rms_nm[0]:.4g} nm with beta = 0: the {c.family} family kept "
                f"(beta = {c.coupling:.3g}; the model written: beta = "
                f"{fit.model.creep_coupling:.3g})"
            )
    print(_line("NNLS fit", fit.nnls_fit_errors))
    print(_line("NNLS val", fit.nnls_validation_errors))
    if fit.refinement is not None:
        print(_line("refined fit", fit.refined_fit_errors))
        print(_line("refined val", fit.refined_validation_errors))
    if fit.reference is not None:
        m = fit.reference.model
        print(f"  reference: the same family by plain NNLS, N_H={m.n_play}, N_c={m.n_creep}")
        print(_line("ref. fit", fit.reference.fit_errors))
        print(_line("ref. val", fit.reference.validation_errors))
    if asym is not None:
        verdict = (
            "kept"
            if asym.kept
            else f"not kept: not {100 * ASYMMETRY_TOLERANCE:g} % better on the held-out part"
        )
        print(
            f"  asymmetry: {asym.model.n_dead_zones} dead zones of eq (8') on the "
            f"{_BASE_NAMES[asym.base]} model ({verdict})"
        )
        print(_line("asym. fit", asym.fit_errors))
        print(_line("asym. val", asym.validation_errors))
    if fit.asymmetry_note is not None:
        print(f"  asymmetry: {fit.asymmetry_note}")
    for path in figures:
        print(f"figure written to {path}")
    if range_nm is None:
        print(
            f"piezocomp {NAME}: warning: the model states no range_nm (the scanner's full "
            "travel): give --range-nm, or compensate will ask for it",
            file=sys.stderr,
        )
    return 0
