"""The symmetric loop of Section IV: eqs (21)-(23), calibration, refusals."""

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from piezocomp.identification.loop.symmetric import SymmetricLoop

U_MIN, U_MAX = -300.0, 1700.0  # an off-centre command range (nm)


def calibrated(coef):
    """Scale P so that P(1) - P(-1) = 2 (the calibration condition)."""
    c = np.asarray(coef, dtype=float)
    odd = c[1::2].sum()
    return c / odd  # P(1) - P(-1) = 2 * sum of odd coefficients


# A curved loop: ascending branch with cubic and quintic terms, 4 % loop width.
TRUTH = SymmetricLoop(calibrated([-0.02, 0.95, 0.04, 0.08, -0.03, 0.02]), U_MIN, U_MAX)


def feature_pairs(loop, n, rng):
    """Commands at which features at random true positions are seen on both traces."""
    y_lo = max(loop.ascending(loop.u_min_nm), loop.descending(loop.u_min_nm))
    y_hi = min(loop.ascending(loop.u_max_nm), loop.descending(loop.u_max_nm))
    y = rng.uniform(y_lo, y_hi, n)
    return loop.ascending_inverse(y), loop.descending_inverse(y), y


def test_exact_recovery_of_a_polynomial_loop():
    rng = np.random.default_rng(0)
    u_a, u_d, _ = feature_pairs(TRUTH, 40, rng)
    fit = SymmetricLoop.from_peaks(u_a, u_d, U_MIN, U_MAX, degree=5)
    np.testing.assert_allclose(fit.coefficients, TRUTH.coefficients, atol=1e-9)
    u = np.linspace(U_MIN, U_MAX, 101)
    np.testing.assert_allclose(fit.ascending(u), TRUTH.ascending(u), atol=1e-6)


@pytest.mark.parametrize("degree", [3, 7])
def test_exact_recovery_other_degrees(degree):
    rng = np.random.default_rng(degree)
    coef = np.zeros(degree + 1)
    coef[:4] = [0.015, 1.0, -0.05, 0.03]
    if degree > 3:
        coef[4:] = [0.02, -0.01, 0.005, 0.004][: degree - 3]
    truth = SymmetricLoop(calibrated(coef), 0.0, 5000.0)
    u_a, u_d, _ = feature_pairs(truth, 3 * degree, rng)
    fit = SymmetricLoop.from_peaks(u_a, u_d, 0.0, 5000.0, degree=degree)
    np.testing.assert_allclose(fit.coefficients, truth.coefficients, atol=1e-9)


def test_descending_is_the_point_reflection_eq22():
    u = np.linspace(U_MIN, U_MAX, 57)
    u_s, y_s = TRUTH.u_s_nm, TRUTH.y_s_nm
    assert u_s == 0.5 * (U_MIN + U_MAX) and y_s == u_s  # the stated convention
    np.testing.assert_allclose(TRUTH.descending(u), 2 * y_s - TRUTH.ascending(2 * u_s - u))
    # (21): a point (u, y) on one branch mirrors to (2u_s - u, 2y_s - y) on the other.
    np.testing.assert_allclose(
        TRUTH.descending(2 * u_s - u), 2 * y_s - TRUTH.ascending(u), atol=1e-9
    )
    # Calibration condition and a loop that opens: descending above ascending inside.
    assert TRUTH.ascending(U_MAX) - TRUTH.ascending(U_MIN) == pytest.approx(U_MAX - U_MIN)
    assert np.all(TRUTH.descending(u[1:-1]) > TRUTH.ascending(u[1:-1]))
    h = 1e-4
    np.testing.assert_allclose(
        TRUTH.ascending_slope(u[1:-1]),
        (TRUTH.ascending(u[1:-1] + h) - TRUTH.ascending(u[1:-1] - h)) / (2 * h),
        rtol=1e-6,
    )
    np.testing.assert_allclose(TRUTH.descending_slope(u), TRUTH.ascending_slope(2 * u_s - u))


@given(y=st.lists(st.floats(-5000.0, 7000.0), min_size=1, max_size=20))
@example(y=[-291.0])  # inside the ascending branch's range, outside the descending one's
def test_inverse_round_trip_and_monotone(y):
    y = np.asarray(y)
    u = TRUTH.ascending_inverse(y)
    inside = (y >= TRUTH.ascending(U_MIN)) & (y <= TRUTH.ascending(U_MAX))
    np.testing.assert_allclose(TRUTH.ascending(u[inside]), y[inside], atol=1e-8)
    order = np.argsort(y)
    assert np.all(np.diff(u[order]) >= -1e-9)
    inside_d = (y >= TRUTH.descending(U_MIN)) & (y <= TRUTH.descending(U_MAX))
    np.testing.assert_allclose(
        TRUTH.descending(TRUTH.descending_inverse(y[inside_d])), y[inside_d], atol=1e-8
    )


def test_noisy_peaks_keep_the_calibration_and_align_the_traces():
    rng = np.random.default_rng(3)
    u_a, u_d, _ = feature_pairs(TRUTH, 400, rng)
    sigma = 0.5  # nm of peak-position noise on each trace
    na = u_a + rng.normal(0, sigma, u_a.size)
    nd = u_d + rng.normal(0, sigma, u_d.size)
    fit = SymmetricLoop.from_peaks(na, nd, U_MIN, U_MAX, degree=5)
    # Hard constraint, met to rounding whatever the noise.
    assert fit.ascending(U_MAX) - fit.ascending(U_MIN) == pytest.approx(U_MAX - U_MIN, abs=1e-9)
    # Eq (23) residuals of the noise-free pairs: each feature lands at one position.
    res = fit.pair_residuals_nm(u_a, u_d)
    assert np.sqrt(np.mean(res**2)) < 0.5
    # What trace/retrace sees is recovered: where the backward trace shows the feature the
    # forward trace shows at u_a, u_d = f_d^-1(f_a(u_a)). (The true axis itself is only known
    # up to an odd distortion that eq (23) cannot see, so y is not compared.)
    ua = np.linspace(np.quantile(u_a, 0.05), np.quantile(u_a, 0.95), 50)
    ud_true = TRUTH.descending_inverse(TRUTH.ascending(ua))
    ud_fit = fit.descending_inverse(fit.ascending(ua))
    assert np.max(np.abs(ud_fit - ud_true)) < 0.25  # half the per-peak noise
    # Without the paired structure (shuffled descending peaks) the residuals are huge.
    shuffled = rng.permutation(nd)
    bad = SymmetricLoop.from_peaks(na, shuffled, U_MIN, U_MAX, degree=1)
    assert np.sqrt(np.mean(bad.pair_residuals_nm(na, shuffled) ** 2)) > 50


def test_pure_shift_gives_the_least_curved_loop():
    # A loop that is only a constant shift leaves odd distortions undetermined by eq (23);
    # the fit picks the straight one.
    u_a = np.linspace(100.0, 900.0, 30)
    u_d = u_a - 50.0
    fit = SymmetricLoop.from_peaks(u_a, u_d, 0.0, 1000.0, degree=5)
    np.testing.assert_allclose(fit.coefficients, [-0.05, 1, 0, 0, 0, 0], atol=1e-7)


def test_smoothing_straightens_but_keeps_calibration():
    rng = np.random.default_rng(5)
    u_a, u_d, _ = feature_pairs(TRUTH, 60, rng)
    stiff = SymmetricLoop.from_peaks(u_a, u_d, U_MIN, U_MAX, degree=5, smoothing=1e3)
    assert stiff.ascending(U_MAX) - stiff.ascending(U_MIN) == pytest.approx(U_MAX - U_MIN)
    curv_truth = np.abs(TRUTH.coefficients[2:]).sum()
    assert np.abs(stiff.coefficients[2:]).sum() < 0.05 * curv_truth
    with pytest.raises(ValueError, match="smoothing must be >= 0"):
        SymmetricLoop.from_peaks(u_a, u_d, U_MIN, U_MAX, smoothing=-1.0)


def test_many_lines_are_just_more_equations():
    rng = np.random.default_rng(7)
    lines = [feature_pairs(TRUTH, k, rng)[:2] for k in (3, 4, 2, 5)]  # each line too short
    fit = SymmetricLoop.from_line_pairs(lines, U_MIN, U_MAX, degree=5)
    np.testing.assert_allclose(fit.coefficients, TRUTH.coefficients, atol=1e-9)
    cat = SymmetricLoop.from_peaks(
        np.concatenate([a for a, _ in lines]), np.concatenate([d for _, d in lines]), U_MIN, U_MAX
    )
    np.testing.assert_allclose(fit.coefficients, cat.coefficients, atol=1e-12)
    with pytest.raises(ValueError, match=r"pairs\[1\]"):
        SymmetricLoop.from_line_pairs([lines[0], ([1.0, 2.0], [1.0])], U_MIN, U_MAX)


def test_refuses_too_few_pairs_with_count_and_rule():
    rng = np.random.default_rng(1)
    u_a, u_d, _ = feature_pairs(TRUTH, 5, rng)
    with pytest.raises(ValueError, match=r"degree 5 needs more than 5 feature pairs.*Got 5"):
        SymmetricLoop.from_peaks(u_a, u_d, U_MIN, U_MAX, degree=5)
    SymmetricLoop.from_peaks(u_a, u_d, U_MIN, U_MAX, degree=4)  # 5 > 4: accepted


def test_refuses_a_non_increasing_fit():
    # Features whose backward positions run against the forward ones cannot be a loop.
    u_a = np.linspace(0.0, 1000.0, 12)
    u_d = 1000.0 - u_a + 5.0 * np.sin(u_a)
    with pytest.raises(ValueError, match="not strictly increasing"):
        SymmetricLoop.from_peaks(u_a, np.clip(u_d, 0, 1000), 0.0, 1000.0, degree=5)


def test_refuses_bad_input():
    with pytest.raises(ValueError, match="must be strictly increasing"):
        SymmetricLoop([0.0, -1.0], 0.0, 1.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        SymmetricLoop([0.0, -0.5, 0.0, 1.5], 0.0, 1.0)  # dips inside the range
    with pytest.raises(ValueError, match="u_min_nm must be < u_max_nm"):
        SymmetricLoop([0.0, 1.0], 1.0, 1.0)
    with pytest.raises(ValueError, match="same length"):
        SymmetricLoop.from_peaks([1.0, 2.0], [1.0], 0.0, 3.0)
    with pytest.raises(ValueError, match=r"u_descending_nm must lie in"):
        SymmetricLoop.from_peaks(np.linspace(0, 1, 8), np.linspace(0, 2, 8), 0.0, 1.0, degree=2)
    with pytest.raises(TypeError, match="degree must be an integer"):
        SymmetricLoop.from_peaks(np.linspace(0, 1, 8), np.linspace(0, 1, 8), 0.0, 1.0, degree=2.5)
    with pytest.raises(ValueError, match="finite"):
        SymmetricLoop.from_peaks([np.nan] * 8, np.linspace(0, 1, 8), 0.0, 1.0, degree=2)


def test_loop_is_frozen():
    with pytest.raises(ValueError):
        TRUTH.coefficients[0] = 1.0
    with pytest.raises(AttributeError):
        TRUTH.u_min_nm = 0.0
