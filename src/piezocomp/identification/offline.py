"""Sensorless identification offline, from a record made on any instrument.

A real instrument need not be driven by piezocomp: ``piezocomp waveform`` writes the
identification waveform of Fig. 7a (command samples, with the parameters that generated it
in the file's metadata); the user runs it on one line with the instrument's own software,
recording the topography, and saves ``t_s, u_nm, height_nm`` with the same metadata line.
:func:`identify_record` then runs the estimation half of the procedure: the loop and
``h(y)`` from the steady cycles of part A (Section IV, eqs 21-23), RLS (eqs 16-20) and the
batch refinement on part B, the orders chosen on a held-out part of the record by its
height prediction (no sensor needed).

A length reference works offline too: run the minor-loop grating path of the same span,
centre and speed (``piezocomp waveform --grating-line I``, one file per line) or the paper's
steady cycles (``piezocomp waveform --n-decaying 0 --n-random 0 --n-steady 6``) across a
grating of known pitch, on one or more lines, and pass the records to
:func:`grating_record_from_signals`;
:func:`identify_record` then scales the models to the grating
(:mod:`~piezocomp.identification.reference.grating`).

What the offline path cannot do that :func:`~piezocomp.identification.sensorless.identify_axis`
does on a driven instrument: choose the line, settle on it, check it after the record, and
map the model onto a full-range calibration frame; without a grating the scale is the
paper's calibration condition on the working span.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.recording import AxisRecords
from piezocomp.identification.acquisition.waveforms import (
    IdentificationWaveform,
    identification_waveform,
    ramps,
)
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.reference.grating import (
    PATH_SEED,
    GratingRecord,
    minor_loop_path,
    sweep_passes,
)
from piezocomp.identification.result import AxisIdentification
from piezocomp.identification.sensorless import check_reference, estimate_axis
from piezocomp.io.signals import RecordedSignal

__all__ = [
    "GRATING_PATH_KEY",
    "WAVEFORM_KEY",
    "grating_path_from_metadata",
    "grating_path_metadata",
    "grating_record_from_signals",
    "identify_record",
    "records_from_signal",
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
_OPTIONAL: dict[str, Any] = {"speed_factors": [1.0], "range_nm": None}
"""Parameters added later, with the value that rebuilds a file written without them
(``range_nm``, the scanner's full travel the waveform was made for: None, not stated)."""


def waveform_metadata(parameters: Mapping[str, Any]) -> dict[str, str]:
    """Metadata that lets :func:`waveform_from_metadata` rebuild the waveform exactly."""
    missing = [k for k in _PARAMETERS if k not in parameters]
    if missing:
        raise ValueError(f"waveform parameters are missing {missing}.")
    keys = _PARAMETERS + tuple(k for k in _OPTIONAL if k in parameters)
    return {WAVEFORM_KEY: json.dumps({k: parameters[k] for k in keys})}


GRATING_PATH_KEY = "piezocomp_grating_path"
"""Metadata key holding a minor-loop grating line's parameters (JSON) in its waveform and
record files (``piezocomp waveform --grating-line I``)."""

_GRATING_PATH_PARAMETERS = (
    "center_nm",
    "span_nm",
    "speed_nm_per_s",
    "sample_period_s",
    "n_sweeps",
    "line",
)


def grating_path_metadata(parameters: Mapping[str, Any]) -> dict[str, str]:
    """Metadata that lets :func:`grating_path_from_metadata` rebuild a minor-loop grating
    line's command exactly (:func:`~piezocomp.identification.reference.grating.minor_loop_path`
    of line ``line``)."""
    if sorted(parameters) != sorted(_GRATING_PATH_PARAMETERS):
        raise ValueError(
            f"grating path parameters must be exactly {_GRATING_PATH_PARAMETERS}. "
            f"Got {sorted(parameters)}."
        )
    return {GRATING_PATH_KEY: json.dumps({k: parameters[k] for k in _GRATING_PATH_PARAMETERS})}


def grating_path_from_metadata(
    metadata: Mapping[str, str], source: str = "grating record"
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """A minor-loop grating line's command rebuilt from a file's metadata, and its
    parameters."""
    try:
        params = json.loads(metadata[GRATING_PATH_KEY])
    except json.JSONDecodeError as exc:
        raise ValueError(f"{source}: '{GRATING_PATH_KEY}' is not valid JSON ({exc.msg}).") from None
    if not isinstance(params, dict) or sorted(params) != sorted(_GRATING_PATH_PARAMETERS):
        raise ValueError(
            f"{source}: '{GRATING_PATH_KEY}' must hold exactly the keys {_GRATING_PATH_PARAMETERS}."
        )
    line = params["line"]
    if isinstance(line, bool) or not isinstance(line, int) or line < 0:
        raise ValueError(f"{source}: the grating line must be an integer >= 0. Got {line!r}.")
    try:
        u = minor_loop_path(
            params["center_nm"], params["span_nm"], params["speed_nm_per_s"],
            params["sample_period_s"], n_sweeps=params["n_sweeps"], rng=PATH_SEED + line,
        )  # fmt: skip
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from None
    return u, params


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


def _recorded_command(
    signal: RecordedSignal,
    expected_nm: NDArray[np.float64],
    sample_period_s: float,
    axis: str,
    tolerance_nm: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The record's command and heights, checked against the waveform it claims to be (its
    command ``expected_nm`` every ``sample_period_s``)."""
    source = signal.source or "record"
    column = "u_nm" if "u_nm" in signal else f"{axis}_nm"
    if column not in signal:
        raise ValueError(f"{source}: no command column 'u_nm' or '{axis}_nm'.")
    u = np.ascontiguousarray(signal[column], dtype=float)
    z = np.ascontiguousarray(signal["height_nm"], dtype=float)
    T = signal.sample_period_s
    if abs(T - sample_period_s) > 1e-6 * sample_period_s:
        raise ValueError(
            f"{source}: sampled every {T:.9g} s but the waveform was made for "
            f"{sample_period_s:.9g} s."
        )
    if u.size != expected_nm.size:
        what = "fewer" if u.size < expected_nm.size else "more"
        raise ValueError(
            f"{source}: {u.size} samples, {what} than the waveform's {expected_nm.size}: the "
            "record must hold the waveform's samples exactly (trim what was recorded before or "
            "after)."
        )
    dev = np.abs(u - expected_nm)
    if dev.max() > tolerance_nm:
        k = int(np.argmax(dev))
        raise ValueError(
            f"{source}: the recorded command differs from the waveform by {dev[k]:.6g} nm at "
            f"sample {k} (allowed {tolerance_nm:g} nm): not a record of this waveform, or a "
            "recorder that rounds the command (then raise --command-tolerance-nm to its step)."
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
    turning point, so the lines join into one continuous command), or of minor-loop lines
    (``piezocomp waveform --grating-line I``, each its own line's path; their sweeps are
    the passes).

    Each signal must carry the waveform's metadata (``piezocomp waveform --n-decaying 0
    --n-random 0``) and match it; the first ``skip_cycles`` cycles of each line are not used.
    Signals that hold both ``x_nm`` and ``y_nm`` give each line's slow command (the other
    axis' mean), from which :func:`fit_scale` measures the grating's angle.
    """
    if not signals:
        raise ValueError("grating records: give at least one signal.")
    paths = [GRATING_PATH_KEY in s.metadata for s in signals]
    if any(paths):
        if not all(paths):
            raise ValueError(
                "grating records: some are minor-loop lines (piezocomp waveform --grating-line) "
                "and some steady cycles; give the lines of one kind."
            )
        return _minor_loop_record(signals, pitch_nm, axis, tolerance_nm)
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
        u, z = _recorded_command(s, wf.u_nm, wf.sample_period_s, axis, tolerance_nm)
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


def _minor_loop_record(
    signals: list[RecordedSignal], pitch_nm: float, axis: str, tolerance_nm: float
) -> GratingRecord:
    """:func:`grating_record_from_signals` for minor-loop lines: each line's command rebuilt
    from its metadata and checked, its sweeps the passes. A line ends where its last sweep
    did and the next starts at the span's low end: the move between them, which no file
    holds, is put in as a ramp at the path's speed (its heights are not used)."""
    us: list[NDArray[np.float64]] = []
    zs: list[NDArray[np.float64]] = []
    passes: list[tuple[int, int]] = []
    lines: list[int] = []
    other = "y_nm" if axis == "x" else "x_nm"
    slows = [float(np.mean(s[other])) for s in signals if other in s]
    first: dict[str, Any] | None = None
    seen: set[int] = set()
    n0 = 0
    for i, s in enumerate(signals):
        where = s.source or "grating record"
        expected, params = grating_path_from_metadata(s.metadata, where)
        same = {k: v for k, v in params.items() if k != "line"}
        if first is None:
            first = same
        elif same != first:
            raise ValueError(
                f"{where}: another span, centre, speed or period than the first line's."
            )
        if params["line"] in seen:
            raise ValueError(f"{where}: grating line {params['line']} is given twice.")
        seen.add(params["line"])
        u, z = _recorded_command(s, expected, params["sample_period_s"], axis, tolerance_nm)
        if us:  # the move from the last line's end, which no file holds, at the path's speed
            move = ramps([us[-1][-1], u[0]], params["speed_nm_per_s"], params["sample_period_s"])
            inner = move[1:-1]
            us.append(inner)
            zs.append(np.zeros(inner.size))
            n0 += inner.size
        us.append(u)
        zs.append(z)
        for a, b in sweep_passes(u, params["span_nm"]):
            passes.append((n0 + a, n0 + b))
            lines.append(i)
        n0 += u.size
    assert first is not None
    return GratingRecord(
        axis=axis,
        pitch_nm=pitch_nm,
        u_nm=np.concatenate(us),
        height_nm=np.concatenate(zs),
        sample_period_s=float(first["sample_period_s"]),
        passes=tuple(passes),
        pass_lines=tuple(lines),
        line_slow_nm=tuple(slows) if len(slows) == len(signals) else None,
    )


def records_from_signal(
    signal: RecordedSignal, *, axis: str = "x", tolerance_nm: float = 1e-3
) -> tuple[AxisRecords, dict[str, Any]]:
    """A recorded identification run as the records the estimation stage takes, and the
    waveform's parameters (from the file's metadata)."""
    wf, params = waveform_from_metadata(signal.metadata, signal.source or "record")
    u, z = _recorded_command(signal, wf.u_nm, wf.sample_period_s, axis, tolerance_nm)
    records = AxisRecords(
        axis=axis, waveform=wf, sample_period_s=signal.sample_period_s, u_nm=u, height_nm=z,
        history_u_nm=u,
    )  # fmt: skip
    return records, params


def identify_record(
    signal: RecordedSignal,
    config: IdentifyConfig | None = None,
    *,
    axis: str = "x",
    tolerance_nm: float = 1e-3,
    reference: GratingRecord | None = None,
) -> AxisIdentification:
    """Estimate the model of one axis from a recorded identification run: the estimation
    stage of the pipeline (:func:`~piezocomp.identification.sensorless.estimate_axis`) on
    the recorded records.

    Parameters
    ----------
    signal : RecordedSignal
        ``t_s``, the command (``u_nm``, or ``x_nm``/``y_nm`` with ``axis``), ``height_nm``
        and the waveform's metadata (:data:`WAVEFORM_KEY`).
    config : IdentifyConfig, optional
        The settings (the loop's, the estimation's and the rounds'; the waveform file fixes
        the acquisition). Default: the defaults.
    axis : {"x", "y"}
        Axis the waveform ran on, when the record holds both commands.
    tolerance_nm : float
        Largest allowed difference between the recorded command and the waveform.
    reference : GratingRecord, optional
        Steady cycles over a grating of known pitch, same axis, span, centre and speed
        (:func:`grating_record_from_signals`): the models are scaled to it.
    """
    cfg = IdentifyConfig() if config is None else config
    check_reference(reference, axis)
    records, _ = records_from_signal(signal, axis=axis, tolerance_nm=tolerance_nm)
    return estimate_axis(records, cfg, reference=reference)
