"""The scan under which the virtual scanner's nominal sensitivity holds.

A real scanner is calibrated by imaging a grating of known pitch: its nominal sensitivity
(nm per volt) is the one that makes a steady full-range scan at the calibration line rate
as wide as commanded. Section IV of the paper relies on exactly that condition,
``f_a(u_max) - f_a(u_min) = u_max - u_min`` on the steady loop. Creep makes the width of a
steady cycle depend on its speed (a slower cycle creeps further), so the condition holds
at one speed only, which a calibration record states.

The virtual scanner defines its sensitivity by the response ``creep_reference_time_s``
after a step (:mod:`piezocomp.virtual_afm.creep`). :func:`calibration_speed` finds, from its
physics, the speed at which a steady full-range triangular scan from rest is as wide as
commanded: ground truth, for scoring and diagnosis only. The virtual instrument states no
calibration record of its own; the virtual lab measures one on a grating through the
instrument interface, as a lab does
(:func:`piezocomp.experiments.virtual_identification.calibration_record`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from piezocomp._validation import check_finite_scalar
from piezocomp.virtual_afm.scanner import ScannerParams, ScannerState, simulate

__all__ = ["calibration_speed", "steady_span_ratio"]


def steady_span_ratio(
    params: ScannerParams,
    speed_nm_per_s: float,
    sample_period_s: float,
    *,
    n_cycles: int = 4,
) -> float:
    """Width of the TRUE steady full-range scan divided by its command span.

    The x axis, from rest at the lower end of the range (drift off), runs ``n_cycles``
    triangular cycles over the whole range at ``speed_nm_per_s``; the ratio is taken on the
    last ascending ramp.
    """
    v = check_finite_scalar("speed_nm_per_s", speed_nm_per_s)
    T = check_finite_scalar("sample_period_s", sample_period_s)
    if v <= 0 or T <= 0:
        raise ValueError(f"speed and sample period must be > 0. Got {v} nm/s, {T} s.")
    if isinstance(n_cycles, bool) or int(n_cycles) != n_cycles or n_cycles < 2:
        raise ValueError(f"n_cycles must be an integer >= 2. Got {n_cycles!r}.")
    quiet = replace(  # a calibration averages the noise and the drift out
        params, drift_velocity_nm_per_s=(0.0, 0.0), drift_random_walk_nm_per_sqrt_s=0.0,
        position_noise_nm=0.0, position_flicker_nm=0.0,
    )  # fmt: skip
    h = quiet.half_range_nm
    n_ramp = max(2, int(np.ceil(2 * h / (v * T))))
    up = np.linspace(-h, h, n_ramp + 1)
    cycle = np.concatenate([up[1:], up[::-1][1:]])
    u = np.concatenate([[-h], np.tile(cycle, int(n_cycles))])
    cmd = np.column_stack([u, np.zeros_like(u)])
    y, _ = simulate(quiet, cmd, T, ScannerState.initial(quiet, (-h, 0.0)))
    last_up = slice(u.size - 2 * n_ramp - 1, u.size - n_ramp)
    ys = y[last_up, 0]
    return float((ys[-1] - ys[0]) / (2 * h))


def calibration_speed(
    params: ScannerParams,
    sample_period_s: float,
    *,
    speed_range_nm_per_s: tuple[float, float] = (20.0, 20000.0),
    rtol: float = 1e-3,
) -> float | None:
    """Speed (nm/s) at which a steady full-range scan is as wide as commanded.

    Bisection in ``log(speed)`` over ``speed_range_nm_per_s`` on
    :func:`steady_span_ratio` (which falls as the speed rises). ``None`` when the ratio
    does not cross 1 in that range. A scanner without creep has a ratio of exactly 1 at
    every speed: any speed calibrates it, and the geometric mean of the range is returned.
    """
    lo = check_finite_scalar("speed_range_nm_per_s[0]", speed_range_nm_per_s[0])
    hi = check_finite_scalar("speed_range_nm_per_s[1]", speed_range_nm_per_s[1])
    if not 0 < lo < hi:
        raise ValueError(f"speed_range_nm_per_s must satisfy 0 < lo < hi. Got ({lo}, {hi}).")
    f_lo = steady_span_ratio(params, lo, sample_period_s) - 1.0
    f_hi = steady_span_ratio(params, hi, sample_period_s) - 1.0
    if max(abs(f_lo), abs(f_hi)) < 1e-9:  # rate independent and calibrated: any speed does
        return float(np.sqrt(lo * hi))
    if f_lo * f_hi > 0:
        return None
    a, b = np.log(lo), np.log(hi)
    while b - a > rtol:
        m = 0.5 * (a + b)
        if (steady_span_ratio(params, float(np.exp(m)), sample_period_s) - 1.0) * f_lo > 0:
            a = m
        else:
            b = m
    return float(np.exp(0.5 * (a + b)))
