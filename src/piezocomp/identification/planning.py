"""The identification's instrument time before it runs: its plan, and a budget.

A user with a shared microscope needs to know, before the scanner moves, how long the identification
will keep it, and to fit it into the time they have. :func:`planned_instrument_s` adds up what the
configuration fixes of each stage of
:func:`~piezocomp.identification.acquisition.recording.record_axis` (what depends on the sample is
counted only as it happens:
:attr:`~piezocomp.identification.acquisition.recording.AxisRecords.instrument_s`).
:func:`within_budget` shortens the protocol, step by step in :data:`BUDGET_STEPS`' order, until its
plan fits a budget; each step's price in accuracy was measured with
``benchmarks/instrument_budget.py`` (docs/identification.md, "Instrument time")."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from piezocomp.identification.acquisition.line_search import OVERVIEW_SHIFTS
from piezocomp.identification.acquisition.recording import (
    axis_waveform,
    calibration_waveform,
    overview_line_rate,
)
from piezocomp.identification.config import AcquisitionConfig, IdentifyConfig
from piezocomp.instrument import Instrument

__all__ = [
    "BUDGET_STEPS",
    "RISKY_AFTER",
    "BudgetPlan",
    "check_extra_lines_fit",
    "planned_instrument_s",
    "within_budget",
]


def planned_instrument_s(
    instrument: Instrument, cfg: AcquisitionConfig, axis: str
) -> dict[str, float]:
    """The instrument time of the stages of one axis that the configuration fixes, s.

    The overview (``overview_pixels`` lines at the overview's line rate), the settling
    (whole cycles of the line lasting ``line_settle_s``), the record and its check cycles,
    the calibration cycles (unless ``calibrate='span'``) and each extra line's overview,
    settling and record. What depends on the sample is not planned: the line search (steady
    cycles of the line until it is found, typically one to a few minutes a line), the
    search and settling again when the line was lost or its record changed, overviews of
    other areas when the first holds no line, and the moves between stages.
    """
    half = 0.5 * float(instrument.range_nm)  # refused here, before anything moves
    centre = cfg.center_nm[0 if axis == "x" else 1]
    if abs(centre) + 0.5 * cfg.span_nm > half:
        raise ValueError(
            f"the working line {centre:g} +- {0.5 * cfg.span_nm:g} nm leaves the scanner's range "
            f"+-{half:g} nm: lower span_nm (--span-nm) or move center_nm."
        )
    check_extra_lines_fit(cfg, axis, float(instrument.range_nm))
    T = float(instrument.sample_period_s)
    wf = axis_waveform(cfg, instrument, axis)
    cycle_s = 2 * wf.half_cycle_samples * T
    overview = cfg.overview_pixels / overview_line_rate(cfg, instrument)
    settling = 0.0
    if cfg.line_settle_s > 0:
        settling = max(1, math.ceil(cfg.line_settle_s / cycle_s - 1e-9)) * cycle_s
    record = wf.u_nm.size * T
    out = {
        "overview": overview,
        "settling": settling,
        "record and check": record + max(cfg.check_cycles, 0) * cycle_s,
    }
    if cfg.calibration_span_nm(float(instrument.range_nm)) is not None:
        cwf, _ = calibration_waveform(cfg, instrument, axis, [])
        out["calibration cycles"] = cwf.u_nm.size * T
    out["extra lines"] = cfg.extra_lines * (overview + settling + record)
    return out


def _extra_areas_fitting(cfg: AcquisitionConfig, axis: str, range_nm: float) -> int:
    """How many of the areas the extra lines are looked for in (``extra_line_offset_nm``
    away on the slow axis, +1, -1, +2, -2, ... offsets, as
    :func:`~piezocomp.identification.acquisition.recording.record_extra_lines` tries them)
    hold an overview of the span (shifted by
    :data:`~piezocomp.identification.acquisition.line_search.OVERVIEW_SHIFTS` spans) inside the
    range."""
    half = 0.5 * range_nm
    centre = cfg.center_nm[1 if axis == "x" else 0]  # the slow axis'
    fitting = 0
    for j in range(2 * cfg.extra_lines + 2):
        d = cfg.extra_line_offset_nm * (j // 2 + 1) * (1 if j % 2 == 0 else -1)
        for shift in OVERVIEW_SHIFTS:
            lo = centre + d + shift * cfg.span_nm - 0.5 * cfg.span_nm
            if abs(lo) <= half and abs(lo + cfg.span_nm) <= half:
                fitting += 1
                break
    return fitting


def check_extra_lines_fit(cfg: AcquisitionConfig, axis: str, range_nm: float) -> None:
    """Refuse, before anything moves, a span whose extra lines cannot be recorded: each
    needs an overview of the whole span ``extra_line_offset_nm`` or more along the slow axis,
    and when none fits inside the range the identification runs on its first line alone,
    whose record the slow axis' creep after a large overview changes (``identify --span-nm
    4000`` on ``cpr5``, seed 1: no area for the extra line held an overview inside the range,
    the first line's profile changed by 5.3 nm RMS during its record, and the x axis' model
    failed its own validation, held-out heights 1.91 nm RMS against 1.5). The message names
    the largest span whose extra lines fit."""
    if cfg.extra_lines <= 0 or _extra_areas_fitting(cfg, axis, range_nm) >= cfg.extra_lines:
        return
    span = cfg.span_nm
    while span > 10.0 and _extra_areas_fitting(replace(cfg, span_nm=span), axis, range_nm) < (
        cfg.extra_lines
    ):
        span -= 10.0
    raise ValueError(
        f"span_nm = {cfg.span_nm:g} nm (--span-nm): the extra line's overview (a "
        f"{cfg.span_nm:g} nm square, {cfg.extra_line_offset_nm:g} nm or more along the slow "
        f"axis) leaves the range +-{0.5 * range_nm:g} nm, and the first line alone does not "
        "identify a large span "
        f"(the slow axis creeps across it after the overview); the largest span whose extra "
        f"line fits is {span:g} nm (or --extra-lines 0, at that risk)."
    )


BUDGET_STEPS: tuple[tuple[str, str, float], ...] = (
    ("no extra line", "extra_lines", 0),
    ("64-line overviews", "overview_pixels", 64),
    ("overviews at 1 um/s", "overview_speed_nm_per_s", 1000.0),
    ("2 minutes of settling", "line_settle_s", 120.0),
)
"""How :func:`within_budget` shortens the protocol, in turn: a description, the
:class:`~piezocomp.identification.config.AcquisitionConfig` field and its value (a step never
lengthens what the configuration already has shorter). The order is that of how often each
step alone left the identification refusing its own model (held-out heights), measured with
``benchmarks/instrument_budget.py`` on design seeds of ``cpr5``: never without the extra line
(whose models were worse on the ground truth, but usable), more often the smaller overviews,
the faster ones and the shorter settling, in that order (docs/identification.md, "Instrument
time")."""

RISKY_AFTER = 1
"""The steps of :data:`BUDGET_STEPS` beyond this many made the identification refuse its own
model on several design seeds (a refused model is recorded again, which costs more time
than the step saved): :meth:`BudgetPlan.describe` says so when they are taken."""


@dataclass(frozen=True)
class BudgetPlan:
    """A protocol and its planned instrument time.

    Attributes
    ----------
    config : IdentifyConfig
        The configuration to run.
    seconds : dict of str to dict
        Each axis' :func:`planned_instrument_s`.
    steps : tuple of str
        The :data:`BUDGET_STEPS` taken (none when the configuration fitted as it was).
    """

    config: IdentifyConfig
    seconds: dict[str, dict[str, float]]
    steps: tuple[str, ...] = ()

    @property
    def total_s(self) -> float:
        """The planned instrument time of every axis together, s."""
        return float(sum(sum(s.values()) for s in self.seconds.values()))

    def describe(self) -> str:
        """One line: the planned minutes and the steps taken."""
        taken = f" ({', '.join(self.steps)})" if self.steps else ""
        risky = ""
        if len(self.steps) > RISKY_AFTER:
            risky = (
                "; a protocol this short often gives a model that fails its own validation "
                "and must be recorded again (docs/identification.md, Instrument time)"
            )
        return (
            f"planned instrument time {self.total_s / 60:.0f} min{taken}; the line searches, "
            "a grating scanned in the run and what the sample asks for come on top"
            f"{risky}"
        )


def _shortened(cfg: IdentifyConfig, field: str, value: float) -> IdentifyConfig:
    acq = cfg.acquisition
    now = getattr(acq, field)
    changes: dict[str, Any]
    if field == "overview_speed_nm_per_s":  # faster is shorter (None: the waveform's speed)
        now = acq.speed_nm_per_s if now is None else now
        changes = {field: max(float(now), value)}
    else:
        changes = {field: type(now)(min(now, value))}
    return replace(cfg, acquisition=replace(acq, **changes))


def within_budget(
    instrument: Instrument,
    cfg: IdentifyConfig,
    axes: tuple[str, ...],
    budget_s: float | None = None,
) -> BudgetPlan:
    """The protocol of ``cfg`` shortened by :data:`BUDGET_STEPS`, in turn, until the plan of
    ``axes`` fits ``budget_s`` (``None``: ``cfg`` as it is, with its plan).

    Raises
    ------
    ValueError
        If even the shortest protocol's plan exceeds the budget (naming both), or the budget
        is not a positive number.
    """
    seconds = {ax: planned_instrument_s(instrument, cfg.acquisition, ax) for ax in axes}
    plan = BudgetPlan(cfg, seconds)
    if budget_s is None:
        return plan
    if not (isinstance(budget_s, int | float) and math.isfinite(budget_s) and budget_s > 0):
        raise ValueError(f"budget_s must be a positive number of seconds. Got {budget_s!r}.")
    steps: list[str] = []
    for name, field, value in BUDGET_STEPS:
        if plan.total_s <= budget_s:
            return plan
        shorter = _shortened(plan.config, field, value)
        seconds = {ax: planned_instrument_s(instrument, shorter.acquisition, ax) for ax in axes}
        if sum(sum(s.values()) for s in seconds.values()) >= plan.total_s:
            continue  # the step saves nothing here (already as short, or the speed limit)
        steps.append(name)
        plan = BudgetPlan(shorter, seconds, tuple(steps))
    if plan.total_s <= budget_s:
        return plan
    taken = f" ({', '.join(plan.steps)})" if plan.steps else ""
    raise ValueError(
        f"a budget of {budget_s / 60:g} min is below the shortest protocol's planned "
        f"{plan.total_s / 60:.0f} min for {len(axes)} axis(es){taken}; "
        "give at least that, or a smaller span or fewer axes."
    )
