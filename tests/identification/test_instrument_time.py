"""The instrument time of an identification, by stage (InstrumentClock)."""

import numpy as np
import pytest

from identify_configs import small, small_quick
from piezocomp.identification.acquisition import recording
from piezocomp.identification.acquisition.instrument_time import InstrumentClock, with_total
from piezocomp.identification.planning import planned_instrument_s
from piezocomp.virtual_afm import VirtualAFM


def test_the_clock_counts_what_the_instrument_ran_by_stage():
    """Each stage's seconds are the instrument's own clock advanced during it (the virtual
    AFM keeps one); what runs outside a stage is ``other``; the inner of nested stages
    counts; the calls' results are the instrument's."""
    afm = VirtualAFM.from_preset("cpr5-nodrift")
    clock = InstrumentClock(afm)
    spent = {}

    def timed(stage, call):
        t0 = afm.time_s
        with clock.stage(stage):
            out = call()
        spent[stage] = spent.get(stage, 0.0) + afm.time_s - t0
        return out

    timed("other", lambda: clock.move_to(50.0, 0.0, 500.0))  # the clock's first output
    timed("image", lambda: clock.scan_image((0.0, 0.0), 200.0, 16, 2.0))
    timed("image", lambda: clock.scan_image((0.0, 0.0), 200.0, 8, 4.0, fast_axis="y"))
    u = np.column_stack([np.linspace(0, 50, 300), np.zeros(300)])
    rec = timed("record", lambda: clock.run(u))
    assert len(rec) == 300 and rec.command_nm[-1, 0] == pytest.approx(50.0)
    timed("hold", lambda: clock.wait(3.0))
    timed("other", lambda: clock.move_to(100.0, 0.0, 500.0))
    with clock.stage("outer"), clock.stage("inner"):
        t0 = afm.time_s
        clock.move_to(0.0, 0.0, 500.0)
        spent["inner"] = afm.time_s - t0
    assert clock.seconds.keys() == spent.keys()
    for stage, seconds in spent.items():
        assert clock.seconds[stage] == pytest.approx(seconds, rel=1e-9, abs=1e-9), stage
    assert 16 / 2.0 + 8 / 4.0 < clock.seconds["image"] < 16 / 2.0 + 8 / 4.0 + 1.0  # approaches
    assert clock.seconds["hold"] == pytest.approx(3.0, abs=afm.sample_period_s)
    assert clock.total_s == pytest.approx(sum(spent.values()))
    # the instrument's other attributes are read through
    assert clock.calibration_scan is afm.calibration_scan
    assert clock.range_nm == afm.range_nm and clock.command_nm == afm.command_nm


def test_the_overview_runs_at_its_own_speed_within_the_limit(monkeypatch):
    """The overview's line rate: the waveform's speed by default, overview_speed_nm_per_s
    when given, the instrument's speed limit at most; a speed that is no speed is refused."""
    rates = []

    def stop(instrument, cfg, axis, line_rate, degree):
        rates.append(line_rate)
        raise ValueError("stopped at the overview")

    monkeypatch.setattr(recording, "overview_and_line", stop)
    afm = VirtualAFM.from_preset("cpr5-nodrift")
    for speed in (None, 2000.0, 1e6):
        with pytest.raises(ValueError, match="stopped at the overview"):
            acq = small(overview_speed_nm_per_s=speed).acquisition
            recording.record_axis(afm, acq, "x", loop_degree=5)
    span = small().acquisition.span_nm
    limit = afm.max_speed_nm_per_s
    assert rates == pytest.approx([250.0 / (2 * span), 2000.0 / (2 * span), limit / (2 * span)])
    for bad in (0.0, -5.0, float("nan")):
        with pytest.raises(ValueError, match="overview_speed_nm_per_s"):
            small(overview_speed_nm_per_s=bad)


def test_the_total_is_the_stages_sum():
    assert with_total({"overview": 60.0, "grating": 30.5}) == {
        "overview": 60.0, "grating": 30.5, "total": 90.5,
    }  # fmt: skip


def test_the_plan_is_what_the_fixed_stages_take():
    """The stages the configuration fixes take the planned time on the instrument (its own
    clock), within the moves and approaches between calls; the line search, which depends
    on the sample, is not planned and its time is counted all the same."""

    afm = VirtualAFM.from_preset("cpr5-nodrift", seed=1)  # its first overview holds a line
    cfg = small_quick(extra_lines=1, line_settle_s=120.0, calibrate=0.8 * afm.range_nm)
    planned = planned_instrument_s(afm, cfg.acquisition, "x")
    records = recording.record_axis(afm, cfg.acquisition, "x", loop_degree=cfg.loop.degree)
    took = records.instrument_s
    assert set(planned) == {"overview", "settling", "record and check", "calibration cycles",
                            "extra lines"}  # fmt: skip
    assert "line search" in took and "line search" not in planned
    for stage, seconds in planned.items():
        assert seconds > 0, stage
        # what the plan leaves out (moves, approaches, the extra line's search) only adds
        more = took["line search"] if stage == "extra lines" else 0.0
        assert seconds * 0.98 <= took[stage] <= seconds * 1.05 + 5.0 + more, (stage, took)
    assert planned["extra lines"] == pytest.approx(
        planned["overview"] + planned["settling"] + records.u_nm.size * afm.sample_period_s
    )
