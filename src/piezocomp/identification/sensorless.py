"""Sensorless identification of one scanner axis: the pipeline, from records to models.

The AFM is its own position sensor (Mokaberi & Requicha 2008, Secs. III.C-V). The stages:

1. acquisition (:func:`~piezocomp.identification.acquisition.recording.record_axis`): overview, line
   choice, settling, the record of the waveform of Fig. 7a, calibration cycles and further
   lines; or a run recorded with an instrument's own software
   (:func:`~piezocomp.identification.offline.records_from_signal`);
2. the loop and the profile (Section IV, eqs 21-23): the steady cycles of part A give the
   symmetric loop ``f_a`` and the height profile ``h(y)``
   (:func:`~piezocomp.identification.loop.fit.estimate_loop`);
3. estimation (Section III.C): the RLS of eqs (16)-(20) and the batch refinement of the same
   height prediction error, for every candidate order, the orders chosen on a held-out part
   of the record, over every line
   (:class:`~piezocomp.identification.estimation.problem.EstimationProblem`), then again with
   the drift along the lines taken out
   (:func:`~piezocomp.identification.estimation.drift_rounds.drift_rounds`);
4. the reference: the models mapped onto the calibration frame
   (:class:`~piezocomp.identification.reference.frames.CalibrationFrame`) and scaled by a
   grating of known pitch (:func:`~piezocomp.identification.reference.scaling.scale_fits`);
5. the result, :class:`AxisIdentification`, with the findings a user should read.

:func:`identify_axis` runs stage 1 on an instrument and :func:`estimate_axis` the rest;
scoring against a virtual AFM's ground truth is separate
(:func:`~piezocomp.experiments.scoring.score_on_truth`).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from piezocomp.identification.acquisition.diagnostics import ExcitationWarning, check_excitation
from piezocomp.identification.acquisition.recording import (
    CHECK_TOLERANCE_NM,
    AxisRecords,
    record_axis,
)
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.estimation.chain import Estimation
from piezocomp.identification.estimation.drift_rounds import DriftRounds, drift_rounds
from piezocomp.identification.estimation.findings import (
    batch_astray,
    batch_restart_notes,
    drift_during_record,
    poor_fit,
    rls_astray,
)
from piezocomp.identification.estimation.problem import EstimationProblem
from piezocomp.identification.loop.fit import estimate_loop
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.reference.frames import CalibrationFrame, FrameMap, mapped
from piezocomp.identification.reference.grating import GratingRecord
from piezocomp.identification.reference.scaling import ScaleFit, referenced_map, scale_fits
from piezocomp.identification.result import AxisIdentification, Identification
from piezocomp.instrument import Instrument
from piezocomp.model import ScannerModel

__all__ = [
    "check_fits",
    "estimate_axis",
    "estimation_findings",
    "identify",
    "identify_axis",
]


def identify_axis(
    instrument: Instrument,
    config: IdentifyConfig | None = None,
    axis: str = "x",
    *,
    reference: GratingRecord | None = None,
) -> AxisIdentification:
    """Identify the model of one axis with the AFM as its own sensor (Sections III.C-V):
    the acquisition on ``instrument`` (:func:`record_axis`), then :func:`estimate_axis`.

    Parameters
    ----------
    instrument : Instrument
        Any instrument (virtual or real); only its public interface is used.
    config : IdentifyConfig, optional
        Default: the defaults of ``piezocomp identify``.
    axis : {"x", "y"}
    reference : GratingRecord, optional
        Steady cycles over a grating of known pitch on this axis, over the working span at the
        identification speed (:func:`~piezocomp.identification.reference.grating.measure_grating`):
        the length reference that fixes the scale particles cannot see.
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y'. Got {axis!r}.")
    check_reference(reference, axis)
    cfg = IdentifyConfig() if config is None else config
    check_fits(cfg, axis, float(instrument.range_nm))
    records = record_axis(instrument, cfg.acquisition, axis, loop_degree=cfg.loop.degree)
    return estimate_axis(records, cfg, reference=reference)


def identify(
    instrument: Instrument,
    config: IdentifyConfig | None = None,
    axes: Sequence[str] = ("x", "y"),
    *,
    references: dict[str, GratingRecord] | None = None,
) -> Identification:
    """Identify the scanner of ``instrument`` with no position sensor, axis by axis
    (:func:`identify_axis`); ``.model`` is the model to compensate with.

    Parameters
    ----------
    instrument : Instrument
        Any instrument (virtual or real); only its public interface is used.
    config : IdentifyConfig, optional
        Default: the defaults of ``piezocomp identify``.
    axes : sequence of {"x", "y"}
        The axes to identify, in this order.
    references : dict of str to GratingRecord, optional
        A grating record by axis (the length reference; see :func:`identify_axis`).
    """
    axes = tuple(axes)
    if not axes or len(set(axes)) != len(axes) or set(axes) - {"x", "y"}:
        raise ValueError(f"axes must be 'x' and/or 'y', each once. Got {list(axes)!r}.")
    refs = {} if references is None else dict(references)
    if set(refs) - set(axes):
        raise ValueError(
            f"references are given for axes {sorted(set(refs) - set(axes))!r} not identified."
        )
    cfg = IdentifyConfig() if config is None else config
    for axis in axes:  # every axis checked before the scanner moves
        check_reference(refs.get(axis), axis)
        check_fits(cfg, axis, float(instrument.range_nm))
    return Identification(
        {a: identify_axis(instrument, cfg, a, reference=refs.get(a)) for a in axes}
    )


def check_reference(reference: GratingRecord | None, axis: str) -> None:
    """Refuse a grating record that is not one, or is of the other axis."""
    if reference is not None and not isinstance(reference, GratingRecord):
        raise TypeError(f"reference must be a GratingRecord. Got {type(reference).__name__}.")
    if reference is not None and reference.axis != axis:
        raise ValueError(
            f"the grating record is of axis {reference.axis!r}; it cannot scale axis {axis!r}."
        )


def estimate_axis(
    records: AxisRecords,
    config: IdentifyConfig,
    *,
    reference: GratingRecord | None = None,
) -> AxisIdentification:
    """Stages 2-5 on the records of one axis, from a driven instrument or a recorded run.

    The loop and ``h(y)`` from part A (with the line search's pairs); the calibration frame
    (the calibration cycles' loop, if any); the estimation of every candidate order and the
    choice by held-out heights (with the further lines' records), and again with the drift
    along the lines taken out; each model's map onto the calibration frame; the grating's
    scale; the findings.
    """
    timing = dict(records.timing_s)
    t0 = time.perf_counter()
    acq = config.acquisition
    loop = estimate_loop(
        records.u_nm, records.height_nm, records.waveform, degree=config.loop.degree,
        min_prominence_nm=acq.min_prominence_nm, extra_peaks=records.search_pairs,
    )  # fmt: skip
    notes = list(records.notes)
    stability = records.line_stability
    if stability is not None and (text := stability.finding(CHECK_TOLERANCE_NM)):
        notes.append(text)
    frame = CalibrationFrame.from_records(records, loop, span_nm=acq.span_nm,
                                          min_prominence_nm=acq.min_prominence_nm,
                                          notes=notes)  # fmt: skip
    timing["loop"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    problem = EstimationProblem.from_records(records, loop, config.estimation, config.rounds)
    est = problem.estimate()
    drift = drift_rounds(problem, est)
    if drift.kept and drift.estimation is not None:
        est = drift.estimation
    notes += estimation_findings(records, est, drift, config.acquisition.waveform.reduced)
    working = {
        "rls": (est.rls.model, est.rls_profile),
        "batch": (est.batch_model, est.batch_profile),
    }
    shift0 = drift.shifts[0] if drift.kept else None
    maps = frame.model_maps(records, working, problem.creep_start_nm, shift0, notes)
    timing["estimation"] = time.perf_counter() - t1
    fits = unreferenced = None
    if reference is None:
        condition = "the working span's" if frame.calibration is None else "the calibration cycles'"
        notes.append(
            f"no length reference: the models' scale is {condition} calibration condition "
            "(Section IV), which the held-out heights cannot check; it is typically a few "
            "per cent off (nanometres at the ends of a micrometre span). Scan a grating of "
            "known pitch with the same scanner to fix it"
        )
    else:
        t2 = time.perf_counter()
        fits, unreferenced = _scaled(
            records, reference, working, maps, dict(est.heldout_rms_nm), notes
        )
        timing["reference"] = time.perf_counter() - t2
    # The creep spectrum is fixed by design up to time constants far beyond any record
    # (config.estimation.creep_tau_range_s, see docs/identification-design.md): that its
    # slowest modes outlast the record is expected on every run and asks nothing of the user,
    # so only the play operators' excitation is checked here.
    n_fit = int(problem.fit_mask.sum())
    findings = notes + list(
        check_excitation(records.u_nm[:n_fit], records.sample_period_s,
                         est.batch_model.thresholds_nm, np.empty(0))
    )  # fmt: skip
    for text in findings:
        warnings.warn(text, ExcitationWarning, stacklevel=2)
    parts = ("acquisition_setup", "loop", "estimation", "extra_lines", "reference")
    timing["total_computing"] = sum(timing.get(k, 0.0) for k in parts)
    # where the models hold: the waveform's commands, within the scanner's travel
    validity: dict[str, Any] = {"domain_nm": records.waveform.domain_nm}
    if records.range_nm is not None:
        validity["range_nm"] = records.range_nm
    models = {m: replace(mapped(working[m][0], *maps[m]), **validity) for m in ("rls", "batch")}
    return AxisIdentification(
        records=records, loop=loop, calibration=frame.calibration, estimation=est,
        fit_mask=problem.fit_mask, creep_start_nm=problem.creep_start_nm, frame_maps=maps,
        models=models, reference=fits, unreferenced_models=unreferenced,
        reference_record=reference, rls_on_lines=est.rls_on_lines,
        final_fit=config.rounds.final_fit, findings=tuple(findings), timing_s=timing,
        line_drift=drift.summary(),
    )  # fmt: skip


def estimation_findings(
    records: AxisRecords, est: Estimation, drift: DriftRounds, reduced: bool
) -> list[str]:
    """What a user should read about the estimation: a batch chain run again, estimates
    astray or fitting poorly, drift during the record (``reduced``: the waveform was cut to
    the paper's shorter protocol)."""
    scores = dict(est.heldout_rms_nm)
    notes = [*batch_restart_notes(est), *rls_astray(scores), *batch_astray(scores)]
    notes += poor_fit(scores, (est.batch_model.n_play, est.batch_model.n_creep))
    notes += drift_during_record(
        records.drift_nm_per_s, records.u_nm.size * records.sample_period_s, drift.summary(),
        n_creep=est.batch_model.n_creep, reduced=reduced,
    )  # fmt: skip
    return notes


def _scaled(
    records: AxisRecords,
    reference: GratingRecord,
    working: dict[str, tuple[ScannerModel, HeightProfile]],
    maps: dict[str, FrameMap],
    scores: dict[str, float],
    notes: list[str],
) -> tuple[dict[str, ScaleFit], dict[str, ScannerModel]]:
    """The grating's scale of each model (:func:`scale_fits`), ``maps`` updated to it about
    the working line's centre; returns the fits and the models as they were before."""
    models = {m: working[m][0] for m in ("rls", "batch")}
    fits = scale_fits(models, reference, scores, notes, prescale={m: maps[m][0] for m in maps})
    unreferenced = {m: mapped(models[m], *maps[m]) for m in ("rls", "batch")}
    centre = records.center_nm
    for m in fits:
        maps[m] = referenced_map(fits[m].alpha, maps[m], centre)
    covered = max(float(np.ptp(reference.u_nm[a:b])) for a, b in reference.passes)
    span = records.waveform.u_max_nm - records.waveform.u_min_nm
    middle = float(np.mean([np.mean(reference.u_nm[a:b]) for a, b in reference.passes]))
    if covered < 0.95 * span or abs(middle - centre) > 0.05 * span:
        notes.append(
            f"the grating passes cover {covered:.0f} nm of command about {middle:.0f} nm, "
            f"not the working span of {span:.0f} nm about {centre:.0f} nm: the scale is "
            "carried over from elsewhere in the range"
        )
    return fits, unreferenced


def check_fits(cfg: IdentifyConfig, axis: str, range_nm: float) -> None:
    """Refuse, before anything moves, a working line or calibration cycles that leave the
    scanner's range."""
    half = 0.5 * range_nm
    centre = cfg.acquisition.center_nm[0 if axis == "x" else 1]
    if abs(centre) + 0.5 * cfg.acquisition.span_nm > half:
        raise ValueError(
            f"the working line {centre:g} +- {0.5 * cfg.acquisition.span_nm:g} nm leaves the "
            f"scanner's range +-{half:g} nm: lower span_nm (--span-nm) or move center_nm."
        )
    cal = cfg.acquisition.calibration_span_nm(range_nm)
    if cal is not None and cal > range_nm:
        raise ValueError(
            f"the calibration span {cal:g} nm (calibrate) exceeds the scanner's range "
            f"{range_nm:g} nm."
        )
