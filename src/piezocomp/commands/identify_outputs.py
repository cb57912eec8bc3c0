"""What ``piezocomp identify`` writes and prints, whatever the identification ran on.

The virtual AFM (:mod:`.identify`), a recorded run (``--record``) and a real instrument
(:mod:`.identify_instrument`) share the settings the command line chose, the warnings on the
terminal, the figures, the model files and the JSON-ready summaries of a scale fit and of
the settings. Not a subcommand (no ``register``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from piezocomp.identification.acquisition.drift_across_line import unfollowed_reason
from piezocomp.identification.acquisition.instrument_time import with_total
from piezocomp.identification.config import IdentifyConfig, read_config, write_config
from piezocomp.identification.estimation.findings import DRIFT_FINDING_NM, line_drift_text
from piezocomp.identification.planning import BudgetPlan
from piezocomp.io.model_files import save_model
from piezocomp.model import ScannerModel2D

__all__ = [
    "budget_seconds",
    "config_of",
    "drift_lines",
    "drift_report",
    "figures",
    "instrument_time_line",
    "plan_summary",
    "refused",
    "save_config",
    "save_models",
    "total_instrument_time",
    "warn",
]


def total_instrument_time(idents: dict[str, Any]) -> float:
    """``summary.json``'s top-level ``instrument_s``: every axis' identification, s."""
    return float(sum(with_total(ident.instrument_s)["total"] for ident in idents.values()))


def instrument_time_line(summary: dict[str, Any]) -> str:
    """The instrument time of the identification on the console (``summary.json``'s), by
    stage, in minutes."""
    parts = []
    for name, ax in summary["axes"].items():
        stages = ", ".join(
            f"{stage} {sec / 60:.1f}" for stage, sec in ax["instrument_s"].items()
            if stage != "total"
        )  # fmt: skip
        parts.append(f"{name}: {ax['instrument_s']['total'] / 60:.0f} min ({stages})")
    return (
        f"instrument time {summary['instrument_s'] / 60:.0f} min, minutes by stage: "
        + "; ".join(parts)
    )


def budget_seconds(args: argparse.Namespace) -> float | None:
    """``--budget-min`` in seconds (``None`` without it); refused unless a positive number."""
    if args.budget_min is None:
        return None
    if not (math.isfinite(args.budget_min) and args.budget_min > 0):
        raise ValueError(
            f"--budget-min must be a positive number of minutes. Got {args.budget_min}."
        )
    return 60.0 * float(args.budget_min)


def plan_summary(plan: BudgetPlan, budget_min: float | None) -> dict[str, Any]:
    """``summary.json``'s plan: each axis' planned instrument time by stage with its total
    (``planned_instrument_s``), the budget (``budget_min``, ``None`` without one) and the
    steps taken to fit it (``budget_steps``)."""
    return {
        "planned_instrument_s": {ax: with_total(s) for ax, s in plan.seconds.items()},
        "budget_min": budget_min,
        "budget_steps": list(plan.steps),
    }


FLAG_SETTINGS = {
    "span_nm": "span_nm",
    "speed_nm_per_s": "speed_nm_per_s",
    "speed_factors": "speed_factors",
    "calibrate": "calibrate",
    "extra_lines": "extra_lines",
    "overview_speed_nm_per_s": "overview_speed_nm_per_s",
    "calibration_speed_nm_per_s": "calibration_speed_nm_per_s",
    "grating_pitch_nm": "grating_pitch_nm",
    "grating_path": "grating_path",
}
"""The command's flags that set a setting of the configuration (flag's dest -> setting)."""


def config_of(args: argparse.Namespace) -> IdentifyConfig:
    """The configuration of the run: the packaged defaults (``--quick``: the reduced ones),
    then ``--config FILE`` over them, then the flags given over both."""
    if (args.n_play is None) != (args.n_creep is None):
        raise ValueError("--n-play and --n-creep go together (fix both orders or neither).")
    base = IdentifyConfig.quick() if args.quick else IdentifyConfig()
    if getattr(args, "config", None):
        base = read_config(args.config, base)
    changes: dict[str, Any] = {
        setting: getattr(args, dest)
        for dest, setting in FLAG_SETTINGS.items()
        if getattr(args, dest, None) is not None
    }
    if "speed_factors" in changes:
        changes["speed_factors"] = tuple(changes["speed_factors"])
    if args.n_play is not None:
        changes["orders"] = ((args.n_play, args.n_creep),)
    if getattr(args, "reference", None) is not None:
        changes["grating"] = args.reference == "grating"
    return base.updated(**changes)


def save_config(path: Path, config: IdentifyConfig, source: str) -> None:
    """The configuration a run used, beside its results (``piezocomp identify --config`` on
    it, with the same source, runs it again)."""
    write_config(
        path,
        config,
        f"the configuration of piezocomp identify on {source}\n"
        "run it again: piezocomp identify --config FILE (with the same source flags)",
    )


def refused(idents: dict[str, Any], quick: bool = False) -> int:
    """The command's exit status once its files are written: 1, with one line saying why on
    stderr, when an axis' batch model fails its own validation
    (:meth:`~piezocomp.identification.result.AxisIdentification.validation_failures`, as
    :attr:`~piezocomp.identification.result.Identification.model` refuses it); else 0.
    ``quick``: the run used ``--quick``'s reduced record and orders, which the line names as
    the likely cause (its small orders usually fail the validation)."""
    why = [f"axis {a}: {w}" for a, i in idents.items() for w in i.validation_failures()]
    if not why:
        return 0
    print(
        "piezocomp identify: error: the model fails its own validation ("
        + "; ".join(why)
        + "): model.json is written for inspection, not for positioning; "
        + (
            "--quick's reduced record and orders are the likely cause: run without --quick"
            if quick
            else "the warnings above say what went wrong; record again, on another area of "
            "the sample"
        ),
        file=sys.stderr,
    )
    return 1


def warn(axis: str | None, texts: list[str]) -> None:
    """Findings on the terminal (stderr), naming the axis when there are two."""
    where = f" (axis {axis})" if axis else ""
    for text in texts:
        print(f"piezocomp identify: warning{where}: {text}", file=sys.stderr)


def figures(ident: Any, out: Path) -> list[str]:
    """The identification's figures (an :class:`AxisIdentification` or an offline
    :class:`~piezocomp.identification.offline.RecordIdentification`)."""
    from piezocomp.plotting import identification as P

    files = []
    for name, fn in (
        ("waveform", P.plot_waveform),
        ("loop", P.plot_loop),
        ("profile", P.plot_profile),
        ("rls_traces", P.plot_rls_traces),
        ("prediction_error", P.plot_prediction_error),
        ("heldout_residual", P.plot_heldout_residual),
    ):
        path = out / f"{name}_{ident.axis}.png"
        fn(ident, path)
        files.append(path.name)
    if ident.reference_record is not None:
        path = out / f"reference_{ident.axis}.png"
        P.plot_reference(ident, path)
        files.append(path.name)
    return files


def save_models(
    out: Path, idents: dict[str, Any], axes: tuple[str, ...], source: str, range_nm_from: str
) -> None:
    """``model.json`` (batch) and ``model_rls.json``: one axis' model, or both axes' as a
    2-D model, with where they came from."""
    meta = {
        "procedure": "sensorless (Mokaberi & Requicha 2008, Secs. III.C-V)",
        "source": source,
        "range_nm_from": range_nm_from,
    }
    for method, attr in (("batch", "batch_model"), ("rls", "rls_model")):
        name = "model.json" if method == "batch" else "model_rls.json"
        if len(axes) == 2:
            model: Any = ScannerModel2D(getattr(idents["x"], attr), getattr(idents["y"], attr))
        else:
            model = getattr(idents[axes[0]], attr)
        save_model(out / name, model, {**meta, "method": method, "axes": list(axes)})


def drift_report(axis: str, summary: dict[str, Any]) -> str | None:
    """One line saying the drift an axis' identification measured and what taking it out
    did (``summary``: the axis' entry of ``summary.json``); ``None`` when it measured none.

    Along the line, as the particles' slide in the command (the sign the settling rate
    has): while the tip settled and, when it was estimated with the model (``line_drift``,
    whose path ``d`` in ``h(y + d)`` moves the particles by ``-d``), during the records,
    with the held-out heights of the batch model without and with it taken out. Across the
    line: the slide over the particles' caps, and whether the record followed it with the
    slow axis."""
    line = summary.get("line") or {}
    parts = []
    ld = summary.get("line_drift")
    along = line.get("drift_nm_per_s")
    if ld:
        parts.append(line_drift_text(ld, along))
    elif along is not None and math.isfinite(along):
        parts.append(
            f"the particles slid {along:+.3f} nm/s along the line while the tip settled (not "
            f"estimated with the model: {DRIFT_FINDING_NM:g} nm or less over the record, or see "
            "the findings)"
        )
    cd = line.get("cross_drift")
    if cd:
        slide = cd.get("record_slide_nm")
        over = "" if slide is None else f"; {slide:+.1f} nm over the record"
        why = "" if cd["followed"] else unfollowed_reason(cd)
        parts.append(
            f"the particles slid {cd['rate_nm_per_s']:+.3f} nm/s across the line at the end "
            f"of the settling (drift and the slow axis' creep{over}), "
            + ("followed by the slow axis" if cd["followed"] else f"not followed ({why})")
        )
    return f"axis {axis}: drift measured: " + "; ".join(parts) if parts else None


def drift_lines(summary: dict[str, Any]) -> list[str]:
    """:func:`drift_report` of every axis of a ``summary.json`` that measured a drift."""
    lines = (drift_report(axis, s) for axis, s in summary["axes"].items())
    return [line for line in lines if line is not None]
