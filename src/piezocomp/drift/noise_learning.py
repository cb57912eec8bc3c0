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

A few tens of measurements cannot tell a random walk smaller than their own noise over the
time they span (q^2 T < sigma^2) from none at all: the likelihood is flat there, and the
fit may wander to 1e-7 nm/sqrt(s). The learnt random walk is therefore kept at or above the
smallest one the series could resolve, sigma / sqrt(T) (:func:`resolvable_walk`), with
sigma the series' own noise as the same fit finds it (the mean of the landmarks' sightings:
about 0.1 nm on ``cpr5``, a floor near 0.003 nm/sqrt(s) over 20 minutes), and never above
the walk in use (a short series does not raise it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from piezocomp.drift.filter import DriftNoise, Measurement, fit_noise

__all__ = ["adopt", "due", "relearn", "resolvable_walk"]


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


def resolvable_walk(measurement_nm: float, span_s: float) -> float:
    """The smallest random walk, nm/sqrt(s), that measurements of standard deviation
    ``measurement_nm`` spanning ``span_s`` seconds can tell from none: sigma / sqrt(T)."""
    return measurement_nm / math.sqrt(max(span_s, 1e-9))


def relearn(
    measurements: Sequence[Measurement],
    t_start_s: float,
    noise: DriftNoise,
    after: int,
    every: int,
) -> DriftNoise | None:
    """The noise re-estimated from ``measurements`` (those that measured a drift, after the
    reference: zero drift at ``t_start_s``) when :func:`due`, starting from ``noise``;
    ``None`` when not due. The random walk learnt is kept at or above
    :func:`resolvable_walk` of the series' noise (as fitted) over the time it spans, capped
    at the walk in use."""
    seen = [m for m in measurements if m.drift_nm is not None]
    if not due(len(seen), after, every):
        return None
    t = np.array([t_start_s] + [m.t_s for m in seen])
    z = np.vstack([np.zeros(2)] + [np.asarray(m.drift_nm) for m in seen])
    learnt = fit_noise(t, z, start=noise).noise
    floor = min(resolvable_walk(learnt.measurement_nm, float(t[-1] - t[0])),
                noise.position_nm_per_sqrt_s)  # fmt: skip
    if learnt.position_nm_per_sqrt_s < floor:
        learnt = replace(learnt, position_nm_per_sqrt_s=floor)
    return adopt(noise, learnt)
