"""End to end: sensorless identification on the virtual AFM through the instrument interface.

The virtual AFM is wrapped so that identification sees the ``Instrument`` protocol and
nothing else (no ground truth); the truth is used only afterwards, by ``score_on_truth``.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from identify_configs import small, small_quick
from loop_estimates import trace_estimate
from piezocomp.experiments import scoring
from piezocomp.experiments.scoring import score_on_truth
from piezocomp.identification.acquisition.diagnostics import ExcitationWarning
from piezocomp.identification.acquisition.line_search import MIN_LINE_PARTICLES
from piezocomp.identification.acquisition.peaks import Peaks, guided_pairs, pair_peaks
from piezocomp.identification.estimation.candidates import initial_from_loop, thresholds_over_span
from piezocomp.identification.estimation.prediction import predicted_forward_trace
from piezocomp.identification.loop.symmetric import SymmetricLoop
from piezocomp.identification.reference.frames import frame_map, mapped, unmapped
from piezocomp.identification.sensorless import identify_axis
from piezocomp.instrument import Instrument
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.virtual_afm import VirtualAFM


class InterfaceOnly:
    """Forwards the Instrument protocol of a virtual AFM and nothing else."""

    def __init__(self, afm: VirtualAFM) -> None:
        self._afm = afm

    sample_period_s = property(lambda self: self._afm.sample_period_s)
    range_nm = property(lambda self: self._afm.range_nm)
    max_speed_nm_per_s = property(lambda self: self._afm.max_speed_nm_per_s)
    command_nm = property(lambda self: self._afm.command_nm)

    def run(self, command_nm):
        return self._afm.run(command_nm)

    def move_to(self, x_nm, y_nm, speed_nm_per_s):
        return self._afm.move_to(x_nm, y_nm, speed_nm_per_s)

    def scan_image(self, center_nm, size_nm, pixels, line_rate_hz, *, fast_axis="x"):
        return self._afm.scan_image(center_nm, size_nm, pixels, line_rate_hz, fast_axis=fast_axis)

    def push(self, x_nm, y_nm, speed_nm_per_s):
        return self._afm.push(x_nm, y_nm, speed_nm_per_s)

    def wait(self, duration_s):
        return self._afm.wait(duration_s)


@pytest.fixture(scope="module")
def gentle_run():
    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    inst = InterfaceOnly(afm)
    assert isinstance(inst, Instrument) and not hasattr(inst, "truth")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ExcitationWarning)
        ident = identify_axis(inst, small_quick(), "x")
    # every excitation finding is reported both ways
    assert sorted(str(w.message) for w in caught) == sorted(ident.findings)
    # the creep spectrum outlasts every record by design: not a finding
    assert max(ident.batch_model.creep_time_constants_s) > ident.u_nm.size * 0.008
    assert not any("creep time constant" in f for f in ident.findings)
    plain = ScannerModel(offset_nm=0.0, gain=1.0, thresholds_nm=[], weights=[],
                         creep_time_constants_s=[], creep_gains=[])  # fmt: skip
    models = {"rls": ident.rls_model, "batch": ident.batch_model, "identity": plain}
    seen = {}

    def spy(model, u, T, state):  # the scoring's own history and start, kept
        seen[id(model)] = (u, T, state)
        return simulate(model, u, T, state)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(scoring, "simulate", spy)
        score = score_on_truth(afm, ident, models)
    truth = afm.truth.last_record_extension_nm[:, 0]
    u, T, state = seen[id(ident.batch_model)]
    y, _ = simulate(ident.batch_model, u, T, state)
    # the scoring replayed here agrees with score_on_truth's, so the wrong-sign figures are
    # what score_on_truth would give
    again = validation_errors(u, y, truth)
    for key, v in again.items():
        assert v == pytest.approx(score["batch"][key], rel=1e-9, abs=1e-9), key
    score["wrong_sign"] = validation_errors(u, wrong_sign(ident.batch_model, u, T, state), truth)
    return ident, score


def validation_errors(u, y, truth):
    """score_on_truth's figures of a prediction ``y`` over the command history ``u`` whose
    last ``truth.size`` samples are the validation trajectory (its first sweep unscored)."""
    v = u[-truth.size :]
    lo = int(np.argmax(v >= v.max() - 1e-9))
    pred, tr = y[-truth.size :][lo:], truth[lo:]
    err = tr - pred - np.mean(tr - pred)
    coef = np.polyfit(pred, tr, 1)
    aff = tr - np.polyval(coef, pred)
    return {
        "validation_max_error_nm": float(np.max(np.abs(err))),
        "validation_rms_error_nm": float(np.sqrt(np.mean(err**2))),
        "scale": float(coef[0]),
        "validation_max_error_after_scale_nm": float(np.max(np.abs(aff))),
        "validation_rms_error_after_scale_nm": float(np.sqrt(np.mean(aff**2))),
    }


def wrong_sign(model, u, T, state):
    """``model``'s prediction with its hysteresis reversed (the loop run clockwise, the same
    span and creep): ``y + 2 sum(w) u - 2 sum(w z)`` for eq (2)'s ``y = a u + sum(w z) + ...``,
    ``sum(w z)`` read as the change a doubling of the weights makes."""
    y, _ = simulate(model, u, T, state)
    doubled = replace(model, weights=2 * np.asarray(model.weights))
    y2, _ = simulate(doubled, u, T, state)
    return y + 2 * float(np.sum(model.weights)) * np.asarray(u) - 2 * (y2 - y)


def test_gentle_end_to_end(gentle_run):
    """The paper's procedure (calibration condition on the working span), quick waveform.

    Bounds from measurements (2026-11-28, seeds 1-3: after removing offset and scale, RLS
    1.3-1.8 nm and batch 2.1-2.4 nm max, 0.47-0.78 nm RMS; offset only, 14.6-16.3 nm), with
    a margin of about 1.3x, below what the identity model ``y = u`` gives on the same path
    (4.2-4.3 nm max and 1.7 nm RMS after scale: checked here, so that the bounds keep
    telling an identified model from none). The offset-only error is dominated by the
    calibration of Section IV: the gentle scanner's +-500 nm cycle spans ~3 % less than its
    command, which the calibration condition cannot see; ``scale`` shows it.
    """
    ident, score = gentle_run
    assert ident.loop.loop.degree == 5
    assert sum(len(a) for a, _ in ident.loop.all_pairs) > 5
    # no calibration cycles: the batch model, refined in its own frame (h re-indexed by it),
    # is put back on the loop's span by its own prediction of part A's steady cycles
    assert ident.calibration is None and ident.frame_map[0] == pytest.approx(1.0, abs=0.03)
    wf = ident.waveform
    fwd = wf.forward_traces
    y = predicted_forward_trace(
        ident.batch_model, ident.u_nm, ident.sample_period_s, fwd, ident.creep_start_nm
    )
    ends = ident.loop.loop.ascending(np.array([wf.u_min_nm, wf.u_max_nm]))
    np.testing.assert_allclose(y[[0, -1]], ends, atol=1e-6)
    max_after, rms_after = 3.2, 1.1
    # no model (y = u) and the hysteresis of the identified model reversed fail the bounds
    for wrong in ("identity", "wrong_sign"):
        plain = score[wrong]
        assert plain["validation_max_error_after_scale_nm"] > max_after, wrong
        assert plain["validation_rms_error_after_scale_nm"] > rms_after, wrong
    plain = score["identity"]
    for name in ("rls", "batch"):
        s = score[name]
        assert s["validation_max_error_after_scale_nm"] < max_after
        assert s["validation_rms_error_after_scale_nm"] < rms_after
        assert s["validation_max_error_nm"] < min(20.0, plain["validation_max_error_nm"])
        assert 0.93 < s["scale"] < 0.99
    # the batch refinement predicts the held-out heights about as well as the start or
    # better (measured 0.28 vs 0.32 nm RMS; 0.95x at worst over seeds 1-3)
    assert ident.heldout_rms_nm["batch"] <= 1.25 * ident.heldout_rms_nm["initial"]


def test_gentle_y_axis_end_to_end():
    """The y axis through the same interface: its overview is scanned y-fast, so the line's
    forward and backward traces are y traces; the same bounds as the x axis' test, which
    the identity model fails there too."""
    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExcitationWarning)
        ident = identify_axis(InterfaceOnly(afm), small_quick(), "y")
    assert ident.axis == "y" and ident.line.axis == "y"
    assert ident.line.n_particles > 5
    plain = ScannerModel(offset_nm=0.0, gain=1.0, thresholds_nm=[], weights=[],
                         creep_time_constants_s=[], creep_gains=[])  # fmt: skip
    models = {"rls": ident.rls_model, "batch": ident.batch_model, "identity": plain}
    score = score_on_truth(afm, ident, models)
    max_after, rms_after = 3.2, 1.1
    assert score["identity"]["validation_max_error_after_scale_nm"] > max_after
    assert score["identity"]["validation_rms_error_after_scale_nm"] > rms_after
    for name in ("rls", "batch"):
        s = score[name]
        assert s["validation_max_error_after_scale_nm"] < max_after
        assert s["validation_rms_error_after_scale_nm"] < rms_after
        assert s["validation_max_error_nm"] < 20.0
        assert 0.93 < s["scale"] < 0.99


def test_the_y_axis_line_is_chosen_from_y_traces():
    """On cpr5 the forward and backward x traces of a pixel column lie ~60 nm apart, so
    columns of an x-fast overview pair few particles (seed 1: only a 4-particle column at
    the image's edge, and the y identification then failed). The y-fast overview's
    columns are y traces: a line with more than ``degree`` paired particles."""
    from piezocomp.identification.acquisition.line_search import overview_and_line

    afm = VirtualAFM.from_preset("cpr5-nodrift", seed=1, sample_period_s=0.008)
    cfg = small()
    rate = 250.0 / (2.0 * cfg.acquisition.span_nm)
    image, line = overview_and_line(InterfaceOnly(afm), cfg.acquisition, "y", rate, 5)
    assert line.axis == "y" and line.n_particles > cfg.loop.degree
    assert 0 < line.index < image.x_nm.size - 1
    fwd, bwd = afm.truth.last_image_positions_nm
    assert np.median(np.abs(fwd[..., 1] - bwd[..., 1])) > 10.0  # y traces, as scanned


def test_gentle_full_range_calibration():
    """With calibration cycles over the full range the scale is right to ~1 %.

    Measured (2026-11-22, quick waveform, seeds 1-3): offset-only max error RLS 1.8-2.9 nm,
    batch 1.9-3.2 nm; scale 1.002-1.007. Bounds about 2.5x.
    """
    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    cfg = small_quick(calibrate="full-range")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExcitationWarning)
        ident = identify_axis(InterfaceOnly(afm), cfg, "x")
    assert ident.calibration is not None
    assert 0.9 < ident.frame_map[0] < 1.0  # the working frame was too wide
    score = score_on_truth(afm, ident, {"rls": ident.rls_model, "batch": ident.batch_model})
    for name in ("rls", "batch"):
        assert score[name]["validation_max_error_nm"] < 8.0
        assert 0.98 < score[name]["scale"] < 1.03


def test_a_grating_reference_fixes_the_scale():
    """The paper's procedure plus a grating of known pitch (scanned with the same scanner
    before the particles are mounted): the scale particles cannot see comes from it.

    Measured (2026-11-22, gentle, quick waveform, seeds 1-3): offset-only max error RLS
    1.07-1.13 nm, batch 1.21-1.78 nm (15.2-16.0 nm without the grating); scale
    1.0009-1.0036 (0.966-0.970 without). Bounds about 2x.
    """
    from piezocomp.identification.reference.grating import measure_grating
    from piezocomp.virtual_afm import Grating

    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    lab = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008, grating=Grating(278.0))
    with pytest.raises(ValueError, match="grating record is of axis 'x'; it cannot scale axis 'y'"):
        identify_axis(afm, small_quick(), "y", reference=measure_grating(lab, 278.0))
    record = measure_grating(InterfaceOnly(lab), 278.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExcitationWarning)
        ident = identify_axis(InterfaceOnly(afm), small_quick(), "x", reference=record)
    assert ident.reference is not None and ident.unreferenced_models is not None
    assert ident.frame_map[0] == ident.reference["batch"].alpha
    models = {"rls": ident.rls_model, "batch": ident.batch_model}
    models |= {f"{k}_before": m for k, m in ident.unreferenced_models.items()}
    score = score_on_truth(afm, ident, models)
    for name in ("rls", "batch"):
        assert score[name]["validation_max_error_nm"] < 3.5
        assert abs(score[name]["scale"] - 1.0) < 0.007
        assert score[f"{name}_before"]["scale"] < 0.98  # what the grating corrected
    assert ident.timing_s["reference"] > 0.0  # timed, and reported (its speed: benchmarks)


def test_a_grating_record_elsewhere_in_the_range_is_reported():
    from piezocomp.identification.reference.grating import measure_grating
    from piezocomp.virtual_afm import Grating

    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    lab = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008, grating=Grating(278.0))
    record = measure_grating(lab, 278.0, span_nm=600.0, center_nm=(300.0, 0.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExcitationWarning)
        ident = identify_axis(afm, small_quick(), "x", reference=record)
    found = [f for f in ident.findings if "grating passes cover 600 nm" in f]
    assert found and "about 300 nm, not the working span of 1000 nm about 0 nm" in found[0]


def test_result_is_feasible_and_records_traces(gentle_run):
    ident, _ = gentle_run
    for m in (ident.rls_model, ident.batch_model):
        assert m.gain > 0 and np.all(m.weights > 0) and np.all(np.diff(m.thresholds_nm) > 0)
    n = ident.u_nm.size  # the last RLS passes run over the whole record (rls_final_passes)
    assert ident.rls.error_nm.shape == (n,)
    assert ident.rls.theta_trace.shape == (n, ident.rls.layout.size)
    y, _ = simulate(
        ident.batch_model, ident.u_nm, 0.008, ModelState.at_rest(ident.batch_model, ident.u_nm[0])
    )
    assert np.all(np.isfinite(y))


def test_thresholds_and_initial_model_follow_the_loop():
    r = thresholds_over_span(8, 1000.0)
    assert r[0] > 0 and r[-1] < 500.0 and np.allclose(np.diff(r), r[0])
    loop = SymmetricLoop(np.array([-0.04, 1.0, 0.04]), -500.0, 500.0)
    m = initial_from_loop(loop, 8, 2)
    u = np.concatenate([np.linspace(-500, 500, 401), np.linspace(500, -500, 401)] * 2)
    y, _ = simulate(m, u, 0.008, ModelState.at_rest(m, -500.0))
    ya = loop.ascending(u[802:1203])
    assert np.abs(y[802:1203] - ya).max() < 2.0  # the start reproduces the steady loop


def test_guided_pairs_follow_a_varying_shift():
    """The loop width (shift) varies along the line: a single typical shift loses the pairs
    near the ends, the shift model of ``guided_pairs`` keeps them all, correctly paired."""
    f = np.array([-440.0, -250.0, -100.0, 50.0, 200.0, 350.0, 450.0])
    shift = 60.0 * (1 - (f / 500.0) ** 2)  # 13 nm at the ends, 60 nm in the middle
    b = f - shift
    h = np.array([10.0, 12.0, 14.0, 11.0, 13.0, 9.0, 12.5])
    pf = Peaks(f, h, h)
    pb = Peaks(b, h, h)
    i, _ = pair_peaks(f, b, max_shift_nm=100.0)
    assert i.size < f.size  # the plain pairing drops the end particles
    for ua, ud in guided_pairs([(pf, pb)] * 3, max_shift_nm=100.0):
        np.testing.assert_allclose(ua, f)
        np.testing.assert_allclose(ud, b)


def _same_particles_two_frames():
    """The same particles in a working frame y and a calibration frame Y = 0.8 y - 40:
    ``(working, calibration, alpha, beta)``."""
    rng = np.random.default_rng(5)
    Y = np.sort(rng.uniform(-2400, 2400, 25))
    H = rng.uniform(5, 15, Y.size)
    alpha, beta = 0.8, -40.0
    y = (Y - beta) / alpha
    inside = np.abs(y) < 480
    work = trace_estimate(-500, 500, y[inside], H[inside])
    return work, trace_estimate(-2500, 2500, Y, H), alpha, beta


def test_frame_map_recovers_scale_and_offset():
    """The same particles in a working frame y and a calibration frame Y = 0.8 y - 40."""
    work, cal, alpha, beta = _same_particles_two_frames()
    a, b = frame_map(work, cal, window_nm=300.0)
    assert a == pytest.approx(alpha, abs=2e-3)
    assert b == pytest.approx(beta, abs=1.0)
    m = mapped(initial_from_loop(work.loop, 4, 1), a, b)
    back = unmapped(m, a, b)
    assert back.gain == pytest.approx(initial_from_loop(work.loop, 4, 1).gain)


def test_frame_map_refuses_an_ambiguous_match():
    """Three working particles that two maps explain equally (alpha 0.8 and 0.9, as when the
    calibration cycles ran on another line): refused, not guessed; with a fourth particle
    that only one map explains, it is found."""
    heights = [10.0, 10.0, 10.0]
    work = trace_estimate(-500, 500, np.array([-300.0, 0.0, 300.0]), np.array(heights))
    Y = np.array([-1500.0, -270.0, -240.0, 0.0, 240.0, 270.0, 1500.0])
    cal = trace_estimate(-2500, 2500, Y, np.full(Y.size, 10.0))
    with pytest.raises(ValueError, match="do not decide") as err:
        frame_map(work, cal, window_nm=300.0)
    assert "too few or too evenly spaced" in str(err.value)  # not only drift
    work4 = trace_estimate(
        -500, 500, np.array([-300.0, 0.0, 300.0, 450.0]), np.array([*heights, 10.0])
    )
    cal4 = trace_estimate(-2500, 2500, np.append(Y, 360.0), np.full(Y.size + 1, 10.0))
    a, _ = frame_map(work4, cal4, window_nm=300.0)
    assert a == pytest.approx(0.8, abs=5e-3)


def test_frame_map_places_the_working_particles_by_working_positions():
    """``working_positions`` replaces ``f_a``: a working frame 1.25x as wide and shifted by
    10 nm (a model's own frame) maps with the scale and the offset undone."""
    work, cal, alpha, beta = _same_particles_two_frames()
    a, b = frame_map(
        work, cal, window_nm=300.0, working_positions=lambda u: 1.25 * np.asarray(u) + 10.0
    )
    assert a == pytest.approx(alpha / 1.25, abs=2e-3)
    assert b == pytest.approx(beta - 10.0 * alpha / 1.25, abs=1.0)


def test_calibration_cycles_run_at_the_instruments_calibration_speed():
    from types import SimpleNamespace

    from piezocomp.identification.acquisition.recording import calibration_speed
    from piezocomp.instrument import ScanCalibration

    notes: list[str] = []
    stated = SimpleNamespace(calibration_scan=ScanCalibration(5000.0, 679.0))
    assert calibration_speed(small().acquisition, stated, notes) == 679.0
    assert (
        calibration_speed(small(calibration_speed_nm_per_s=800.0).acquisition, stated, notes)
        == 800.0
    )
    assert notes == []
    assert calibration_speed(small().acquisition, SimpleNamespace(), notes) == 1000.0
    assert len(notes) == 1 and "states no calibration scan" in notes[0]
    for bad in (0.0, float("inf"), True):
        with pytest.raises(ValueError, match="calibration_speed_nm_per_s"):
            small(calibration_speed_nm_per_s=bad)


def test_an_area_without_a_line_is_reported_and_the_other_side_tried(monkeypatch):
    """The extra line's areas: +offset first; where no usable line is found there (cpr5
    seed 31 at +1000 nm: a single line left its models 4 nm off), the finding says so and
    the area on the other side is tried."""
    from piezocomp.identification.acquisition import recording as S

    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    cfg = small_quick(extra_lines=1)
    centres: list[tuple[float, float]] = []
    real = S.overview_and_line

    def first_area_empty(instrument, sub, axis, line_rate, degree):
        centres.append(sub.center_nm)
        if len(centres) == 1:
            raise ValueError("no line crosses enough particles here")
        return real(instrument, sub, axis, line_rate, degree)

    monkeypatch.setattr(S, "overview_and_line", first_area_empty)
    acq = cfg.acquisition
    wf = S.identification_waveform(0.0, acq.span_nm, acq.speed_nm_per_s, 0.008, n_steady=3,
                                   n_decaying=2, n_random=2, rng=0)  # fmt: skip
    notes: list[str] = []
    lines = S.record_extra_lines(afm, acq, "x", wf, acq.speed_nm_per_s, 0.125, notes,
                                 loop_degree=cfg.loop.degree)  # fmt: skip
    assert centres == [(0.0, 1000.0), (0.0, -1000.0)]
    assert len(lines) == 1 and lines[0].line.slow_nm < -300.0
    assert len(notes) == 1 and "no extra line at +1000 nm" in notes[0]
    assert "the next area is tried" in notes[0]


def test_a_second_line_refines_the_batch_model():
    """``extra_lines=1``: a second line, found 1000 nm away on the slow axis after the first
    line's record, refines the batch model with it; the command history carries it, so the
    validation runs through it. Measured (2026-11-22, gentle, quick waveform, seed 1,
    grating-scaled): batch 1.28 nm with the line, 1.26 nm without (on gentle's quick run the
    line's information is not what limits; on cpr5 with the full waveform it is, see
    docs/identification.md); bounds as the single-line grating test's."""
    from piezocomp.identification.reference.grating import measure_grating
    from piezocomp.virtual_afm import Grating

    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    lab = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008, grating=Grating())
    cfg = small_quick(extra_lines=1, joint_rounds=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExcitationWarning)
        ident = identify_axis(afm, cfg, "x", reference=measure_grating(lab, 278.0))
    assert len(ident.extra_lines) == 1
    extra = ident.extra_lines[0]
    assert extra.n_particles >= MIN_LINE_PARTICLES
    assert abs(extra.slow_nm - ident.line.slow_nm) > 300.0
    assert ident.history_u_nm.size > ident.u_nm.size + ident.waveform.u_nm.size
    m = ident.batch_model
    assert m.gain > 0 and np.all(m.weights > 0)
    score = score_on_truth(afm, ident, {"batch": m})
    assert score["batch"]["validation_max_error_nm"] < 3.5
    assert abs(score["batch"]["scale"] - 1.0) < 0.007
    with pytest.raises(ValueError, match="extra_lines must be an integer >= 0"):
        small(extra_lines=-1)
    with pytest.raises(ValueError, match="extra_line_offset_nm must be > 0"):
        small(extra_line_offset_nm=0.0)


@pytest.mark.parametrize("retries", [0, 1, "worse"])
def test_a_line_whose_profile_changed_is_found_again_and_recorded_anew(monkeypatch, retries):
    """When the check cycles say the slow axis crept across the line during the record, the
    line is searched again close by and recorded anew (``rerecord_unstable``); the steadier
    record is the one the models are fitted on, and a note says so. Here the first check is
    made to report a change (the virtual gentle scanner's line holds still)."""
    import piezocomp.identification.acquisition.recording as S
    from piezocomp.identification.acquisition.line_search import LineStability

    real = S.line_stability
    calls = []

    traces = []  # part A's forward traces of each record checked

    def first_changed(*a, **k):
        st = real(*a, **k)
        calls.append(st)
        traces.append(a[1])
        if len(calls) == 1 or retries == "worse":  # crept across the line: 3 nm, then 4 nm
            return LineStability(len(calls) + 2.0 + st.noise_rms_nm, 9.0, np.zeros(0),
                                 np.zeros(0), st.noise_rms_nm)  # fmt: skip
        return st

    monkeypatch.setattr(S, "line_stability", first_changed)
    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    n = 1 if retries == "worse" else retries
    cfg = small_quick(rerecord_unstable=n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExcitationWarning)
        ident = identify_axis(InterfaceOnly(afm), cfg, "x")
    assert len(calls) == 1 + n
    notes = [f for f in ident.findings if "recorded anew" in f]
    changed = [f for f in ident.findings if "profile changed during the identification" in f]
    if retries == 0:
        assert not notes and len(changed) == 1  # reported only
        return
    first_fwd = ident.height_nm[ident.waveform.ascending(1)]
    if retries == "worse":  # the first record is kept, and the second joins the history
        assert len(notes) == 1 and "4.00 nm, the first record is kept" in notes[0]
        assert len(changed) == 1 and ident.line_stability is not calls[1]
        np.testing.assert_array_equal(first_fwd, traces[0][0])
        m, wf = ident.u_nm.size, ident.waveform
        chk = 1 + cfg.acquisition.check_cycles * 2 * wf.half_cycle_samples  # the first check's
        np.testing.assert_array_equal(ident.history_u_nm[:m], ident.u_nm)
        np.testing.assert_array_equal(ident.history_u_nm[m + chk : 2 * m + chk], ident.u_nm)
        return
    assert len(notes) == 1 and "3.00 nm" in notes[0] and "the new record is used" in notes[0]
    assert not changed and ident.line_stability is calls[1]
    # the models were fitted on the second record, which starts the command history
    np.testing.assert_array_equal(first_fwd, traces[1][0])
    assert not np.array_equal(first_fwd, traces[0][0])
    np.testing.assert_array_equal(ident.history_u_nm[: ident.u_nm.size], ident.u_nm)
    assert ident.heldout_rms_nm["batch"] < 1.0


def test_rerecord_unstable_must_be_a_non_negative_integer():
    with pytest.raises(ValueError, match=r"rerecord_unstable must be an integer >= 0\. Got -1"):
        small(rerecord_unstable=-1)


def test_a_line_lost_while_settling_is_found_again_and_settled_again(monkeypatch):
    """When the last settling cycle no longer pairs enough particles, the line is searched
    again close by and scanned for ``relocate_settle_s`` more before the record. Here the
    loss is made: the settling cycle is said to pair no particle."""
    import piezocomp.identification.acquisition.recording as S

    settles = []
    real_settle = S.settle_on_line

    def settle(instrument, axis, cycle, slow, duration_s, dither_nm=0.0):
        settles.append((slow, duration_s))
        return real_settle(instrument, axis, cycle, slow, duration_s, dither_nm)

    monkeypatch.setattr(S, "settle_on_line", settle)
    monkeypatch.setattr(S, "cycle_pairs", lambda *a, **k: 0)
    afm = VirtualAFM.from_preset("gentle", seed=1, sample_period_s=0.008)
    cfg = small_quick(relocate_settle_s=120.0, extra_lines=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExcitationWarning)
        ident = identify_axis(InterfaceOnly(afm), cfg, "x")
    assert [d for _, d in settles] == [cfg.acquisition.line_settle_s, 120.0]
    assert settles[1][0] == ident.line.slow_nm  # settled again on the line found again


@pytest.mark.parametrize("name", ["line_settle_s", "relocate_settle_s"])
def test_settling_times_must_be_finite_and_non_negative(name):
    with pytest.raises(ValueError, match=rf"{name} must be >= 0\. Got -1\.0"):
        small(**{name: -1.0})
    with pytest.raises(ValueError, match=name):
        small(**{name: float("nan")})
