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
   of the record (:func:`~piezocomp.identification.estimation.chain.estimate`, and
   :mod:`~piezocomp.identification.estimation.lines` over several lines);
4. frames and scale: the models mapped onto the calibration frame
   (:mod:`~piezocomp.identification.loop.frames`) and scaled by a grating of known pitch
   (:mod:`~piezocomp.identification.reference.scaling`);
5. the result, :class:`AxisIdentification`, with the findings a user should read.

:func:`identify_axis` runs stage 1 on an instrument and :func:`estimate_axis` the rest;
scoring against a virtual AFM's ground truth is separate
(:func:`~piezocomp.experiments.scoring.score_on_truth`).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.diagnostics import ExcitationWarning, check_excitation
from piezocomp.identification.acquisition.recording import (
    CHECK_TOLERANCE_NM,
    AxisRecords,
    record_axis,
)
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.estimation.candidates import initial_from_loop
from piezocomp.identification.estimation.chain import ChainStages, Estimation, estimate
from piezocomp.identification.estimation.drift_rounds import drift_rounds
from piezocomp.identification.estimation.findings import (
    batch_astray,
    batch_restart_notes,
    drift_during_record,
    poor_fit,
    rls_astray,
)
from piezocomp.identification.estimation.lines import (
    Lines,
    joint_rounds,
    line_penalties,
    rls_on_lines,
    whole_record_stages,
)
from piezocomp.identification.estimation.prediction import predicted_forward_trace
from piezocomp.identification.estimation.rls import RLSResult
from piezocomp.identification.loop.fit import (
    LoopEstimate,
    estimate_loop,
    fit_pi_loop,
)
from piezocomp.identification.loop.frames import frame_map, mapped, span_frame
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.reference.grating import GratingRecord
from piezocomp.identification.reference.scaling import ScaleFit, referenced_map, scale_fits
from piezocomp.identification.result import AxisIdentification, FrameMap, Identification
from piezocomp.instrument import Instrument
from piezocomp.model import ScannerModel

__all__ = [
    "CALIBRATION_DEGREE",
    "HOLDOUT_FRACTION",
    "check_fits",
    "estimate_axis",
    "identify",
    "identify_axis",
]

HOLDOUT_FRACTION = 0.25
"""Fraction of part B (its end) held out to choose the orders and rounds."""

CALIBRATION_DEGREE = 9
"""Degree of the eq (23) polynomial that pairs the calibration cycles' particles (the
calibration loop itself is a Prandtl-Ishlinskii branch,
:func:`~piezocomp.identification.loop.fit.fit_pi_loop`)."""


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

    The loop and ``h(y)`` from part A (with the line search's pairs); the calibration loop
    and the frame map onto it, if there are calibration cycles; the estimation of every
    candidate order and the choice by held-out heights (with the further lines' records);
    each model's own frame; the grating's scale; the findings.
    """
    timing = dict(records.timing_s)
    t0 = time.perf_counter()
    wf, u, z = records.waveform, records.u_nm, records.height_nm
    loop = estimate_loop(
        u, z, wf, degree=config.loop.degree, min_prominence_nm=config.acquisition.min_prominence_nm,
        extra_peaks=records.search_pairs,
    )  # fmt: skip
    notes = list(records.notes)
    stability = records.line_stability
    if stability is not None and (text := stability.finding(CHECK_TOLERANCE_NM)):
        notes.append(text)
    calibration, to_frame = _calibration_frame(records, config, loop, notes)
    timing["loop"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    n = u.size
    n_fit = n - round(HOLDOUT_FRACTION * (n - wf.part_b.start))
    fit_mask = np.zeros(n, dtype=bool)
    fit_mask[:n_fit] = True
    # the slow creep modes sit near the line's centre after the settling, not at the first
    # command (docs/identification-design.md)
    creep_start = 0.5 * (wf.u_min_nm + wf.u_max_nm)
    # each line's smoothing of h, chosen once for the record (it does not depend on the drift)
    all_lines: Lines = [(u, z, None), *((e.u_nm, e.height_nm, None) for e in records.extra)]
    penalties = line_penalties(loop, all_lines, wf)
    est, on_lines = _estimate_orders(records, config, loop, fit_mask, creep_start, penalties)
    drift = drift_rounds(
        records, config.estimation, config.rounds, fit_mask, creep_start, est,
        lambda shifts: _estimate_orders(
            records, config, loop, fit_mask, creep_start, penalties, shifts
        ),
    )  # fmt: skip
    if drift.kept and drift.estimation is not None:
        est, on_lines = drift.estimation, drift.on_lines
    scores = dict(est.heldout_rms_nm)
    notes += [*batch_restart_notes(est), *rls_astray(scores), *batch_astray(scores)]
    notes += poor_fit(scores, (est.batch_model.n_play, est.batch_model.n_creep))
    notes += drift_during_record(
        records.drift_nm_per_s, n * records.sample_period_s, drift.summary(),
        n_creep=est.batch_model.n_creep, reduced=config.acquisition.waveform.reduced,
    )  # fmt: skip
    shift0 = drift.shifts[0] if drift.kept else None
    working = {
        "rls": (est.rls.model, est.rls_profile),
        "batch": (est.batch_model, est.batch_profile),
    }
    maps = _frame_maps(records, working, loop.profile, to_frame, creep_start, shift0, notes)
    timing["estimation"] = time.perf_counter() - t1
    fits = unreferenced = None
    if reference is None:
        frame = "the working span's" if calibration is None else "the calibration cycles'"
        notes.append(
            f"no length reference: the models' scale is {frame} calibration condition "
            "(Section IV), which the held-out heights cannot check; it is typically a few "
            "per cent off (nanometres at the ends of a micrometre span). Scan a grating of "
            "known pitch with the same scanner to fix it"
        )
    if reference is not None:
        t2 = time.perf_counter()
        fits, unreferenced = _scaled(records, reference, working, maps, scores, notes)
        timing["reference"] = time.perf_counter() - t2
    # The creep spectrum is fixed by design up to time constants far beyond any record
    # (config.estimation.creep_tau_range_s, see docs/identification-design.md): that its
    # slowest modes outlast the record is expected on every run and asks nothing of the user,
    # so only the play operators' excitation is checked here.
    findings = notes + list(
        check_excitation(
            u[:n_fit], records.sample_period_s, est.batch_model.thresholds_nm, np.empty(0)
        )
    )  # fmt: skip
    for text in findings:
        warnings.warn(text, ExcitationWarning, stacklevel=2)
    parts = ("acquisition_setup", "loop", "estimation", "extra_lines", "reference")
    timing["total_computing"] = sum(timing.get(k, 0.0) for k in parts)
    # where the models hold: the waveform's commands, within the scanner's travel
    validity: dict[str, Any] = {"domain_nm": wf.domain_nm}
    if records.range_nm is not None:
        validity["range_nm"] = records.range_nm
    models = {m: replace(mapped(working[m][0], *maps[m]), **validity) for m in ("rls", "batch")}
    final = config.rounds.final_fit
    return AxisIdentification(
        records=records, loop=loop, calibration=calibration, estimation=est,
        fit_mask=fit_mask, creep_start_nm=creep_start, frame_maps=maps, models=models,
        reference=fits, unreferenced_models=unreferenced, reference_record=reference,
        rls_on_lines=on_lines, final_fit=final, findings=tuple(findings), timing_s=timing,
        line_drift=drift.summary(),
    )  # fmt: skip


def _frame_maps(
    records: AxisRecords,
    working: dict[str, tuple[ScannerModel, HeightProfile]],
    loop_profile: HeightProfile,
    to_frame: Callable[[Any], FrameMap],
    creep_start: float,
    shift0: NDArray[np.float64] | None,
    notes: list[str],
) -> dict[str, FrameMap]:
    """Each model's map onto the calibration frame (``to_frame`` of
    :func:`_calibration_frame`): the loop's for a model estimated on the loop's ``h``; for one
    whose ``h`` was re-indexed by it, its own, from its prediction of part A's forward trace
    (the loop's, with a note, when that cannot be mapped)."""
    wf, u = records.waveform, records.u_nm
    forward = wf.forward_traces
    maps: dict[str, FrameMap] = {}
    for name in ("batch", "rls"):
        model, prof = working[name]
        if prof is loop_profile:  # in the loop's frame
            maps[name] = to_frame(None)
            continue
        # A model whose h was re-indexed by it lives in its own frame: place the working
        # line's particles by its prediction of part A's forward trace.
        y_fwd = predicted_forward_trace(
            model, u, records.sample_period_s, forward, creep_start, shift0
        )
        u_fwd = u[forward[0]]
        try:
            maps[name] = to_frame((u_fwd, y_fwd))
        except ValueError as exc:
            label = "RLS" if name == "rls" else name
            notes.append(
                f"the {label} model's frame could not be mapped on its own ({exc}); it uses "
                "the loop's frame map"
            )
            maps[name] = to_frame(None)
    return maps


def _calibration_frame(
    records: AxisRecords, config: IdentifyConfig, loop: LoopEstimate, notes: list[str]
) -> tuple[LoopEstimate | None, Callable[[Any], FrameMap]]:
    """The calibration loop (Section IV on the calibration cycles, ``None`` without them or
    if they cannot be used) and the function that maps a model's frame onto it: given
    ``None`` (the loop's frame) or the working line's forward trace ``(u, y_hat)`` of a
    model in its own frame, its ``(alpha, beta)``. Without calibration cycles the loop's
    frame is the identity and a model's own frame is put on the loop's span (Section IV)."""
    calibration = None
    cal = records.calibration
    if cal is not None:
        calibration = estimate_loop(
            cal.u_nm, cal.height_nm, cal.waveform, degree=CALIBRATION_DEGREE,
            min_prominence_nm=config.acquisition.min_prominence_nm,
        )  # fmt: skip
    cal_pi = None
    if calibration is not None:
        lo, hi = calibration.loop.u_min_nm, calibration.loop.u_max_nm
        cal_pi = fit_pi_loop(calibration.all_pairs, lo, hi)

    def onto_calibration(trace: Any) -> FrameMap:
        assert calibration is not None
        positions = None if trace is None else (lambda x: np.interp(x, trace[0], trace[1]))
        return frame_map(
            loop, calibration, window_nm=0.3 * config.acquisition.span_nm,
            min_prominence_nm=config.acquisition.min_prominence_nm, calibration_loop=cal_pi,
            working_positions=positions,
        )  # fmt: skip

    if calibration is not None:
        try:
            loop_map = onto_calibration(None)
        except ValueError as exc:
            calibration = None
            notes.append(
                f"the calibration cycles could not be used ({exc}); the model keeps the "
                "working span's calibration condition (Section IV), whose scale may be off"
            )
    if calibration is None:
        return None, lambda t: (1.0, 0.0) if t is None else span_frame(loop.loop, *t)
    return calibration, lambda t: loop_map if t is None else onto_calibration(t)


def _estimate_orders(
    records: AxisRecords,
    config: IdentifyConfig,
    loop: LoopEstimate,
    fit_mask: NDArray[np.bool_],
    creep_start: float | None,
    penalties: Sequence[float],
    shifts: Sequence[NDArray[np.float64] | None] | None = None,
) -> tuple[Estimation, bool]:
    """:func:`~piezocomp.identification.estimation.chain.estimate` with the configuration's
    settings and, with further lines, the joint rounds and the RLS on every line
    (:mod:`~piezocomp.identification.estimation.lines`); ``penalties``: each line's smoothing of
    ``h`` (:func:`~piezocomp.identification.estimation.lines.line_penalties`); ``shifts``: each
    line's drift path (:mod:`~piezocomp.identification.estimation.drift_rounds`). Returns the
    estimation and whether the RLS estimate kept is the one run on every line."""
    cfg, wf, T = config, records.waveform, records.sample_period_s
    u, z = records.u_nm, records.height_nm
    extra = records.extra
    # with extra lines, the joint rounds replace as many of the first line's own rounds
    first_rounds = cfg.estimation.reindex_rounds
    if extra and cfg.estimation.reindex_rounds > 0:
        at_least = (
            1
            if cfg.estimation.selection_rounds is None
            else max(cfg.estimation.selection_rounds_used, 1)
        )
        first_rounds = max(at_least, cfg.estimation.reindex_rounds - cfg.rounds.joint_rounds)
    d = [None] * (1 + len(extra)) if shifts is None else list(shifts)
    lines = [(u, z, d[0])] + [
        (e.u_nm, e.height_nm, d_i) for e, d_i in zip(extra, d[1:], strict=True)
    ]
    batch_final, rls_final = whole_record_stages(
        lines, T, cfg.estimation, cfg.rounds, wf, creep_start, penalties
    )
    on_lines = False

    def batch_then(model: ScannerModel, prof: HeightProfile) -> tuple[ScannerModel, HeightProfile]:
        return joint_rounds(
            model, lines, T, cfg.estimation, cfg.rounds, wf, fit_mask, creep_start, prof,
            penalties,
        )  # fmt: skip

    def rls_then(res: RLSResult, prof: HeightProfile) -> tuple[RLSResult, HeightProfile]:
        nonlocal on_lines
        res, prof, on_lines = rls_on_lines(
            res, prof, lines, T, cfg.estimation, cfg.rounds, wf, fit_mask, creep_start, penalties
        )
        return res, prof

    stages = ChainStages(
        batch_then=batch_then if extra else None,
        rls_then=rls_then if extra and cfg.rounds.rls_lines_passes > 0 else None,
        batch_final=batch_final,
        rls_final=rls_final,
    )
    est = estimate(
        u, z, T, loop.profile,
        lambda nh, taus: initial_from_loop(loop.loop, nh, taus.size, time_constants_s=taus),
        fit_mask=fit_mask, warmup_samples=2 * wf.half_cycle_samples,
        options=replace(cfg.estimation, reindex_rounds=first_rounds), creep_start_nm=creep_start,
        forward_traces=wf.forward_traces, stages=stages,
        shift_nm=d[0],
    )  # fmt: skip
    return est, on_lines


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
