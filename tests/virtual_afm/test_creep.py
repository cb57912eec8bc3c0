"""Logarithmic creep: the creep key is what a step measures; the response is log-like."""

import numpy as np
from numpy.testing import assert_allclose

from piezocomp.virtual_afm.creep import CreepParams, CreepState, creep_run


def test_step_measures_the_creep_key_and_grows_logarithmically():
    c = CreepParams.logarithmic(0.1, 1e-3, 1800.0, 6)
    T = 0.01
    t = np.arange(20001) * T  # 200 s after the step
    u = np.full(t.size, 1000.0)
    y, _ = creep_run(c, u, T, CreepState.steady(c, 0.0))
    measured = (y[10000] - y[10]) / 1000.0  # 100 s and 0.1 s after the step
    assert_allclose(measured, 0.1, rtol=1e-9)
    assert_allclose(
        y[[10, 100, 1000, 10000]] / 1000.0, c.step_response([0.1, 1, 10, 100]), atol=1e-12
    )
    decades = np.diff(y[[10, 100, 1000, 10000]])
    assert_allclose(decades, decades.mean(), rtol=0.1)  # equal creep per decade
    assert_allclose(c.step_response(c.reference_time_s), 0.0, atol=1e-15)


def test_batch_equals_chunked_stream():
    c = CreepParams.logarithmic(0.05)
    u = np.cumsum(np.random.default_rng(3).normal(0, 5, 500))
    s0 = CreepState.steady(c, 0.0)
    full, _ = creep_run(c, u, 0.008, s0)
    a, s1 = creep_run(c, u[:123], 0.008, s0)
    b, _ = creep_run(c, u[123:], 0.008, s1)
    assert_allclose(np.concatenate([a, b]), full, rtol=1e-13, atol=1e-10)
