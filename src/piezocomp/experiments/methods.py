"""The methods the experiments compare, and the models each one compensates with.

Six ways of sending the tip to a position, side by side in the same run on the same samples:

- ``uncompensated``: the position sent as the command (nominal lengths);
- ``static``: the vendor's static linearisation, a memoryless polynomial through the middle
  of the scanner's steady loop (:class:`~piezocomp.positioning.axis_compensation.StaticAxis`);
- ``pi_no_creep``: a Prandtl-Ishlinskii model without creep operators, identified without a
  sensor like the others;
- ``paper``: the paper's method as published: ``N_H = 8``, ``N_c = 2``, every parameter of
  eq (15) estimated (thresholds and creep poles included) by the RLS of Sec. III.C with its
  data-dependent gain and covariance resetting, no priors, no robust update;
- ``rls``: the package's regularised RLS (Sec. III.C with the thresholds and creep poles
  held on a fixed grid, orders 16-32 x 22, a robust update and smoothness priors);
- ``compensated``: the package's default, the batch-refined model ``piezocomp identify``
  writes (the extended family: its creep driven by the command and the hysteresis output,
  eq 2'); the RLS models (``rls``, ``paper``) are of the paper's family;
- ``oracle``: the same model family fitted to the true extension (ground truth) of one long
  record, its thresholds and creep time constants held on a grid, the creep coupling kept
  where held-out truth prefers it: a reference, not a bound (the sensorless default sees
  more of the scanner and may beat it).

Every model comes from the virtual lab's identification
(:mod:`.virtual_identification`), one axis per job, each on a fresh virtual AFM of
the same configuration and seed.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from piezocomp.drift.compensated import DriftCompensatedInstrument, DriftSettings
from piezocomp.experiments.contract import DRIFT_METHOD
from piezocomp.experiments.virtual_identification import (
    IdentifyConfig,
    fit_on_truth,
    identify_virtual,
    score_on_truth,
)
from piezocomp.identification.acquisition.instrument_time import with_total
from piezocomp.identification.config import PAPER_CREEP_START_S
from piezocomp.identification.estimation.candidates import DEFAULT_CREEP_TAU_RANGE_S
from piezocomp.identification.estimation.rls import GROUPS, RLSSettings
from piezocomp.instrument import Instrument
from piezocomp.model import ScannerModel, ScannerModel2D
from piezocomp.positioning.axis_compensation import ModelAxis, StaticAxis, working_interval
from piezocomp.positioning.compensated import CompensatedInstrument
from piezocomp.virtual_afm import AFMConfig, VirtualAFM

__all__ = [
    "DESCRIPTIONS",
    "IDENTIFICATIONS",
    "JOBS",
    "METHODS",
    "PAPER_CHANGES",
    "PAPER_CREEP_START_S",
    "RETRY_LINE_SHIFTS_NM",
    "IdentificationSettings",
    "MethodModels",
    "drift_tracked",
    "identification_failures",
    "identification_job",
    "instrument_for",
    "retry_lines",
    "trial_instrument",
    "working_half_width",
    "working_half_widths",
]

METHODS = ("uncompensated", "static", "pi_no_creep", "paper", "rls", "compensated", "oracle")
"""The methods, in the order reports list them."""

DESCRIPTIONS = {
    "uncompensated": "commands sent as they are (nominal lengths)",
    "static": "the vendor's static linearisation: a memoryless polynomial",
    "pi_no_creep": "Prandtl-Ishlinskii hysteresis without creep, identified sensorlessly",
    "paper": "the paper's method as published: N_H = 8, N_c = 2, all of eq (15) by the RLS "
    "with covariance resetting (Sec. III.C)",
    "rls": "the package's regularised RLS: thresholds and poles held, robust, smoothness priors",
    "compensated": "the package's default creep and hysteresis compensator: the batch-refined "
    "model of piezocomp identify, its creep driven by the command and the hysteresis output "
    "(eq 2')",
    "oracle": "the same model family fitted to the true extension (ground truth), thresholds "
    "and time constants held, the creep coupling where held-out truth prefers it: a "
    "reference, not a bound",
    "both": "the package's default on a drifting scanner: the default model inside the drift "
    "compensator, which re-images landmarks between moves (every other method runs without "
    "drift compensation)",
}


IDENTIFICATIONS = {
    "sensorless": (
        "the default identification",
        "compensated: its batch model, rls: its RLS, static: a polynomial through its batch model",
    ),
    "no_creep": ("pi_no_creep's identification", "pi_no_creep: its batch model"),
    "paper": ("paper's identification", "paper: its RLS model; its batch model serves no method"),
}
"""Each identification of a run (the keys of ``results.json``'s ``identification``): how
reports name it, and which of its models each method uses."""


@dataclass(frozen=True)
class IdentificationSettings:
    """How the experiments' models are identified.

    Parameters
    ----------
    span_nm : float
        Command span of the identification line; the models' domain, which sets the
        working area (a 2000 nm span covers about +-800 true nm on ``cpr5``).
    speed_nm_per_s : float
        Base ramp speed.
    speed_factors : tuple of float
        Part B's ramps at these multiples of the speed: up to 8 (2 um/s) so that the models
        cover the speeds the experiments move at.
    no_creep_orders : tuple of (int, int)
        Candidate orders of ``pi_no_creep``.
    oracle_orders : (int, int)
        Orders of ``oracle``.
    oracle_coupling : float or "fit"
        The creep coupling ``beta`` of eq (2') of ``oracle``
        (:func:`~piezocomp.experiments.virtual_identification.fit_on_truth`): ``"fit"``
        searches it and keeps the extended family only where it predicts held-out samples of
        the truth better, as the default model's family is the extended one; ``0``: the
        paper's family.
    """

    span_nm: float = 2000.0
    speed_nm_per_s: float = 250.0
    speed_factors: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0, 8.0)
    no_creep_orders: tuple[tuple[int, int], ...] = ((16, 0), (32, 0))
    oracle_orders: tuple[int, int] = (32, 22)
    oracle_coupling: float | Literal["fit"] = "fit"

    def __post_init__(self) -> None:
        c = self.oracle_coupling
        if c != "fit" and (isinstance(c, bool) or not isinstance(c, (int, float)) or not c >= 0):
            raise ValueError(f"oracle_coupling must be 'fit' or a number >= 0. Got {c!r}.")

    def config(self, range_nm: float, **changes: Any) -> IdentifyConfig:
        """The sensorless configuration (calibration cycles over the whole range,
        ``range_nm``, as ``piezocomp identify`` does by default); ``changes``: settings by
        name (:meth:`~piezocomp.identification.config.IdentifyConfig.updated`)."""
        return IdentifyConfig().updated(
            span_nm=self.span_nm,
            speed_nm_per_s=self.speed_nm_per_s,
            speed_factors=tuple(self.speed_factors),
            calibrate=float(range_nm),
            **changes,
        )


PAPER_CHANGES: dict[str, Any] = {
    "orders": ((8, 2),),
    "creep_tau_range_s": PAPER_CREEP_START_S,
    "rls_settings": RLSSettings(
        alpha="paper",
        free=GROUPS,
        k0=3000,
        passes=20,
        min_time_constant_s=DEFAULT_CREEP_TAU_RANGE_S[0],
    ),
    "rls_start": None,
    "rls_continue": None,
    "rls_reindex_rounds": 0,
    "rls_lines_passes": 0,
    "rls_final_passes": 0,
    "refine_free": ("c", "a", "w", "y0"),
}
"""The paper's method: orders 8 x 2, every group of eq (15) free (thresholds and creep poles
included), the gain of eq (20) and covariance resetting (every 3000 samples and when the
smallest eigenvalue of ``P`` falls below 1e-4), no robust update, no priors, no re-indexing
of ``h`` by the estimate; its RLS estimate is the model. It starts with creep gains 0 (the
paper's zero initial values), the poles at :data:`PAPER_CREEP_START_S` and the
Prandtl-Ishlinskii part from the loop of Section IV (the paper estimates the loop first)."""

RETRY_LINE_SHIFTS_NM = (400.0, -400.0)
"""Where the identification goes when a record fails (an error, or a default model that fails
its own validation): lines this far across the first one, on the slow axis, in turn."""


def retry_lines(config: IdentifyConfig, axis: str) -> list[tuple[str, IdentifyConfig]]:
    """The configuration's line of ``axis`` and those it is recorded again on when a record
    fails (:data:`RETRY_LINE_SHIFTS_NM` across on the slow axis), each as ``(where,
    configuration)``, ``where`` naming its place ("line at 400 nm on the slow axis")."""
    slow = 1 if axis == "x" else 0
    out = []
    for shift in (0.0, *RETRY_LINE_SHIFTS_NM):
        centre = list(config.acquisition.center_nm)
        centre[slow] += shift
        where = f"line at {centre[slow]:g} nm on the slow axis"
        out.append((where, config.updated(center_nm=(centre[0], centre[1]))))
    return out


def identification_job(
    kind: str, axis: str, config: AFMConfig, seed: int, settings: IdentificationSettings
) -> dict[str, Any]:
    """One axis' models of one kind, each on a fresh virtual AFM.

    ``kind``: ``"sensorless"`` (the batch and RLS models), ``"no_creep"`` (the batch model
    without creep) or ``"oracle"``. Returns ``{"kind", "axis", "models": {name: model},
    "summary": {...}}`` with each model's validation errors against the ground truth
    (:func:`~piezocomp.experiments.scoring.score_on_truth`).

    A sensorless identification that stops with an error, or whose batch model fails its own
    validation (:meth:`~piezocomp.identification.result.AxisIdentification.validation_failures`,
    read without ground truth), is run again on another line (:data:`RETRY_LINE_SHIFTS_NM`),
    as a user would record again. When every attempt fails, ``models`` is empty and
    ``summary["error"]`` says why: the methods of this kind are reported as failed for the
    run, never run with a model that may be wrong. ``summary["attempts"]`` lists every try.
    """
    if kind not in ("sensorless", "no_creep", "paper", "oracle"):
        raise ValueError(
            f"kind must be 'sensorless', 'no_creep', 'paper' or 'oracle'. Got {kind!r}."
        )
    t0, c0 = time.perf_counter(), time.process_time()
    summary: dict[str, Any] = {}
    models: dict[str, ScannerModel] = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if kind == "oracle":
            afm = VirtualAFM(config, seed=seed)
            cfg = settings.config(afm.range_nm)
            models = {
                "oracle": fit_on_truth(
                    afm, cfg, axis, settings.oracle_orders,
                    creep_coupling=settings.oracle_coupling,
                )
            }  # fmt: skip
        else:
            models, summary = _sensorless_with_retries(kind, axis, config, seed, settings)
    summary["warnings"] = sorted({str(w.message) for w in caught})
    summary["computing_s"] = time.perf_counter() - t0
    summary["cpu_s"] = time.process_time() - c0
    return {"kind": kind, "axis": axis, "models": models, "summary": summary}


def _sensorless_with_retries(
    kind: str, axis: str, config: AFMConfig, seed: int, settings: IdentificationSettings
) -> tuple[dict[str, ScannerModel], dict[str, Any]]:
    """The identification of ``kind`` on the first line that gives a usable model."""
    attempts: list[dict[str, Any]] = []
    changes: dict[str, Any] = {}
    if kind == "no_creep":
        changes["orders"] = settings.no_creep_orders
    elif kind == "paper":
        changes.update(PAPER_CHANGES)
    for where, cfg in retry_lines(settings.config(config.scanner.range_nm, **changes), axis):
        afm = VirtualAFM(config, seed=seed)
        try:
            ident = identify_virtual(afm, cfg, axis)
        except (ValueError, RuntimeError) as exc:
            attempts.append({"line": where, "error": str(exc)})
            continue
        # the default model is checked on its own validation; a comparison method is not
        # (without creep operators the held-out heights are poor by design)
        failed = ident.validation_failures() if kind == "sensorless" else []
        if kind == "paper" and "rls" not in (ident.reference or {}):
            failed = ["the grating could not scale the RLS estimate (its lengths are far off)"]
        attempts.append({"line": where, "validation_failures": failed})
        if failed:
            continue
        names = {"sensorless": {"compensated": ident.batch_model, "rls": ident.rls_model},
                 "no_creep": {"pi_no_creep": ident.batch_model},
                 "paper": {"paper": ident.rls_model}}  # fmt: skip
        models = names[kind]
        score = score_on_truth(
            afm,
            ident,
            models,
            span_nm=cfg.acquisition.span_nm,
            center_nm=cfg.acquisition.center_nm[0 if axis == "x" else 1],
        )
        summary: dict[str, Any] = {
            name: {k: v for k, v in score[name].items() if k.startswith("validation_")}
            for name in models
        }
        summary["orders"] = {"n_play": ident.orders.n_play, "n_creep": ident.orders.n_creep}
        summary["heldout_height_rms_nm"] = ident.heldout_rms_nm
        summary["line_drift"] = ident.line_drift
        summary["cross_drift"] = ident.cross_drift
        summary["findings"] = list(ident.findings)
        summary["attempts"] = attempts
        summary["instrument_s"] = with_total(ident.instrument_s)
        return models, summary
    last = attempts[-1]
    why = last.get("error") or "; ".join(last["validation_failures"])
    return {}, {
        "error": f"no usable model on {len(attempts)} lines (last: {why})",
        "attempts": attempts,
    }


JOBS = {"compensated": "sensorless", "rls": "sensorless", "static": "sensorless",
        "pi_no_creep": "no_creep", "paper": "paper", "oracle": "oracle"}  # fmt: skip
"""The identification job each model-based method needs (``static`` is derived from the
``compensated`` model)."""


@dataclass(frozen=True)
class MethodModels:
    """The 2-D model of each model-based method of a run (``static`` is derived from
    ``compensated``, when there is one)."""

    models: dict[str, ScannerModel2D]
    sample_period_s: float = 0.008
    static: tuple[StaticAxis, StaticAxis] | None = field(init=False)

    def __post_init__(self) -> None:
        base = self.models.get("compensated")
        static = None
        if base is not None:
            static = tuple(StaticAxis.from_model(m, self.sample_period_s) for m in (base.x, base.y))
        object.__setattr__(self, "static", static)

    @classmethod
    def from_jobs(cls, jobs: list[dict[str, Any]], sample_period_s: float) -> MethodModels:
        """Pair the axes of :func:`identification_job` results into 2-D models."""
        per: dict[str, dict[str, ScannerModel]] = {}
        for job in jobs:
            for name, model in job["models"].items():
                per.setdefault(name, {})[job["axis"]] = model
        both = {n: ScannerModel2D(m["x"], m["y"]) for n, m in per.items() if len(m) == 2}
        return cls(both, sample_period_s)


def identification_failures(methods: tuple[str, ...], jobs: list[dict[str, Any]]) -> dict[str, str]:
    """The methods whose identification gave no usable model on some axis, with why
    (``summary["error"]`` of :func:`identification_job`)."""
    out = {}
    for m in methods:
        for job in jobs:
            if m in JOBS and job["kind"] == JOBS[m] and not job["models"]:
                out[m] = f"axis {job['axis']}: {job['summary'].get('error', 'no model')}"
    return out


def instrument_for(
    method: str, afm: Instrument, models: MethodModels
) -> tuple[Instrument, tuple[float, float]]:
    """The instrument a method drives and the origin of the experiments' coordinates on it
    (the centre of the working area: the command centre 0 for ``uncompensated``).

    Compensated instruments are initialised (the paper's first large cycle) here.
    """
    if method == "uncompensated":
        return afm, (0.0, 0.0)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}. Got {method!r}.")
    if method == "static" and models.static is not None:
        comp = CompensatedInstrument(afm, models.static)
    elif method in models.models:
        comp = CompensatedInstrument(afm, models.models[method])
    else:
        raise ValueError(f"no model was identified for the method {method!r}.")
    comp.initialise()
    (x0, x1), (y0, y1) = comp.working_area_nm
    return comp, (0.5 * (x0 + x1), 0.5 * (y0 + y1))


def working_half_widths(models: MethodModels, sample_period_s: float) -> dict[str, float]:
    """Each model-based method's working half-width about its centre (the smaller of its
    two axes'), nm; ``static`` is the compensated model's linearisation."""
    out: dict[str, float] = {}
    for name, m in models.models.items():
        widths = []
        for axis in (m.x, m.y):
            lo, hi = working_interval(ModelAxis(axis), sample_period_s)
            widths.append(0.5 * (hi - lo))
        out[name] = float(min(widths))
    if models.static is not None:
        out["static"] = float(
            min(0.5 * (hi - lo) for lo, hi in (working_interval(st, sample_period_s)
                                                for st in models.static))
        )  # fmt: skip
    return out


def working_half_width(
    models: MethodModels, sample_period_s: float, leave_out: Collection[str] = ()
) -> float:
    """The largest half-width about its centre that every method's working area holds, nm
    (the methods in ``leave_out`` aside)."""
    widths = [w for m, w in working_half_widths(models, sample_period_s).items()
              if m not in leave_out]  # fmt: skip
    return float(np.min(widths)) if widths else math.inf


def drift_tracked(
    inner: Instrument, origin_nm: tuple[float, float], size_nm: float
) -> DriftCompensatedInstrument:
    """``inner`` inside the drift compensator, its landmarks chosen in an overview of
    ``size_nm`` about ``origin_nm`` (the area the experiment works in; nothing is pushed, so
    the landmarks may lie anywhere in it)."""
    tracked = DriftCompensatedInstrument(inner, DriftSettings())
    tracked.start(center_nm=origin_nm, size_nm=size_nm)
    return tracked


def trial_instrument(
    method: str, afm: Instrument, models: MethodModels, size_nm: float
) -> tuple[Instrument, tuple[float, float]]:
    """:func:`instrument_for`, or for :data:`~piezocomp.experiments.contract.DRIFT_METHOD`
    the compensated instrument inside the drift compensator, its landmarks in an overview
    of ``size_nm`` about the origin (:func:`drift_tracked`)."""
    if method != DRIFT_METHOD:
        return instrument_for(method, afm, models)
    inner, origin = instrument_for("compensated", afm, models)
    return drift_tracked(inner, origin, size_nm), origin
