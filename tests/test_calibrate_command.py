"""``piezocomp calibrate``: the calibration record measured on a grating, from the command
line (virtual AFM; the instrument path is the same function through the interface)."""

from __future__ import annotations

import json

import pytest

from piezocomp.cli import main
from piezocomp.experiments.virtual_identification import calibration_record
from piezocomp.virtual_afm import VirtualAFM


def test_calibrate_writes_the_record_identify_takes(tmp_path, capsys):
    assert main(["calibrate", "--preset", "cpr5", "--grating-pitch-nm", "278",
                 "--out", str(tmp_path)]) == 0  # fmt: skip
    body = json.loads((tmp_path / "calibration.json").read_text())
    assert body["span_nm"] == 5000.0 and 300.0 < body["speed_nm_per_s"] < 1500.0
    speeds = [w["speed_nm_per_s"] for w in body["width_ratios"]]
    assert speeds[:2] == [100.0, 278.0 / (10 * 0.008)]  # the bracket: 10 samples a pitch
    assert body["truth"]["note"] == "ground truth, for scoring only"
    assert body["speed_nm_per_s"] == calibration_record(VirtualAFM("cpr5", seed=1)).speed_nm_per_s
    err = capsys.readouterr().err
    assert "the virtual lab's record" in err and "ground truth, for scoring" in err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--grating-pitch-nm", "0"], "--grating-pitch-nm must be"),
        (["--grating-pitch-nm", "278", "--speeds-nm-per-s", "500", "100"], "0 < LOW < HIGH"),
        (["--grating-pitch-nm", "278", "--emulator"], "--emulator goes with --instrument"),
    ],
)
def test_bad_options_are_refused_in_one_line(tmp_path, capsys, extra, message):
    assert main(["calibrate", "--preset", "cpr5", "--out", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "o").exists()


def test_no_speed_in_the_range_is_a_failure_with_its_widths(tmp_path, capsys):
    assert main(["calibrate", "--preset", "cpr5", "--grating-pitch-nm", "278",
                 "--speeds-nm-per-s", "2000", "5000", "--out", str(tmp_path)]) == 1  # fmt: skip
    err = capsys.readouterr().err
    assert "lower LOW" in err and "0.9" in err and "at 2000 nm/s" in err
    assert not (tmp_path / "calibration.json").exists()  # a failed run leaves no output
