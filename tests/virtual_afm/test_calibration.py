"""The calibration record of the virtual scanner: the speed at which a steady full-range
scan is as wide as commanded (the calibration condition of Section IV)."""

import numpy as np
import pytest

from piezocomp.instrument import ScanCalibration
from piezocomp.virtual_afm import VirtualAFM
from piezocomp.virtual_afm.calibration import calibration_speed, steady_span_ratio

T = 0.008


def test_width_falls_with_speed_and_the_record_is_where_it_is_one():
    afm = VirtualAFM.from_preset("cpr5-nodrift", sample_period_s=T)
    params = afm.truth.scanner_params
    ratios = [steady_span_ratio(params, v, T) for v in (100.0, 500.0, 2000.0, 10000.0)]
    assert np.all(np.diff(ratios) < 0)  # a slower cycle creeps further
    speed = calibration_speed(params, T)
    assert ratios[1] > 1.0 > ratios[2]
    assert 500.0 < speed < 2000.0
    assert steady_span_ratio(params, speed, T) == pytest.approx(1.0, abs=2e-3)
    assert afm.calibration_scan is None  # the software is told only what a lab measured
    stated = ScanCalibration(afm.range_nm, 600.0)
    assert VirtualAFM("cpr5", calibration_scan=stated).calibration_scan is stated
    with pytest.raises(TypeError, match="calibration_scan must be a ScanCalibration"):
        VirtualAFM("cpr5", calibration_scan=600.0)


def test_a_scanner_without_creep_is_calibrated_at_any_speed():
    afm = VirtualAFM({"scanner": {"creep": 0.0}}, sample_period_s=T)
    params = afm.truth.scanner_params
    for v in (100.0, 5000.0):
        assert steady_span_ratio(params, v, T) == pytest.approx(1.0, abs=1e-12)
    assert calibration_speed(params, T) is not None


@pytest.mark.parametrize(
    ("span", "speed", "name"),
    [(0.0, 500.0, "span_nm"), (5000.0, np.nan, "speed_nm_per_s"), (5000.0, True, "speed")],
)
def test_scan_calibration_refuses_bad_values(span, speed, name):
    with pytest.raises(ValueError, match=name):
        ScanCalibration(span, speed)


def test_refusals():
    params = VirtualAFM.from_preset("cpr5-nodrift").truth.scanner_params
    with pytest.raises(ValueError, match="speed"):
        steady_span_ratio(params, -1.0, T)
    with pytest.raises(ValueError, match="n_cycles"):
        steady_span_ratio(params, 500.0, T, n_cycles=1)
    with pytest.raises(ValueError, match="0 < lo < hi"):
        calibration_speed(params, T, speed_range_nm_per_s=(500.0, 100.0))
