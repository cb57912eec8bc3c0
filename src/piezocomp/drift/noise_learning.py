"""The drift's noise learnt from the session's own landmark measurements.

The drift filter needs the noise of the drift it tracks
(:class:`~piezocomp.drift.filter.DriftNoise`): how fast the drift's own random walk wanders
and how fast its rate changes. No instrument states them and they change from one session
to the next (the room, the warm-up, the sample), so tracking starts from a generic prior
(the defaults of ``DriftNoise``, set for no instrument in particular) and re-estimates them
from its own measurements as they accumulate: by maximum likelihood over the filter's
innovations (:func:`~piezocomp.drift.filter.fit_noise`), first after ``after``
measurements, then after every ``every`` more. Only the drift's own noise is taken from the
fit. The measurement noise is what the landmark sightings say: the spread of the landmarks
of one measurement about their mean, pooled over the session with the prior counted as
:data:`PRIOR_DOF` observations (:class:`SightingSpread`); sighted seconds apart, two landmarks
differ by their own errors and hardly by the drift.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar
from piezocomp.drift.filter import DriftNoise, Measurement, fit_noise

__all__ = ["PRIOR_DOF", "SightingSpread", "adopt", "due", "relearn"]

PRIOR_DOF = 4
"""Degrees of freedom the prior measurement noise counts for in :class:`SightingSpread`
(two measurements of two landmarks, both axes): the prior holds until the session has said
about as much."""


def due(n_measurements: int, after: int, every: int) -> bool:
    """Whether the noise is re-estimated once ``n_measurements`` drift measurements have
    been taken: at ``after``, then every ``every`` more (``after = 0``: never)."""
    if after <= 0 or n_measurements < after:
        return False
    return (n_measurements - after) % max(every, 1) == 0


def adopt(noise: DriftNoise, learnt: DriftNoise) -> DriftNoise:
    """``noise`` with the drift's own noise (random walk, rate noise) of ``learnt``."""
    return replace(noise, position_nm_per_sqrt_s=learnt.position_nm_per_sqrt_s,
                   rate_noise=learnt.rate_noise)  # fmt: skip


def relearn(
    measurements: Sequence[Measurement],
    t_start_s: float,
    noise: DriftNoise,
    after: int,
    every: int,
) -> DriftNoise | None:
    """The noise re-estimated from ``measurements`` (those that measured a drift, after the
    reference: zero drift at ``t_start_s``) when :func:`due`, starting from ``noise``;
    ``None`` when not due."""
    seen = [m for m in measurements if m.drift_nm is not None]
    if not due(len(seen), after, every):
        return None
    t = np.array([t_start_s] + [m.t_s for m in seen])
    z = np.vstack([np.zeros(2)] + [np.asarray(m.drift_nm) for m in seen])
    return adopt(noise, fit_noise(t, z, start=noise).noise)


@dataclass(frozen=True)
class SightingSpread:
    """The squared spread of the landmarks about each measurement's mean, pooled over the
    session's measurements and both axes, the prior counted as observations (the conjugate
    update of a variance): ``sigma_nm`` is the standard deviation of one landmark's sighting.

    The landmarks of one measurement are sighted seconds apart, so the drift over those
    seconds counts in the spread too (an overestimate, on the safe side, of a few tenths of
    a nanometre at most for the drift of an AFM in air).
    """

    sum_sq_nm2: float
    dof: int

    @classmethod
    def prior(cls, sigma_nm: float, dof: int = PRIOR_DOF) -> SightingSpread:
        """The prior ``sigma_nm`` (> 0) counted as ``dof`` (>= 1) observations."""
        s = check_finite_scalar("sigma_nm", sigma_nm)
        if s <= 0:
            raise ValueError(f"sigma_nm must be > 0. Got {s}.")
        if isinstance(dof, bool) or int(dof) != dof or dof < 1:
            raise ValueError(f"dof must be an integer >= 1. Got {dof!r}.")
        return cls(int(dof) * s**2, int(dof))

    def with_measurement(self, drifts: Sequence[NDArray[np.float64]]) -> SightingSpread:
        """With one more measurement's trusted landmarks (each one's drift, shape (2,)); one
        landmark alone says nothing of the spread."""
        if len(drifts) < 2:
            return self
        d = np.asarray(drifts, dtype=float)
        ss = self.sum_sq_nm2 + float(((d - d.mean(axis=0)) ** 2).sum())
        return SightingSpread(ss, self.dof + (d.shape[0] - 1) * d.shape[1])

    @property
    def sigma_nm(self) -> float:
        """The pooled standard deviation of one sighting, nm."""
        return float(np.sqrt(self.sum_sq_nm2 / self.dof))
