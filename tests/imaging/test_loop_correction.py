"""Section IV on images: a synthetic scan with a known loop, and the mismatch measure."""

import numpy as np
import pytest

from piezocomp.identification.loop.symmetric import SymmetricLoop
from piezocomp.imaging.loop_correction import correct_scan
from piezocomp.imaging.mismatch import line_shifts_nm, mismatch_stats
from piezocomp.io import AfmScan

NX, NY, PX = 400, 48, 5.0  # 2 um lines of 5 nm pixels
U = np.arange(NX) * PX
# A curved loop: 30 nm trace/retrace gap in the middle, narrower towards the ends.
TRUTH = SymmetricLoop([-0.015, 1.0, 0.0015, 0.02, 0.0, -0.02], U[0], U[-1])


def particles(rng, n=25):
    centres = rng.uniform(-100.0, U[-1] + 100.0, n)
    heights = rng.uniform(2.0, 8.0, n)

    def h(y):
        return sum(
            a * np.exp(-0.5 * ((y - c) / 9.0) ** 2) for a, c in zip(heights, centres, strict=True)
        )

    return h


def synthetic_scan(rng, noise_nm=0.05):
    fw = np.empty((NY, NX))
    bw = np.empty((NY, NX))
    y_f, y_b = TRUTH.ascending(U), TRUTH.descending(U)
    for i in range(NY):
        h = particles(rng)
        fw[i] = h(y_f) + 0.002 * U + rng.normal(0, noise_nm, NX)
        bw[i] = h(y_b) + 0.002 * U + rng.normal(0, noise_nm, NX)
    return AfmScan(fw, bw, (NX * PX, NY * 20.0), channel="Height", source="synthetic")


def test_line_shifts_measure_a_known_subpixel_shift():
    rng = np.random.default_rng(0)
    x = np.arange(300) * 4.0
    rows_f, rows_b = [], []
    for _ in range(10):
        h = particles(rng)
        rows_f.append(h(x - 13.3))  # features 13.3 nm further along on the forward trace
        rows_b.append(h(x))
    s = line_shifts_nm(np.array(rows_f), np.array(rows_b), 4.0, max_shift_nm=40.0)
    np.testing.assert_allclose(s, 13.3, atol=0.4)  # parabolic peak: < 0.1 pixel
    st = mismatch_stats(s)
    assert st.median_abs_nm == pytest.approx(13.3, abs=0.4) and st.lines == 10
    flat = line_shifts_nm(np.zeros((2, 50)), np.zeros((2, 50)), 1.0, max_shift_nm=5.0)
    assert np.all(np.isnan(flat))
    with pytest.raises(ValueError, match="no line gave a measurable"):
        mismatch_stats(flat)


def test_recovers_a_known_loop_from_a_synthetic_scan():
    rng = np.random.default_rng(1)
    scan = synthetic_scan(rng)
    res = correct_scan(scan, degree=5)
    assert 25.0 < res.before.median_abs_nm < 35.0
    assert res.after.median_abs_nm < 0.01 * res.before.median_abs_nm  # measured 29.1 -> 0.017
    # What the two traces see is recovered: where the backward trace shows the feature the
    # forward trace shows at u (invariant to the odd axis distortion eq (23) cannot see).
    u = U[20:-20]
    truth = TRUTH.descending_inverse(TRUTH.ascending(u))
    fit = res.loop.descending_inverse(res.loop.ascending(u))
    assert np.max(np.abs(fit - truth)) < 0.05 * PX  # measured 0.04 nm
    # Calibration condition of the fit.
    assert res.loop.ascending(U[-1]) - res.loop.ascending(U[0]) == pytest.approx(U[-1] - U[0])
    assert len(res.pairs) > 500
    summary = res.summary()
    assert summary["mismatch_before_nm"] == res.before.median_abs_nm
    assert summary["mismatch_after_nm"] == res.after.median_abs_nm


def test_a_scan_without_features_or_retrace_is_refused():
    rng = np.random.default_rng(2)
    flat = rng.normal(0, 0.1, (8, 64))
    with pytest.raises(ValueError, match="synthetic: channel 'Height' has no backward"):
        correct_scan(AfmScan(flat, None, (640.0, 80.0), channel="Height", source="synthetic"))
    with pytest.raises(ValueError, match="synthetic: channel 'Height' has no forward image"):
        correct_scan(AfmScan(None, flat, (640.0, 80.0), channel="Height", source="synthetic"))
    with pytest.raises(ValueError, match=r"found \d+ features on both traces|feature pairs"):
        correct_scan(AfmScan(flat, rng.normal(0, 0.1, (8, 64)), (640.0, 80.0), source="noise"))
