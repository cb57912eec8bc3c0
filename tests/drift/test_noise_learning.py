"""The drift's noise learnt from the session's own measurements, from a generic prior."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezocomp.drift.compensated import DriftCompensatedInstrument, DriftSettings
from piezocomp.drift.filter import DriftEstimate, DriftNoise, Measurement
from piezocomp.drift.noise_learning import (
    PRIOR_DOF,
    SightingSpread,
    due,
    relearn,
)
from piezocomp.virtual_afm import VirtualAFM, list_presets, load_config


def test_the_prior_is_generic_not_any_presets_hidden_random_walk():
    prior = DriftNoise().position_nm_per_sqrt_s
    walks = {load_config(p).scanner.drift_random_walk_nm_per_sqrt_s for p in list_presets()}
    assert 0.02 in walks and prior not in walks


def test_the_noise_is_learnt_after_n_measurements_then_periodically():
    assert [n for n in range(1, 20) if due(n, 8, 4)] == [8, 12, 16]
    assert not any(due(n, 0, 4) for n in range(1, 20))  # 0: never
    assert [n for n in range(1, 6) if due(n, 2, 1)] == [2, 3, 4, 5]


def _series(n, walk, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(40, 80, n))
    dt = np.diff(np.concatenate([[0.0], t]))
    d = np.cumsum(walk * np.sqrt(dt)[:, None] * rng.standard_normal((n, 2)), axis=0)
    z = d + 0.05 * t[:, None] + 0.2 * rng.standard_normal((n, 2))
    return [Measurement(float(a), b, (), (), 1.0) for a, b in zip(t, z, strict=True)]


def test_a_known_random_walk_is_found_from_the_prior():
    """Measurements of a drift with a 0.02 nm/sqrt(s) random walk: from the generic prior
    (0.05) the estimate comes down near the truth; the measurement noise is kept."""
    prior = DriftNoise(order=2, measurement_nm=0.2)
    ms = _series(28, 0.02)
    assert relearn(ms[:27], 0.0, prior, 8, 4) is None  # not due: 27 = 8 + 4k + 3
    got = relearn(ms, 0.0, prior, 8, 4)
    assert got is not None
    assert got.position_nm_per_sqrt_s == pytest.approx(0.02, abs=0.008)
    assert got.measurement_nm == prior.measurement_nm and got.order == 2
    ignored = [Measurement(1.0, None, (), (), 1.0)] * 40  # no drift measured: nothing learnt
    assert relearn(ignored, 0.0, prior, 8, 4) is None


def _warming(n, seed=0):
    """Measurements of a drift whose rate decays from 0.5 nm/s over 300 s (warm-up)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(20, 40, n))
    d = 0.5 * 300.0 * (1 - np.exp(-t / 300.0))
    z = d[:, None] * np.array([1.0, 0.5]) + 0.2 * rng.standard_normal((n, 2))
    return [Measurement(float(a), b, (), (), 1.0) for a, b in zip(t, z, strict=True)]


def test_the_drifts_order_is_learnt_from_its_measurements():
    """From the generic prior ([d, v, a]): a steady rate with a random walk is read as
    [d, v] (its walk near the truth), a rate that decays as [d, v, a]; without the prior
    the order stays."""
    prior = replace(DriftNoise(), measurement_nm=0.2)
    steady = relearn(_series(28, 0.02), 0.0, prior, 8, 4, prior=prior)
    assert steady is not None and steady.order == 2
    assert steady.position_nm_per_sqrt_s == pytest.approx(0.02, abs=0.01)
    warming = relearn(_warming(28), 0.0, prior, 8, 4, prior=prior)
    assert warming is not None and warming.order == 3
    kept = relearn(_series(28, 0.02), 0.0, prior, 8, 4)
    assert kept is not None and kept.order == 3


def test_the_drifts_noise_is_the_scatter_the_measurements_own_noise_leaves():
    """``given_sigma``: with each measurement's true deviation (0.2 nm) the walk is found
    near the truth; told the measurements are better than they are (0.05 nm), the fit
    puts the rest of their scatter into the drift, never into a noise of its own."""
    prior = DriftNoise(order=2, measurement_nm=0.2)

    def told(sigma):
        return [replace(m, sigma_nm=np.full(2, sigma)) for m in _series(28, 0.02)]

    honest = relearn(told(0.2), 0.0, prior, 8, 4, given_sigma=True)
    assert honest is not None
    assert honest.position_nm_per_sqrt_s == pytest.approx(0.02, abs=0.01)
    flattered = relearn(told(0.05), 0.0, prior, 8, 4, given_sigma=True)
    assert flattered is not None
    assert flattered.position_nm_per_sqrt_s > 1.5 * honest.position_nm_per_sqrt_s
    assert flattered.measurement_nm == prior.measurement_nm
    with pytest.raises(ValueError, match="sigma_nm"):  # never a silent change of model
        relearn(_series(28, 0.02), 0.0, prior, 8, 4, given_sigma=True)


def test_an_estimate_changes_order_by_its_marginal():
    three = DriftNoise(order=3)
    est = DriftEstimate(5.0, np.array([[1.0, 0.1, 1e-4], [2.0, -0.1, 0.0]]),
                        np.tile(np.diag([0.04, 1e-4, 1e-8]), (2, 1, 1)))  # fmt: skip
    two = est.with_order(DriftNoise(order=2))
    np.testing.assert_array_equal(two.mean, est.mean[:, :2])
    np.testing.assert_array_equal(two.cov, est.cov[:, :2, :2])
    back = two.with_order(three)
    assert back.mean.shape == (2, 3) and np.all(back.mean[:, 2] == 0.0)
    assert back.cov[0, 2, 2] == DriftEstimate.start(0.0, three).cov[0, 2, 2]
    assert est.with_order(three) is est


def _learning():
    """``cpr5``'s drift on a scanner without creep or hysteresis, tracked with the noise
    learnt after 3 measurements, then every 2."""
    cfg = load_config("cpr5")
    scanner = replace(cfg.scanner, hysteresis=0.0, hysteresis_small=0.0, creep=0.0)
    afm = VirtualAFM(replace(cfg, scanner=scanner), seed=3)
    inst = DriftCompensatedInstrument(afm, DriftSettings(learn_noise_after=3, learn_noise_every=2))
    inst.start(center_nm=(0.0, 0.0), size_nm=800.0)
    return afm, inst


def test_the_drift_compensator_learns_its_noise_as_it_measures():
    afm, inst = _learning()
    prior = inst.noise
    for _ in range(5):
        afm.wait(60.0)  # time passes (under the compensator's clock)
        inst.measure()
    assert [n for n, _ in inst.learnt_noise] == [3, 5]
    learnt = inst.noise
    assert learnt is inst.learnt_noise[-1][1]
    assert learnt.position_nm_per_sqrt_s != prior.position_nm_per_sqrt_s
    assert inst.settings.noise.position_nm_per_sqrt_s == learnt.position_nm_per_sqrt_s
    assert inst.settings.noise.measurement_nm == prior.measurement_nm


def test_a_restart_learns_from_the_prior_tracking_started_with(tmp_path):
    """The drift model learnt changes the settings; the state keeps the prior it was learnt
    from, and a restarted tracking learns from it again; a file without one (or without
    areas) reads as before."""
    afm, inst = _learning()
    prior = inst.noise
    for _ in range(3):
        afm.wait(60.0)
        inst.measure()
    assert inst.learnt_noise and inst.settings.noise != prior
    assert inst.estimate.mean.shape[1] == inst.noise.order  # the estimate follows the order
    inst.save(tmp_path / "t.npz")
    again = DriftCompensatedInstrument.load(tmp_path / "t.npz", afm)
    assert again.state().prior_noise == prior
    assert again.noise == inst.noise and again.areas == {}
    old = replace(again.state(), prior_noise=None)  # as a file written before it was saved
    assert DriftCompensatedInstrument.resume(old, afm).state().prior_noise == inst.noise


def test_learning_can_be_switched_off_and_is_checked():
    assert DriftSettings(learn_noise_after=0).learn_noise_after == 0
    with pytest.raises(ValueError, match="learn_noise_every must be an integer >= 1"):
        DriftSettings(learn_noise_every=0)
    with pytest.raises(ValueError, match="learn_order must be True or False"):
        DriftSettings(learn_order=1)  # type: ignore[arg-type]


def _pooled(sightings, prior_nm):
    spread = SightingSpread.prior(prior_nm)
    for drifts in sightings:
        spread = spread.with_measurement(drifts)
    return spread.sigma_nm


def test_the_measurement_noise_is_the_landmarks_pooled_spread_with_the_prior():
    """Landmarks sighted together differ by their own errors: their pooled spread about each
    measurement's mean is the sigma of one sighting, the prior counted as PRIOR_DOF
    observations; a measurement of one landmark says nothing of it."""
    rng = np.random.default_rng(3)
    sigma, shared = 0.3, 5.0  # the shared part (the drift) does not enter the spread
    common = shared * rng.standard_normal((400, 2))  # each measurement's own drift
    many = [[c + rng.normal(0, sigma, 2) for _ in range(3)] for c in common]
    dof = 400 * 2 * 2
    pooled = np.sqrt((PRIOR_DOF * 2.0**2 + dof * sigma**2) / (PRIOR_DOF + dof))
    assert _pooled(many, prior_nm=2.0) == pytest.approx(pooled, rel=0.05)
    assert _pooled([], prior_nm=2.0) == 2.0
    assert _pooled([[np.zeros(2)]], prior_nm=2.0) == 2.0
    two = [[np.array([0.0, 0.0]), np.array([1.0, 1.0])]]  # spread 0.5 per axis, 2 dof
    expected = np.sqrt((PRIOR_DOF * 1.0 + 4 * 0.25) / (PRIOR_DOF + 2))
    assert _pooled(two, prior_nm=1.0) == pytest.approx(expected)


def test_the_spread_refuses_a_prior_it_cannot_use():
    with pytest.raises(ValueError, match=r"sigma_nm must be > 0\. Got -1"):
        SightingSpread.prior(-1.0)
    with pytest.raises(ValueError, match=r"dof must be an integer >= 1\. Got 0"):
        SightingSpread.prior(0.5, 0)
    with pytest.raises(ValueError, match="learn_measurement_noise must be True or False"):
        DriftSettings(learn_measurement_noise="off")  # type: ignore[arg-type]
