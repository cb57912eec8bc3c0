"""The estimation stage of one axis: what it estimates from, and the estimation itself.

:class:`EstimationProblem` holds the acquisition's records and the loop's results with the
stage's own settings, and what follows from them once: the part of the record held out to
choose the orders (:data:`HOLDOUT_FRACTION`), the creep states' start and each line's
smoothing of ``h``. :meth:`EstimationProblem.estimate` runs the chain of
:func:`~piezocomp.identification.estimation.chain.estimate` on the first line, ending with the
stages over every line (:class:`~piezocomp.identification.estimation.several_lines.SeveralLines`);
given each line's drift path it estimates with the drift taken out
(:mod:`~piezocomp.identification.estimation.drift_rounds` does so).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.recording import AxisRecords
from piezocomp.identification.estimation.candidates import initial_from_loop
from piezocomp.identification.estimation.chain import Estimation, estimate
from piezocomp.identification.estimation.config import EstimationConfig, RoundsConfig
from piezocomp.identification.estimation.several_lines import Lines, SeveralLines, line_penalties
from piezocomp.identification.loop.fit import LoopEstimate

__all__ = ["HOLDOUT_FRACTION", "EstimationProblem", "heldout_split"]

HOLDOUT_FRACTION = 0.25
"""Fraction of part B (its end) held out to choose the orders and rounds."""


def heldout_split(n_samples: int, part_b_start: int) -> NDArray[np.bool_]:
    """The fitted samples of a record of ``n_samples`` whose part B starts at
    ``part_b_start``: all but the last :data:`HOLDOUT_FRACTION` of part B."""
    n_fit = n_samples - round(HOLDOUT_FRACTION * (n_samples - part_b_start))
    fit_mask = np.zeros(n_samples, dtype=bool)
    fit_mask[:n_fit] = True
    return fit_mask


@dataclass(frozen=True)
class EstimationProblem:
    """The estimation stage's input for one axis (Section III.C).

    Attributes
    ----------
    records : AxisRecords
        The acquisition's records (the first line, further lines).
    loop : LoopEstimate
        The loop stage's ``f_a`` and ``h(y)`` of the first line.
    options : EstimationConfig
    rounds : RoundsConfig
    fit_mask : ndarray of bool
        The fitted samples of every line (:func:`heldout_split`).
    creep_start_nm : float
        The creep states before each record: the slow creep modes sit near the line's centre
        after the settling, not at the first command (docs/identification-design.md).
    penalties : tuple of float
        Each line's smoothing of ``h``, chosen once for the record (it does not depend on
        the drift, :func:`~piezocomp.identification.estimation.several_lines.line_penalties`).
    """

    records: AxisRecords
    loop: LoopEstimate
    options: EstimationConfig
    rounds: RoundsConfig
    fit_mask: NDArray[np.bool_]
    creep_start_nm: float
    penalties: tuple[float, ...]

    @classmethod
    def from_records(
        cls,
        records: AxisRecords,
        loop: LoopEstimate,
        options: EstimationConfig,
        rounds: RoundsConfig,
    ) -> EstimationProblem:
        """The problem of ``records`` with the loop stage's ``loop``."""
        wf = records.waveform
        all_lines: Lines = [(records.u_nm, records.height_nm, None)]
        all_lines += [(e.u_nm, e.height_nm, None) for e in records.extra]
        return cls(
            records, loop, options, rounds,
            fit_mask=heldout_split(records.u_nm.size, wf.part_b.start),
            creep_start_nm=0.5 * (wf.u_min_nm + wf.u_max_nm),
            penalties=tuple(line_penalties(loop, all_lines, wf)),
        )  # fmt: skip

    def lines(self, shifts: Sequence[NDArray[np.float64] | None] | None = None) -> SeveralLines:
        """Every line with its drift path in ``shifts`` (``None``: none)."""
        r = self.records
        d = [None] * (1 + len(r.extra)) if shifts is None else list(shifts)
        lines: Lines = [(r.u_nm, r.height_nm, d[0])]
        lines += [(e.u_nm, e.height_nm, d_i) for e, d_i in zip(r.extra, d[1:], strict=True)]
        return SeveralLines(lines, r.sample_period_s, r.waveform, self.fit_mask,
                            self.creep_start_nm, self.penalties, self.options,
                            self.rounds)  # fmt: skip

    def estimate(self, shifts: Sequence[NDArray[np.float64] | None] | None = None) -> Estimation:
        """Every candidate order estimated and the orders chosen on the held-out heights
        (:func:`~piezocomp.identification.estimation.chain.estimate`), with further lines the
        joint rounds and the RLS on every line; ``shifts``: each line's drift path."""
        o, wf, r = self.options, self.records.waveform, self.records
        lines = self.lines(shifts)
        shift0 = lines.lines[0][2]  # the first line's drift path
        # with extra lines, the joint rounds replace as many of the first line's own rounds
        first_rounds = o.reindex_rounds
        if r.extra and o.reindex_rounds > 0:
            at_least = 1 if o.selection_rounds is None else max(o.selection_rounds_used, 1)
            first_rounds = max(at_least, o.reindex_rounds - self.rounds.joint_rounds)
        loop = self.loop.loop
        return estimate(
            r.u_nm, r.height_nm, r.sample_period_s, self.loop.profile,
            lambda nh, taus: initial_from_loop(loop, nh, taus.size, time_constants_s=taus),
            fit_mask=self.fit_mask, warmup_samples=2 * wf.half_cycle_samples,
            options=replace(o, reindex_rounds=first_rounds), creep_start_nm=self.creep_start_nm,
            forward_traces=wf.forward_traces, lines=lines, shift_nm=shift0,
        )  # fmt: skip
