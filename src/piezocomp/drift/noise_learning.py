"""The drift's noise learnt from the session's own landmark measurements.

The drift filter needs the noise of the drift it tracks
(:class:`~piezocomp.drift.filter.DriftNoise`): how fast the drift's own random walk wanders
and how fast its rate changes. No instrument states them and they change from one session
to the next (the room, the warm-up, the sample), so tracking starts from a generic prior
(the defaults of ``DriftNoise``, set for no instrument in particular) and re-estimates them
from its own measurements as they accumulate: by maximum likelihood over the filter's
innovations (:func:`~piezocomp.drift.filter.fit_noise`), first after ``after``
measurements, then after every ``every`` more. Only the drift's own noise is taken from the
fit: the measurement noise stays what the landmark sightings say.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from piezocomp.drift.filter import DriftNoise, Measurement, fit_noise

__all__ = ["adopt", "due", "relearn"]


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
