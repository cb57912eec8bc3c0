"""The drift filter: the mathematics of the discretisation and the update, and what it
estimates on drifts it did not generate."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.integrate import quad_vec

from piezocomp.drift.filter import (
    DriftEstimate,
    DriftFilter,
    DriftNoise,
    fit_noise,
    log_likelihood,
    predict,
    update,
)


@pytest.mark.parametrize("order", [2, 3])
def test_process_noise_is_the_integral_of_the_continuous_white_noises(order):
    noise = DriftNoise(position_nm_per_sqrt_s=0.03, rate_noise=0.002, order=order)
    dt = 7.0
    L = np.zeros((order, 2))
    L[0, 0] = noise.position_nm_per_sqrt_s
    L[-1, 1] = noise.rate_noise

    def integrand(tau):
        F = noise.transition(tau)
        return F @ L @ L.T @ F.T

    Q, _ = quad_vec(integrand, 0.0, dt)
    assert_allclose(noise.process(dt), Q, rtol=1e-9, atol=1e-15)
    F = noise.transition(dt)
    assert_allclose(noise.transition(3.0) @ noise.transition(4.0), F)


def test_pure_functions_and_the_filter_agree():
    noise = DriftNoise(order=2)
    rng = np.random.default_rng(0)
    est = DriftEstimate.start(0.0, noise)
    filt = DriftFilter(noise, est)
    for k in range(1, 6):
        z = rng.normal(size=2)
        est, _, _ = update(predict(est, 30.0 * k, noise), z, None, noise)
        filt.measure(30.0 * k, z)
        assert_allclose(filt.estimate.mean, est.mean)
        assert_allclose(filt.estimate.cov, est.cov)
    assert len(filt.innovations) == 5


def test_update_is_the_kalman_update():
    noise = DriftNoise(order=2, measurement_nm=0.5)
    est = DriftEstimate(10.0, np.array([[1.0, 0.1], [-2.0, 0.0]]),
                        np.array([np.diag([4.0, 0.01]), [[1.0, 0.05], [0.05, 0.02]]]))  # fmt: skip
    new, innov, var = update(est, [2.0, -1.0], None, noise)
    H = np.array([[1.0, 0.0]])
    for a, z in enumerate([2.0, -1.0]):
        P = est.cov[a]
        S = H @ P @ H.T + 0.25
        K = P @ H.T / S
        assert_allclose(new.mean[a], est.mean[a] + (K * (z - est.mean[a, 0])).ravel())
        assert_allclose(new.cov[a], (np.eye(2) - K @ H) @ P, atol=1e-12)
        assert var[a] == pytest.approx(S.item())
    assert_allclose(innov, [1.0, 1.0])


def drifting(t, rng, v=(0.05, -0.03), walk=0.02, sigma=0.2):
    """A drift the filter did not generate: steady velocity, a random walk sampled finely,
    measured with noise at times ``t``."""
    fine = np.arange(0.0, t[-1] + 1.0, 1.0)
    d = np.outer(fine, v) + np.cumsum(rng.normal(0, walk, (fine.size, 2)), axis=0)
    true = np.column_stack([np.interp(t, fine, d[:, a]) for a in range(2)])
    return true, true + rng.normal(0, sigma, true.shape)


def test_the_filter_follows_a_drift_and_predicts_it_between_measurements():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(20.0, 60.0, 40))
    true, z = drifting(t, rng)
    noise = DriftNoise(order=2, position_nm_per_sqrt_s=0.02, rate_noise=1e-4, measurement_nm=0.2)
    f = DriftFilter(noise, DriftEstimate.start(t[0], noise))
    errors, normalised = [], []
    for k in range(1, t.size):
        pred = f.at(t[k])
        errors.append(np.abs(pred.displacement_nm - true[k]))
        normalised.append((z[k] - pred.displacement_nm) ** 2 / (pred.cov[:, 0, 0] + 0.04))
        f.measure(t[k], z[k])
    # after a few measurements the prediction 20-60 s ahead is within about 1 nm
    assert np.max(errors[10:]) < 1.5
    assert_allclose(f.estimate.mean[:, 1], [0.05, -0.03], atol=0.02)
    # the innovations are consistent with their predicted variance
    assert 0.4 < np.mean(normalised[10:]) < 2.5


def test_noise_is_estimated_from_a_recorded_series():
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(10.0, 30.0, 120))
    _, z = drifting(t, rng, walk=0.05, sigma=0.8)
    start = DriftNoise(order=2, position_nm_per_sqrt_s=0.5, rate_noise=1e-3, measurement_nm=0.1)
    fit = fit_noise(t, z, start)
    assert fit.log_likelihood > log_likelihood(t, z, start)
    assert 0.5 < fit.noise.measurement_nm < 1.2
    assert 0.02 < fit.noise.position_nm_per_sqrt_s < 0.1


def _stepped_log_likelihood(t, z, noise, sigma=None):
    """The log-likelihood by the filter's own steps (predict, update): the reference."""
    est = DriftEstimate.start(float(t[0]), noise)
    mean = np.column_stack([z[0], np.zeros((2, noise.order - 1))])
    est = DriftEstimate(est.t_s, mean, est.cov)
    total = 0.0
    for k in range(1, t.size):
        est = predict(est, float(t[k]), noise)
        est, innov, var = update(est, z[k], None if sigma is None else sigma[k], noise)
        total += float(-0.5 * np.sum(innov**2 / var + np.log(2 * np.pi * var)))
    return total


@pytest.mark.parametrize("order", [2, 3])
@pytest.mark.parametrize("with_sigma", [False, True])
def test_the_compiled_log_likelihood_is_the_filters(order, with_sigma):
    """The noise fit's compiled filter gives the log-likelihood of the filter's own steps,
    over noises from a still drift to a fast one, irregular times and a repeated time."""
    rng = np.random.default_rng(order + 2 * with_sigma)
    for _ in range(50):
        n = int(rng.integers(2, 40))
        t = np.cumsum(rng.uniform(0.5, 60.0, n))
        t[n // 2 :] -= t[n // 2] - t[n // 2 - 1] if n > 2 else 0.0  # two at one time
        z = np.cumsum(rng.normal(0.0, 2.0, (n, 2)), axis=0)
        sigma = rng.uniform(0.05, 3.0, (n, 2)) if with_sigma else None
        noise = DriftNoise(
            position_nm_per_sqrt_s=float(np.exp(rng.uniform(-7, 1))),
            rate_noise=float(np.exp(rng.uniform(-14, -1))),
            measurement_nm=float(np.exp(rng.uniform(-3, 1))),
            order=order,
        )
        expected = _stepped_log_likelihood(t, z, noise, sigma)
        assert log_likelihood(t, z, noise, sigma) == pytest.approx(expected, rel=1e-12, abs=1e-9)


def test_bad_input_is_refused_with_the_value_and_the_rule():
    with pytest.raises(ValueError, match="order must be 2 or 3"):
        DriftNoise(order=4)
    with pytest.raises(ValueError, match="measurement_nm must be > 0"):
        DriftNoise(measurement_nm=0.0)
    est = DriftEstimate.start(10.0, DriftNoise())
    with pytest.raises(ValueError, match="before the estimate"):
        predict(est, 5.0, DriftNoise())
    with pytest.raises(ValueError, match="at least 2 measurements"):
        log_likelihood([0.0], [[0.0, 0.0]], DriftNoise())
    with pytest.raises(ValueError, match="before the estimate"):
        log_likelihood([0.0, 2.0, 1.0], np.zeros((3, 2)), DriftNoise())
    with pytest.raises(ValueError, match="not finite"):  # exact twice at one time
        log_likelihood([0.0, 0.0, 0.0], np.zeros((3, 2)), DriftNoise(), sigma_nm=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="sigma_nm must have the shape"):
        log_likelihood([0.0, 1.0], np.zeros((2, 2)), DriftNoise(), sigma_nm=np.ones((3, 2)))
    with pytest.raises(ValueError, match="states"):
        DriftFilter(DriftNoise(order=2), est)
    from piezocomp.drift.filter import DriftSettings

    for name in ("tolerance_nm", "image_tolerance_nm", "max_interval_s"):
        with pytest.raises(ValueError, match=f"{name} must be > 0"):
            DriftSettings(**{name: 0.0})
    with pytest.raises(ValueError, match=r"image_tolerance_nm must be >= tolerance_nm \(0.5\)"):
        DriftSettings(image_tolerance_nm=0.3)
