"""Rounds of the sample's drift along the identification lines and the estimation again
with it taken out (the stage of :func:`~piezocomp.identification.sensorless.estimate_axis`
that runs on a drifting instrument).

Each round estimates every line's drift path together with the batch model
(:func:`~piezocomp.identification.estimation.drift_along_line.joint_line_drift`), then the whole
estimation again with the paths as known shifts of ``h``'s argument
(:meth:`~piezocomp.identification.estimation.problem.EstimationProblem.estimate`). The result is
kept when the batch model then predicts the held-out heights better."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.estimation.chain import Estimation
from piezocomp.identification.estimation.drift_along_line import (
    LineDrift,
    fit_line_drift,
    joint_line_drift,
    straight,
)
from piezocomp.identification.estimation.findings import DRIFT_FINDING_NM
from piezocomp.identification.estimation.prediction import model_profile, predicted_forward_trace
from piezocomp.identification.estimation.problem import EstimationProblem

__all__ = ["DRIFT_ANCHOR", "DRIFT_KNOT_SPACING_S", "DRIFT_SMOOTHING", "DriftRounds", "drift_rounds"]

DRIFT_KNOT_SPACING_S = 20.0
"""Knot spacing of the drift path
(:func:`~piezocomp.identification.estimation.drift_along_line.fit_line_drift`)."""

DRIFT_SMOOTHING = 1.0
"""Smoothing of the drift path
(:func:`~piezocomp.identification.estimation.drift_along_line.fit_line_drift`)."""

DRIFT_ANCHOR = 1.0
"""How strongly the drift path stays near the rate measured while the tip settled on the line
(:func:`~piezocomp.identification.estimation.drift_along_line.joint_line_drift`'s ``anchor``): with
many slow creep modes the heights alone leave part of a steady drift to creep."""


@dataclass(frozen=True)
class DriftRounds:
    """What :func:`drift_rounds` found: each line's drift path, the estimation with them
    taken out, and whether it was kept."""

    paths: tuple[LineDrift, ...] = ()
    estimation: Estimation | None = None
    kept: bool = False
    heldout_without_nm: float = float("nan")
    heldout_with_nm: float = float("nan")

    @property
    def shifts(self) -> list[NDArray[np.float64]]:
        return [p.path() for p in self.paths]

    def summary(self) -> dict[str, Any] | None:
        """``line_drift`` of :class:`AxisIdentification` (``None`` when not estimated)."""
        if not self.paths:
            return None
        first = self.paths[0]
        return {
            "kept": self.kept,
            "rate_nm_per_s": first.rate_nm_per_s,
            "extent_nm": first.extent_nm,
            "lines": [
                {"rate_nm_per_s": p.rate_nm_per_s, "extent_nm": p.extent_nm,
                 "knots_s": p.knots_s.tolist(), "drift_nm": p.drift_nm.tolist()}
                for p in self.paths
            ],
            "heldout_rms_without_nm": self.heldout_without_nm,
            "heldout_rms_with_nm": self.heldout_with_nm,
        }  # fmt: skip


def drift_rounds(problem: EstimationProblem, est: Estimation) -> DriftRounds:
    """``RoundsConfig.drift_rounds`` rounds of the drift paths of every line, estimated with the
    batch model (:func:`~piezocomp.identification.estimation.drift_along_line.joint_line_drift`,
    started from the rate measured while the tip settled, or from
    :func:`~piezocomp.identification.estimation.drift_along_line.fit_line_drift` without one), and
    the estimation again with them taken out (``problem.estimate``); kept when its batch model
    predicts the held-out heights better than ``est``'s. Not run when the particles did not slide
    while the tip settled by more than
    :data:`~piezocomp.identification.estimation.findings.DRIFT_FINDING_NM` over a record's length (a
    scanner that does not drift keeps its estimation as it was)."""
    records, options, rounds = problem.records, problem.options, problem.rounds
    fit_mask, creep_start = problem.fit_mask, problem.creep_start_nm
    wf, T = records.waveform, records.sample_period_s
    settled = records.drift_nm_per_s
    if rounds.drift_rounds <= 0 or (
        settled is not None and not abs(settled) * records.u_nm.size * T > DRIFT_FINDING_NM
    ):  # no drift to speak of while the tip settled: the estimation stands as it is
        return DriftRounds()
    forward = wf.forward_traces
    lines = [(records.u_nm, records.height_nm)]
    lines += [(e.u_nm, e.height_nm) for e in records.extra]
    current = est
    paths: list[LineDrift] = []
    anchor = DRIFT_ANCHOR if settled is not None else 0.0
    for _ in range(rounds.drift_rounds):
        model = current.batch_model
        if settled is not None and not paths:
            # The particles slid along the line at `settled` nm/s of command while the tip
            # settled: in h's coordinates the drift runs the other way, times the slope.
            y_fwd = predicted_forward_trace(model, records.u_nm, T, forward, creep_start)
            slope = float(np.ptp(y_fwd) / np.ptp(records.u_nm[forward[0]]))
            paths = [straight(u_i.size, T, forward, -slope * settled) for u_i, _ in lines]
        with_h = []
        for i, (u_i, z_i) in enumerate(lines):
            shift = paths[i].path() if paths else None
            try:
                prof = (
                    current.batch_profile
                    if i == 0
                    else model_profile(model, u_i, z_i, T, forward, creep_start, shift_nm=shift)
                )
                start = paths[i] if paths else fit_line_drift(
                    model, prof, u_i, z_i, T, reference=forward, fit_mask=fit_mask,
                    warmup_samples=2 * wf.half_cycle_samples, creep_start_nm=creep_start,
                    knot_spacing_s=DRIFT_KNOT_SPACING_S,
                    smoothing=DRIFT_SMOOTHING, rate_nm_per_s=records.drift_nm_per_s,
                )  # fmt: skip
            except ValueError:  # this line's heights cannot place it: it is left out
                if i == 0:
                    return DriftRounds()
                continue
            with_h.append((i, (u_i, z_i, prof, start)))
        _, found = joint_line_drift(
            model, [line for _, line in with_h], T, reference=forward, fit_mask=fit_mask,
            warmup_samples=2 * wf.half_cycle_samples, creep_start_nm=creep_start,
            knot_spacing_s=DRIFT_KNOT_SPACING_S, smoothing=DRIFT_SMOOTHING,
            anchor=anchor, free=options.refine_free,
            max_nfev=options.reindex_max_nfev or options.refine_max_nfev,
            creep_smoothing_nm=options.creep_smoothing_nm,
            weight_smoothing_nm=options.weight_smoothing_nm,
        )  # fmt: skip
        by_line = dict(zip((i for i, _ in with_h), found, strict=True))
        paths = [by_line.get(i) or straight(line[0].size, T, (), 0.0)  # none found: still
                 for i, line in enumerate(lines)]  # fmt: skip
        shifts = [p.path() for p in paths]
        current = problem.estimate(shifts)
    without = est.heldout_rms_nm["batch"]
    with_drift = current.heldout_rms_nm["batch"]
    kept = bool(np.isfinite(with_drift) and not with_drift >= without)
    return DriftRounds(tuple(paths), current, kept, float(without), float(with_drift))
