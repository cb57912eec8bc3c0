"""The drift session's "drift only": a limit by design is a result, never a failure.

On the uncompensated scanner the drift compensator's landmarks carry the scanner's own
error; where it cannot track at all, the session is reported as far as it went, with the
reason, and ``piezocomp reproduce`` does not count it among the failures that make it exit
1. The same loss for the methods that should hold the areas stays a failure.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from piezocomp.drift.compensated import TrackingLost
from piezocomp.experiments import drift_session as D
from piezocomp.experiments.methods import MethodModels
from piezocomp.experiments.report import _drift
from piezocomp.experiments.reproduce import ReproduceSettings, Trial, aggregate
from piezocomp.virtual_afm import VirtualAFM, load_config

SHORT = D.DriftSessionSettings(minutes=2.0, area_nm=600.0)


class LosesTrackingAfter:
    """An instrument that loses drift tracking at its ``n``-th image (else the AFM's)."""

    def __init__(self, afm: VirtualAFM, n: int) -> None:
        self.afm, self.n, self.images = afm, n, 0

    def scan_image(self, *args, **kwargs):
        self.images += 1
        if self.images >= self.n:
            raise TrackingLost("drift tracking lost every landmark (test)")
        return self.afm.scan_image(*args, **kwargs)

    def move_to(self, *args, **kwargs):
        return self.afm.move_to(*args, **kwargs)


def test_a_session_that_loses_tracking_keeps_its_images_and_says_why():
    afm = VirtualAFM(load_config("cpr5"), seed=1)
    r = D.run(LosesTrackingAfter(afm, 6), SHORT, truth=afm.truth)  # overview, A, B, 2 more
    assert r.stopped.startswith("drift tracking lost")
    assert r.errors_nm.size == 2 and r.true_errors_nm.size == 2
    assert r.true_final_error_nm == pytest.approx(r.true_errors_nm[-1])


def test_drift_only_that_cannot_start_is_reported_not_raised(monkeypatch):
    def lost(*args, **kwargs):
        raise TrackingLost("no landmark was found again (test)")

    monkeypatch.setattr(D, "session_instrument", lost)
    afm = VirtualAFM(load_config("cpr5"), seed=1)
    r = D.run_method("drift_only", afm, MethodModels({}), SHORT)
    assert r.stopped == "no landmark was found again (test)" and r.errors_nm.size == 0
    with pytest.raises(TrackingLost):  # for both compensators it is a failure
        D.run_method("both", afm, MethodModels({}), SHORT)
    summary = D.session_summary(SHORT, {"drift_only": r})
    d = summary["methods"]["drift_only"]
    assert d["stopped"] and d["limitation"] == D.LIMITATIONS["drift_only"]
    assert d["images"] == 0 and d["true_max_error_nm"] is None and d["final_error_nm"] is None
    json.dumps(summary, allow_nan=False)


def test_reproduce_counts_a_limit_by_design_as_a_result_not_a_failure():
    """``aggregate`` (what ``reproduce`` decides its exit status from) lists no failure for
    a stopped drift-only session, and the report says why it stopped; a failed "both" is
    still a failure."""
    empty = np.zeros(0)
    stopped = D.DriftSessionResult(SHORT, empty, (), empty, empty, stopped="lost (test)")
    s = ReproduceSettings(config=load_config("cpr5"), methods=("compensated",),
                          drift_minutes=2.0)  # fmt: skip
    outcomes = [(Trial("drift_session", "drift_only", SHORT), stopped),
                (Trial("drift_session", "both", SHORT), "RuntimeError: lost")]  # fmt: skip
    res = aggregate(s, outcomes, [], 600.0, {})
    assert [(f["experiment"], f["method"]) for f in res["failures"]] == [("drift_session", "both")]
    page = _drift(res)
    assert "could not go on" in page and "not a failure" in page and "failed: RuntimeError" in page
    json.dumps(res, allow_nan=False)


def test_drift_only_runs_on_cpr5_drift_and_reports_the_scanner_error_it_measured():
    """Five minutes of the session on ``cpr5`` with the drift compensator around the
    raw scanner: it tracks to the end (no stop), measures its landmarks' error (several
    nanometres, the scanner's own), and the summary carries it with the final errors."""
    afm = VirtualAFM(load_config("cpr5"), seed=1)
    five = D.DriftSessionSettings(minutes=5.0, area_nm=600.0)
    r = D.run_method("drift_only", afm, MethodModels({}), five)
    assert r.stopped == "" and r.errors_nm.size >= 4 and r.measurements >= 3
    assert r.scanner_error_nm is not None and np.max(r.scanner_error_nm) > 2.0
    d = D.session_summary(r.settings, {"drift_only": r})["methods"]["drift_only"]
    assert d["scanner_error_nm"] == pytest.approx(list(r.scanner_error_nm))
    assert d["true_final_error_nm"] == pytest.approx(r.true_errors_nm[-1])
    assert "stopped" in d and d["stopped"] is None
    noise = d["drift_noise"]  # the noise the filter ran with: the prior, or learnt
    assert noise["position_nm_per_sqrt_s"] == r.noise.position_nm_per_sqrt_s > 0
    assert noise["learnt_from_measurements"] == r.noise_learnt_from
    page = _drift({"drift_session": D.session_summary(r.settings, {"drift_only": r})})
    assert "Its landmarks measured that error" in page


def test_a_learnt_walk_below_what_the_sightings_resolve_is_said_to_be_so():
    from piezocomp.experiments.drift_session import unresolved_note

    def noise(walk, meas, rate=1e-6, order=2):
        return {"position_nm_per_sqrt_s": walk, "rate_noise": rate, "measurement_nm": meas,
                "order": order, "learnt_from_measurements": 12}  # fmt: skip

    # drift only on cpr5 (a full run): 21 nm sightings, a fitted walk of 8e-7 nm/sqrt(s)
    assert unresolved_note(noise(8.4e-7, 21.4), 20.0) == (
        ": no wander beyond its sightings' 21 nm noise"
    )
    assert unresolved_note(noise(0.173, 0.5), 20.0) == ""  # both: 6 nm over 20 min vs 0.5 nm
    assert unresolved_note(noise(0.01, 0.5), 0.5) != ""  # 0.05 nm over half a minute
    # the wander in the rate counts too: 1e-4 nm/s/sqrt(s) on the velocity over 20 minutes
    # moves the drift by 2.4 nm, 2e-7 nm/s^2/sqrt(s) on the acceleration by 2.2 nm
    assert unresolved_note(noise(1e-7, 1.0, rate=1e-4), 20.0) == ""
    assert unresolved_note(noise(1e-7, 1.0, rate=2e-7, order=3), 20.0) == ""
    assert unresolved_note(noise(1e-7, 1.0, rate=5e-10, order=3), 20.0) != ""


def test_the_first_images_are_scored_when_taken_not_from_an_old_log(monkeypatch):
    """The truth keeps only its most recent samples: a long session (or one that measures
    much) scores every image against its area's first, long gone from the log by then."""
    from piezocomp.virtual_afm import truth_log

    monkeypatch.setattr(truth_log, "TRUTH_LOG_SAMPLES", 1 << 14)
    afm = VirtualAFM(load_config("cpr5"), seed=1)
    r = D.run(afm, SHORT, truth=afm.truth)
    assert r.true_errors_nm.size >= 2 and np.all(np.isfinite(r.true_errors_nm))
