"""Scoring an identified model against the ground truth of a virtual AFM (benchmarks only).

:func:`score_on_truth` runs a fresh validation trajectory with minor loops
(:func:`~piezocomp.identification.acquisition.waveforms.validation_waveform`) on the identification
line of a *virtual* AFM and compares each model's prediction (eq 14, run over the whole command
history since the identification record) with the true extension read from the simulator's
ground-truth door. The sensorless identification
(:func:`~piezocomp.identification.sensorless.identify_axis`) never calls it: no real instrument has
that door."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from piezocomp.identification.acquisition.line_search import axis_command
from piezocomp.identification.acquisition.waveforms import (
    IdentificationWaveform,
    validation_waveform,
)
from piezocomp.model import ScannerModel, simulate

if TYPE_CHECKING:
    from piezocomp.identification.result import AxisIdentification

__all__ = ["score_model_on_truth", "score_on_truth"]


def score_on_truth(
    afm: Any,
    ident: AxisIdentification,
    models: dict[str, ScannerModel],
    *,
    span_nm: float = 1000.0,
    center_nm: float = 0.0,
    speed_nm_per_s: float | None = None,
    n_turns: int = 24,
    rng: int | np.random.Generator | None = 12345,
) -> dict[str, Any]:
    """Score models against the TRUE extension of a virtual AFM (for benchmarks only).

    Runs a fresh validation trajectory with minor loops (:func:`validation_waveform`) over
    ``center +- span/2`` on the identification line, right after the identification (and
    calibration) records, and compares each model's prediction, run continuously from the
    start of the identification record over ``ident.history_u_nm``, the move and the
    validation trajectory (so model and scanner carry the same history), with the true
    extension (``afm.truth.last_record_positions_nm`` less the drift over the trajectory,
    ``last_record_drift_nm``: a model of the scanner is not a model of the sample's drift).
    The first sweep of the validation trajectory is
    not scored, and the constant offset between the model's frame (loop centre at the
    command centre, Section IV) and the sample's frame, which no sensorless measurement can
    see, is removed (mean difference).

    The scale of the position frame is fixed, sensorlessly, by the calibration condition of
    Section IV (the steady loop over the span spans the command span). A scanner whose
    small-signal sensitivity differs from its nominal one breaks that condition; the slope of
    the truth against the prediction (``scale``) measures it, and the errors after removing
    that slope too (``*_after_scale_nm``) measure what remains.

    Parameters
    ----------
    afm : VirtualAFM
        The simulator the identification ran on (its ``truth`` door is read here only).
    ident : AxisIdentification
    models : dict of str to ScannerModel
        Models to score, by name.
    span_nm, center_nm, speed_nm_per_s, n_turns, rng
        The validation trajectory (speed default: that of the identification waveform).

    Returns
    -------
    dict
        Per model: ``validation_max_error_nm``, ``validation_rms_error_nm`` (offset removed),
        ``offset_nm``, ``scale``, ``validation_max_error_after_scale_nm`` and
        ``validation_rms_error_after_scale_nm`` (offset and scale removed).
    """
    axis = ident.axis
    k = 0 if axis == "x" else 1
    T = ident.sample_period_s
    speed = _speed_of(ident.waveform) if speed_nm_per_s is None else float(speed_nm_per_s)
    v = validation_waveform(center_nm, span_nm, speed, T, n_turns=n_turns, rng=rng, start_nm=None)
    if ident.line is None:
        raise ValueError("scoring needs an identification run on this AFM (a line); got a record.")
    slow = ident.line.slow_nm
    cur = afm.command_nm
    pieces = []
    start = (v[0], slow) if axis == "x" else (slow, v[0])
    if cur[0] != start[0] or cur[1] != start[1]:  # e.g. back from another line
        mv = afm.move_to(*start, speed)
        pieces.append(np.asarray(mv.command_nm[:, k]))
    rec = afm.run(axis_command(axis, v, slow))
    # the scanner's own extension: the sample's drift over the trajectory is not the model's
    truth = afm.truth.last_record_extension_nm[:, k]
    history = np.concatenate([ident.history_u_nm, *pieces, rec.command_nm[:, k]])
    n_v = v.size
    lo_i = int(np.argmax(v >= v.max() - 1e-9))  # after the first full sweep
    out: dict[str, Any] = {"n_samples": int(n_v - lo_i), "speed_nm_per_s": float(speed)}
    for name, model in models.items():
        y, _ = simulate(model, history, T, ident.initial_state(model))
        pred = y[-n_v:][lo_i:]
        tr = truth[lo_i:]
        d = tr - pred
        off = float(np.mean(d))
        err = d - off
        coef = np.polyfit(pred, tr, 1)
        err_aff = tr - np.polyval(coef, pred)
        out[name] = {
            "validation_max_error_nm": float(np.max(np.abs(err))),
            "validation_rms_error_nm": float(np.sqrt(np.mean(err**2))),
            "offset_nm": off,
            "scale": float(coef[0]),
            "validation_max_error_after_scale_nm": float(np.max(np.abs(err_aff))),
            "validation_rms_error_after_scale_nm": float(np.sqrt(np.mean(err_aff**2))),
        }
    return out


def _speed_of(wf: IdentificationWaveform) -> float:
    return (wf.u_max_nm - wf.u_min_nm) / (wf.half_cycle_samples * wf.sample_period_s)


def score_model_on_truth(
    afm: Any,
    model: ScannerModel,
    axis: str,
    *,
    span_nm: float = 2000.0,
    center_nm: float = 0.0,
    speed_nm_per_s: float = 250.0,
    n_turns: int = 24,
    rng: int | np.random.Generator | None = 12345,
) -> dict[str, float]:
    """Score one axis' model against the TRUE extension of a FRESH virtual AFM (benchmarks
    only), without the identification that made it: a model file from anywhere (another
    run, a real instrument's rehearsal over the emulator) scored like any other.

    ``afm`` must not have moved: its scanner rests at the command ``(0, 0)`` with its creep
    settled, which is the model's state at rest (:func:`record_state` at 0). The validation
    trajectory (:func:`validation_waveform`, from 0, over ``center +- span/2`` on ``axis``,
    the other axis held at 0) runs at once; its first sweep is not scored, and the constant
    offset between the model's frame and the sample's is removed, as in
    :func:`score_on_truth`, whose figures these are (``validation_max_error_nm``,
    ``validation_rms_error_nm``, ``offset_nm``, ``scale`` and the errors after the scale).
    """
    from piezocomp.identification.estimation.prediction import record_state

    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y'. Got {axis!r}.")
    if afm.time_s != 0 or tuple(afm.command_nm) != (0.0, 0.0):
        raise ValueError("score_model_on_truth needs a fresh virtual AFM (at rest at 0, time 0).")
    k = 0 if axis == "x" else 1
    T = float(afm.sample_period_s)
    v = validation_waveform(
        center_nm, span_nm, speed_nm_per_s, T, n_turns=n_turns, rng=rng, start_nm=0.0
    )
    rec = afm.run(axis_command(axis, v, 0.0))
    truth = afm.truth.last_record_extension_nm[:, k]
    y, _ = simulate(model, rec.command_nm[:, k], T, record_state(model, 0.0))
    lo_i = int(np.argmax(v >= v.max() - 1e-9))  # after the first full sweep
    tr, pred = truth[lo_i:], y[lo_i:]
    d = tr - pred
    off = float(np.mean(d))
    err = d - off
    coef = np.polyfit(pred, tr, 1)
    err_aff = tr - np.polyval(coef, pred)
    return {
        "validation_max_error_nm": float(np.max(np.abs(err))),
        "validation_rms_error_nm": float(np.sqrt(np.mean(err**2))),
        "offset_nm": off,
        "scale": float(coef[0]),
        "validation_max_error_after_scale_nm": float(np.max(np.abs(err_aff))),
        "validation_rms_error_after_scale_nm": float(np.sqrt(np.mean(err_aff**2))),
        "n_samples": int(v.size - lo_i),
    }
