"""Preisach operator: closed-form Everett function, wiping-out, calibration of the keys."""

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.integrate import dblquad

from piezocomp.virtual_afm import _kernels as K
from piezocomp.virtual_afm.preisach import (
    PreisachParams,
    PreisachState,
    everett,
    loop_hysteresis,
    preisach_run,
)

P = PreisachParams.from_targets(0.12, 0.03, 0.1, asymmetry=0.05, saturation=0.3)


def _triangle(amp, n=1500):
    """Start at 0, go to +amp, then one full cycle +amp -> -amp -> +amp."""
    up = np.linspace(0, amp, n)
    down = np.linspace(amp, -amp, 2 * n)
    return np.concatenate([up, down, down[::-1], down])


def test_everett_closed_form_matches_the_density_integral():
    p, s, q = P.p, P.s, P.q

    def density(beta, alpha):
        r, c = (alpha - beta) / 2, (alpha + beta) / 2
        return r**p * (1 + s * c + q * c * c)

    total = dblquad(density, -1, 1, lambda a: -1, lambda a: a)[0]
    for alpha, beta in [(0.5, -0.2), (0.9, 0.3), (-0.1, -0.8)]:
        lower = float(beta)
        num = dblquad(density, beta, alpha, lambda a, lo=lower: lo, lambda a: a)[0] / total
        assert_allclose(everett(alpha, beta, p, s, q), num, rtol=1e-6)
        assert_allclose(K.everett(alpha, beta, p, s, q, P.norm), num, rtol=1e-6)
    assert_allclose(everett(1.0, -1.0, p, s, q), 1.0, rtol=1e-14)


@pytest.mark.parametrize(("amp", "target"), [(1.0, 0.12), (0.05, 0.03)])
def test_measured_cycle_hysteresis_equals_the_keys(amp, target):
    x = _triangle(amp)
    v, _ = preisach_run(P, x, PreisachState.demagnetised(P))
    n = 1500
    cycle = slice(n - 1, 5 * n - 1)  # +amp -> -amp -> +amp (steady after the first reversal)
    assert_allclose(loop_hysteresis(x[cycle], v[cycle]), target, rtol=0.01)
    assert_allclose(P.cycle_hysteresis(amp), target, rtol=1e-9)


def test_small_excursions_show_far_less_hysteresis_than_full_range():
    ratios = [P.cycle_hysteresis(a) for a in (0.02, 0.1, 0.3, 1.0)]
    assert np.all(np.diff(ratios) > 0)
    assert ratios[0] < 0.25 * ratios[-1]


def test_output_is_continuous_far_below_a_nanometre():
    x = np.linspace(-1, 1, 200001)  # 0.025 nm steps on a 5 um scanner
    v, _ = preisach_run(P, x, PreisachState.negative_saturation())
    steps_nm = np.abs(np.diff(v)) * 2500
    assert steps_nm.max() < 0.025 * 1.5  # slope of at most ~1.5 nm/nm, no staircase


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-0.95, 0.95), min_size=1, max_size=30))
def test_wiping_out_an_excursion_beyond_every_extremum_erases_the_history(hist):
    tail = np.linspace(1.0, -0.3, 50)
    a, _ = preisach_run(P, np.concatenate([hist, tail]), PreisachState.demagnetised(P))
    b, _ = preisach_run(P, tail, PreisachState.negative_saturation())
    assert_allclose(a[len(hist) :], b, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=3, max_size=40), st.integers(1, 39))
def test_batch_equals_chunked_stream_and_return_point_memory(xs, cut):
    x = np.asarray(xs)
    s0 = PreisachState.demagnetised(P, 0.1)
    full, end = preisach_run(P, x, s0)
    cut = min(cut, x.size - 1)
    a, mid = preisach_run(P, x[:cut], s0)
    b, end2 = preisach_run(P, x[cut:], mid)
    assert_allclose(np.concatenate([a, b]), full, atol=1e-13)
    assert_allclose(end.stack, end2.stack)
    # return-point memory: rise from x[-1] to M, go down to m >= x[-1] (inside the
    # preceding reversals), come back to M: same output as at the first visit of M
    M = 0.5 * (x[-1] + 1)
    m = x[-1] + 0.3 * (M - x[-1])
    v, _ = preisach_run(P, [*np.linspace(x[-1], M, 5), m, 0.5 * (m + M), M], end)
    assert_allclose(v[-1], v[4], atol=1e-13)


def test_rate_independence_inserting_monotone_points_changes_nothing():
    ext = np.array([0.0, 0.7, -0.4, 0.5, -0.2, 0.3])
    fine = np.concatenate([*(np.linspace(a, b, 37)[:-1] for a, b in pairwise(ext)), ext[-1:]])
    v1, _ = preisach_run(P, ext, PreisachState.negative_saturation())
    v2, _ = preisach_run(P, fine, PreisachState.negative_saturation())
    assert_allclose(v2[::36], v1, atol=1e-13)


def test_impossible_targets_are_refused_with_the_keys_named():
    with pytest.raises(ValueError, match="hysteresis_small"):
        PreisachParams.from_targets(0.1, 0.2)
    with pytest.raises(ValueError, match="b must be"):
        PreisachParams(p=0.0, b=1.0)
