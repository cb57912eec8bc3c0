"""Acquisition helpers: settling on the line, and the line-stability check."""

from __future__ import annotations

import numpy as np
import pytest

from loop_estimates import trace_estimate
from piezocomp.identification.acquisition.line_search import (
    axis_command,
    line_stability,
    settle_on_line,
)
from piezocomp.identification.reference.frames import frame_map
from piezocomp.virtual_afm import VirtualAFM


def _trace(u, centres, heights, y_offset=0.0, width=7.5):
    """Heights of spheres of radius ``width`` seen along a line ``y_offset`` off their centres."""
    z = np.zeros_like(u)
    for c, h in zip(centres, heights, strict=True):
        r2 = width**2 - y_offset**2
        z = np.maximum(z, h * np.sqrt(np.clip(1.0 - ((u - c) ** 2) / max(r2, 1e-9), 0.0, None)))
    return z


CENTRES = [-400.0, -250.0, -60.0, 90.0, 300.0, 420.0]
HEIGHTS = [14.0, 15.0, 13.5, 15.5, 14.5, 14.0]


def test_axis_command_puts_u_on_the_fast_axis():
    u = np.array([1.0, 2.0, 3.0])
    assert np.array_equal(axis_command("x", u, 7.0), np.column_stack([u, [7.0] * 3]))
    assert np.array_equal(axis_command("y", u, 7.0), np.column_stack([[7.0] * 3, u]))


def test_settle_on_line_runs_whole_cycles_at_the_slow_command():
    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.01)
    cycle = np.concatenate([np.linspace(-50, 50, 11), np.linspace(40, -50, 10)])  # 0.2 s
    assert settle_on_line(afm, "x", cycle, 5.0, 0.0) is None
    rec = settle_on_line(afm, "x", cycle, 5.0, 0.5)
    assert rec is not None
    n_cycles = 3  # ceil(0.5 / 0.2)
    assert rec.command_nm.shape == (1 + n_cycles * (cycle.size - 1), 2)
    assert np.all(rec.command_nm[:, 1] == 5.0)
    assert afm.command_nm == (-50.0, 5.0)


def test_line_stability_ignores_a_shift_and_sees_a_profile_change():
    u = np.linspace(-500, 500, 1001)
    rng = np.random.default_rng(0)
    start = np.array([_trace(u, CENTRES, HEIGHTS) + 0.05 * rng.standard_normal(u.size)] * 3)
    # the same profile, shifted along the line by 3 nm + 0.5 %: no profile change
    shifted = _trace(u, [c + 3.0 + 0.005 * c for c in CENTRES], HEIGHTS)
    st = line_stability(u, start, u, np.array([shifted, shifted]))
    assert st.height_change_rms_nm < 0.3
    assert np.allclose(st.peak_shift_nm, [3.0 + 0.005 * c for c in CENTRES], atol=0.5)
    assert np.allclose(st.peak_height_change_nm, 0.0, atol=0.2)
    assert st.finding() is None
    # the tip crept 4 nm across the line: every particle lower, flanks narrower
    crept = _trace(u, CENTRES, [h * 0.8 for h in HEIGHTS], y_offset=4.0)
    st = line_stability(u, start, u[::-1], np.array([crept[::-1]]))
    assert np.all(st.peak_height_change_nm < -2.0)
    text = st.finding(tolerance_nm=0.5)
    assert text is not None and "changed" in text


@pytest.mark.parametrize("n_start", [1, 3])
def test_line_stability_noise_is_the_cycle_to_cycle_difference(n_start):
    u = np.linspace(-500, 500, 501)
    z = _trace(u, CENTRES, HEIGHTS)
    start = np.array([z + 0.1 * k for k in range(n_start)])
    st = line_stability(u, start, u, z[None, :])
    assert st.noise_rms_nm == pytest.approx(0.1 * (n_start - 1))


def test_frame_map_widens_its_tolerance_on_a_three_particle_line():
    """cpr5 seed 2: three particles on the working line, the middle one 8 nm off in the
    working frame (f_a's shape): no map within 3 nm, the right one once widened."""
    alpha, beta = 0.78, 3.0
    y = np.array([-370.0, 254.0, 467.0])
    H = np.array([15.0, 12.0, 15.0])
    Y_true = alpha * y + beta
    others = np.array([-2100.0, -1400.0, -515.0, 514.0, 672.0, 1500.0])
    Y = np.concatenate([Y_true, others])
    order = np.argsort(Y)
    cal = trace_estimate(-2500, 2500, Y[order], np.concatenate([H, [9, 12, 8, 4, 10, 13]])[order])
    work = trace_estimate(-500, 500, y + np.array([0.0, -8.0, 0.0]), H)
    with pytest.raises(ValueError, match="need 3"):
        frame_map(work, cal, window_nm=300.0, max_inlier_nm=3.0)
    a, _ = frame_map(work, cal, window_nm=300.0)
    assert a == pytest.approx(alpha, rel=0.01)


def test_identify_axis_settles_and_checks_the_line():
    """Quick gentle run: the record starts after settling on the line, the line is scanned
    again after it, and a stable line raises no finding."""
    import warnings

    from identify_configs import small_quick
    from piezocomp.identification.sensorless import identify_axis

    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    cfg = small_quick(line_settle_s=120.0, check_cycles=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident = identify_axis(afm, cfg, "x")
    st = ident.line_stability
    assert st is not None
    assert st.height_change_rms_nm < 1.0 and st.finding() is None
    m2 = 2 * ident.waveform.half_cycle_samples
    assert ident.history_u_nm.size == ident.u_nm.size + 1 + 2 * m2  # record, then the check
    assert not any("height profile changed" in f for f in ident.findings)


def test_the_particles_slide_along_the_line_at_the_drift_rate():
    """Steady triangle cycles over a line of particles that slides at 0.04 nm/s (a drift
    the function does not model: a ramp with a slow wobble), after an exponential creep
    transient: the rate is measured from the second half of the settling."""
    from piezocomp.identification.acquisition.line_search import settling_drift_rate
    from piezocomp.identification.estimation.findings import drift_during_record

    T, half = 0.008, 500
    up = np.linspace(-500.0, 500.0, half + 1)
    cycle = np.concatenate([up, up[-2::-1]])
    n = 70
    u = np.concatenate([cycle[:1], *([cycle[1:]] * n)])
    t = np.arange(u.size) * T
    slide = 0.04 * t + 0.3 * np.sin(t / 90.0) + 3.0 * np.exp(-t / 60.0)
    centres = np.linspace(-420.0, 420.0, 9)
    z = sum(12.0 * np.exp(-((u - slide - c) ** 2) / (2 * 8.0**2)) for c in centres)
    rate = settling_drift_rate(u, z, t, 2 * half)
    assert rate == pytest.approx(0.04, abs=0.004)
    assert settling_drift_rate(u[: 5 * 2 * half + 1], z[: 5 * 2 * half + 1], t, 2 * half) is None
    (unestimated,) = drift_during_record(0.04, 145.0)  # no path estimated: says so
    assert "5.8 nm" in unestimated and "not estimated with the model" in unestimated
    assert drift_during_record(0.0002, 145.0) == [] and drift_during_record(None, 145.0) == []


def test_drift_finding_follows_the_estimate_taken_out():
    """A drift taken out is reported, not warned about, in the particles' sign (the model's
    path d of h(y + d) moves them by -d: d = -0.043 nm/s while they slid +0.047 nm/s as the
    tip settled); one that could not be taken out is a finding, in the same sign, whose
    advice fits the model and the record."""
    from piezocomp.identification.estimation.findings import drift_during_record, line_drift_text

    kept = {"kept": True, "extent_nm": 9.7, "rate_nm_per_s": -0.043,
            "heldout_rms_without_nm": 2.4, "heldout_rms_with_nm": 1.1}  # fmt: skip
    assert drift_during_record(0.047, 226.0, kept) == []  # taken out: no warning
    text = line_drift_text(kept, 0.047)
    assert "slid +0.043 nm/s" in text and "+0.047 nm/s while the tip settled" in text
    assert "9.7 nm" in text and "2.40" in text and "1.10" in text and "not kept" not in text
    spurious = {**kept, "kept": False, "extent_nm": 2.4}
    assert "(not kept: it did not help)" in line_drift_text(spurious)
    assert drift_during_record(0.0002, 226.0, spurious) == []  # a still scanner: no finding
    (finding,) = drift_during_record(-0.047, 226.0, spurious)
    assert "slid -0.047 nm/s" in finding and "not taken out" in finding
    assert "did not predict the held-out part better" in finding  # estimated, not kept
    assert "as creep" in finding and "default length" not in finding
    (no_creep,) = drift_during_record(-0.047, 226.0, spurious, n_creep=0, reduced=True)
    assert "no creep operators" in no_creep and "as creep" not in no_creep
    assert "default length" in no_creep  # a --quick record
