"""The grating's angle to the axis, from how its crests shift from scan line to scan line.

A grating a few degrees off square to the axis shows it a pitch ``1/cos`` longer;
:func:`grating_angle` measures the angle from the passes' shifts that
:func:`~piezocomp.identification.reference.scaling.fit_scale` fitted, after
:func:`drift_free_line_shifts` has taken out the sample's drift along the axis between the
lines (scanned one after the other, lines would read the drift as angle).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.reference.grating import GratingRecord

__all__ = ["drift_free_line_shifts", "grating_angle"]


def _wrap(v: Any, period_nm: float) -> Any:
    """``v`` to ``+-period_nm / 2`` (arrays or numbers): a shift known modulo the period."""
    return (v + 0.5 * period_nm) % period_nm - 0.5 * period_nm


def drift_free_line_shifts(
    record: GratingRecord,
    pass_line: NDArray[np.intp],
    shifts: NDArray[np.float64],
    period_nm: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each line's mean shift with the sample's drift along the axis taken out, and each
    line's drift rate (model's lengths per second; NaN where not measured).

    A pass's shift moves with the drift along the axis while its line is scanned: fitted as
    ``delta_p = m_j + v_j (t_p - t_j) + e s_p`` (``t_j`` the line's mean time, ``s_p = +-1``
    the pass's direction, ``e`` the hysteresis left between directions, shared). The drift
    between lines, the rates integrated from line to line (trapezoids), is subtracted from
    the ``m_j``: scanned one after the other, lines would otherwise read drift as the
    grating's angle (on the warming-up virtual cpr5, 0.3 nm/s along x read 17 degrees, and
    the 1/cos pitch correction put the scale 4.6 % off). Lines with fewer than
    four passes, or one direction only, measure no rate: no drift is taken out then."""
    n_line = int(pass_line.max()) + 1
    T = record.sample_period_s
    t = np.array([0.5 * (a + b - 1) * T for a, b in record.passes])
    u = record.u_nm
    s = np.array([1.0 if u[b - 1] > u[a] else -1.0 for a, b in record.passes])
    # a pass's shift is known modulo the period: each line's taken about its first pass
    d = np.empty_like(shifts)
    for j in range(n_line):
        sel = pass_line == j
        d[sel] = shifts[sel][0] + _wrap(shifts[sel] - shifts[sel][0], period_nm)
    t_line = np.array([t[pass_line == j].mean() for j in range(n_line)])
    measured = np.array(
        [(pass_line == j).sum() >= 4 and np.ptp(s[pass_line == j]) > 0 for j in range(n_line)]
    )
    rates = np.full(n_line, np.nan)
    if not measured.all():
        return np.array([d[pass_line == j].mean() for j in range(n_line)]), rates
    A = np.zeros((d.size, 2 * n_line + 1))
    rows = np.arange(d.size)
    A[rows, pass_line] = 1.0
    A[rows, n_line + pass_line] = t - t_line[pass_line]
    A[:, -1] = s
    coef = np.linalg.lstsq(A, d, rcond=None)[0]
    means, rates = coef[:n_line], coef[n_line : 2 * n_line]
    order = np.argsort(t_line)
    steps = 0.5 * (rates[order][1:] + rates[order][:-1]) * np.diff(t_line[order])
    drift = np.empty(n_line)
    drift[order] = np.concatenate([[0.0], np.cumsum(steps)])
    return np.asarray(means - drift, dtype=float), np.asarray(rates, dtype=float)


def grating_angle(
    record: GratingRecord,
    line_ids: list[int],
    pass_line: NDArray[np.intp],
    shifts: NDArray[np.float64],
    period_nm: float,
    alpha: float,
) -> tuple[float, float]:
    """The grating's angle (degrees, :attr:`Grating.angle_deg`'s convention) from how the
    crests shift from line to line, and the drift along the axis the record measured (nm/s
    in the grating's lengths, NaN where not measured): ``tan(a) = -/+ alpha d(delta)/d(slow)``
    for the x / y axis, with the lines' drift-free mean shifts (:func:`drift_free_line_shifts`)
    unwrapped line to line. The angle is NaN without slow commands or with fewer than two
    distinct lines. The slow axis is taken at its nominal scale (its error enters the pitch
    correction only at second order in the angle)."""
    means, rates = drift_free_line_shifts(record, pass_line, shifts, period_nm)
    rate = -float(alpha * np.mean(rates))  # crests move back as the tip drifts forward
    if record.line_slow_nm is None or len(line_ids) < 2:
        return float("nan"), rate
    slow = np.array([record.line_slow_nm[i] for i in line_ids])
    if np.ptp(slow) <= 0:
        return float("nan"), rate

    order = np.argsort(slow)
    s, m = slow[order], means[order]

    # Unwrap from the closest pair of lines outwards, each line against the slope fitted to
    # the lines before it: lines far apart then need not be within half a period's shift.
    j = int(np.argmin(np.diff(s)))
    d = np.full(s.size, np.nan)
    d[j], d[j + 1] = 0.0, _wrap(m[j + 1] - m[j], period_nm)
    for i in np.argsort(np.abs(s - 0.5 * (s[j] + s[j + 1])), kind="stable"):
        if not np.isnan(d[i]):
            continue
        known = ~np.isnan(d)
        k_i, c_i = np.polyfit(s[known], d[known], 1)
        pred = k_i * s[i] + c_i
        d[i] = pred + _wrap(m[i] - m[j] - pred, period_nm)
    k = float(np.polyfit(s, d, 1)[0])
    sign = -1.0 if record.axis == "x" else 1.0
    return float(np.degrees(np.arctan(sign * alpha * k))), rate
