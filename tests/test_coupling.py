"""The creep coupling of eq (2'): creep driven by ``s(k-1) = u(k-1) + beta H(k-1)``.

These tests run models of the extended family on trajectories they generate themselves:
they check the mathematics (forward, inverse, state, streaming), not an identification.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given

from golden_cases import cases, outputs
from piezocomp.inverse import compensate
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.testing import reference
from strategies import T, coupled_models, trajectories

GOLDEN = Path(__file__).parent / "data" / "paper_model_golden.npz"


def _rel_err(y, yd):
    return np.max(np.abs(y - yd)) / max(1.0, np.max(np.abs(yd)))


def test_coupling_is_validated():
    for bad in (-0.1, np.nan, np.inf):
        with pytest.raises(ValueError, match="creep_coupling"):
            ScannerModel(creep_coupling=bad)
    assert ScannerModel().creep_coupling == 0.0
    assert ScannerModel(creep_coupling=-0.0).creep_coupling == 0.0


def test_beta_zero_is_the_paper_model_before_the_change():
    """Forward and inverse outputs stored by the code before the coupling (commit 590d1dc).
    They were bit for bit the same with the libraries of then; another numba or numpy may
    compile the same kernels to other roundings (1e-12 relative with numba 0.68), so the
    stored outputs hold to 1e-10 relative, far below any change of the model's meaning."""
    stored = np.load(GOLDEN)
    now = outputs()
    assert set(now) == set(stored.files)
    for key in stored.files:
        np.testing.assert_allclose(now[key], stored[key], rtol=1e-10, atol=1e-9, err_msg=key)


@given(coupled_models(), trajectories(), trajectories(max_size=100))
def test_coupled_forward_matches_reference(model, u, history):
    _, st = simulate(model, history, T)
    y, _ = simulate(model, u, T, st)
    ref = reference.forward(
        u, model.offset_nm, model.gain, model.thresholds_nm, model.weights,
        model.creep_time_constants_s, model.creep_gains, T, z0=st.play_nm, x0=st.creep_nm,
        u_prev=st.u_prev_nm, beta=model.creep_coupling,
    )  # fmt: skip
    np.testing.assert_allclose(y, ref, rtol=1e-11, atol=1e-8)


def test_coupling_changes_the_creep_and_nothing_else():
    """A step: the coupled creep settles on s = u + beta H instead of u (eq 2')."""
    m0 = ScannerModel(gain=0.8, thresholds_nm=[5.0], weights=[0.2],
                      creep_time_constants_s=[0.05], creep_gains=[0.1])  # fmt: skip
    m1 = replace(m0, creep_coupling=0.5)
    u = np.full(2000, 100.0)
    y0, _ = simulate(m0, u, T)
    y1, _ = simulate(m1, u, T)
    assert y0[0] == y1[0]  # the creep starts from rest at zero: the first sample agrees
    h = 0.8 * 100 + 0.2 * 95.0
    assert y0[-1] == pytest.approx(h + 0.1 * 100.0, rel=1e-9)
    assert y1[-1] == pytest.approx(h + 0.1 * (100.0 + 0.5 * h), rel=1e-9)
    assert m1.static_gain == pytest.approx(0.8 + 0.1 * (1 + 0.5 * 0.8))


@given(coupled_models(), trajectories(max_size=300))
def test_state_needs_nothing_new(model, u):
    """At rest is a fixed point of the coupled model, and a state continues the stream."""
    rest = ModelState.at_rest(model, 37.0)
    y, end = simulate(model, np.full(5, 37.0), T, rest)
    np.testing.assert_allclose(end.creep_nm, rest.creep_nm, rtol=1e-12, atol=1e-9)
    assert np.ptp(y) <= 1e-9 * max(1.0, abs(y[0]))


@given(coupled_models(), trajectories(), trajectories(max_size=200))
def test_coupled_forward_of_inverse_is_identity(model, yd, history):
    """forward(inverse(y_d)) == y_d to rounding from a shared non-zero state (eq 13')."""
    _, shared = simulate(model, history, T)
    result = compensate(model, yd, T, shared)
    y, end = simulate(model, result.command_nm, T, shared)
    assert _rel_err(y, yd) <= 1e-9
    np.testing.assert_allclose(end.play_nm, result.state.play_nm, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(end.creep_nm, result.state.creep_nm, rtol=1e-9, atol=1e-9)


@given(coupled_models(), trajectories(max_size=300))
def test_coupled_inverse_matches_reference(model, yd):
    u = compensate(model, yd, T).command_nm
    ref = reference.inverse(
        yd, model.offset_nm, model.gain, model.thresholds_nm, model.weights,
        model.creep_time_constants_s, model.creep_gains, T, beta=model.creep_coupling,
    )  # fmt: skip
    np.testing.assert_allclose(u, ref, rtol=1e-10, atol=1e-8)


def test_golden_cases_cover_creep_and_play():
    assert any(m.n_creep and m.n_play for m, _, _ in cases())
