"""Sensorless identification offline, from a record made on any instrument.

A real instrument need not be driven by piezocomp: ``piezocomp waveform`` writes the
identification waveform of Fig. 7a (command samples, with the parameters that generated it
in the file's metadata); the user runs it on one line with the instrument's own software,
recording the topography, and saves ``t_s, u_nm, height_nm`` with the same metadata line.
:func:`identify_record` then runs the estimation half of the procedure: the loop and
``h(y)`` from the steady cycles of part A (Section IV, eqs 21-23), RLS (eqs 16-20) and the
batch refinement on part B, the orders chosen on a held-out part of the record by its
height prediction (no sensor needed).

A length reference works offline too: run steady cycles of the same span, centre and speed
(``piezocomp waveform --n-decaying 0 --n-random 0 --n-steady 6``) across a grating of known
pitch, on one or more lines, and pass the records to :func:`grating_record_from_signals`;
:func:`identify_record` then scales the models to the grating
(:mod:`~piezocomp.identification.reference`).

What the offline path cannot do that :func:`~piezocomp.identification.sensorless.identify_axis`
does on a driven instrument: choose the line, settle on it, check it after the record, and
map the model onto a full-range calibration frame; without a grating the scale is the
paper's calibration condition on the working span.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.diagnostics import check_excitation
from piezocomp.identification.estimation import (
    Estimation,
    estimate,
    initial_from_loop,
    predicted_forward_trace,
    record_state,
)
from piezocomp.identification.frames import mapped, span_frame, unmapped
from piezocomp.identification.loop_fit import LoopEstimate, estimate_loop
from piezocomp.identification.profile import HeightProfile
from piezocomp.identification.reference import (
    GratingRecord,
    ScaleFit,
)
from piezocomp.identification.rls import RLSResult
from piezocomp.identification.sensorless import (
    SensorlessConfig,
    _whole_record_stages,
    batch_astray,
    batch_restart_notes,
    poor_fit,
    rls_astray,
    scale_fits,
)
from piezocomp.identification.waveforms import IdentificationWaveform, identification_waveform
from piezocomp.io.signals import RecordedSignal
from piezocomp.model import ScannerModel, simulate

__all__ = [
    "WAVEFORM_KEY",
    "RecordIdentification",
    "grating_record_from_signals",
    "identify_record",
    "waveform_from_metadata",
    "waveform_metadata",
]

WAVEFORM_KEY = "piezocomp_waveform"
"""Metadata key holding the waveform's parameters (JSON) in waveform and record files."""

_PARAMETERS = (
    "center_nm",
    "span_nm",
    "speed_nm_per_s",
    "sample_period_s",
    "n_steady",
    "n_decaying",
    "n_random",
    "max_dwell_s",
    "seed",
)
_OPTIONAL = {"speed_factors": [1.0]}
"""Parameters added later, with the value that rebuilds a file written without them."""


def waveform_metadata(parameters: Mapping[str, Any]) -> dict[str, str]:
    """Metadata that lets :func:`waveform_from_metadata` rebuild the waveform exactly."""
    missing = [k for k in _PARAMETERS if k not in parameters]
    if missing:
        raise ValueError(f"waveform parameters are missing {missing}.")
    keys = _PARAMETERS + tuple(k for k in _OPTIONAL if k in parameters)
    return {WAVEFORM_KEY: json.dumps({k: parameters[k] for k in keys})}


def waveform_from_metadata(
    metadata: Mapping[str, str], source: str = "record"
) -> tuple[IdentificationWaveform, dict[str, Any]]:
    """Rebuild the identification waveform from a file's metadata."""
    if WAVEFORM_KEY not in metadata:
        raise ValueError(
            f"{source}: no '{WAVEFORM_KEY}' metadata line; record the waveform written by "
            "'piezocomp waveform' and keep its '# piezocomp_waveform: {...}' line."
        )
    try:
        params = json.loads(metadata[WAVEFORM_KEY])
    except json.JSONDecodeError as exc:
        raise ValueError(f"{source}: '{WAVEFORM_KEY}' is not valid JSON ({exc.msg}).") from None
    if not isinstance(params, dict) or sorted(set(params) - set(_OPTIONAL)) != sorted(_PARAMETERS):
        raise ValueError(
            f"{source}: '{WAVEFORM_KEY}' must hold exactly the keys {_PARAMETERS} (and "
            f"optionally {tuple(_OPTIONAL)})."
        )
    params = {**_OPTIONAL, **params}
    wf = identification_waveform(
        params["center_nm"],
        params["span_nm"],
        params["speed_nm_per_s"],
        params["sample_period_s"],
        n_steady=params["n_steady"],
        n_decaying=params["n_decaying"],
        n_random=params["n_random"],
        max_dwell_s=params["max_dwell_s"],
        speed_factors=params["speed_factors"],
        rng=params["seed"],
    )
    return wf, params


@dataclass(frozen=True)
class RecordIdentification:
    """Outcome of :func:`identify_record`.

    Attributes
    ----------
    waveform : IdentificationWaveform
    loop : LoopEstimate
        The loop and ``h(y)`` of part A.
    estimation : Estimation
        RLS, batch refinement and order selection (held-out height RMS per method).
    findings : tuple of str
        Warnings a user should read (excitation, held-out fit).
    rls_model, batch_model : ScannerModel
        The estimates of ``estimation`` mapped by ``frame_maps``.
    reference : dict of str to ScaleFit, or None
        The grating's scale for ``"rls"`` and ``"batch"``.
    frame_maps : dict of str to (float, float)
        ``(alpha, beta)`` that took each estimate of ``estimation`` to the model returned
        (output ``alpha y + beta``): the loop's span condition for a model in its own frame
        (:func:`~piezocomp.identification.frames.span_frame`), with a reference the
        grating's ``alpha`` about the line's centre.
    axis : str
    u_nm, height_nm : ndarray
        The record (command of the axis, measured heights).
    sample_period_s : float
    fit_mask : ndarray of bool
        Samples fitted (the rest held out).
    creep_start_nm : float or None
        Creep states the estimation assumed before the record.
    reference_record : GratingRecord or None
        The grating record the scales came from.

    It answers the same questions as
    :class:`~piezocomp.identification.sensorless.AxisIdentification` for the figures
    (:mod:`piezocomp.plotting.identification`).
    """

    waveform: IdentificationWaveform
    loop: LoopEstimate
    estimation: Estimation
    findings: tuple[str, ...]
    rls_model: ScannerModel
    batch_model: ScannerModel
    reference: dict[str, ScaleFit] | None = None
    frame_maps: dict[str, tuple[float, float]] | None = None
    axis: str = "x"
    u_nm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    height_nm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    sample_period_s: float = 0.0
    fit_mask: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    creep_start_nm: float | None = None
    reference_record: GratingRecord | None = None
    final_fit: bool = False

    @property
    def profile(self) -> HeightProfile:
        """The loop's ``h(y)`` (Section IV)."""
        return self.loop.profile

    @property
    def rls(self) -> RLSResult:
        """The RLS run of the chosen orders (Fig. 7b traces)."""
        return self.estimation.rls

    @property
    def frame_map(self) -> tuple[float, float]:
        """``(alpha, beta)`` of the batch model."""
        return (self.frame_maps or {}).get("batch", (1.0, 0.0))

    def predict_heights(
        self, model: ScannerModel, profile: HeightProfile | None = None
    ) -> NDArray[np.float64]:
        """``h(y_hat)`` of a working-frame model over the record (eqs 14, 16)."""
        st = record_state(model, float(self.u_nm[0]), self.creep_start_nm)
        y, _ = simulate(model, self.u_nm, self.sample_period_s, st)
        return np.asarray((self.profile if profile is None else profile)(y))

    def working_models(self) -> dict[str, tuple[ScannerModel, HeightProfile]]:
        """The RLS and batch models in their working frames, each with its ``h(y)``."""
        maps = self.frame_maps or {}
        est = self.estimation
        return {
            "rls": (unmapped(self.rls_model, *maps.get("rls", (1.0, 0.0))), est.rls_profile),
            "batch": (unmapped(self.batch_model, *self.frame_map), est.batch_profile),
        }


def _recorded_command(
    signal: RecordedSignal, wf: IdentificationWaveform, axis: str, tolerance_nm: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The record's command and heights, checked against the waveform it claims to be."""
    source = signal.source or "record"
    column = "u_nm" if "u_nm" in signal else f"{axis}_nm"
    if column not in signal:
        raise ValueError(f"{source}: no command column 'u_nm' or '{axis}_nm'.")
    u = np.ascontiguousarray(signal[column], dtype=float)
    z = np.ascontiguousarray(signal["height_nm"], dtype=float)
    T = signal.sample_period_s
    if abs(T - wf.sample_period_s) > 1e-6 * wf.sample_period_s:
        raise ValueError(
            f"{source}: sampled every {T:.9g} s but the waveform was made for "
            f"{wf.sample_period_s:.9g} s."
        )
    if u.size != wf.u_nm.size:
        raise ValueError(
            f"{source}: {u.size} samples, the waveform has {wf.u_nm.size} (truncated record?)."
        )
    dev = np.abs(u - wf.u_nm)
    if dev.max() > tolerance_nm:
        k = int(np.argmax(dev))
        raise ValueError(
            f"{source}: the recorded command differs from the waveform by {dev[k]:.6g} nm at "
            f"sample {k} (allowed {tolerance_nm:g} nm): not a record of this waveform."
        )
    return u, z


def grating_record_from_signals(
    signals: list[RecordedSignal],
    pitch_nm: float,
    *,
    axis: str = "x",
    skip_cycles: int = 2,
    tolerance_nm: float = 1e-3,
) -> GratingRecord:
    """A :class:`GratingRecord` from recorded runs of a steady-cycle waveform over a grating,
    one signal per scan line (all of the same waveform, which starts and ends at its lower
    turning point, so the lines join into one continuous command).

    Each signal must carry the waveform's metadata (``piezocomp waveform --n-decaying 0
    --n-random 0``) and match it; the first ``skip_cycles`` cycles of each line are not used.
    Signals that hold both ``x_nm`` and ``y_nm`` give each line's slow command (the other
    axis' mean), from which :func:`fit_scale` measures the grating's angle.
    """
    if not signals:
        raise ValueError("grating records: give at least one signal.")
    wfs = [waveform_from_metadata(s.metadata, s.source or "grating record") for s in signals]
    params = wfs[0][1]
    for s, (_, p) in zip(signals, wfs, strict=True):
        if p != params:
            raise ValueError(
                f"{s.source or 'grating record'}: another waveform than the first record's; "
                "every line must run the same waveform."
            )
    wf = wfs[0][0]
    if params["n_decaying"] or params["n_random"]:
        raise ValueError(
            f"{signals[0].source or 'grating record'}: the waveform has a part B; a grating "
            "record runs steady cycles only (--n-decaying 0 --n-random 0)."
        )
    if isinstance(skip_cycles, bool) or not 0 <= int(skip_cycles) < wf.n_steady:
        raise ValueError(
            f"skip_cycles must be an integer in [0, {wf.n_steady}). Got {skip_cycles!r}."
        )
    us, zs, passes, lines = [], [], [], []
    other = "y_nm" if axis == "x" else "x_nm"
    slows = [float(np.mean(s[other])) for s in signals if other in s]
    n0 = 0
    for i, s in enumerate(signals):
        u, z = _recorded_command(s, wf, axis, tolerance_nm)
        us.append(u)
        zs.append(z)
        for c in range(int(skip_cycles), wf.n_steady):
            for sl in (wf.ascending(c), wf.descending(c)):
                passes.append((n0 + int(sl.start), n0 + int(sl.stop)))
                lines.append(i)
        n0 += u.size
    return GratingRecord(
        axis=axis,
        pitch_nm=pitch_nm,
        u_nm=np.concatenate(us),
        height_nm=np.concatenate(zs),
        sample_period_s=wf.sample_period_s,
        passes=tuple(passes),
        pass_lines=tuple(lines),
        line_slow_nm=tuple(slows) if len(slows) == len(signals) else None,
    )


def identify_record(
    signal: RecordedSignal,
    config: SensorlessConfig | None = None,
    *,
    axis: str = "x",
    tolerance_nm: float = 1e-3,
    reference: GratingRecord | None = None,
) -> RecordIdentification:
    """Estimate the model of one axis from a recorded identification run.

    Parameters
    ----------
    signal : RecordedSignal
        ``t_s``, the command (``u_nm``, or ``x_nm``/``y_nm`` with ``axis``), ``height_nm``
        and the waveform's metadata (:data:`WAVEFORM_KEY`).
    config : SensorlessConfig, optional
        Estimation settings (degree, orders, RLS, refinement, creep spectrum, hold-out).
    axis : {"x", "y"}
        Axis the waveform ran on, when the record holds both commands.
    tolerance_nm : float
        Largest allowed difference between the recorded command and the waveform.
    reference : GratingRecord, optional
        Steady cycles over a grating of known pitch, same axis, span, centre and speed
        (:func:`grating_record_from_signals`): the models are scaled to it.
    """
    cfg = SensorlessConfig() if config is None else config
    source = signal.source or "record"
    if reference is not None and not isinstance(reference, GratingRecord):
        raise TypeError(f"reference must be a GratingRecord. Got {type(reference).__name__}.")
    if reference is not None and reference.axis != axis:
        raise ValueError(
            f"the grating record is of axis {reference.axis!r}; it cannot scale axis {axis!r}."
        )
    wf, params = waveform_from_metadata(signal.metadata, source)
    cfg = cfg.for_speed(float(params["speed_nm_per_s"]))
    u, z = _recorded_command(signal, wf, axis, tolerance_nm)
    T = signal.sample_period_s
    loop = estimate_loop(u, z, wf, degree=cfg.degree, min_prominence_nm=cfg.min_prominence_nm)
    n = u.size
    n_fit = n - round(cfg.holdout_fraction * (n - wf.part_b.start))
    fit_mask: NDArray[np.bool_] = np.zeros(n, dtype=bool)
    fit_mask[:n_fit] = True
    creep_start = 0.5 * (wf.u_min_nm + wf.u_max_nm) if cfg.creep_start == "centre" else None
    forward = [wf.ascending(c) for c in range(1, wf.n_steady)]
    batch_final, rls_final = _whole_record_stages(
        [(u, z)], T, cfg, wf, creep_start, [loop.profile.penalty]
    )
    est = estimate(
        u,
        z,
        T,
        loop.profile,
        lambda nh, taus: initial_from_loop(loop.loop, nh, taus.size, time_constants_s=taus),
        fit_mask=fit_mask,
        warmup_samples=2 * wf.half_cycle_samples,
        orders=cfg.orders,
        rls_settings=cfg.rls_settings,
        refine_max_nfev=cfg.refine_max_nfev,
        refine_free=cfg.refine_free,
        tau_range_s=cfg.creep_tau_range_s,
        creep_start_nm=creep_start,
        forward_traces=forward,
        reindex_rounds=cfg.reindex_rounds,
        selection_rounds=cfg.selection_rounds_used,
        reindex_max_nfev=cfg.reindex_max_nfev,
        rls_continue=cfg.rls_continue,
        rls_start=cfg.rls_start,
        order_tolerance=cfg.order_tolerance,
        prefer_orders=cfg.prefer_orders,
        rls_reindex_rounds=cfg.rls_reindex_rounds,
        rls_reindex_passes=cfg.rls_reindex_passes,
        creep_smoothing_nm=cfg.creep_smoothing_nm,
        weight_smoothing_nm=cfg.weight_smoothing_nm,
        batch_final=batch_final,
        rls_final=rls_final,
        batch_restart_ratio=cfg.batch_restart_ratio,
        workers=cfg.workers_used,
    )
    findings = tuple(
        check_excitation(
            u[:n_fit],
            T,
            est.batch_model.thresholds_nm,
            est.batch_model.creep_time_constants_s,
        )
    )
    findings = (
        *findings,
        *batch_restart_notes(est),
        *rls_astray(dict(est.heldout_rms_nm)),
        *batch_astray(dict(est.heldout_rms_nm)),
        *poor_fit(dict(est.heldout_rms_nm)),
    )
    models = {"rls": est.rls.model, "batch": est.batch_model}
    # A model whose h was re-indexed by it lives in its own frame: back onto the loop's
    # span (Section IV), as identify_axis does without calibration cycles.
    maps = {}
    for m, prof in (("rls", est.rls_profile), ("batch", est.batch_profile)):
        maps[m] = (1.0, 0.0)
        if prof is not loop.profile:
            y_fwd = predicted_forward_trace(models[m], u, T, forward, creep_start)
            try:
                maps[m] = span_frame(loop.loop, u[forward[0]], y_fwd)
            except ValueError as exc:  # a model whose steady cycle does not advance
                findings = (
                    *findings,
                    f"the {m} model could not be put on the loop's span ({exc}); it is left "
                    "in the frame it was fitted in, whose scale may be far off",
                )
    fits = None
    if reference is not None:
        notes: list[str] = []
        pre = {m: a for m, (a, _) in maps.items()}
        fits = scale_fits(models, reference, dict(est.heldout_rms_nm), notes, prescale=pre)
        findings = (*findings, *notes)
        # scaled about the line's centre, which stays where the span frame put it
        c = 0.5 * (wf.u_min_nm + wf.u_max_nm)
        for m in fits:
            a, b = maps[m]
            maps[m] = (fits[m].alpha, a * c + b - fits[m].alpha * c)
    models = {
        m: replace(mapped(model, *maps[m]), domain_nm=wf.domain_nm) for m, model in models.items()
    }
    return RecordIdentification(
        wf, loop, est, findings, models["rls"], models["batch"], reference=fits,
        frame_maps=maps, axis=axis, u_nm=u, height_nm=z, sample_period_s=T,
        fit_mask=fit_mask, creep_start_nm=creep_start, reference_record=reference,
        final_fit=batch_final is not None or rls_final is not None,
    )  # fmt: skip
