"""Sub-sample peaks and forward/backward pairing (Section IV)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from piezocomp.identification.acquisition.peaks import Peaks, find_peaks, pair_peaks


def gaussians(x, centres, heights, width):
    z = np.zeros_like(x)
    for c, h in zip(centres, heights, strict=True):
        z += h * np.exp(-0.5 * ((x - c) / width) ** 2)
    return z


CENTRES = np.array([103.37, 251.9, 402.05, 688.6, 870.21])
HEIGHTS = np.array([5.0, 8.0, 3.0, 6.0, 4.0])


def test_subsample_positions_of_symmetric_peaks():
    x = np.arange(0.0, 1000.0, 7.5)  # 7.5 nm pixels; centres fall between samples
    z = gaussians(x, CENTRES, HEIGHTS, width=12.0)
    p = find_peaks(x, z, min_prominence_nm=1.0)
    assert len(p) == CENTRES.size
    # Linear interpolation of the half-height crossings: < 0.01 pixel.
    np.testing.assert_allclose(p.position_nm, CENTRES, atol=0.05)
    assert np.all(p.prominence_nm > 0.9 * HEIGHTS)
    assert np.all(p.height_nm <= HEIGHTS + 1e-12)


def test_decreasing_and_nonuniform_axes_give_the_same_positions():
    x = np.arange(0.0, 1000.0, 5.0)
    z = gaussians(x, CENTRES, HEIGHTS, width=12.0)
    up = find_peaks(x, z, min_prominence_nm=1.0)
    down = find_peaks(x[::-1], z[::-1], min_prominence_nm=1.0)
    np.testing.assert_allclose(down.position_nm, up.position_nm, atol=1e-9)
    assert np.all(np.diff(down.position_nm) > 0)  # always sorted increasing
    # A smoothly stretched axis: positions follow the axis (linear between samples).
    s = x + 2e-5 * x**2
    zs = gaussians(s, CENTRES, HEIGHTS, width=12.0)
    pw = find_peaks(s, zs, min_prominence_nm=1.0)
    np.testing.assert_allclose(pw.position_nm, CENTRES, atol=0.05)


def test_prominence_and_separation_filter():
    rng = np.random.default_rng(1)
    x = np.arange(0.0, 1000.0, 2.0)
    z = gaussians(x, CENTRES, HEIGHTS, width=10.0) + rng.normal(0.0, 0.05, x.size)
    p = find_peaks(x, z, min_prominence_nm=1.0)
    np.testing.assert_allclose(p.position_nm, CENTRES, atol=0.5)
    assert len(find_peaks(x, z, min_prominence_nm=20.0)) == 0
    # Two peaks 30 nm apart: a 50 nm separation keeps only the higher one.
    z2 = gaussians(x, [400.0, 430.0], [5.0, 7.0], width=5.0)
    assert len(find_peaks(x, z2, min_prominence_nm=1.0)) == 2
    one = find_peaks(x, z2, min_prominence_nm=1.0, min_separation_nm=50.0)
    assert len(one) == 1
    assert abs(one.position_nm[0] - 430.0) < 0.5


def test_find_peaks_refuses_bad_input():
    x = np.arange(10.0)
    with pytest.raises(ValueError, match="min_prominence_nm must be > 0"):
        find_peaks(x, x, min_prominence_nm=0.0)
    with pytest.raises(ValueError, match="strictly monotone"):
        find_peaks(np.r_[0.0, 2.0, 1.0, 3.0], np.zeros(4), min_prominence_nm=1.0)
    with pytest.raises(ValueError, match="same length"):
        find_peaks(x, x[:-1], min_prominence_nm=1.0)
    with pytest.raises(ValueError, match="finite"):
        find_peaks(x, np.r_[x[:-1], np.nan], min_prominence_nm=1.0)
    assert len(find_peaks(x[:2], x[:2], min_prominence_nm=1.0)) == 0


def test_peaks_is_frozen_and_checked():
    p = Peaks(np.array([1.0, 2.0]), np.array([3.0, 4.0]), np.array([1.0, 1.0]))
    with pytest.raises(ValueError):
        p.position_nm[0] = 5.0
    with pytest.raises(ValueError, match="same length"):
        Peaks(np.array([1.0]), np.array([1.0, 2.0]), np.array([1.0]))
    with pytest.raises(ValueError, match="sorted"):
        Peaks(np.array([2.0, 1.0]), np.ones(2), np.ones(2))


def test_pairing_with_missing_and_extra_peaks():
    fwd = np.array([100.0, 180.0, 300.0, 420.0, 555.0, 700.0])
    shift = 20.0 + 0.01 * fwd  # smooth, monotone loop width
    bwd_true = fwd - shift
    # Drop the 3rd backward peak, add two spurious ones far from any shifted forward peak.
    bwd = np.sort(np.r_[np.delete(bwd_true, 2), 10.0, 470.0])
    i_f, i_b = pair_peaks(fwd, bwd, max_shift_nm=60.0, tolerance_nm=10.0)
    assert list(i_f) == [0, 1, 3, 4, 5]
    np.testing.assert_allclose(bwd[i_b], bwd_true[i_f])
    # Nothing pairs when the shift exceeds max_shift_nm.
    i_f, _ = pair_peaks(fwd, fwd - 1000.0, max_shift_nm=60.0)
    assert i_f.size == 0


def test_pairing_rejects_ambiguous_candidates():
    fwd = np.array([100.0, 300.0, 500.0])
    bwd = np.array([80.0, 280.0, 283.0, 480.0])  # two candidates for the forward peak at 300
    i_f, i_b = pair_peaks(fwd, bwd, max_shift_nm=50.0, tolerance_nm=8.0)
    assert list(i_f) == [0, 2]
    assert list(i_b) == [0, 3]


def test_pairing_refuses_bad_input():
    with pytest.raises(ValueError, match="max_shift_nm must be > 0"):
        pair_peaks([1.0], [1.0], max_shift_nm=0.0)
    with pytest.raises(ValueError, match="tolerance_nm must be > 0"):
        pair_peaks([1.0], [1.0], max_shift_nm=1.0, tolerance_nm=-1.0)
    i_f, i_b = pair_peaks([], [1.0], max_shift_nm=1.0)
    assert i_f.size == 0 and i_b.size == 0


@given(
    n=st.integers(2, 30),
    offset=st.floats(-40.0, 40.0),
    seed=st.integers(0, 2**31 - 1),
)
def test_pairing_recovers_a_shifted_copy(n, offset, seed):
    rng = np.random.default_rng(seed)
    # Features at least 30 nm apart; shift varies by at most +-2 nm.
    fwd = np.cumsum(rng.uniform(30.0, 100.0, n))
    bwd = fwd - offset - 2.0 * np.sin(fwd / 300.0)
    i_f, i_b = pair_peaks(fwd, bwd, max_shift_nm=50.0, tolerance_nm=6.0)
    np.testing.assert_array_equal(i_f, np.arange(n))
    np.testing.assert_array_equal(i_b, np.arange(n))
