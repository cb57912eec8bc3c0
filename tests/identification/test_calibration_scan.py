"""The calibration record measured on a grating through the instrument interface (checked
against the virtual scanner's true extension, which the measurement never reads)."""

import numpy as np
import pytest

from piezocomp.experiments.virtual_identification import calibrated, calibration_record
from piezocomp.identification.acquisition.line_search import axis_command
from piezocomp.identification.acquisition.waveforms import identification_waveform
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.reference.calibration_scan import (
    measure_calibration_scan,
    width_ratio,
)
from piezocomp.identification.reference.grating import GratingRecord
from piezocomp.instrument import ScanCalibration
from piezocomp.virtual_afm import Grating, VirtualAFM, load_config
from piezocomp.virtual_afm.calibration import calibration_speed

PITCH = 278.0


@pytest.mark.parametrize("speed", [300.0, 600.0, 1500.0])
def test_the_width_read_from_the_grating_is_the_true_one(speed):
    afm = VirtualAFM(load_config("cpr5").with_seed(4), grating=Grating(PITCH, axis="y"))
    wf = identification_waveform(0.0, afm.range_nm, speed, 0.008, n_steady=3, n_decaying=0,
                                 n_random=0)  # fmt: skip
    afm.move_to(0.0, wf.u_nm[0], speed)
    rec = afm.run(axis_command("y", wf.u_nm, 0.0))
    y = afm.truth.positions_at(rec.t_s)[:, 1]  # for scoring only
    passes = tuple((int(p.start), int(p.stop)) for c in (1, 2)
                   for p in (wf.ascending(c), wf.descending(c)))  # fmt: skip
    true = np.median([(y[b - 1] - y[a]) / (wf.u_nm[b - 1] - wf.u_nm[a]) for a, b in passes])
    record = GratingRecord("y", PITCH, wf.u_nm, rec.height_nm, 0.008, passes)
    assert width_ratio(record) == pytest.approx(true, abs=2e-3)
    if speed != 600.0:  # about the calibration speed: elsewhere the width differs
        assert abs(true - 1.0) > 5e-3  # a width that ignored the speed would fail


def test_the_record_is_measured_where_the_scan_is_as_wide_as_commanded():
    afm = VirtualAFM(load_config("cpr5").with_seed(2))
    found = measure_calibration_scan(
        VirtualAFM(afm.config, grating=Grating(PITCH, axis="x")), PITCH
    )
    assert isinstance(found.scan, ScanCalibration) and found.scan.span_nm == afm.range_nm
    exact = calibration_speed(afm.truth.scanner_params, afm.sample_period_s)  # physics
    assert 0.85 < found.scan.speed_nm_per_s / exact < 1.05  # its cycles are not the physics'
    v, r = np.array(found.width_ratios).T
    top = PITCH / (10 * afm.sample_period_s)  # the fastest scan that samples a pitch 10 times
    assert v.min() == 100.0 and v.max() == top
    assert r[v.argmin()] > 1 > r[v.argmax()] and len(set(v)) == v.size
    assert found.instrument_s > 600.0
    # the virtual lab's record: another day's grating, the same scanner, nearly the same speed
    lab = calibration_record(afm)
    assert lab.span_nm == afm.range_nm and lab.speed_nm_per_s != found.scan.speed_nm_per_s
    assert lab.speed_nm_per_s == pytest.approx(found.scan.speed_nm_per_s, rel=0.03)
    cfg = calibrated(afm, IdentifyConfig())
    assert cfg.acquisition.calibration_speed_nm_per_s == lab.speed_nm_per_s
    given = IdentifyConfig().updated(calibration_speed_nm_per_s=700.0)
    assert calibrated(afm, given) is given


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"speeds_nm_per_s": (500.0, 100.0)}, "0 < low < high"), ({"rtol": 0.0}, "rtol")],
)
def test_bad_settings_are_refused_before_anything_moves(kwargs, match):
    afm = VirtualAFM("cpr5", grating=Grating(PITCH))
    with pytest.raises(ValueError, match=match):
        measure_calibration_scan(afm, PITCH, **kwargs)
    assert afm.command_nm == (0.0, 0.0)


def test_a_scanner_with_little_creep_gets_a_record_too():
    afm = VirtualAFM("gentle", seed=1)
    lab = calibration_record(afm)
    assert lab is not None and 300.0 < lab.speed_nm_per_s < 2000.0
    assert calibrated(afm, IdentifyConfig().updated(calibrate="span")).acquisition == (
        IdentifyConfig().updated(calibrate="span").acquisition
    )  # no calibration cycles: nothing measured


def test_a_search_above_the_fastest_useful_scan_is_refused():
    afm = VirtualAFM("cpr5", grating=Grating(PITCH))
    with pytest.raises(ValueError, match="10 times a pitch"):
        measure_calibration_scan(afm, PITCH, speeds_nm_per_s=(5000.0, 8000.0))
    assert afm.command_nm == (0.0, 0.0)


def test_a_wrong_pitch_is_refused():
    afm = VirtualAFM("cpr5", grating=Grating(PITCH))
    with pytest.raises(ValueError, match="is the pitch right"):
        measure_calibration_scan(afm, 1000.0)
