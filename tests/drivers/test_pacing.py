"""The timing log of client-paced paths: counted, refused or flagged."""

from __future__ import annotations

import numpy as np
import pytest

from piezocomp.drivers.pacing import TimingError, TimingLog
from piezocomp.instrument import Record, RunFailure, SampleTiming


def _record(sent_s: list[float], period_s: float = 0.01) -> Record:
    n = len(sent_s)
    timing = SampleTiming(period_s, np.asarray(sent_s), 0.5 * period_s)
    return Record(np.asarray(sent_s), np.zeros((n, 2)), np.zeros(n), timing)


def test_timing_log_counts_refuses_and_flags():
    on_time = _record([0.0, 0.01, 0.02])
    late = _record([0.0, 0.01, 0.05])  # the third sample 30 ms (3 periods) after its slot
    log = TimingLog("raise")
    assert log.check(on_time) is on_time
    with pytest.raises(TimingError, match="broke the model's assumption") as info:
        log.check(late, "a wait of 1 s")
    assert info.value.record is late
    assert str(info.value).startswith("stopped at a wait of 1 s: ")
    assert isinstance(info.value, RunFailure)  # found during a run: the command exits 1
    assert (log.paths, log.samples, log.late_paths, log.late_samples) == (2, 6, 1, 1)
    assert log.worst_s == pytest.approx(0.03) and log.worst_periods == pytest.approx(3.0)
    flagged = TimingLog("flag")
    assert flagged.check(late) is late and flagged.as_dict()["late_paths"] == 1
    assert "1 beyond their tolerance (1 samples, flagged and used)" in flagged.summary()
    with pytest.raises(ValueError, match="must carry its timing"):
        flagged.check(Record(np.zeros(1), np.zeros((1, 2)), np.zeros(1)))
    with pytest.raises(ValueError, match="timing must be one of"):
        TimingLog("ignore")
