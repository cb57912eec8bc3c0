"""The acquisition stage's recording of one axis: what the instrument is asked to do, and what
comes back (the stage's other modules: :mod:`piezocomp.identification.acquisition`).

Section V, steps 1-2 on the instrument: an overview image and the line crossing the most
particles (:func:`~piezocomp.identification.acquisition.line_search.overview_and_line`), the tip
brought back onto it (:func:`~piezocomp.identification.acquisition.line_search.locate_line`) and
left to settle, the identification waveform of Fig. 7a recorded along it and the line checked right
after; then, if asked, calibration cycles over the whole range and the records of further lines.
:func:`record_axis` returns it all as :class:`AxisRecords`, plain data the later stages
(:func:`~piezocomp.identification.sensorless.estimate_axis`) take; a recorded run made with
an instrument's own software enters the same stages through
:func:`~piezocomp.identification.offline.records_from_signal`.

Only :class:`~piezocomp.instrument.Instrument` methods are used.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.config import AcquisitionConfig
from piezocomp.identification.acquisition.drift_across_line import CrossDrift
from piezocomp.identification.acquisition.following import follow_line, run_following
from piezocomp.identification.acquisition.instrument_time import InstrumentClock
from piezocomp.identification.acquisition.line_choice import LineChoice
from piezocomp.identification.acquisition.line_search import (
    MIN_LINE_PARTICLES,
    LineStability,
    cycle_pairs,
    line_stability,
    locate_line,
    overview_and_line,
    settle_on_line,
    settling_drift_rate,
)
from piezocomp.identification.acquisition.waveforms import (
    IdentificationWaveform,
    identification_waveform,
)
from piezocomp.instrument import Instrument, ScanCalibration, ScanImage

__all__ = [
    "AxisRecords",
    "CalibrationRecord",
    "ExtraLine",
    "axis_waveform",
    "calibration_speed",
    "calibration_waveform",
    "overview_line_rate",
    "record_axis",
    "record_extra_lines",
]

RELOCATE_SEARCH_NM = 40.0
"""Neighbourhood searched for the line when the tip left it while settling."""

CHECK_TOLERANCE_NM = 1.0
"""Change of the line's profile over the record, beyond its repeatability (RMS), reported as
a finding (and recorded anew, ``AcquisitionConfig.rerecord_unstable``)."""

DEFAULT_CALIBRATION_SPEED_NM_PER_S = 1000.0
"""Speed of the calibration cycles when neither the configuration nor the instrument
states one."""


@dataclass(frozen=True)
class CalibrationRecord:
    """Steady cycles over ``calibration_span_nm`` (the axis' command, heights, waveform)."""

    u_nm: NDArray[np.float64]
    height_nm: NDArray[np.float64]
    waveform: IdentificationWaveform


@dataclass(frozen=True)
class ExtraLine:
    """A further particle line's record (``AcquisitionConfig.extra_lines``), and the axis'
    commands from its settling on (for the command history)."""

    line: LineChoice
    u_nm: NDArray[np.float64]
    height_nm: NDArray[np.float64]
    history_u_nm: NDArray[np.float64]


@dataclass(frozen=True)
class AxisRecords:
    """What the instrument returned for one axis: the input of the later stages.

    Attributes
    ----------
    axis : {"x", "y"}
    waveform : IdentificationWaveform
        The waveform of Fig. 7a that was run.
    sample_period_s : float
    u_nm, height_nm : ndarray
        The identification record: the axis' command and the measured heights.
    history_u_nm : ndarray
        Every command of the axis from the record on (for continuing a model).
    line : LineChoice or None
        The line recorded (``slow_nm`` where it was recorded); ``None`` for a recorded run.
    overview : ScanImage or None
        The overview image the line was chosen on.
    search_pairs : tuple
        Paired peaks of the lines scanned while locating the line (more equations (23) of
        the same steady loop).
    line_stability : LineStability or None
        The line's profile change over the record, if checked.
    calibration : CalibrationRecord or None
        Steady cycles over the calibration span, if run.
    extra : tuple of ExtraLine
        The further lines' records.
    notes : tuple of str
        What happened during the acquisition that a user should read.
    timing_s : dict
        Time spent in each part of the acquisition.
    range_nm : float or None
        The scanner's travel, if known.
    drift_nm_per_s : float or None
        How fast the line's particles slid along the fast axis while the tip settled on the
        line (:func:`~piezocomp.identification.acquisition.line_search.settling_drift_rate`): the
        sample's drift along the line, which the record cannot tell from creep.
    cross_drift : CrossDrift or None
        The line's slide across its particles measured while the tip settled
        (:func:`~piezocomp.identification.acquisition.drift_across_line.cross_line_drift`); its
        ``followed`` says whether the record's slow command followed it.
    instrument_s : dict
        Instrument time of each stage of the acquisition, s
        (:class:`~piezocomp.identification.acquisition.instrument_time.InstrumentClock`): the
        overview, the line search, settling, the record and its check, the calibration cycles, the
        extra lines; empty for a recorded run.
    """

    axis: str
    waveform: IdentificationWaveform
    sample_period_s: float
    u_nm: NDArray[np.float64]
    height_nm: NDArray[np.float64]
    history_u_nm: NDArray[np.float64]
    line: LineChoice | None = None
    overview: ScanImage | None = None
    search_pairs: tuple[Any, ...] = ()
    line_stability: LineStability | None = None
    calibration: CalibrationRecord | None = None
    extra: tuple[ExtraLine, ...] = ()
    notes: tuple[str, ...] = ()
    timing_s: dict[str, float] = field(default_factory=dict)
    range_nm: float | None = None
    drift_nm_per_s: float | None = None
    cross_drift: CrossDrift | None = None
    instrument_s: dict[str, float] = field(default_factory=dict)

    @property
    def center_nm(self) -> float:
        """Centre of the working line (its fast-axis command)."""
        return 0.5 * (self.waveform.u_min_nm + self.waveform.u_max_nm)


def axis_waveform(
    cfg: AcquisitionConfig, instrument: Instrument, axis: str
) -> IdentificationWaveform:
    """The identification waveform of Fig. 7a for ``axis``, at the configured speed capped at
    the instrument's limit."""
    speed = min(cfg.speed_nm_per_s, float(instrument.max_speed_nm_per_s))
    w = cfg.waveform
    return identification_waveform(
        cfg.center_nm[0 if axis == "x" else 1], cfg.span_nm, speed,
        float(instrument.sample_period_s), n_steady=w.n_steady, n_decaying=w.n_decaying,
        n_random=w.n_random, max_dwell_s=w.max_dwell_s, speed_factors=w.speed_factors,
        max_speed_nm_per_s=float(instrument.max_speed_nm_per_s), rng=w.seed,
    )  # fmt: skip


def record_axis(
    instrument: Instrument, cfg: AcquisitionConfig, axis: str, *, loop_degree: int
) -> AxisRecords:
    """Run the acquisition of one axis on ``instrument`` (Section V, steps 1-2), on lines
    crossing enough particles for a loop of ``loop_degree`` (eq 23).

    The overview and the line choice, the search back onto the line, settling on it
    (``cfg.line_settle_s``; the line is found again if the tip left it), the identification
    record and the check of the line right after it (recorded anew, at most
    ``cfg.rerecord_unstable`` times, if the line's profile changed), then the calibration
    cycles (``cfg.calibrate``) and the further lines (``cfg.extra_lines``): a
    slow-axis move of a micrometre before the first record would leave the slow axis creeping
    across the line during it. Raises ValueError if no usable line is found.
    """
    t0 = time.perf_counter()
    clock = InstrumentClock(instrument)
    instrument = clock  # every call below is timed, by the stage it belongs to
    speed = min(cfg.speed_nm_per_s, float(instrument.max_speed_nm_per_s))
    wf = axis_waveform(cfg, instrument, axis)
    line_rate = overview_line_rate(cfg, instrument)
    notes: list[str] = []
    with clock.stage("overview"):
        overview, line = overview_and_line(instrument, cfg, axis, line_rate, loop_degree)
    with clock.stage("line search"):
        slow, _, pairs = locate_line(instrument, cfg, axis, line, wf, speed, degree=loop_degree)
    line = replace(line, slow_nm=slow)
    cycle = wf.u_nm[: 2 * wf.half_cycle_samples + 1]
    with clock.stage("settling"):
        settled = settle_on_line(
            instrument, axis, cycle, slow, cfg.line_settle_s, dither_nm=cfg.cross_dither_nm
        )
    k = 0 if axis == "x" else 1
    record_s = wf.u_nm.size * float(instrument.sample_period_s)
    since = overview.t_start_s + overview.forward_nm.shape[0] * overview.line_time_s
    cross = follow_line(settled, axis, cycle.size - 1, record_s, cfg, since)
    drift = None
    if settled is not None:
        drift = settling_drift_rate(
            settled.command_nm[:, k], settled.height_nm, settled.t_s, cycle.size - 1,
            min_prominence_nm=cfg.min_prominence_nm,
        )  # fmt: skip
        if drift is None:
            notes.append(
                "the drift along the line could not be measured on the settling cycles (their "
                "particles could not be followed from one cycle to the next): a drift during "
                "the record would go unnoticed"
            )
    if settled is not None and cycle_pairs(
        settled.command_nm[:, k], settled.height_nm, wf.half_cycle_samples,
        min_prominence_nm=cfg.min_prominence_nm, max_shift_nm=0.15 * cfg.span_nm,
    ) < MIN_LINE_PARTICLES:  # fmt: skip
        # The line was lost while settling (thermal drift): find it again close by.
        try:
            with clock.stage("line search"):
                slow, more = _relocate(instrument, cfg, axis, line, wf, speed)
        except ValueError as exc:
            notes.append(
                f"the tip left the line while settling and the line was not found again "
                f"({exc}); the record runs at the settled slow command"
            )
            more = []
        pairs = [*pairs, *more]
        line = replace(line, slow_nm=slow)
        if cfg.relocate_settle_s > 0:
            with clock.stage("settling"):
                again = settle_on_line(
                    instrument, axis, cycle, slow, cfg.relocate_settle_s,
                    dither_nm=cfg.cross_dither_nm,
                )  # fmt: skip
            cross = follow_line(again, axis, cycle.size - 1, record_s, cfg, since)
    timing = {"acquisition_setup": time.perf_counter() - t0}
    t1 = time.perf_counter()
    follow = cross if cross is not None and cross.followed else None
    with clock.stage("record and check"):
        u, z, history, stability, line, more, ref = _steadiest_record(
            instrument, cfg, axis, line, wf, speed, notes, follow
        )
    pairs = [*pairs, *more]
    timing["acquisition"] = time.perf_counter() - t1
    calibration = None
    if cfg.calibration_span_nm(float(instrument.range_nm)) is not None:
        with clock.stage("calibration cycles"):
            calibration, moves = _calibration_cycles(
                instrument, cfg, axis, line.slow_nm, notes, follow, ref
            )
        history += moves
    t_extra = time.perf_counter()
    with clock.stage("extra lines"):
        extra = record_extra_lines(
            instrument, cfg, axis, wf, speed, line_rate, notes, loop_degree=loop_degree
        )
    if cfg.extra_lines:  # counted like the first line's set-up (its record's run included)
        timing["extra_lines"] = time.perf_counter() - t_extra
    return AxisRecords(
        axis=axis, waveform=wf, sample_period_s=float(instrument.sample_period_s), u_nm=u,
        height_nm=z, history_u_nm=np.concatenate([*history, *(e.history_u_nm for e in extra)]),
        line=line, overview=overview, search_pairs=tuple(pairs), line_stability=stability,
        calibration=calibration, extra=tuple(extra), notes=tuple(notes), timing_s=timing,
        range_nm=float(instrument.range_nm), drift_nm_per_s=drift, cross_drift=cross,
        instrument_s=dict(clock.seconds),
    )  # fmt: skip


def overview_line_rate(cfg: AcquisitionConfig, instrument: Instrument) -> float:
    """Line rate of the overview images, Hz: ``cfg.overview_speed_nm_per_s`` (or the
    waveform's speed) over the span and back, within the instrument's speed limit."""
    v = cfg.overview_speed_nm_per_s
    v = cfg.speed_nm_per_s if v is None else v
    return min(float(v), float(instrument.max_speed_nm_per_s)) / (2.0 * cfg.span_nm)


def _relocate(
    instrument: Instrument,
    cfg: AcquisitionConfig,
    axis: str,
    line: LineChoice,
    wf: IdentificationWaveform,
    speed: float,
) -> tuple[float, list[Any]]:
    """The line searched again over :data:`RELOCATE_SEARCH_NM` about ``line.slow_nm``: its
    slow command and the pairs found (ValueError if not found)."""
    found, _, pairs = locate_line(
        instrument, cfg, axis, line, wf, speed, degree=0, accept_best=True,
        search_nm=RELOCATE_SEARCH_NM, pairs_factor=0,
    )  # fmt: skip
    return found, pairs


def _record_line(
    instrument: Instrument,
    cfg: AcquisitionConfig,
    axis: str,
    wf: IdentificationWaveform,
    slow_nm: float,
    follow: CrossDrift | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], list[Any], LineStability | None, float]:
    """The identification record at ``slow_nm`` (the slow command following the line's
    slide ``follow``, :func:`run_following`), then ``cfg.check_cycles`` steady cycles of the
    line at once (before anything else moves): has its profile changed? Returns the record's
    command and heights, the axis' commands run, the line's stability and the session time
    the slide is reckoned from."""
    k = 0 if axis == "x" else 1
    rec, ref = run_following(instrument, axis, wf.u_nm, slow_nm, follow)
    u = np.ascontiguousarray(rec.command_nm[:, k], dtype=float)
    z = np.ascontiguousarray(rec.height_nm, dtype=float)
    if cfg.check_cycles <= 0:
        return u, z, [u], None, ref
    m2 = 2 * wf.half_cycle_samples
    chk = np.concatenate([wf.u_nm[:1], *([wf.u_nm[1 : m2 + 1]] * cfg.check_cycles)])
    after, _ = run_following(
        instrument, axis, chk, slow_nm, follow, reference_s=ref,
        next_s=float(rec.t_s[-1]) + float(instrument.sample_period_s),
    )  # fmt: skip
    asc = [slice(m2 * c, m2 * c + wf.half_cycle_samples + 1) for c in range(cfg.check_cycles)]
    stability = line_stability(
        u[wf.ascending(1)],
        np.array([z[wf.ascending(c)] for c in range(1, wf.n_steady)]),
        chk[asc[0]],
        np.array([after.height_nm[a] for a in asc[1:] or asc]),
        min_prominence_nm=cfg.min_prominence_nm,
    )
    return u, z, [u, after.command_nm[:, k]], stability, ref


def _steadiest_record(
    instrument: Instrument,
    cfg: AcquisitionConfig,
    axis: str,
    line: LineChoice,
    wf: IdentificationWaveform,
    speed: float,
    notes: list[str],
    follow: CrossDrift | None = None,
) -> tuple[Any, ...]:
    """The record on ``line`` (:func:`_record_line`, the slow command following the line's
    slide ``follow``); while its check finds the profile
    changed (the slow axis crept across the line), the line found again close by (its creep
    has slowed since) and recorded anew, at most ``cfg.rerecord_unstable`` times, keeping the
    steadier record. Returns ``(u, z, history, stability, line, search_pairs, reference_s)``
    (the session time the kept record's slide is reckoned from)."""
    u, z, history, stability, ref = _record_line(instrument, cfg, axis, wf, line.slow_nm, follow)
    pairs: list[Any] = []
    for attempt in range(cfg.rerecord_unstable):
        if stability is None or stability.finding(CHECK_TOLERANCE_NM) is None:
            break
        try:
            slow2, more = _relocate(instrument, cfg, axis, line, wf, speed)
        except ValueError as exc:
            notes.append(
                f"the line's profile changed during the record and the line was not found "
                f"again to record it anew ({exc})"
            )
            break
        again = _record_line(instrument, cfg, axis, wf, slow2, follow)
        assert again[3] is not None
        before = stability.height_change_rms_nm - stability.noise_rms_nm
        after = again[3].height_change_rms_nm - again[3].noise_rms_nm
        kept = after < before
        notes.append(
            f"the line's profile changed during the record by {before:.2f} nm RMS beyond the "
            f"cycle-to-cycle repeatability; the line was found again and recorded anew "
            f"(attempt {attempt + 1}): {after:.2f} nm, "
            + ("the new record is used" if kept else "the first record is kept")
        )
        if kept:
            u, z, history, stability, ref = again
            pairs = [*pairs, *more]
            line = replace(line, slow_nm=slow2)
        else:  # the scanner ran the new record all the same (its search's steady cycles
            # are left out, as for the extra lines: the record's part A wipes them out)
            history += again[2]
    return u, z, history, stability, line, pairs, ref


def _calibration_cycles(
    instrument: Instrument,
    cfg: AcquisitionConfig,
    axis: str,
    slow: float,
    notes: list[str],
    follow: CrossDrift | None = None,
    reference_s: float | None = None,
) -> tuple[CalibrationRecord, list[NDArray[np.float64]]]:
    """Steady cycles over the calibration span (``cfg.calibrate``) about the line's centre at the
    calibration speed (:func:`calibration_speed`), on the record's line (at ``slow``, plus
    the slide ``follow`` since ``reference_s`` when the record followed it), and the axis'
    commands of the move there and of the cycles."""
    k = 0 if axis == "x" else 1
    cwf, speed = calibration_waveform(cfg, instrument, axis, notes)
    here = float(instrument.command_nm[1 - k])  # the slow axis stays on the line
    go = (cwf.u_nm[0], here) if axis == "x" else (here, cwf.u_nm[0])
    moved = instrument.move_to(go[0], go[1], speed).command_nm[:, k]
    rec, _ = run_following(instrument, axis, cwf.u_nm, slow, follow, reference_s=reference_s)
    record = CalibrationRecord(
        np.ascontiguousarray(rec.command_nm[:, k]), np.ascontiguousarray(rec.height_nm), cwf
    )
    return record, [moved, rec.command_nm[:, k]]


def calibration_waveform(
    cfg: AcquisitionConfig, instrument: Instrument, axis: str, notes: list[str]
) -> tuple[IdentificationWaveform, float]:
    """The calibration cycles' command: ``cfg.waveform.n_steady`` steady cycles over
    the calibration span (``cfg.calibrate``) about the line's centre, and their speed
    (:func:`calibration_speed` within the instrument's limit, nm/s)."""
    span = cfg.calibration_span_nm(float(instrument.range_nm))
    if span is None:
        raise ValueError("calibrate='span': there are no calibration cycles.")
    speed = min(calibration_speed(cfg, instrument, notes), float(instrument.max_speed_nm_per_s))
    wf = identification_waveform(
        cfg.center_nm[0 if axis == "x" else 1], span, speed,
        float(instrument.sample_period_s), n_steady=cfg.waveform.n_steady, n_decaying=0, n_random=0,
    )  # fmt: skip
    return wf, speed


def calibration_speed(cfg: AcquisitionConfig, instrument: Any, notes: list[str]) -> float:
    """The calibration cycles' speed: the configuration's, else the instrument's calibration
    record (``calibration_scan``), else the default with a note."""
    if cfg.calibration_speed_nm_per_s is not None:
        return float(cfg.calibration_speed_nm_per_s)
    scan = getattr(instrument, "calibration_scan", None)
    if isinstance(scan, ScanCalibration):
        return scan.speed_nm_per_s
    notes.append(
        "the instrument states no calibration scan: the calibration cycles ran at "
        f"{DEFAULT_CALIBRATION_SPEED_NM_PER_S:g} nm/s, and the model's scale holds only if "
        "the scanner was calibrated at that speed (set calibration_speed_nm_per_s)"
    )
    return DEFAULT_CALIBRATION_SPEED_NM_PER_S


def record_extra_lines(
    instrument: Instrument,
    cfg: AcquisitionConfig,
    axis: str,
    wf: IdentificationWaveform,
    speed: float,
    line_rate: float,
    notes: list[str],
    *,
    loop_degree: int,
) -> list[ExtraLine]:
    """Overview, line search, settling and the identification record on each extra line
    (instrument calls only). The areas tried are ``extra_line_offset_nm`` away on the slow
    axis, then twice as far, alternating sides (+1, -1, +2, -2, ... offsets), until
    ``extra_lines`` lines are found or twice as many areas plus two have been tried; an
    area without a usable line is reported and skipped."""
    out: list[ExtraLine] = []
    k_axis = 0 if axis == "x" else 1
    cx, cy = cfg.center_nm
    for j in range(2 * cfg.extra_lines + 2 if cfg.extra_lines else 0):
        if len(out) == cfg.extra_lines:
            break
        d = cfg.extra_line_offset_nm * (j // 2 + 1) * (1 if j % 2 == 0 else -1)
        sub = replace(cfg, center_nm=(cx, cy + d) if axis == "x" else (cx + d, cy))
        try:
            image_k, line_k = overview_and_line(instrument, sub, axis, line_rate, loop_degree)
            slow_k, _, _ = locate_line(instrument, sub, axis, line_k, wf, speed, degree=loop_degree)
        except ValueError as exc:
            notes.append(
                f"no extra line at {d:+g} nm on the slow axis ({exc}); "
                + ("the next area is tried" if j + 1 < 2 * cfg.extra_lines + 2 else "none left")
            )
            continue
        cycle = wf.u_nm[: 2 * wf.half_cycle_samples + 1]
        settled = settle_on_line(
            instrument, axis, cycle, slow_k, cfg.line_settle_s, dither_nm=cfg.cross_dither_nm
        )
        record_s = wf.u_nm.size * float(instrument.sample_period_s)
        since = image_k.t_start_s + image_k.forward_nm.shape[0] * image_k.line_time_s
        cross = follow_line(settled, axis, cycle.size - 1, record_s, cfg, since)
        follow = cross if cross is not None and cross.followed else None
        rec, _ = run_following(instrument, axis, wf.u_nm, slow_k, follow)
        u_k = np.ascontiguousarray(rec.command_nm[:, k_axis], dtype=float)
        before = [] if settled is None else [settled.command_nm[:, k_axis]]
        out.append(
            ExtraLine(
                replace(line_k, slow_nm=slow_k),
                u_k,
                np.ascontiguousarray(rec.height_nm, dtype=float),
                np.concatenate([*before, u_k]),
            )
        )
    return out
