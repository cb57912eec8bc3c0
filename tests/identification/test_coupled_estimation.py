"""The batch refinement of the extended family (eq 2', creep driven by ``u + beta H``).

Exact-model tests: the data come from a model of the extended family itself, so they check the
mathematics (the coupled sensitivity recursion, the layout with ``beta``, the bounds), not the
family's fitness for a real scanner (``benchmarks/model_floor.py`` and the identification's
validation on the virtual AFM measure that).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings

from piezocomp.identification.estimation.batch import RefineOptions, refine
from piezocomp.identification.estimation.parameters import (
    ThetaLayout,
    model_from_theta,
    simulate_with_gradient,
    theta_from_model,
)
from piezocomp.model import ModelState, ScannerModel, simulate
from strategies import T, coupled, coupled_models


def _command(n: int = 3000) -> np.ndarray:
    t = np.arange(n) * T
    return 150.0 * np.sin(2 * np.pi * 0.7 * t) * (0.4 + 0.6 * np.abs(np.sin(2 * np.pi * 0.05 * t)))


@settings(max_examples=15, deadline=None)
@given(coupled_models(max_play=5, max_creep=3))
def test_the_coupled_gradient_matches_finite_differences(model: ScannerModel):
    """Every column of ``dy/dtheta`` of eq (2'), ``dy/dbeta`` included, against central
    differences of the forward model (from a state at rest, which the gradient holds fixed)."""
    u = _command(600)
    st = ModelState.at_rest(model, float(u[0]))
    y, jac, _ = simulate_with_gradient(model, u, T, st, coupled=True)
    np.testing.assert_array_equal(y, simulate(model, u, T, st)[0])
    layout = ThetaLayout(model.n_creep, model.n_play, coupled=True)
    theta = theta_from_model(model, T, coupled=True)
    for i, name in enumerate(layout.names()):
        h = 1e-6 * max(1.0, abs(theta[i]))
        if name.startswith("p"):
            h = min(h, 1e-7, 0.5 * (1 - theta[i]), 0.5 * theta[i])
        up, down = theta.copy(), theta.copy()
        up[i] += h
        down[i] -= h
        if name.startswith("r") and (down[i] <= 0 or np.any(np.diff(down[layout.r]) <= 0)):
            continue  # a step that would break the thresholds' order
        if name == "beta" and down[i] < 0:
            down[i] = theta[i]
            h_eff = h
        else:
            h_eff = 2 * h
        fd = (
            simulate(model_from_theta(up, layout, T), u, T, st)[0]
            - simulate(model_from_theta(down, layout, T), u, T, st)[0]
        ) / h_eff
        scale = max(1e-9, float(np.abs(fd).max()))
        assert float(np.abs(jac[:, i] - fd).max()) <= 1e-5 * scale + 1e-9, name


def test_at_beta_zero_the_coupled_gradient_is_the_papers_plus_one_column():
    m = replace(coupled(), creep_coupling=0.0)
    u = _command(500)
    _, paper, _ = simulate_with_gradient(m, u, T)
    _, both, _ = simulate_with_gradient(m, u, T, coupled=True)
    np.testing.assert_array_equal(both[:, :-1], paper)
    assert np.abs(both[:, -1]).max() > 0  # dy/dbeta: the creep of the hysteresis output


def test_refine_recovers_beta_from_the_papers_family():
    """Freeing ``b`` from ``beta = 0`` finds the coupling of data of the extended family,
    with the thresholds and poles held at the truth's (as the identification holds them)."""
    truth = coupled()
    u = _command()
    st = ModelState.at_rest(truth, float(u[0]))
    y, _ = simulate(truth, u, T, st)
    start = replace(truth, creep_coupling=0.0, creep_gains=truth.creep_gains * 1.5,
                    weights=truth.weights * 0.9, gain=0.5)  # fmt: skip
    paper = refine(start, u, y, T, state=st, options=RefineOptions(free=("c", "a", "w", "y0")))
    assert paper.model.creep_coupling == 0.0
    res = refine(start, u, y, T, state=st,
                 options=RefineOptions(free=("c", "a", "w", "y0", "b")))  # fmt: skip
    assert res.rms < 1e-3 * paper.rms  # the paper's family cannot follow it
    assert res.model.creep_coupling == pytest.approx(truth.creep_coupling, rel=1e-5)
    np.testing.assert_allclose(res.model.creep_gains, truth.creep_gains, rtol=1e-5)


def test_beta_of_the_papers_family_is_exactly_zero_and_an_unknown_group_is_refused():
    """On data of the paper's family a free beta ends on its bound: exactly 0, so that the
    model is the paper's (not one a hair into the extended family)."""
    u = _command(800)
    m = replace(coupled(), creep_coupling=0.0)
    y, _ = simulate(m, u, T)
    res = refine(replace(m, creep_gains=m.creep_gains * 1.2), u, y, T,
                 options=RefineOptions(free=("c", "b"), max_nfev=30))  # fmt: skip
    assert res.model.creep_coupling == 0.0
    with pytest.raises(ValueError, match=r"free must name groups among .*'b'.*Got unknown \['q'\]"):
        RefineOptions(free=("c", "q"))


def test_beta_is_found_when_the_creep_rests_away_from_zero():
    """A record whose creep starts settled on a held command u_rest != 0: its creep states,
    (1 + beta (a + sum w)) u_rest, move with beta. Held fixed at the start's they would pin
    beta near it; followed (``creep_rest_nm``) beta is found."""
    truth = coupled()
    u = 300.0 + _command()
    rest = 300.0
    st = ModelState(np.full(truth.n_play, u[0]), ModelState.at_rest(truth, rest).creep_nm, u[0])
    y, _ = simulate(truth, u, T, st)
    start = replace(truth, creep_coupling=0.0)
    st0 = ModelState(np.full(truth.n_play, u[0]), ModelState.at_rest(start, rest).creep_nm, u[0])
    free = RefineOptions(free=("c", "a", "w", "y0", "b"))
    pinned = refine(start, u, y, T, state=st0, options=free)
    followed = refine(start, u, y, T, state=st0, creep_rest_nm=rest, options=free)
    assert pinned.model.creep_coupling < 0.1  # the defect a held state would leave
    assert followed.model.creep_coupling == pytest.approx(truth.creep_coupling, rel=1e-5)
    assert followed.rms < 1e-6


def test_a_coupled_model_with_beta_held_keeps_it():
    m = coupled()
    u = _command(800)
    y, _ = simulate(m, u, T)
    res = refine(replace(m, creep_gains=m.creep_gains * 1.3), u, y, T,
                 options=RefineOptions(free=("c",)))  # fmt: skip
    assert res.model.creep_coupling == m.creep_coupling
    np.testing.assert_allclose(res.model.creep_gains, m.creep_gains, rtol=1e-6)


def test_holding_the_thresholds_skips_their_columns_and_changes_no_other():
    m = coupled()
    u = _command(700)
    st = ModelState.at_rest(m, float(u[0]))
    y, full, _ = simulate_with_gradient(m, u, T, st, coupled=True)
    y2, held, _ = simulate_with_gradient(m, u, T, st, coupled=True, thresholds=False)
    r = ThetaLayout(m.n_creep, m.n_play, coupled=True).r
    keep = np.ones(full.shape[1], bool)
    keep[r] = False
    np.testing.assert_array_equal(y2, y)
    np.testing.assert_array_equal(held[:, keep], full[:, keep])
    assert np.isnan(held[:, r]).all()


def test_a_records_creep_rests_on_the_drive_of_its_held_command():
    """``record_state`` with a creep start: the play operators at the first command, the
    creep settled on the drive ``(1 + beta (a + sum w)) u_rest`` of the command held before
    (``creep_rest`` names that command)."""
    from piezocomp.identification.estimation.prediction import creep_rest, record_state

    m = coupled()
    st = record_state(m, -150.0, 300.0)
    np.testing.assert_array_equal(st.play_nm, np.full(m.n_play, -150.0))
    drive = (1 + m.creep_coupling * (m.gain + m.weights.sum())) * 300.0
    np.testing.assert_allclose(st.creep_nm, np.full(m.n_creep, drive), rtol=1e-15)
    assert creep_rest(-150.0, 300.0) == 300.0 and creep_rest(-150.0) == -150.0
