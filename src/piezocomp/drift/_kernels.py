"""Numba kernel of the drift filter (private: no input checks; callers check everything).

- :func:`log_likelihood_run`: the Kalman filter of :mod:`piezocomp.drift.filter` run over a
  series of measurements, summing the log-likelihood of its innovations. A noise fit
  evaluates it thousands of times on series of a few tens of measurements, where numpy's
  overhead on 3 x 3 matrices was most of the session's computing. The same arithmetic as
  :func:`~piezocomp.drift.filter.predict` and :func:`~piezocomp.drift.filter.update`
  (which stay the reference: ``tests/drift/test_filter.py`` compares them), summed in its own
  order: the two agree to about 1e-14 relative.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def log_likelihood_run(
    t, z, sigma, has_sigma, position, rate, measurement, order, initial_velocity
):  # pragma: no cover - compiled
    """Log-likelihood of the displacements ``z`` (n, 2) measured at times ``t`` (n,) with
    standard deviations ``sigma`` (n, 2; ``measurement`` for every one unless
    ``has_sigma``), the first taken as the start (velocity prior ``initial_velocity``, and
    for ``order`` 3 an acceleration prior of ``initial_velocity / 600``), under the white
    noises ``position`` (the displacement's random walk) and ``rate`` (the highest
    derivative's)."""
    k = order
    mean = np.zeros((2, k))
    cov = np.zeros((2, k, k))
    for a in range(2):
        mean[a, 0] = z[0, a]
        cov[a, 1, 1] = initial_velocity * initial_velocity
        if k == 3:
            cov[a, 2, 2] = (initial_velocity / 600.0) ** 2
    F = np.zeros((k, k))
    Q = np.zeros((k, k))
    prior = np.zeros((k, k))
    m = np.zeros(k)
    gain = np.zeros(k)
    row = np.zeros(k)
    r = rate * rate
    total = 0.0
    for n in range(1, t.size):
        dt = max(t[n] - t[n - 1], 0.0)
        # F and Q over dt (DriftNoise.transition, DriftNoise.process)
        F[:, :] = 0.0
        Q[:, :] = 0.0
        for i in range(k):
            F[i, i] = 1.0
        F[0, 1] = dt
        if k == 2:
            Q[0, 0] = position * position * dt + r * (dt**3 / 3.0)
            Q[0, 1] = Q[1, 0] = r * (dt**2 / 2.0)
            Q[1, 1] = r * dt
        else:
            F[0, 2] = 0.5 * dt * dt
            F[1, 2] = dt
            Q[0, 0] = position * position * dt + r * (dt**5 / 20.0)
            Q[0, 1] = Q[1, 0] = r * (dt**4 / 8.0)
            Q[0, 2] = Q[2, 0] = r * (dt**3 / 6.0)
            Q[1, 1] = r * (dt**3 / 3.0)
            Q[1, 2] = Q[2, 1] = r * (dt**2 / 2.0)
            Q[2, 2] = r * dt
        for a in range(2):
            # predict: mean F', F cov F' + Q
            for i in range(k):
                m[i] = mean[a, i]
            for i in range(k):
                acc = 0.0
                for j in range(k):
                    acc += m[j] * F[i, j]
                mean[a, i] = acc
            for i in range(k):
                for c in range(k):
                    acc = 0.0
                    for j in range(k):
                        for q in range(k):
                            acc += F[i, j] * cov[a, j, q] * F[c, q]
                    prior[i, c] = acc + Q[i, c]
            # update with the displacement measured on this axis
            s_dev = sigma[n, a] if has_sigma else measurement
            innov = z[n, a] - mean[a, 0]
            s = prior[0, 0] + s_dev * s_dev
            if not s > 0.0:  # an exact measurement of a known drift: no likelihood
                return math.nan
            for i in range(k):
                gain[i] = prior[i, 0] / s
                row[i] = prior[0, i]
            for i in range(k):
                mean[a, i] += gain[i] * innov
                for j in range(k):
                    prior[i, j] -= gain[i] * row[j]
            for i in range(k):
                for j in range(k):
                    cov[a, i, j] = 0.5 * (prior[i, j] + prior[j, i])
            total += -0.5 * (innov * innov / s + math.log(2.0 * math.pi * s))
    return total
