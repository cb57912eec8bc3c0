"""The record following the line's slide across its particles: the slide measured on the
dithered settling cycles (:func:`follow_line`), and runs whose slow command follows it
(:func:`run_following`) for the identification record, its check and the calibration
cycles (:mod:`~piezocomp.identification.acquisition.recording`).

Only :class:`~piezocomp.instrument.Instrument` methods are used.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.config import AcquisitionConfig
from piezocomp.identification.acquisition.drift_across_line import CrossDrift, cross_line_drift
from piezocomp.identification.acquisition.line_search import axis_command
from piezocomp.instrument import Instrument, Record

__all__ = ["follow_line", "run_following"]


def follow_line(
    settled: Record | None,
    axis: str,
    cycle_samples: int,
    record_s: float,
    cfg: AcquisitionConfig,
    since_s: float | None,
) -> CrossDrift | None:
    """The line's slide across its particles measured on a dithered settling record
    (:func:`~piezocomp.identification.acquisition.drift_across_line.cross_line_drift`; ``since_s``:
    the end of the overview, the slow axis' last large move), marked ``followed`` when it would move
    the line by more than a nanometre over the record that follows the settling."""
    if settled is None or cfg.cross_dither_nm <= 0:
        return None
    k = 0 if axis == "x" else 1
    cross = cross_line_drift(
        settled.command_nm[:, k], settled.height_nm, settled.t_s, settled.command_nm[:, 1 - k],
        cycle_samples, min_prominence_nm=cfg.min_prominence_nm, since_s=since_s,
    )  # fmt: skip
    if cross is None:
        return None
    end = float(settled.t_s[-1])
    return replace(cross, followed=cross.significant(end, record_s),
                   record_slide_nm=cross.moved_nm(end, record_s))  # fmt: skip


def run_following(
    instrument: Instrument,
    axis: str,
    u: NDArray[np.float64],
    slow_nm: float,
    follow: CrossDrift | None,
    *,
    reference_s: float | None = None,
    next_s: float | None = None,
) -> tuple[Record, float]:
    """Run ``u`` on the fast ``axis`` with the slow command at ``slow_nm`` plus, if
    ``follow``, the line's slide since ``reference_s`` (:meth:`CrossDrift.slide_nm`;
    ``None``: since the run's start). A new run's first sample is sent alone, the slow axis
    held where it is, to read the session time; a run continuing another gives its first
    sample's time ``next_s``.
    Returns the record and the time the slide is reckoned from (s)."""
    if follow is None:
        rec = instrument.run(axis_command(axis, u, slow_nm))
        return rec, float(rec.t_s[0]) if rec.t_s.size else 0.0
    T = float(instrument.sample_period_s)
    parts = []
    if next_s is None:
        held = float(instrument.command_nm[1 if axis == "x" else 0])
        parts.append(instrument.run(axis_command(axis, u[:1], held)))
        next_s = float(parts[0].t_s[0])
    ref = next_s if reference_s is None else float(reference_s)
    t = next_s + T * np.arange(u.size, dtype=float)
    slow = slow_nm + follow.slide_nm(t) - follow.slide_nm(ref)
    parts.append(instrument.run(axis_command(axis, u[len(parts) :], slow[len(parts) :])))
    rec = Record(
        np.concatenate([r.t_s for r in parts]),
        np.vstack([r.command_nm for r in parts]),
        np.concatenate([r.height_nm for r in parts]),
    )
    return rec, ref
