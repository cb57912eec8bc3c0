"""The sensorless recursive estimator, eqs (16)-(20): kernel vs reference, feasibility,
convergence."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezocomp.identification import _rls_kernel
from piezocomp.identification.acquisition.waveforms import identification_waveform
from piezocomp.identification.estimation.parameters import ThetaLayout, theta_from_model
from piezocomp.identification.estimation.rls import RLSSettings, default_scale, feasible_bounds, rls
from piezocomp.identification.loop.profile import HeightProfile, hermite_eval
from piezocomp.model import ModelState, ScannerModel, simulate

T = 0.008
R = np.array([50.0, 120.0, 200.0, 290.0, 380.0])
W = np.array([0.06, 0.05, 0.04, 0.03, 0.02])
TRUE = ScannerModel(
    offset_nm=3.0,
    gain=0.8,
    thresholds_nm=R,
    weights=W,
    creep_time_constants_s=[1.0, 20.0],
    creep_gains=[0.02, 0.03],
)


def _profile(seed: int = 0) -> HeightProfile:
    """A known smooth topography: 30 Gaussian particles 12 nm high over +-560 nm."""
    rng = np.random.default_rng(seed)
    centres = np.sort(rng.uniform(-560, 560, 30))
    grid = np.linspace(-800, 800, 6401)
    h = sum(12 * np.exp(-0.5 * ((grid - c) / 10) ** 2) for c in centres)
    return HeightProfile.from_samples(grid, h, lam=1e-8, step_nm=0.25)


def _perturbed(f: float) -> ScannerModel:
    return ScannerModel(
        offset_nm=3.0 + 100 * f,
        gain=0.8 * (1 + f),
        thresholds_nm=R * (1 - f),
        weights=W * (1 - 2 * f),
        creep_time_constants_s=[1.5, 30.0],
        creep_gains=[0.02 * (1 - 5 * f), 0.03 * (1 + 5 * f)],
    )


def _record(n_random: int = 20):
    wf = identification_waveform(
        0, 1000, 250, T, n_steady=2, n_decaying=10, n_random=n_random, rng=3
    )
    u = wf.u_nm
    y, _ = simulate(TRUE, u, T, ModelState.at_rest(TRUE, u[0]))
    prof = _profile()
    return u, y, prof, np.asarray(prof(y))


# --------------------------------------------------------------------------- reference
def reference_rls(u, zm, nc, nh, theta, P, state, prof, scale, free, lower, upper, gap, p0, k0,
                  min_eig, eig_every, paper_alpha, clip=0.0):  # fmt: skip
    """Plain-Python eqs (16)-(20), written from the paper and NOTES.md, not from the kernel."""
    theta = theta.copy()
    P = P.copy()
    z = list(state[:nh])
    x = list(state[nh : nh + nc])
    u_prev = state[nh + nc]
    s = [0.0] * nc
    q = [0.0] * nh
    lay = ThetaLayout(nc, nh)
    eps_all, thetas, since = [], [], 0
    for k in range(u.size):
        uk = u[k]
        c, p = theta[lay.c], theta[lay.p]
        a, w, r, y0 = theta[lay.a], theta[lay.w], theta[lay.r], theta[lay.y0]
        grad = np.zeros(lay.size)
        y = y0 + a * uk
        for i in range(nc):
            s[i] = x[i] - u_prev + p[i] * s[i]
            x[i] = p[i] * x[i] + (1 - p[i]) * u_prev
            y += c[i] * x[i]
            grad[lay.c.start + i] = x[i]
            grad[lay.p.start + i] = c[i] * s[i]
        grad[lay.a] = uk
        for j in range(nh):
            if z[j] >= uk + r[j]:  # eq (19), clamped at u + r
                z[j], q[j] = uk + r[j], 1.0
            elif z[j] <= uk - r[j]:  # clamped at u - r
                z[j], q[j] = uk - r[j], -1.0
            y += w[j] * z[j]
            grad[lay.w.start + j] = z[j]
            grad[lay.r.start + j] = w[j] * q[j]
        grad[lay.y0] = 1.0
        u_prev = uk
        h, dh = hermite_eval(np.array([y]), *prof.table())
        eps = zm[k] - h[0]  # eq (17)
        psi = dh[0] * grad * scale * free  # eq (18), scaled
        if psi @ psi > 0:
            Ppsi = P @ psi
            alpha = (psi @ Ppsi) / (psi @ psi) if paper_alpha else 1.0  # eq (20)
            den = 1 + alpha * (psi @ Ppsi)
            e = float(np.clip(eps, -clip, clip)) if clip > 0 else eps  # Huber
            theta = theta + scale * alpha * Ppsi / den * e
            P = P - alpha * np.outer(Ppsi, Ppsi) / den
            theta = np.clip(theta, lower, upper)
            rr = theta[lay.r]
            for j in range(1, nh):
                rr[j] = max(rr[j], rr[j - 1] + gap)
            for j in range(nh - 2, -1, -1):
                rr[j] = min(rr[j], rr[j + 1] - gap)
            theta[lay.r] = rr
        since += 1
        reset = k0 > 0 and since >= k0
        if not reset and eig_every > 0 and (k + 1) % eig_every == 0:
            P = 0.5 * (P + P.T)
            reset = np.linalg.eigvalsh(P)[0] < min_eig
        if reset:
            P = p0 * np.eye(lay.size)
            since = 0
        eps_all.append(eps)
        thetas.append(theta.copy())
    return np.array(eps_all), np.array(thetas), theta


@pytest.mark.parametrize(
    ("paper_alpha", "k0", "min_eig", "clip"),
    [(True, 150, 0.0, 0.0), (False, 0, 0.5, 0.0), (False, 150, 0.0, 0.3)],
)
def test_kernel_matches_reference(paper_alpha, k0, min_eig, clip):
    u, _, prof, z = _record(n_random=3)
    u, z = u[:1200], z[:1200] + 0.05 * np.random.default_rng(1).standard_normal(1200)
    init = _perturbed(0.02)
    lay = ThetaLayout(init.n_creep, init.n_play)
    cfg = RLSSettings()
    lower, upper = feasible_bounds(lay, cfg, T, 500.0)
    scale = default_scale(init, T, 1000.0)
    free = np.ones(lay.size)
    free[lay.y0] = 0.0  # a held parameter
    theta0 = theta_from_model(init, T)
    P0 = 3.0 * np.eye(lay.size)
    st = ModelState.at_rest(init, u[0]).packed()
    args = (lower, upper, 1.0, 3.0, k0, min_eig, 50, paper_alpha)
    eps_ref, tr_ref, _ = reference_rls(
        u, z, lay.n_creep, lay.n_play, theta0, P0, st, prof, scale, free, *args, clip
    )
    theta = theta0.copy()
    eps = np.empty(u.size)
    trace = np.empty((u.size, lay.size))
    resets = np.zeros(u.size, dtype=np.bool_)
    idx = np.flatnonzero(free)  # the kernel carries the free block of P only
    _rls_kernel.rls_run(u, z, lay.n_creep, lay.n_play, theta, P0[np.ix_(idx, idx)].copy(),
                        st.copy(), np.zeros(lay.n_creep + lay.n_play), *prof.table(), scale, idx,
                        *args[:2], 1.0, 3.0, k0, min_eig, 50, paper_alpha, clip,
                        np.zeros((0, lay.size)), np.zeros(u.size), eps,
                        np.empty(u.size), trace, resets)  # fmt: skip
    np.testing.assert_allclose(eps, eps_ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(trace, tr_ref, rtol=1e-10, atol=1e-10)
    assert resets.any()  # the resetting branch was exercised
    assert np.all(trace[:, lay.y0] == theta0[lay.y0])


def _feasible(trace: np.ndarray, lay: ThetaLayout) -> bool:
    r = trace[:, lay.r]
    p = trace[:, lay.p]
    return bool(
        np.all(trace[:, lay.c] >= 0)
        and np.all((p > 0) & (p < 1))
        and np.all(trace[:, lay.a] > 0)
        and np.all(trace[:, lay.w] > 0)
        and np.all(r[:, 0] > 0)
        and np.all(np.diff(r, axis=1) > 0)
    )


def test_projection_keeps_every_step_feasible():
    """A deliberately aggressive run (large p0, noisy heights) is projected at every step."""
    u, _, prof, z = _record(n_random=5)
    z = z + 2.0 * np.random.default_rng(2).standard_normal(z.size)
    res = rls(u, z, prof, _perturbed(0.05), T, settings=RLSSettings(alpha="unit", p0=100.0))
    lay = res.layout
    assert _feasible(res.theta_trace, lay)
    # the bounds were active somewhere: projection did work
    lower, upper = feasible_bounds(lay, RLSSettings(), T, 500.0)
    at_bound = np.isclose(res.theta_trace, lower) | np.isclose(res.theta_trace, upper)
    assert at_bound.any()
    res.model.loading_curve(np.linspace(0, 500, 11))  # a valid, invertible model


@pytest.mark.parametrize(
    ("alpha", "p0", "passes", "gain"), [("unit", 0.1, 3, 5.0), ("paper", 1.0, 3, 2.0)]
)
def test_converges_towards_truth_on_exact_model(alpha, p0, passes, gain):
    """Exact model + known smooth h: RLS (eq 20) shrinks the extension error of the start.

    The start is within a fraction of a particle of the truth (the regime the sensorless
    pipeline provides from the loop of Section IV); the final estimate must predict the true
    extension ``gain`` times better and keep the height error small.
    """
    u, y, prof, z = _record()
    init = _perturbed(0.01)
    y_init, _ = simulate(init, u, T, ModelState.at_rest(init, u[0]))
    e0 = np.abs(y_init - y)[2000:].max()
    res = rls(u, z, prof, init, T, settings=RLSSettings(alpha=alpha, p0=p0, passes=passes))
    y_hat, _ = simulate(res.model, u, T, ModelState.at_rest(res.model, u[0]))
    e1 = np.abs(y_hat - y)[2000:].max()
    assert e0 > 2.0
    assert e1 < e0 / gain
    assert _feasible(res.theta_trace, res.layout)
    assert np.abs(res.error_nm[-3000:]).max() < 1.2


def test_settings_are_checked():
    with pytest.raises(ValueError, match="alpha"):
        RLSSettings(alpha="fast")
    with pytest.raises(ValueError, match="p0"):
        RLSSettings(p0=0.0)
    with pytest.raises(ValueError, match="free"):
        RLSSettings(free=("a", "q"))
    for bad in (0.0, -1.0, float("nan"), True):
        with pytest.raises(ValueError, match="clip_nm"):
            RLSSettings(clip_nm=bad)
    for name in ("creep_smoothing_nm", "weight_smoothing_nm"):
        with pytest.raises(ValueError, match=name):
            RLSSettings(**{name: -1.0})
    u, _, prof, z = _record(n_random=1)
    with pytest.raises(ValueError, match="height_nm"):
        rls(u, z[:-1], prof, TRUE, T)
    with pytest.raises(TypeError, match="profile"):
        rls(u, z, None, TRUE, T)  # type: ignore[arg-type]


@pytest.mark.parametrize("true_tau_s", [(1.0, 20.0), (0.5, 40.0), (2.0, 10.0)])
def test_the_papers_method_converges_from_its_start_on_its_own_family(true_tau_s):
    """A check of the mathematics, not of the method on a scanner: heights of a model of the
    paper's own family (8 play operators, 2 creep operators) over a known ``h``, and the
    RLS as the ``paper`` method runs it (eq 20's gain, every group free, covariance
    resetting, 20 passes) from the ``paper`` method's start: creep gains 0 as the paper's
    zero initial values, creep poles at ``creep_tau_range_s`` of
    :data:`~piezocomp.experiments.methods.PAPER_CHANGES` (where a zero pole is undefined),
    the Prandtl-Ishlinskii part within a few per cent (the loop of Section IV's part).
    It must find the poles and predict the extension within a nanometre."""
    from piezocomp.experiments.methods import PAPER_CHANGES
    from piezocomp.identification.estimation.candidates import creep_spectrum, thresholds_over_span

    true = ScannerModel(offset_nm=3.0, gain=0.8, thresholds_nm=thresholds_over_span(8, 1000.0),
                        weights=np.linspace(0.06, 0.015, 8), creep_time_constants_s=true_tau_s,
                        creep_gains=[0.03, 0.04])  # fmt: skip
    wf = identification_waveform(0, 1000, 250, T, n_steady=2, n_decaying=10, n_random=20, rng=3)
    u = wf.u_nm
    y, _ = simulate(true, u, T, ModelState.at_rest(true, u[0]))
    prof = _profile()
    start = replace(true, offset_nm=3.5, gain=0.808, weights=0.98 * true.weights,
                    creep_time_constants_s=creep_spectrum(2, PAPER_CHANGES["creep_tau_range_s"]),
                    creep_gains=[0.0, 0.0])  # fmt: skip
    res = rls(u, np.asarray(prof(y)), prof, start, T, settings=PAPER_CHANGES["rls_settings"])
    y0, _ = simulate(start, u, T, ModelState.at_rest(start, u[0]))
    y1, _ = simulate(res.model, u, T, ModelState.at_rest(res.model, u[0]))
    assert np.abs(y0 - y)[2000:].max() > 15.0  # the start is far off
    assert np.abs(y1 - y)[2000:].max() < 1.0
    np.testing.assert_allclose(res.model.creep_time_constants_s, true_tau_s, rtol=0.05)


def test_truth_is_a_fixed_point():
    """Started at the true parameters with exact data, nothing moves (eps = 0)."""
    u, _, prof, z = _record(n_random=2)
    res = rls(u, z, prof, TRUE, T, state=ModelState.at_rest(TRUE, u[0]))
    np.testing.assert_allclose(res.theta, theta_from_model(TRUE, T), atol=1e-9)
    assert np.abs(res.error_nm).max() < 1e-9


def test_clipped_errors_resist_gross_outliers():
    """Heights with gross outliers (a tip artefact: 40 bursts of +25 nm): the Huber update
    (``clip_nm``) keeps the estimate near the truth where eq (20) as printed is pulled off."""
    u, y, prof, z = _record()
    rng = np.random.default_rng(5)
    z = z + 0.05 * rng.standard_normal(z.size)
    for k in rng.choice(np.arange(2000, z.size - 20), 40, replace=False):
        z[k : k + 15] += 25.0
    init = _perturbed(0.005)
    errs = {}
    for clip in (None, 1.0):
        cfg = RLSSettings(alpha="unit", p0=0.1, passes=3, k0=3000, clip_nm=clip)
        res = rls(u, z, prof, init, T, settings=cfg)
        y_hat, _ = simulate(res.model, u, T, ModelState.at_rest(res.model, u[0]))
        errs[clip] = np.abs(y_hat - y)[2000:].max()
    assert errs[1.0] < 0.5 * errs[None]
    assert errs[1.0] < 1.0


def test_prior_pseudo_measurement_is_the_regularised_least_squares_update():
    """One pseudo-measurement ``0 = r . theta`` from ``theta0`` with covariance ``P``: the
    update is the minimiser of ``|theta - theta0|^2_{P^-1} + (r . theta)^2`` (in the scaled
    parameters), and ``P`` becomes that problem's inverse Hessian."""
    init = _perturbed(0.01)
    lay = ThetaLayout(init.n_creep, init.n_play)
    theta0 = theta_from_model(init, T)
    free = np.arange(lay.size)[lay.w]  # the weights free, the rest held
    scale = default_scale(init, T, 1000.0)
    rng = np.random.default_rng(3)
    A = rng.standard_normal((free.size, free.size))
    P0 = 0.1 * (A @ A.T / free.size + np.eye(free.size))
    row = np.zeros((1, lay.size))
    row[0, np.arange(lay.size)[lay.w][:3]] = 50.0 * np.array([1.0, -2.0, 1.0])
    theta, P = theta0.copy(), P0.copy()
    lower, upper = np.full(lay.size, -np.inf), np.full(lay.size, np.inf)
    _rls_kernel.apply_prior(theta, P, free, scale, row, lay.n_creep, lay.n_play,
                            lower, upper, 1e-9)  # fmt: skip
    psi = row[0, free] * scale[free]  # d(r . theta)/d(phi) on the free, scaled parameters
    H = np.linalg.inv(P0) + np.outer(psi, psi)
    phi0 = theta0[free] / scale[free]
    phi = np.linalg.solve(H, np.linalg.inv(P0) @ phi0)  # minimiser of the quadratic
    np.testing.assert_allclose(theta[free] / scale[free], phi, rtol=1e-9)
    np.testing.assert_allclose(P, np.linalg.inv(H), rtol=1e-9, atol=1e-12)
    held = np.setdiff1d(np.arange(lay.size), free)
    assert np.array_equal(theta[held], theta0[held])


def test_smoothness_prior_smooths_the_estimated_weights():
    """Exact data, 5 play operators: with the weight prior the RLS estimate's second
    differences shrink (it is processed after every reset); without it they do not."""
    u, _, prof, z = _record(n_random=5)
    init = _perturbed(0.005)
    base = RLSSettings(alpha="unit", p0=0.1, passes=2, k0=1000, free=("a", "w", "y0"))
    plain = rls(u, z, prof, init, T, settings=base)
    smooth = rls(u, z, prof, init, T, settings=replace(base, weight_smoothing_nm=3000.0))

    def rough(m: ScannerModel) -> float:
        return float(np.sum(np.diff(m.weights, 2) ** 2))

    assert rough(smooth.model) < 0.3 * rough(plain.model)


# ---------------------------------------------------------------------------- eq (2')
def _coupled_truth() -> ScannerModel:
    return replace(TRUE, creep_coupling=0.6)


def test_coupled_predictor_and_gradient_are_those_of_the_coupled_model():
    """The RLS kernel's coupled step, with theta held, predicts what simulate gives and has
    the gradient of simulate_with_gradient(coupled=True) (same recursion, eq 2')."""
    from piezocomp.identification.estimation.parameters import simulate_with_gradient
    from piezocomp.operators._kernels import sensitivity_size

    m = _coupled_truth()
    u = _record(n_random=2)[0][:3000]
    st = ModelState.at_rest(m, u[0])
    y, jac, _ = simulate_with_gradient(m, u, T, st, coupled=True)
    theta = theta_from_model(m, T, coupled=True)
    nc, nh = m.n_creep, m.n_play
    packed = st.packed()
    z, x = packed[:nh], packed[nh : nh + nc]
    sens = np.zeros(sensitivity_size(nh, nc, True))
    grad = np.zeros(theta.size)
    zp, qp = np.zeros(nh), np.zeros(nh)
    u_prev = packed[-1]
    for k in range(u.size):
        yk = _rls_kernel.coupled_step(u[k], u_prev, theta, nc, nh, z, x, sens, grad, zp, qp)
        u_prev = u[k]
        assert yk == pytest.approx(y[k], rel=1e-12, abs=1e-9)
        np.testing.assert_allclose(grad, jac[k], rtol=1e-9, atol=1e-9)


def test_coupled_rls_with_nothing_free_is_the_coupled_prediction():
    m = _coupled_truth()
    u, _, prof, _ = _record(n_random=2)
    y, _ = simulate(m, u, T, ModelState.at_rest(m, u[0]))
    res = rls(u, np.asarray(prof(y)), prof, m, T, settings=RLSSettings(free=()))
    np.testing.assert_allclose(res.y_hat_nm, y, rtol=1e-12, atol=1e-8)
    assert res.model.creep_coupling == 0.6 and res.layout.coupled
    np.testing.assert_allclose(res.error_nm, 0.0, atol=1e-8)


def test_coupled_rls_frees_beta_and_converges_towards_truth():
    """Exact coupled model + known h, start perturbed (beta 0.3 against 0.6): with "b" free
    the RLS shrinks the extension error of the start (mathematics, as the paper-model test
    above)."""
    truth = _coupled_truth()
    wf = identification_waveform(0, 1000, 250, T, n_steady=2, n_decaying=10, n_random=20, rng=3)
    u = wf.u_nm
    y, _ = simulate(truth, u, T, ModelState.at_rest(truth, u[0]))
    prof = _profile()
    z = np.asarray(prof(y))
    init = replace(_perturbed(0.01), creep_coupling=0.3)
    y_init, _ = simulate(init, u, T, ModelState.at_rest(init, u[0]))
    e0 = np.abs(y_init - y)[2000:].max()
    cfg = RLSSettings(alpha="unit", p0=0.1, passes=3, free=(*RLSSettings().free, "b"))
    res = rls(u, z, prof, init, T, settings=cfg)
    y_hat, _ = simulate(res.model, u, T, ModelState.at_rest(res.model, u[0]))
    e1 = np.abs(y_hat - y)[2000:].max()
    assert e0 > 2.0
    assert e1 < e0 / 3.0
    assert _feasible(res.theta_trace, res.layout)
    # beta alone (the rest true): it moves towards the truth. With every group free it moves
    # little on this record: the creep gains take most of the change (u and H are nearly
    # proportional on one line's sweeps), which the prediction error above does not mind.
    alone = rls(u, z, prof, replace(truth, creep_coupling=0.3), T,
                settings=RLSSettings(alpha="unit", p0=1.0, passes=3, free=("b",)))  # fmt: skip
    assert abs(alone.model.creep_coupling - 0.6) < 0.5 * abs(0.3 - 0.6)
