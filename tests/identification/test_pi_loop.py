"""The Prandtl-Ishlinskii loop fitted by eq (23): one operator shared by nested loops."""

import numpy as np
import pytest
from scipy.optimize import brentq

from piezocomp.identification.loop.pi_branch import PILoop

H = 1000.0
R = H * np.arange(48) / 48  # the fit's thresholds


def truth() -> PILoop:
    w = 0.02 * np.exp(-R / 300.0)
    w[0] += 0.6
    w *= H / np.sum(w * np.maximum(H - R, 0.0))  # calibration condition on [-H, H]
    return PILoop(w, R, -H, H)


def pairs(loop: PILoop, n: int, rng: np.random.Generator):
    a = loop.half_height_nm
    ys = rng.uniform(-0.97 * a, 0.97 * a, n)
    lo, hi = loop.u_min_nm, loop.u_max_nm
    ua = np.array([brentq(lambda u, y=y: loop.ascending(u) - y, lo, hi) for y in ys])
    ud = np.array([brentq(lambda u, y=y: loop.descending(u) - y, lo, hi) for y in ys])
    return ua, ud


def test_branches_closed_point_symmetric_and_calibrated():
    t = truth()
    assert t.ascending(H) - t.ascending(-H) == pytest.approx(2 * H)
    assert t.ascending(H) == pytest.approx(t.descending(H))
    assert t.ascending(-H) == pytest.approx(t.descending(-H))
    assert t.half_height_nm == pytest.approx(H)
    assert np.all(np.diff(t.ascending_slope(np.linspace(-H, H, 101))) >= 0)  # convex


def test_exact_operator_recovered_from_nested_loops():
    t = truth()
    rng = np.random.default_rng(1)
    full = pairs(t, 60, rng)
    inner = pairs(t.with_range(-500.0, 500.0), 15, rng)
    fit = PILoop.from_loops_pairs([([full], -H, H), ([inner], -500.0, 500.0)])
    g = np.linspace(-H, H, 41)
    np.testing.assert_allclose(fit.ascending(g), t.ascending(g), atol=1e-6)
    inner_fit = fit.with_range(-500.0, 500.0)
    assert inner_fit.half_height_nm == pytest.approx(t.with_range(-500, 500).half_height_nm)
    assert np.max(np.abs(fit.pair_residuals_nm(*full))) < 1e-6


def test_refusals():
    with pytest.raises(ValueError, match="at least 2"):
        PILoop.from_line_pairs([(np.array([0.0]), np.array([0.0]))], -H, H)
    with pytest.raises(ValueError, match="weights\\[0\\] > 0"):
        PILoop(np.zeros(3), np.array([0.0, 1.0, 2.0]), -H, H)
