"""Batch refinement (bounded nonlinear least squares over a record).

Exact-model tests: data come from a known ScannerModel, so they check the mathematics
(residuals, Jacobian, reparametrisation, bounds), not the model's fitness for real data.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from piezocomp.identification.estimation.batch import (
    GROUPS,
    RefineOptions,
    RefineResult,
    Segment,
    refine,
)
from piezocomp.identification.estimation.parameters import simulate_with_gradient
from piezocomp.identification.estimation.reparametrisation import POLE_BOUNDS, Reparametrisation
from piezocomp.model import ModelState, ScannerModel, simulate

T = 0.01

TRUTH = ScannerModel(
    offset_nm=5.0,
    gain=0.6,
    thresholds_nm=[50.0, 120.0, 200.0, 300.0],
    weights=[0.2, 0.1, 0.08, 0.05],
    creep_time_constants_s=[0.3, 3.0],
    creep_gains=[0.05, 0.1],
)

START = ScannerModel(
    offset_nm=0.0,
    gain=0.5,
    thresholds_nm=[40.0, 100.0, 220.0, 280.0],
    weights=[0.15, 0.12, 0.1, 0.04],
    creep_time_constants_s=[0.5, 2.0],
    creep_gains=[0.03, 0.12],
)


def _command(n: int = 4000) -> np.ndarray:
    """Sine with slowly varying amplitude: sweeps every threshold, many reversals."""
    t = np.arange(n) * T
    return 300.0 + 400.0 * np.sin(2 * np.pi * 0.5 * t) * (
        0.3 + 0.7 * np.abs(np.sin(2 * np.pi * 0.03 * t))
    )


def _assert_models_close(a: ScannerModel, b: ScannerModel, rtol: float) -> None:
    assert_allclose(a.gain, b.gain, rtol=rtol)
    assert_allclose(a.offset_nm, b.offset_nm, rtol=rtol, atol=rtol * 100)
    assert_allclose(a.thresholds_nm, b.thresholds_nm, rtol=rtol)
    assert_allclose(a.weights, b.weights, rtol=rtol)
    assert_allclose(a.creep_time_constants_s, b.creep_time_constants_s, rtol=rtol)
    assert_allclose(a.creep_gains, b.creep_gains, rtol=rtol)


def test_refine_recovers_exact_model_from_perturbed_start():
    u = _command()
    y, _ = simulate(TRUTH, u, T)
    res = refine(START, u, y, T)
    assert isinstance(res, RefineResult)
    assert res.success
    assert res.cost < 1e-12 * res.initial_cost
    assert res.free == GROUPS
    assert res.n_residuals == u.size
    assert len(res.cost_history) == res.nfev
    _assert_models_close(res.model, TRUTH, rtol=1e-6)


class _Topography:
    """A smooth, monotone synthetic height map ``h(y)`` (nm -> nm) and its derivative."""

    def __call__(self, y):
        return 0.5 * y + 40.0 * np.tanh((y - 200.0) / 80.0)

    def derivative(self, y):
        return 0.5 + 0.5 / np.cosh((y - 200.0) / 80.0) ** 2


def test_sensorless_output_map_recovers_exact_model():
    u = _command()
    h = _Topography()
    y, _ = simulate(TRUTH, u, T)
    zm = h(y)
    res = refine(START, u, zm, T, output=h)
    assert res.success
    _assert_models_close(res.model, TRUTH, rtol=1e-5)


def test_output_map_must_have_a_derivative():
    u = _command(100)
    with pytest.raises(TypeError, match="derivative"):
        refine(START, u, u, T, output=lambda y: y)


def test_reparametrised_jacobian_matches_finite_differences():
    u = _command(1500)
    free = GROUPS
    rep = Reparametrisation(START, T, free, 1e-9, 1e-9, 1e-3)

    def pred(x):
        y, _ = simulate(rep.model(x), u, T)
        return y

    x0 = rep.x0
    _, jac_theta, _ = simulate_with_gradient(rep.model(x0), u, T)
    analytic = rep.chain(jac_theta)
    numeric = np.empty_like(analytic)
    for j in range(x0.size):
        h = 1e-6 * max(abs(x0[j]), 1.0)
        if rep.upper[j] < np.inf:  # poles: stay inside (0, 1)
            h = min(h, 1e-7)
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h
        xm[j] -= h
        numeric[:, j] = (pred(xp) - pred(xm)) / (2 * h)
    scale = np.abs(analytic).max(axis=0) + 1e-12
    err = np.abs(numeric - analytic).max(axis=0) / scale
    assert err.max() < 1e-6, dict(zip(range(x0.size), err, strict=True))


def test_without_free_thresholds_the_chain_is_the_free_columns():
    """With the thresholds held, ``d/dx`` is ``d/dtheta``'s free columns; the same model with
    thresholds free gives the same columns for the other groups; of a subset of rows, it is
    those rows of the whole."""
    u = _command(600)
    _, jac_theta, _ = simulate_with_gradient(START, u, T)
    held = Reparametrisation(START, T, ("c", "a", "w", "y0"), 1e-9, 1e-9, 1e-3)
    both = Reparametrisation(START, T, ("c", "a", "w", "r", "y0"), 1e-9, 1e-9, 1e-3)
    assert not held.thresholds_free and both.thresholds_free
    np.testing.assert_array_equal(held.chain(jac_theta), jac_theta[:, held.free_index])
    keep = np.isin(both.free_index, held.free_index)
    np.testing.assert_array_equal(both.chain(jac_theta)[:, keep], held.chain(jac_theta))
    rows = np.arange(u.size) % 3 == 1  # of some rows only: the same rows of the whole
    for rep in (held, both):
        np.testing.assert_array_equal(rep.chain(jac_theta, rows), rep.chain(jac_theta)[rows])


def test_thresholds_stay_increasing_through_increments():
    rep = Reparametrisation(START, T, GROUPS, 1e-9, 1e-9, 1e-3)
    x = rep.x0.copy()
    r = rep.layout.r
    idx = np.searchsorted(rep.free_index, np.arange(rep.layout.size)[r])
    x[idx] = rep.lower[idx]  # every increment at its lower bound
    th = rep.theta(x)[r]
    assert np.all(np.diff(th) > 0) and th[0] > 0


def test_held_groups_stay_fixed():
    u = _command(2000)
    y, _ = simulate(TRUTH, u, T)
    res = refine(START, u, y, T, options=RefineOptions(free=("c", "a", "w", "y0")))
    assert_allclose(res.model.thresholds_nm, START.thresholds_nm, rtol=0, atol=0)
    assert_allclose(res.model.creep_time_constants_s, START.creep_time_constants_s, rtol=1e-12)
    assert res.cost < res.initial_cost
    assert res.free == ("c", "a", "w", "y0")


def test_start_outside_bounds_is_projected_and_model_feasible():
    start = ScannerModel(
        gain=1.0,
        thresholds_nm=[50.0, 120.0],
        weights=[1e-15, 0.1],  # below min_weight
        creep_time_constants_s=[1e-6],  # pole exp(-T/tau) ~ 0 < lower bound
        creep_gains=[0.0],
    )
    truth = ScannerModel(
        gain=0.7,
        thresholds_nm=[50.0, 120.0],
        weights=[0.2, 0.1],
        creep_time_constants_s=[0.5],
        creep_gains=[0.1],
    )
    u = _command(1500)
    y, _ = simulate(truth, u, T)
    res = refine(start, u, y, T)
    m = res.model
    assert np.all(m.weights > 0) and m.gain > 0 and np.all(m.creep_gains >= 0)
    p = m.creep_poles(T)
    assert np.all((p >= POLE_BOUNDS[0]) & (p <= POLE_BOUNDS[1]))
    assert res.cost < 1e-6 * res.initial_cost


def test_warmup_excludes_an_unknown_initial_state():
    """A record that starts mid-history: after a full sweep the play states are wiped out."""
    truth = ScannerModel(offset_nm=2.0, gain=0.6, thresholds_nm=[40.0, 150.0], weights=[0.3, 0.2])
    start = ScannerModel(offset_nm=0.0, gain=0.5, thresholds_nm=[60.0, 130.0], weights=[0.2, 0.25])
    u = _command(3000)
    hidden = ModelState(np.array([250.0, -80.0]), np.zeros(0), 310.0)  # unknown pre-history
    y, _ = simulate(truth, u, T, hidden)
    first_sweep = 200  # one period of the 0.5 Hz sine at T = 10 ms
    res = refine(start, u, y, T, state=ModelState.at_rest(start, u[0]), warmup_samples=first_sweep)
    assert res.n_residuals == u.size - first_sweep
    _assert_models_close(res.model, truth, rtol=1e-6)
    # without the warm-up the wrong initial state biases the fit
    biased = refine(start, u, y, T, state=ModelState.at_rest(start, u[0]))
    assert biased.rms > 1e3 * res.rms


def test_fit_mask_limits_the_cost_to_the_chosen_samples():
    u = _command(2000)
    y, _ = simulate(TRUTH, u, T)
    y_bad = y.copy()
    y_bad[1500:] += 1000.0  # corrupted tail, masked out
    mask = np.zeros(u.size, bool)
    mask[:1500] = True
    res = refine(START, u, y_bad, T, fit_mask=mask)
    assert res.n_residuals == 1500
    _assert_models_close(res.model, TRUTH, rtol=1e-5)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"free": ("a", "bogus")}, "bogus"),
        ({"free": ()}, "at least one"),
        ({"fit_mask": np.ones(3, bool)}, "fit_mask"),
        ({"warmup_samples": 10_000}, "warmup_samples"),
        ({"min_weight": 0.0}, "min_weight"),
        ({"min_threshold_step_nm": -1.0}, "min_threshold_step_nm"),
        ({"creep_smoothing_nm": -1.0}, "creep_smoothing_nm"),
        ({"creep_smoothing_nm": float("nan")}, "creep_smoothing_nm"),
        ({"weight_smoothing_nm": -1.0}, "weight_smoothing_nm"),
    ],
)
def test_bad_arguments_are_refused(kwargs, match):
    u = _command(200)
    data = {k: v for k, v in kwargs.items() if k in ("fit_mask", "warmup_samples")}
    with pytest.raises(ValueError, match=match):
        options = RefineOptions(**{k: v for k, v in kwargs.items() if k not in data})
        refine(START, u, u, T, **data, options=options)


def test_measured_length_must_match():
    with pytest.raises(ValueError, match="measured"):
        refine(START, np.zeros(10), np.zeros(9), T)


def test_records_split_in_two_segments_recover_the_model():
    """One record cut in two, the second fitted as an extra segment from its true state:
    the same model comes out, and the residuals of both count."""
    u = _command()
    y, _ = simulate(TRUTH, u, T)
    k = 2500
    _, mid = simulate(TRUTH, u[:k], T)
    second = Segment(u[k:], y[k:], state=mid)
    res = refine(START, u[:k], y[:k], T, extra=[second])
    assert res.n_residuals == u.size
    _assert_models_close(res.model, TRUTH, rtol=1e-6)


def test_two_lines_with_their_own_output_maps():
    """Two records through different height maps (two scan lines) share one model: the
    joint fit recovers it, while either line alone sees a different part of the range."""

    class _Shifted(_Topography):
        def __call__(self, y):
            return super().__call__(y - 150.0)

        def derivative(self, y):
            return super().derivative(y - 150.0)

    u = _command()
    y, _ = simulate(TRUTH, u, T)
    h1, h2 = _Topography(), _Shifted()
    other = Segment(u, h2(y), output=h2, state=ModelState.zeros(TRUTH))
    res = refine(START, u, h1(y), T, output=h1, extra=[other])
    assert res.n_residuals == 2 * u.size
    _assert_models_close(res.model, TRUTH, rtol=1e-5)


def test_extra_segments_are_checked():

    u = _command(500)
    y, _ = simulate(TRUTH, u, T)
    with pytest.raises(TypeError, match=r"extra\[0\] must be a Segment"):
        refine(START, u, y, T, extra=[(u, y)])  # type: ignore[list-item]
    with pytest.raises(ValueError, match=r"extra\[0\]\.measured must have one sample"):
        refine(START, u, y, T, extra=[Segment(u, y[:-1])])
    with pytest.raises(ValueError, match=r"extra\[0\]\.u_nm"):
        refine(START, u, y, T, extra=[Segment(np.r_[u[:-1], np.nan], y)])


_TAUS = [0.05, 0.1, 0.2, 0.4, 0.8]
_R5 = [40.0, 90.0, 140.0, 190.0, 240.0]
_SMOOTHING_CASES = {
    # a single creep mode among five
    "creep_smoothing_nm": (
        ScannerModel(offset_nm=0.0, gain=0.7, thresholds_nm=[60.0, 150.0], weights=[0.1, 0.05],
                     creep_time_constants_s=_TAUS, creep_gains=[0.0, 0.0, 0.06, 0.0, 0.0]),
        ScannerModel(offset_nm=0.0, gain=0.7, thresholds_nm=[60.0, 150.0], weights=[0.1, 0.05],
                     creep_time_constants_s=_TAUS, creep_gains=[0.03, 0.0, 0.0, 0.0, 0.03]),
        ("c", "a", "w", "y0"), "creep_gains", (20.0, 100.0),
    ),
    # alternating play weights (second differences in the order of the thresholds)
    "weight_smoothing_nm": (
        ScannerModel(offset_nm=0.0, gain=0.6, thresholds_nm=_R5,
                     weights=[0.1, 0.02, 0.1, 0.02, 0.1]),
        ScannerModel(offset_nm=0.0, gain=0.6, thresholds_nm=_R5, weights=np.full(5, 0.06)),
        ("a", "w", "y0"), "weights", (100.0, 1000.0),
    ),
}  # fmt: skip


@pytest.mark.parametrize("name", list(_SMOOTHING_CASES))
def test_smoothing_trades_data_fit_for_smooth_parameters(name):
    """The penalty's weight flattens the second differences of the creep gains (or the play
    weights), at a cost in data fit; weight 0 is the plain least-squares fit, which recovers
    the uneven truth."""
    truth, start, free, attr, mus = _SMOOTHING_CASES[name]
    u = _command(3000)
    y, _ = simulate(truth, u, T)
    kw = {"free": free, "max_nfev": 100}
    plain = refine(start, u, y, T, options=RefineOptions(**kw))
    zero = refine(start, u, y, T, options=RefineOptions(**{name: 0.0}, **kw))
    assert_allclose(getattr(zero.model, attr), getattr(plain.model, attr), rtol=0, atol=0)
    assert_allclose(getattr(plain.model, attr), getattr(truth, attr), atol=1e-6)

    def rough(m: ScannerModel) -> float:
        return float(np.sum(np.diff(getattr(m, attr), 2) ** 2))

    fits = [refine(start, u, y, T, options=RefineOptions(**{name: mu}, **kw)) for mu in mus]
    assert rough(plain.model) > rough(fits[0].model) > rough(fits[1].model)
    assert rough(fits[1].model) < 0.1 * rough(plain.model)
    assert plain.rms < fits[0].rms < fits[1].rms
    assert fits[1].n_residuals == plain.n_residuals  # the data residuals only


def test_single_threaded_blas_is_shared_by_threads_and_lifted_by_its_first_user():
    """The BLAS limit is process-wide: set by the first user (here the main thread, around
    the threads, as ``estimate`` does), shared by refinements on threads and nested uses,
    and lifted when the first user leaves; the same again on a second round."""
    import threading

    from threadpoolctl import threadpool_info

    from piezocomp.identification.estimation.threads import single_threaded_blas

    def blas_threads() -> list[int]:
        return [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]

    before = blas_threads()
    assert before  # numpy's BLAS is loaded
    for _ in range(2):
        inside: list[list[int]] = []

        def worker(out: list[list[int]] = inside) -> None:
            with single_threaded_blas():
                out.append(blas_threads())

        with single_threaded_blas():
            with single_threaded_blas():  # re-entrant
                inside.append(blas_threads())
            threads = [threading.Thread(target=worker) for _ in range(2)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            inside.append(blas_threads())
        assert len(inside) == 4
        assert all(n == 1 for lim in inside for n in lim), (before, inside)
        assert blas_threads() == before
