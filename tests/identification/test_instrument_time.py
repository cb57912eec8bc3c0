"""The instrument time of an identification, by stage (InstrumentClock)."""

import numpy as np
import pytest

from piezocomp.identification.instrument_time import InstrumentClock
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
