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

By default (:func:`relearn`) the fit takes each measurement's standard deviation as the
filter took it, so that the two noises agree, and it learns the drift's order too (a steady
rate, ``[d, v]``, or one that changes, ``[d, v, a]``), starting from the prior and from the
model in use with either order and keeping the most likely.
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
    """``noise`` with the drift's own model (random walk, rate noise, order) of ``learnt``."""
    return replace(noise, position_nm_per_sqrt_s=learnt.position_nm_per_sqrt_s,
                   rate_noise=learnt.rate_noise, order=learnt.order)  # fmt: skip


def relearn(
    measurements: Sequence[Measurement],
    t_start_s: float,
    noise: DriftNoise,
    after: int,
    every: int,
    *,
    prior: DriftNoise | None = None,
    given_sigma: bool = False,
) -> DriftNoise | None:
    """The noise re-estimated from ``measurements`` (those that measured a drift, after the
    reference: zero drift at ``t_start_s``) when :func:`due`; ``None`` when not due.

    The fit starts from ``noise``. With a ``prior`` (the generic one tracking started
    from), the drift's order is learnt too: the fit also starts from the prior and from
    either model with the other order (``[d, v]``: a steady drift rate whose random walk
    wanders; ``[d, v, a]``: a rate that changes, as while warming up), and the noise of the
    largest likelihood is taken. The two orders have the same free parameters (the random
    walk, the rate noise, and without ``given_sigma`` the measurement noise), and the
    likelihood of each is that of the whole series with its unknown rate (and
    acceleration) integrated over the prior: the order the measurements support. A switch
    of order drops what was learnt of the acceleration, or starts it from the prior. Several
    starts also keep the fit from staying at a local optimum it once reached (where the
    same series is read as a wandering acceleration rather than a random walk).

    ``given_sigma``: the measurement noise is what each measurement was taken into the
    estimate with (its ``sigma_nm``), not fitted: the drift's noise is then the scatter
    those do not explain, and the filter's two noises agree (fitted together, the fit can
    put the whole scatter into a measurement noise the filter does not use, and leave it a
    drift that never wanders).

    Raises
    ------
    ValueError
        With ``given_sigma``, if a measurement that measured a drift has no ``sigma_nm``."""
    seen = [m for m in measurements if m.drift_nm is not None]
    if not due(len(seen), after, every):
        return None
    t = np.array([t_start_s] + [m.t_s for m in seen])
    z = np.vstack([np.zeros(2)] + [np.asarray(m.drift_nm) for m in seen])
    sigma = None
    if given_sigma:
        if any(m.sigma_nm is None for m in seen):
            raise ValueError(
                "given_sigma needs every measurement's sigma_nm (the standard deviation it "
                "was taken with): a measurement that measured a drift has none."
            )
        sigma = np.vstack([np.zeros(2)] + [np.asarray(m.sigma_nm) for m in seen])
    starts = [noise]
    if prior is not None:
        starts += [replace(prior, order=k) for k in (2, 3)]
        starts += [replace(noise, order=k) for k in (2, 3) if k != noise.order]
    # the same start twice (the prior, before anything is learnt) is fitted once
    fits = [fit_noise(t, z, start=s, sigma_nm=sigma) for s in dict.fromkeys(starts)]
    return adopt(noise, max(fits, key=lambda f: f.log_likelihood).noise)


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
