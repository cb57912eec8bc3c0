"""The commands on a Nanonis instrument (``--instrument``), against the emulator on loopback.

Each test serves its own emulator in a thread; the paths are short (small images, large
sample periods) and the client paces far faster than real time with ``--timing flag`` (the
emulator's clock is the set-point stream, so pacing changes nothing it measures), so that a
loaded machine cannot make them fail. What the emulator serves equals the virtual AFM run
directly wherever both draw the same random numbers (streamed paths, any period).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from piezocomp.cli import main
from piezocomp.drivers.nanonis import NanonisInstrument
from piezocomp.drivers.nanonis_emulator import Fault, NanonisEmulator
from piezocomp.experiments.on_instrument import NO_TRUTH, InstrumentRunSettings, run_experiments
from piezocomp.io.model_files import save_model
from piezocomp.virtual_afm import VirtualAFM

FAST = ["--emulator", "--speedup", "50", "--timing", "flag", "--max-speed-nm-per-s", "20000"]
"""Rehearsal flags: paced far faster than real time, late paths counted, not refused."""


def _afm(period_s: float = 0.008) -> VirtualAFM:
    return VirtualAFM.from_preset("cpr5-nodrift", seed=1, sample_period_s=period_s)


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("piezocomp ")
    return err[-1]


@pytest.fixture
def model_file(tmp_path, oracle_models):
    path = tmp_path / "model.json"
    save_model(path, oracle_models)
    return str(path)


# ----------------------------------------------------------------- the emulator's clock
def test_nanonis_emulator_runs_each_path_at_its_declared_period():
    u = np.column_stack([np.linspace(2.0, 60.0, 30), np.zeros(30)])
    direct = _afm()
    want = direct.run(u, sample_period_s=0.002)
    with NanonisEmulator(_afm()) as emu:
        inst = NanonisInstrument.connect(emu.url, sample_period_s=0.008, max_speed_nm_per_s=2e4,
                                         speedup=50.0, emulator=True, timing="flag")  # fmt: skip
        got = inst.run(u, sample_period_s=0.002)
        assert emu.afm.time_s == pytest.approx(direct.time_s)  # 30 x 2 ms, not 30 x T
        np.testing.assert_allclose(got.height_nm, want.height_nm, atol=1e-5)  # float32 Z
        before = emu.afm.time_s
        img = inst.scan_image((0.0, 0.0), 200.0, 16, 5.0)  # the controller's scan
        assert emu.calls("Scan.Action") == 1
        # the scan took its scanner time on the client's clock too (3.2 s / 50)
        assert inst.time_s >= emu.afm.time_s - before - 1e-6
        assert img.forward_nm.shape == (16, 16)
        inst.close()


def test_nanonis_speedup_and_flagged_timing_need_the_emulator(tmp_path, capsys):
    with NanonisEmulator(_afm()) as emu:
        with pytest.raises(ValueError, match="only the emulator"):
            NanonisInstrument.connect(emu.url, sample_period_s=0.008, max_speed_nm_per_s=2e4,
                                      speedup=2.0)  # fmt: skip
    base = ["drift", "--instrument", "nanonis://127.0.0.1:1", "--max-speed-nm-per-s", "100"]
    out = str(tmp_path / "d")
    assert main([*base, "--speedup", "2", "--out", out]) == 2
    assert "--speedup goes with --emulator" in _one_line_error(capsys)
    assert main([*base, "--timing", "flag", "--out", out]) == 2
    assert "--timing flag goes with --emulator" in _one_line_error(capsys)
    assert not (tmp_path / "d").exists()


# ----------------------------------------------------------------- options, one line each
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["drift", "--preset", "cpr5-nodrift", "--emulator"], "--emulator goes with --instrument"),
        (["drift", "--instrument", "nanonis://h:1"], "needs --max-speed-nm-per-s"),
        (["drift", "--instrument", "tcp://h:1", "--max-speed-nm-per-s", "1"], "nanonis://HOST"),
        (["drift", "--instrument", "nanonis://h:1", "--max-speed-nm-per-s", "1", "--seed", "2"],
         "--seed: a virtual AFM option"),
        (["reproduce", "--model", "m.json"], "--model goes with --instrument"),
        (["reproduce", "--instrument", "nanonis://h:1", "--max-speed-nm-per-s", "1", "--quick"],
         "--quick: virtual AFM option"),
        (["reproduce", "--instrument", "nanonis://h:1", "--max-speed-nm-per-s", "1",
          "--methods", "compensated"], "--methods compensated needs --model"),
        (["reproduce", "--instrument", "nanonis://h:1", "--max-speed-nm-per-s", "1",
          "--pixels", "4"], "--pixels must be >= 8"),
        (["identify", "--instrument", "nanonis://h:1", "--max-speed-nm-per-s", "1",
          "--grating-record", "g.csv", "--grating-pitch-nm", "278"], "one axis' grating runs"),
        (["identify", "--instrument", "nanonis://h:1", "--max-speed-nm-per-s", "1",
          "--reference", "none", "--calibrate", "span", "--calibration-speed-nm-per-s", "600"],
         "goes with --calibrate full-range"),
        (["identify", "--preset", "cpr5-nodrift", "--calibration-speed-nm-per-s", "600"],
         "--calibration-speed-nm-per-s goes with --instrument"),
    ],
)  # fmt: skip
def test_nanonis_instrument_options_refused_in_one_line(tmp_path, capsys, argv, message):
    out = tmp_path / "run"
    assert main([*argv, "--out", str(out)]) == 2
    line = _one_line_error(capsys)
    assert message in line, line
    assert not out.exists()  # refused before anything connected or was written


# ----------------------------------------------------------------- the commands
def test_nanonis_drift_command_takes_its_movie_on_the_instrument(tmp_path, capsys):
    out = tmp_path / "drift"
    movie = ["--sample-period-s", "0.1", "--frames", "3", "--size-nm", "200", "--pixels", "16",
             "--line-rate-hz", "8", "--interval-s", "2"]  # fmt: skip
    with NanonisEmulator(_afm()) as emu:
        url = emu.url
        assert main(["drift", "--instrument", url, *FAST, *movie, "--out", str(out)]) == 0
        assert emu.calls("Scan.Action") == 3  # one controller scan a frame
    summary = json.loads((out / "summary.json").read_text())
    assert summary["source"] == [url] and summary["frames"] == 3
    assert "true_max_error_nm" not in summary  # no ground truth on an instrument
    assert summary["timing"]["mode"] == "flag" and summary["timing"]["paths"] >= 3
    assert (out / "drift.csv").is_file()
    assert "streamed paths" in capsys.readouterr().err


def test_nanonis_reproduce_reports_measured_errors_only(tmp_path, capsys):
    out = tmp_path / "rep"
    argv = ["reproduce", "--instrument", "", *FAST, "--sample-period-s", "0.02",
            "--experiments", "table1", "fig9", "--distances-nm", "645", "--table1-experiments",
            "1", "--settle-s", "0", "--pixels", "32", "--overview-pixels", "64",
            "--out", str(out)]  # fmt: skip
    with NanonisEmulator(_afm()) as emu:
        argv[2] = emu.url
        assert main(argv) == 0
    res = json.loads((out / "results.json").read_text())
    assert res["mode"] == "instrument" and res["true_errors"] == NO_TRUTH
    assert res["methods"] == ["uncompensated"] and not res["failures"]
    row = res["table1"][0]["methods"]["uncompensated"]
    assert len(row["trials"]) == 1 and row["true_max_error_nm"] is None
    assert row["trials"][0]["true_error_nm"] is None
    assert res["fig9"]["uncompensated"]["true_error_nm"] is None
    assert res["fig9"]["uncompensated"]["error_nm"] is not None
    assert "true: not available" in capsys.readouterr().out
    # the virtual run's report and figures, measured only
    for name in ("table1", "fig9"):
        assert (out / f"{name}.png").stat().st_size > 10_000
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 2 and "true errors: unavailable" in page
    assert f"{res['fig9']['uncompensated']['error_nm']:.2f} nm" in page
    assert "true_error" not in page and "(true)" not in page


def test_a_flagged_rehearsal_says_how_far_its_timing_explains_a_difference():
    from piezocomp.experiments.report_instrument import timing_note

    timing = {"mode": "flag", "paths": 40, "late_paths": 3, "worst_deviation_s": 256.0,
              "worst_deviation_periods": 1.31e5}  # fmt: skip
    note = timing_note(timing, emulator=True)
    assert note.startswith("3 of 40 streamed paths") and "explains none of a difference" in note
    assert timing_note({**timing, "late_paths": 0}, emulator=True) == ""
    assert "explains" not in timing_note({**timing, "mode": "raise"}, emulator=False)


def test_nanonis_compensated_run_over_sockets_equals_the_direct_one(tmp_path, model_file,
                                                                   oracle_models):  # fmt: skip
    st = InstrumentRunSettings(experiments=("fig9",), methods=("compensated",), pixels=32)
    direct_afm = _afm(0.02)
    direct = run_experiments(direct_afm, oracle_models, st, truth=direct_afm.truth)
    out = tmp_path / "rep"
    with NanonisEmulator(_afm(0.02)) as emu:
        argv = ["reproduce", "--instrument", emu.url, *FAST, "--sample-period-s", "0.02",
                "--model", model_file, "--methods", "compensated", "--experiments", "fig9",
                "--pixels", "32", "--out", str(out)]  # fmt: skip
        assert main(argv) == 0
    res = json.loads((out / "results.json").read_text())
    got, want = res["fig9"]["compensated"]["error_nm"], direct["fig9"]["compensated"]["error_nm"]
    assert got == pytest.approx(want, abs=1e-3)  # the same samples, float32 heights apart
    assert direct["fig9"]["compensated"]["true_error_nm"] is not None  # the direct run's truth


def test_nanonis_reproduce_stops_when_the_instrument_drops(tmp_path, capsys):
    out = tmp_path / "rep"
    with NanonisEmulator(_afm(), faults=[Fault("drop", after=40)]) as emu:
        argv = ["reproduce", "--instrument", emu.url, *FAST, "--timeout-s", "0.5",
                "--sample-period-s", "0.02", "--experiments", "fig9", "--pixels", "32",
                "--out", str(out)]  # fmt: skip
        assert main(argv) == 1
        assert emu.set_points == 40  # nothing after the drop
    res = json.loads((out / "results.json").read_text())
    assert "connection dropped" in res["stopped"] and res["failures"]
    err = capsys.readouterr().err
    assert "the instrument stopped the run" in err and "nothing more was sent" in err


def test_nanonis_reproduce_refuses_distances_the_area_cannot_hold(tmp_path, capsys):
    with NanonisEmulator(_afm()) as emu:
        argv = ["reproduce", "--instrument", emu.url, *FAST, "--range-nm", "2000",
                "--distances-nm", "1500", "--out", str(tmp_path / "rep")]  # fmt: skip
        assert main(argv) == 2
        assert emu.set_points == 0  # refused after reading the range, before any move
    line = _one_line_error(capsys)
    assert "Table I at 1500 nm needs an area of +-867 nm" in line and "smaller distances" in line


def test_emulate_refuses_a_grating_axis_without_a_grating(capsys):
    assert main(["emulate", "--grating-axis", "y", "--port", "0"]) == 2
    line = _one_line_error(capsys)
    assert "--grating-axis y goes with --grating-pitch-nm" in line, line
