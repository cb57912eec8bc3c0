"""Waveforms of Fig. 7a (parts A and B) and validation trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from piezocomp.identification.acquisition.waveforms import (
    identification_waveform,
    ramps,
    validation_waveform,
)

T = 0.008


def _turns(u: np.ndarray) -> np.ndarray:
    """Values of ``u`` at its reversals."""
    d = np.diff(u)
    d = d[d != 0]
    s = np.sign(d)
    idx = np.flatnonzero(s[1:] != s[:-1])
    moving = u[np.r_[True, np.diff(u) != 0]]
    return moving[idx + 1]


def test_ramps_respect_speed_and_end_on_turning_points():
    u = ramps([0.0, 100.0, -50.0], 250.0, T, dwells_s=[0.0, 0.08, 0.0])
    assert u[0] == 0.0 and u[-1] == -50.0
    assert np.abs(np.diff(u)).max() <= 250.0 * T * (1 + 1e-12)
    assert np.count_nonzero(u == 100.0) == 1 + 10  # arrival + 0.08 s of dwell
    with pytest.raises(ValueError, match="speed_nm_per_s"):
        ramps([0, 1], 0.0, T)


def test_ramps_take_one_speed_per_turning_point():
    u = ramps([0.0, 100.0, 0.0], [0.0, 100.0, 400.0], T)
    up, down = np.diff(u[: np.argmax(u) + 1]), np.diff(u[np.argmax(u) :])
    assert up.max() <= 100.0 * T * (1 + 1e-12) and up.size == 125  # 100 nm at 0.8 nm/sample
    assert -down.max() <= 400.0 * T * (1 + 1e-12) and down.size == 32
    with pytest.raises(ValueError, match=r"speed_nm_per_s\[2\] = -1"):
        ramps([0.0, 1.0, 0.0], [1.0, 1.0, -1.0], T)
    with pytest.raises(ValueError, match="one per turning point"):
        ramps([0.0, 1.0, 0.0], [1.0, 1.0], T)


def test_part_b_runs_at_the_speed_factors_in_turn():
    """Part A and the closing sweep keep the speed; part B's ramps cycle through the factors,
    capped at the instrument's limit; the turning points and dwells stay those of one speed."""
    one = identification_waveform(0.0, 1000.0, 250.0, T, rng=3)
    wf = identification_waveform(
        0.0, 1000.0, 250.0, T, rng=3, speed_factors=(0.5, 1.0, 4.0), max_speed_nm_per_s=600.0
    )
    np.testing.assert_array_equal(wf.u_nm[wf.part_a], one.u_nm[one.part_a])
    np.testing.assert_array_equal(_turns(wf.u_nm), _turns(one.u_nm))
    step = np.abs(np.diff(wf.u_nm[wf.part_b]))
    moving = step[step > 0] / T
    assert moving.max() <= 600.0 * (1 + 1e-12)  # 4 x 250 capped at 600
    assert np.any(moving > 500.0) and np.any(moving < 130.0)  # both ends used
    assert np.count_nonzero(moving < 130.0) > 0.2 * moving.size
    end = wf.u_nm[-2 * wf.half_cycle_samples :]  # the closing sweep at the nominal speed
    np.testing.assert_array_equal(end, one.u_nm[-2 * one.half_cycle_samples :])
    for bad in ((), (1.0, 0.0), (np.inf,)):
        with pytest.raises(ValueError, match="speed_factors"):
            identification_waveform(0.0, 1000.0, 250.0, T, speed_factors=bad)


def test_part_a_is_steady_full_cycles():
    wf = identification_waveform(10.0, 800.0, 200.0, T, n_steady=3, rng=0)
    assert wf.u_min_nm == -390.0 and wf.u_max_nm == 410.0
    for c in range(wf.n_steady):
        up = wf.u_nm[wf.ascending(c)]
        down = wf.u_nm[wf.descending(c)]
        assert up[0] == wf.u_min_nm and up[-1] == wf.u_max_nm and np.all(np.diff(up) > 0)
        assert down[0] == wf.u_max_nm and down[-1] == wf.u_min_nm and np.all(np.diff(down) < 0)
        np.testing.assert_array_equal(up, wf.u_nm[wf.ascending(0)])  # identical cycles
    assert wf.part_b.start == wf.part_a.stop


def test_part_b_excites_every_reversal_size():
    """Part B: reversals from the full span down to a few per cent of it, inside the span."""
    wf = identification_waveform(0.0, 1000.0, 250.0, T, rng=4)
    b = wf.u_nm[wf.part_b]
    assert b.min() >= -500.0 and b.max() <= 500.0
    assert np.abs(np.diff(wf.u_nm)).max() <= 250.0 * T * (1 + 1e-12)
    sizes = np.abs(np.diff(_turns(b)))
    # every play operator r in (0, span/2) sees reversals larger and smaller than 2 r
    for r in np.linspace(30.0, 480.0, 10):
        assert np.any(sizes > 2 * r) and np.any(sizes < 2 * r)
    assert np.any(np.diff(b) == 0)  # dwells, for creep


def test_validation_waveform_has_minor_loops_and_depends_on_rng():
    v1 = validation_waveform(0.0, 1000.0, 250.0, T, rng=1)
    v2 = validation_waveform(0.0, 1000.0, 250.0, T, rng=2)
    assert not np.array_equal(v1, v2)
    np.testing.assert_array_equal(v1, validation_waveform(0.0, 1000.0, 250.0, T, rng=1))
    assert v1.min() == -500.0 and v1.max() == 500.0
    sizes = np.abs(np.diff(_turns(v1)))
    assert sizes.min() < 100.0 and sizes.max() > 500.0  # nested minor loops and major ones
