"""Identification on the virtual AFM: its particle sample, scaled by a calibration grating.

On a real instrument the length reference is a grating of known pitch scanned with the same
scanner before the particle sample is mounted
(:func:`~piezocomp.identification.reference.grating.measure_grating`).
The virtual lab does the same with a second :class:`~piezocomp.virtual_afm.VirtualAFM`
built from the same configuration with a grating mounted instead of the particles. The
scanner's calibration record (the speed at which its nominal sensitivity holds) is measured
the same way, on another day (:func:`calibration_record`), unless the instrument states one.
:func:`identify_virtual` is the one entry the experiments and ``piezocomp identify`` use.

:func:`fit_on_truth` is not an identification: it fits the same model family to the TRUE
extension of the virtual scanner (the simulator's ground truth), the best that family can do
on it. The experiments use it as the "oracle" against which the sensorless models are judged.
:func:`~piezocomp.experiments.scoring.score_on_truth` (re-exported here) scores models
against the ground truth on a fresh validation trajectory.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from piezocomp.experiments.scoring import score_on_truth
from piezocomp.identification.acquisition.line_search import axis_command
from piezocomp.identification.acquisition.waveforms import (
    identification_waveform,
    validation_waveform,
)
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.estimation.candidates import creep_spectrum, thresholds_over_span
from piezocomp.identification.reference.calibration_scan import (
    CALIBRATION_SPEEDS_NM_PER_S,
    CalibrationScan,
    measure_calibration_scan,
)
from piezocomp.identification.reference.grating import (
    GratingRecord,
    grating_path_for,
    measure_grating,
)
from piezocomp.identification.result import AxisIdentification
from piezocomp.identification.sensorless import check_fits, identify_axis
from piezocomp.instrument import ScanCalibration
from piezocomp.model import ScannerModel
from piezocomp.sensor.fit import choose_creep_coupling, nnls_stage

if TYPE_CHECKING:
    from piezocomp.virtual_afm import VirtualAFM

__all__ = [
    "CALIBRATION_SEED_OFFSET",
    "VIRTUAL_PITCH_NM",
    "AxisIdentification",
    "IdentifyConfig",
    "calibrated",
    "calibration_record",
    "fit_on_truth",
    "grating_reference",
    "identify_virtual",
    "lab_calibration",
    "score_on_truth",
    "scored_summary",
    "true_calibration_speed",
]

VIRTUAL_PITCH_NM = 278.0
"""Pitch of the virtual calibration grating (a holographic grating like NT-MDT TDG01)."""


def grating_reference(
    afm: VirtualAFM, config: IdentifyConfig, axis: str, pitch_nm: float = VIRTUAL_PITCH_NM
) -> GratingRecord:
    """The length reference of the virtual lab: ``afm``'s scanner with a grating (lines
    perpendicular to ``axis``) mounted instead of the particles, scanned over the working
    span at the identification speed."""
    from piezocomp.virtual_afm import Grating, VirtualAFM

    gafm = VirtualAFM(
        afm.config, sample_period_s=afm.sample_period_s, grating=Grating(pitch_nm, axis=axis)
    )
    return measure_grating(
        gafm,
        pitch_nm,
        axis=axis,
        center_nm=config.acquisition.center_nm,
        span_nm=config.acquisition.span_nm,
        speed_nm_per_s=config.acquisition.speed_nm_per_s,
        path=grating_path_for(config.acquisition.span_nm, pitch_nm, config.reference.grating_path),
    )


CALIBRATION_SEED_OFFSET = 100_000
"""The calibration record's grating scan draws its noise, drift and roughness from the
sample's seed plus this: another day, another grating."""


def lab_calibration(
    afm: VirtualAFM,
    axis: str = "x",
    pitch_nm: float = VIRTUAL_PITCH_NM,
    speeds_nm_per_s: tuple[float, float] = CALIBRATION_SPEEDS_NM_PER_S,
) -> CalibrationScan:
    """The calibration of ``afm``'s scanner as a lab makes it: a grating (lines
    perpendicular to ``axis``) mounted on the same scanner on another day
    (:data:`CALIBRATION_SEED_OFFSET`), scanned over the whole range through the instrument
    interface
    (:func:`~piezocomp.identification.reference.calibration_scan.measure_calibration_scan`):
    the measured record, with its errors, never the scanner's physics."""
    from piezocomp.virtual_afm import Grating, VirtualAFM

    config = afm.config.with_seed(afm.config.sample.seed + CALIBRATION_SEED_OFFSET)
    gafm = VirtualAFM(
        config, sample_period_s=afm.sample_period_s, grating=Grating(pitch_nm, axis=axis)
    )
    return measure_calibration_scan(gafm, pitch_nm, axis=axis, speeds_nm_per_s=speeds_nm_per_s)


def calibration_record(
    afm: VirtualAFM, axis: str = "x", pitch_nm: float = VIRTUAL_PITCH_NM
) -> ScanCalibration | None:
    """The calibration record of ``afm``'s scanner (one for the instrument, measured on its
    fast axis by default) as its virtual lab measures it (:func:`lab_calibration`); ``None``
    if no speed searched makes the scan as wide as commanded."""
    return lab_calibration(afm, axis, pitch_nm).scan


def true_calibration_speed(afm: VirtualAFM) -> float | None:
    """The speed at which the virtual scanner's physics makes a steady full-range scan from
    rest as wide as commanded: ground truth, for scoring only
    (:func:`piezocomp.virtual_afm.calibration.calibration_speed`)."""
    from piezocomp.virtual_afm.calibration import calibration_speed

    return calibration_speed(afm.truth.scanner_params, afm.sample_period_s)


def calibrated(afm: VirtualAFM, config: IdentifyConfig) -> IdentifyConfig:
    """``config`` with its calibration cycles at the speed of the lab's record
    (:func:`calibration_record`) where neither ``config`` gives a speed nor the instrument
    states a record; else ``config`` itself."""
    acq = config.acquisition
    if acq.calibration_speed_nm_per_s is not None or afm.calibration_scan is not None:
        return config
    if acq.calibration_span_nm(float(afm.range_nm)) is None:  # no calibration cycles
        return config
    scan = calibration_record(afm)
    if scan is None:
        return config
    return replace(config, acquisition=replace(acq, calibration_speed_nm_per_s=scan.speed_nm_per_s))


def identify_virtual(
    afm: VirtualAFM,
    config: IdentifyConfig,
    axis: str,
) -> AxisIdentification:
    """The sensorless identification of one axis of a virtual AFM
    (:func:`~piezocomp.identification.sensorless.identify_axis`), scaled by a virtual
    grating (``config.reference.grating``; its pitch ``grating_pitch_nm``, by default
    :data:`VIRTUAL_PITCH_NM`) or by the calibration condition only. The models carry the
    command interval they were identified over (``domain_nm``) and the scanner's travel
    (``range_nm``). The calibration cycles run at the speed of :func:`calibrated`."""
    check_fits(config, axis, float(afm.range_nm))  # before the grating moves anything
    config = calibrated(afm, config)
    ref = None
    if config.reference.grating:
        pitch = config.reference.grating_pitch_nm
        pitch = VIRTUAL_PITCH_NM if pitch is None else pitch
        ref = grating_reference(afm, config, axis, pitch)
    return identify_axis(afm, config, axis, reference=ref)


def scored_summary(
    afm: VirtualAFM, ident: AxisIdentification, config: IdentifyConfig
) -> dict[str, Any]:
    """The validation of an identification's models against ``afm``'s ground truth, as
    ``summary.json`` reports it beside the axis' own
    :meth:`~piezocomp.identification.result.AxisIdentification.summary`: ``methods`` (the RLS
    and batch models' validation errors, :func:`score_on_truth` on a fresh trajectory over
    ``config``'s working span), ``without_reference`` (the models before the grating's scale, with
    one) and ``validation_samples``."""
    models = {"rls": ident.rls_model, "batch": ident.batch_model}
    for m, before in (ident.unreferenced_models or {}).items():
        models[f"{m}_unreferenced"] = before
    acq = config.acquisition
    score = score_on_truth(
        afm, ident, models, span_nm=acq.span_nm,
        center_nm=acq.center_nm[0 if ident.axis == "x" else 1],
    )  # fmt: skip
    out: dict[str, Any] = {"methods": {name: score[name] for name in ("rls", "batch")}}
    if ident.unreferenced_models is not None:
        out["without_reference"] = {m: score[f"{m}_unreferenced"] for m in ("rls", "batch")}
    out["validation_samples"] = score["n_samples"]
    return out


ORACLE_DWELL_S = 60.0
"""Longest hold of the oracle's extra record: long enough to see the slow creep modes."""

ORACLE_TURNS = 40
"""Turning points of the oracle's extra record (about 12 minutes with its holds at
``reproduce``'s settings)."""


def fit_on_truth(
    afm: VirtualAFM,
    config: IdentifyConfig,
    axis: str,
    orders: tuple[int, int],
    *,
    creep_smoothing_nm: float | None = None,
    weight_smoothing_nm: float | None = None,
    extra_record: bool = True,
    creep_coupling: float | Literal["fit"] = 0.0,
    validation_fraction: float = 0.25,
) -> ScannerModel:
    """The model of ``orders`` ``(N_H, N_c)`` fitted to the TRUE extension of ``afm``'s axis
    (ground truth: for scoring only, never a compensator a real instrument could have).

    From rest, the identification waveform of ``config`` (same span, speeds and seed) runs
    on ``axis``, the other axis held at its centre, then a long trajectory of nested minor
    loops with holds of up to :data:`ORACLE_DWELL_S` (the slow creep modes need more than
    the identification's few minutes; ``extra_record=False`` leaves it out, to see what the
    identification's record alone can tell, the part a sensorless identification holds out
    included); the first cycle is not fitted. The thresholds are spread over the span and
    the creep time constants over ``config.estimation.creep_tau_range_s`` as the sensorless
    identification places them; the weights, gains and offset are fitted by non-negative
    least squares to the true extension (positions less drift), with the batch refinement's
    smoothness priors (``config``'s unless given; :func:`~piezocomp.sensor.fit.nnls_stage`).
    The model carries the waveform's command interval as its domain.

    ``creep_coupling`` is the creep coupling ``beta`` of eq (2'): ``0`` (default) the
    paper's model, exactly as before the coupling existed; a number ``> 0``, held;
    ``"fit"``: the last ``validation_fraction`` of the fitted samples is held out,
    :func:`~piezocomp.sensor.fit.choose_creep_coupling` searches ``beta`` on the rest and
    keeps the coupled family only if it predicts the held-out samples better than
    ``beta = 0``; the chosen ``beta`` is then fitted on all the samples (``beta = 0`` gives
    the default's model exactly).
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y'. Got {axis!r}.")
    k = 0 if axis == "x" else 1
    T = float(afm.sample_period_s)
    acq, wcfg = config.acquisition, config.acquisition.waveform
    speed = min(acq.speed_nm_per_s, float(afm.max_speed_nm_per_s))
    centre, slow = acq.center_nm[k], acq.center_nm[1 - k]
    wf = identification_waveform(
        centre, acq.span_nm, speed, T, n_steady=wcfg.n_steady, n_decaying=wcfg.n_decaying,
        n_random=wcfg.n_random, max_dwell_s=wcfg.max_dwell_s, speed_factors=wcfg.speed_factors,
        max_speed_nm_per_s=float(afm.max_speed_nm_per_s), rng=wcfg.seed,
    )  # fmt: skip
    more = validation_waveform(
        centre, acq.span_nm, speed, T, n_turns=ORACLE_TURNS, max_dwell_s=ORACLE_DWELL_S,
        start_nm=float(wf.u_nm[-1]), rng=wcfg.seed + 1,
    ) if extra_record else np.empty(0)  # fmt: skip
    x0, y0 = (wf.u_nm[0], slow) if axis == "x" else (slow, wf.u_nm[0])
    first = afm.move_to(float(x0), float(y0), speed)
    first_y = afm.truth.last_record_extension_nm
    rec = afm.run(axis_command(axis, np.concatenate([wf.u_nm, more]), slow))
    u = np.concatenate([first.command_nm[:, k], rec.command_nm[:, k]])
    rec_y = afm.truth.last_record_extension_nm
    y = np.concatenate([first_y, rec_y])[:, k]
    rows = np.ones(u.size, bool)
    rows[: len(first) + 2 * wf.half_cycle_samples] = False  # the first cycle sets the state
    n_play, n_creep = orders
    r = thresholds_over_span(int(n_play), wf.u_max_nm - wf.u_min_nm)
    tau = creep_spectrum(int(n_creep), config.estimation.creep_tau_range_s)
    cs = config.estimation.creep_smoothing_nm if creep_smoothing_nm is None else creep_smoothing_nm
    ws = (
        config.estimation.weight_smoothing_nm
        if weight_smoothing_nm is None
        else weight_smoothing_nm
    )
    beta = 0.0
    if creep_coupling == "fit":
        frac = float(validation_fraction)
        if not 0.0 < frac < 1.0:
            raise ValueError(f"validation_fraction must lie in (0, 1). Got {frac}.")
        idx = np.flatnonzero(rows)
        held = np.zeros(u.size, bool)
        held[idx[round((1.0 - frac) * idx.size) :]] = True
        _, _, choice = choose_creep_coupling(
            u, y, T, r, tau, fit_rows=rows & ~held, validation_rows=held,
            initial_state="rest", creep_smoothing_nm=cs, weight_smoothing_nm=ws,
        )  # fmt: skip
        beta = choice.coupling
    else:
        beta = float(creep_coupling)
    model, *_ = nnls_stage(
        u, y, T, r, tau, rows=rows, initial_state="rest", creep_smoothing_nm=cs,
        weight_smoothing_nm=ws, creep_coupling=beta,
    )  # fmt: skip
    return replace(model, domain_nm=wf.domain_nm, range_nm=float(afm.range_nm))
