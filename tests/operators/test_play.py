import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezocomp.operators import creep_bank, creep_poles, play_bank, play_operator
from piezocomp.testing import reference
from strategies import trajectories


@given(trajectories(), st.floats(0.1, 300.0), st.floats(-200.0, 200.0))
def test_play_matches_reference(u, r, z0):
    z, zf = play_operator(u, r, z0)
    np.testing.assert_allclose(z, reference.play(u, r, z0), rtol=0, atol=1e-12)
    assert zf == z[-1]


@given(trajectories(min_size=2), st.floats(0.1, 300.0))
def test_play_output_stays_within_band(u, r):
    z, _ = play_operator(u, r)
    assert np.all(np.abs(u - z) <= r * (1 + 1e-12) + 1e-9)


@given(trajectories(min_size=2), st.floats(0.1, 300.0), st.integers(1, 5))
def test_play_is_rate_independent(u, r, repeat):
    """Repeating every sample (a slower traversal of the same path) changes nothing."""
    z, _ = play_operator(u, r)
    z_slow, _ = play_operator(np.repeat(u, repeat), r)
    np.testing.assert_array_equal(z_slow[repeat - 1 :: repeat], z)


@settings(max_examples=30)
@given(trajectories(min_size=3), st.floats(1.0, 100.0))
def test_play_wiping_out(u, r):
    """After a monotone excursion longer than 2r the initial state is forgotten."""
    sweep = np.concatenate([u, np.linspace(u[-1], u[-1] + 2.5 * r, 20)])
    za, _ = play_operator(sweep, r, state=-500.0)
    zb, _ = play_operator(sweep, r, state=500.0)
    assert za[-1] == pytest.approx(zb[-1], abs=1e-9)


def test_play_bank_chunked_equals_batch():
    rng = np.random.default_rng(3)
    u = np.cumsum(rng.standard_normal(500)) * 10
    r = [5.0, 20.0, 80.0]
    z, _ = play_bank(u, r)
    z1, s = play_bank(u[:137], r)
    z2, _ = play_bank(u[137:], r, s)
    np.testing.assert_array_equal(np.vstack([z1, z2]), z)


def test_creep_bank_step_response_is_first_order():
    T, tau = 0.01, 0.5
    x, _ = creep_bank(np.ones(200), [tau], T)
    k = np.arange(200)
    # x(k) = 1 - p^k (u(-1) = 0, u(k) = 1 for k >= 0), eq (2)
    np.testing.assert_allclose(x[:, 0], 1 - np.exp(-T / tau) ** k, atol=1e-14)


@pytest.mark.parametrize(
    ("thresholds", "match"),
    [
        ([5.0, 5.0], "strictly increasing"),
        ([0.0, 5.0], "> 0"),
        ([-1.0], "> 0"),
        ([1.0, np.nan], "finite"),
    ],
)
def test_bad_thresholds_are_refused(thresholds, match):
    with pytest.raises(ValueError, match=match):
        play_bank([0.0, 1.0], thresholds)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match=r"u_nm .*finite.*index 1"):
        play_bank([0.0, np.inf], [1.0])
    with pytest.raises(ValueError, match="time_constants_s must be > 0"):
        creep_poles([1.0, 0.0], 0.01)
    with pytest.raises(ValueError, match="sample_period_s must be > 0"):
        creep_poles([1.0], -0.01)
