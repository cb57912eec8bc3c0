"""h(y) of Section IV: the cubic Hermite table, its derivative and the smoothing fit."""

from __future__ import annotations

import numpy as np
import pytest

from piezocomp.identification import _rls_kernel
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.loop.symmetric import SymmetricLoop


def test_hermite_reproduces_cubics_exactly():
    grid = np.linspace(-3.0, 5.0, 17)
    f = lambda y: 0.2 * y**3 - y**2 + 3 * y - 1  # noqa: E731
    df = lambda y: 0.6 * y**2 - 2 * y + 3  # noqa: E731
    prof = HeightProfile(grid[0], grid[1] - grid[0], f(grid), df(grid))
    y = np.linspace(-3.0, 5.0, 1001)
    np.testing.assert_allclose(prof(y), f(y), atol=1e-12)
    np.testing.assert_allclose(prof.derivative(y), df(y), atol=1e-11)


def test_derivative_is_that_of_the_values_and_kernel_agrees():
    rng = np.random.default_rng(0)
    prof = HeightProfile(-10.0, 0.5, rng.normal(size=41), rng.normal(size=41))
    y = rng.uniform(-12.0, 12.0, 300)
    d = 1e-6
    fd = (prof(y + d) - prof(y - d)) / (2 * d)
    inside = (y > -10 + d) & (y < 10 - d)
    np.testing.assert_allclose(prof.derivative(y)[inside], fd[inside], atol=1e-5)
    for yk in y:
        h, dh = _rls_kernel.hermite(yk, *prof.table())
        assert h == pytest.approx(float(prof(yk)), abs=1e-13)
        assert dh == pytest.approx(float(prof.derivative(yk)), abs=1e-12)


def test_outside_the_table_is_flat():
    prof = HeightProfile(0.0, 1.0, [1.0, 2.0, 4.0], [1.0, 1.0, 3.0])
    assert prof(-5.0) == 1.0 and prof(10.0) == 4.0
    assert prof.derivative(-5.0) == 0.0 and prof.derivative(10.0) == 0.0


def test_smoothing_recovers_a_particle_profile_under_noise():
    rng = np.random.default_rng(1)
    y = np.linspace(-300, 300, 601)
    truth = lambda v: 15 * np.exp(-0.5 * ((v - 40) / 12) ** 2)  # noqa: E731
    z = truth(y) + 0.1 * rng.standard_normal(y.size)
    prof = HeightProfile.from_samples(y, z)
    yy = np.linspace(-290, 290, 2000)
    assert np.abs(prof(yy) - truth(yy)).max() < 0.3
    dtruth = -(yy - 40) / 144 * truth(yy)
    assert np.abs(prof.derivative(yy) - dtruth).max() < 0.1  # h' usable in eq (18)


def test_from_loop_reindexes_by_the_ascending_branch():
    loop = SymmetricLoop(np.array([-0.05, 1.0, 0.05]), -500.0, 500.0)
    u = np.linspace(-500, 500, 501)
    y = loop.ascending(u)
    z = 10 * np.exp(-0.5 * ((y - 100) / 15) ** 2)
    rng = np.random.default_rng(2)
    traces = z + 0.05 * rng.standard_normal((3, u.size))
    prof = HeightProfile.from_loop(loop, u, traces)
    peak = np.linspace(50, 150, 10001)[np.argmax(prof(np.linspace(50, 150, 10001)))]
    assert peak == pytest.approx(100.0, abs=0.3)
    assert prof.noise_nm == pytest.approx(0.05, rel=0.3)
    with pytest.raises(ValueError, match="heights_nm"):
        HeightProfile.from_loop(loop, u, traces[:, :-1])


def test_checks():
    with pytest.raises(ValueError, match="step_nm"):
        HeightProfile(0.0, 0.0, [1.0, 2.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="strictly increasing"):
        HeightProfile.from_samples([0, 1, 1, 2, 3, 4], [0, 1, 2, 3, 4, 5])


def test_from_positions_matches_from_loop_and_refuses_non_increasing_positions():
    from piezocomp.identification.loop.symmetric import SymmetricLoop

    loop = SymmetricLoop(np.array([-0.05, 1.0, 0.05]), -500.0, 500.0)
    u = np.linspace(-500, 500, 401)
    z = np.array([8 * np.exp(-0.5 * ((u - c) / 15) ** 2) for c in (-100.0, 200.0)]).sum(axis=0)
    a = HeightProfile.from_loop(loop, u, np.vstack([z, z + 0.01]))
    b = HeightProfile.from_positions(loop.ascending(u), np.vstack([z, z + 0.01]))
    assert np.array_equal(a.values_nm, b.values_nm) and a.noise_nm == b.noise_nm
    y = np.asarray(loop.ascending(u)).copy()
    y[10] = y[9]
    with pytest.raises(ValueError, match=r"strictly increasing; y_nm\[10\]"):
        HeightProfile.from_positions(y, z)
    with pytest.raises(ValueError, match="shape"):
        HeightProfile.from_positions(y, z[:-1])


def test_spline_penalty_recovers_the_gcv_choice():
    """The penalty read back from a GCV smoothing spline refits the same spline; it is
    stored with the profile, and a given penalty is stored as given."""
    from scipy.interpolate import make_smoothing_spline

    from piezocomp.identification.loop.profile import spline_penalty

    rng = np.random.default_rng(3)
    x = np.linspace(-500.0, 500.0, 400)
    clean = 15.0 * np.exp(-(((x - 90.0) / 12.0) ** 2)) + 9.0 * np.exp(-(((x + 240.0) / 10.0) ** 2))
    y = clean + 0.2 * rng.standard_normal(x.size)
    gcv = make_smoothing_spline(x, y)
    lam = spline_penalty(gcv, x, y)
    assert np.isfinite(lam) and lam > 0
    again = make_smoothing_spline(x, y, lam=lam)
    assert np.max(np.abs(again(x) - gcv(x))) < 1e-8
    # a wrong penalty does not (the check can fail)
    assert np.max(np.abs(make_smoothing_spline(x, y, lam=3 * lam)(x) - gcv(x))) > 1e-3
    prof = HeightProfile.from_samples(x, y)
    assert prof.penalty == pytest.approx(lam, rel=1e-9)
    assert HeightProfile.from_samples(x, y, lam=2.5).penalty == 2.5
    with pytest.raises(ValueError, match="lam"):
        HeightProfile.from_samples(x, y, lam=float("nan"))


def test_scaled_multiplies_heights_and_slopes():
    y = np.linspace(-50.0, 50.0, 201)
    prof = HeightProfile.from_samples(y, 10.0 * np.exp(-0.5 * (y / 8.0) ** 2), lam=1e-6)
    twice = prof.scaled(2.5)
    q = np.linspace(-40.0, 40.0, 33)
    np.testing.assert_allclose(twice(q), 2.5 * prof(q), rtol=1e-12)
    np.testing.assert_allclose(twice.derivative(q), 2.5 * prof.derivative(q), rtol=1e-12)
    assert twice.penalty == prof.penalty and twice.y_range_nm == prof.y_range_nm
    with pytest.raises(ValueError, match="factor"):
        prof.scaled(float("nan"))
