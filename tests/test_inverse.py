import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from piezocomp.inverse import (
    Compensator,
    InversePI,
    compensate,
    inverse_play_state,
    plant_play_state,
)
from piezocomp.limits import CommandLimits
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.testing import reference
from strategies import T, coupled_models, models, trajectories


def _rel_err(y, yd):
    return np.max(np.abs(y - yd)) / max(1.0, np.max(np.abs(yd)))


@given(models(), trajectories())
def test_inverse_matches_reference(model, yd):
    u = compensate(model, yd, T).command_nm
    ref = reference.inverse(
        yd,
        model.offset_nm,
        model.gain,
        model.thresholds_nm,
        model.weights,
        model.creep_time_constants_s,
        model.creep_gains,
        T,
    )
    np.testing.assert_allclose(u, ref, rtol=1e-10, atol=1e-9)


def test_inverse_parameters_are_eq10():
    m = ScannerModel(gain=0.6, thresholds_nm=[10.0, 25.0, 60.0], weights=[0.05, 0.1, 0.2])
    inv = InversePI.from_model(m)
    a_hat, r_hat, w_hat = reference.inverse_parameters(0.6, [10.0, 25.0, 60.0], [0.05, 0.1, 0.2])
    assert inv.gain == pytest.approx(a_hat)
    np.testing.assert_allclose(inv.thresholds_nm, r_hat)
    np.testing.assert_allclose(inv.weights, w_hat)
    assert np.all(inv.weights < 0)


@given(models(), trajectories(), trajectories(max_size=200))
def test_forward_of_inverse_is_identity(model, yd, history):
    """forward(inverse(y_d)) == y_d to rounding, from a non-zero state shared by both sides."""
    u_hist = history
    _, shared = simulate(model, u_hist, T)
    result = compensate(model, yd, T, shared)
    y, end = simulate(model, result.command_nm, T, shared)
    assert _rel_err(y, yd) <= 1e-9
    np.testing.assert_allclose(end.play_nm, result.state.play_nm, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(end.creep_nm, result.state.creep_nm, rtol=1e-9, atol=1e-9)


@given(models(), trajectories(max_size=300))
def test_play_state_map_round_trips(model, history):
    _, state = simulate(model, history, T)
    zh = inverse_play_state(model, state.play_nm)
    np.testing.assert_allclose(plant_play_state(model, zh), state.play_nm, rtol=1e-12, atol=1e-9)


@given(st.one_of(models(), coupled_models()), trajectories(min_size=3), trajectories(max_size=50))
def test_compensator_stream_equals_batch(model, yd, history):
    """Per sample == batch, chunks == batch to rounding; the paper's models and those with a
    creep coupling (eq 13')."""
    _, shared = simulate(model, history, T)
    batch = compensate(model, yd, T, shared).command_nm
    comp = Compensator(model, T, shared)
    per_sample = np.array([comp.step(v) for v in yd])
    np.testing.assert_array_equal(per_sample, batch)
    comp.reset(shared)
    cut = len(yd) // 2
    chunked = np.concatenate([comp.run(yd[:cut]), comp.run(yd[cut:])])
    np.testing.assert_allclose(chunked, batch, rtol=1e-12, atol=1e-9)


def test_plant_state_mismatch_error_is_bounded_and_wiped_out():
    """A plant whose history the compensator does not know: the error is at most the
    memory difference of the play operators, and a large excursion wipes it out."""
    m = ScannerModel(
        gain=0.6,
        thresholds_nm=[20.0, 60.0, 150.0],
        weights=[0.05, 0.08, 0.1],
        creep_time_constants_s=[0.05],
        creep_gains=[0.03],
    )
    _, plant_state = simulate(m, [400.0, -300.0, 100.0], T)  # unknown history
    t = np.arange(4000) * T
    yd = 60 * np.sin(2 * np.pi * t / 2)  # small loops first ...
    yd[2000:] = 500 * np.sin(2 * np.pi * t[2000:] / 4)  # ... then large cycles
    u = compensate(m, yd, T).command_nm  # compensator believes: zero state
    y, _ = simulate(m, u, T, plant_state)
    err = np.abs(y - yd)
    memory_bound = float(np.sum(m.weights * 2 * m.thresholds_nm)) + 0.03 * 500
    assert err[:2000].max() > 1.0  # the mismatch shows on small loops
    assert err.max() <= memory_bound
    assert err[-500:].max() < 1e-6  # wiped out by the large cycles (creep decayed too)


def test_limits_refuse_before_sending_and_clip_reports():
    m = ScannerModel(gain=0.5)
    limits = CommandLimits(-100.0, 100.0, max_slew_nm_per_s=1e6)
    yd = np.array([0.0, 20.0, 60.0, 20.0])  # needs u = 120 at sample 2
    comp = Compensator(m, T, limits=limits)
    with pytest.raises(ValueError, match=r"command\[2\] = 120 nm is outside the scanner range"):
        comp.run(yd)
    assert comp.state == ModelState.zeros(m)  # nothing happened
    comp = Compensator(m, T, limits=limits, clip=True)
    u = comp.run(yd)
    np.testing.assert_allclose(u, [0.0, 40.0, 100.0, 40.0])
    assert comp.clipped_samples == [(2, 120.0, 100.0)]


def test_slew_limit():
    m = ScannerModel(gain=1.0)
    limits = CommandLimits(-1e4, 1e4, max_slew_nm_per_s=1000.0)  # 8 nm per 8 ms sample
    with pytest.raises(ValueError, match="above the slew limit"):
        compensate(m, [0.0, 20.0], T, limits=limits)
    res = compensate(m, [0.0, 20.0, 20.0, 20.0], T, limits=limits, clip=True)
    np.testing.assert_allclose(res.command_nm, [0.0, 8.0, 16.0, 20.0])
    assert res.report.slew_clipped.tolist() == [1, 2]
    assert res.state.u_prev_nm == 20.0


def test_compensator_refuses_nan():
    comp = Compensator(ScannerModel(), T)
    with pytest.raises(ValueError, match="finite"):
        comp.step(float("nan"))
    with pytest.raises(ValueError, match="finite"):
        comp.run([0.0, np.inf])
