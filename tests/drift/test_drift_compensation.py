"""Drift compensation on the virtual AFM: landmarks, the wrapper, persistence, warm-up.

The scanners here have no creep or hysteresis (an ideal, drifting scanner) so that drift is
the only error: what the drift compensator must remove. Its composition with the creep and
hysteresis compensator is measured by ``piezocomp reproduce --preset cpr5``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from piezocomp.drift.compensated import DriftCompensatedInstrument, DriftSettings
from piezocomp.drift.landmarks import (
    LandmarkSettings,
    choose_landmarks,
    scan_window,
    sight,
    take_template,
)
from piezocomp.experiments.truth import true_image_position
from piezocomp.imaging.features import find_particles
from piezocomp.instrument import Instrument
from piezocomp.virtual_afm import VirtualAFM, load_config


def ideal(**drift):
    cfg = load_config("cpr5-nodrift")
    scanner = replace(cfg.scanner, hysteresis=0.0, hysteresis_small=0.0, creep=0.0, **drift)
    return VirtualAFM(replace(cfg, scanner=scanner), seed=3)


def true_drift(afm):
    return np.asarray(afm.truth.scanner_state.drift_nm)


@pytest.fixture(scope="module")
def session():
    """An ideal scanner drifting at 0.2 nm/s plus a random walk; tracking started."""
    afm = ideal(drift_nm_per_s=0.2, drift_random_walk_nm_per_sqrt_s=0.02)
    inst = DriftCompensatedInstrument(afm, DriftSettings(tolerance_nm=0.5))
    inst.start(center_nm=(0.0, 0.0), size_nm=800.0)
    inst.reference_nm = true_drift(afm)  # the true drift when tracking started (about)
    return afm, inst


def test_the_wrapper_is_an_instrument_and_needs_a_start(session):
    _, inst = session
    assert isinstance(inst, Instrument)
    fresh = DriftCompensatedInstrument(ideal())
    with pytest.raises(RuntimeError, match="start"):
        fresh.move_to(0.0, 0.0, 100.0)
    with pytest.raises(TypeError, match="Instrument"):
        DriftCompensatedInstrument(object())  # type: ignore[arg-type]


def test_an_area_stays_put_on_a_drifting_sample(session):
    """Images of one area ten minutes apart, with moves in between, coincide within a
    nanometre; the drift in that time is over a hundred."""
    afm, inst = session
    first = inst.scan_image((100.0, 50.0), 120.0, 48, 2.0)
    d0 = true_drift(afm)
    rng = np.random.default_rng(1)
    while inst.time_s - first.t_start_s < 600.0:
        x, y = rng.uniform(-300, 300, 2)
        inst.move_to(float(x), float(y), 1000.0)
        inst.wait(20.0)
    second = inst.scan_image((100.0, 50.0), 120.0, 48, 2.0)
    moved = np.hypot(*(true_drift(afm) - d0))
    error = np.hypot(*(true_image_position(afm.truth, second)
                       - true_image_position(afm.truth, first)))  # fmt: skip
    assert moved > 100.0
    assert error < 1.0, f"{error:.2f} nm after {moved:.0f} nm of drift"
    assert 0 < inst.overhead_fraction < 0.3
    assert all(m.drift_nm is not None for m in inst.measurements)


def test_an_image_longer_than_the_tolerance_allows_is_measured_during_it():
    """A 6-minute image on a scanner drifting 0.2 nm/s: the drift is measured between its
    lines when due, the lines' start times go with the image (the truth reads them), and
    the whole image stays fixed to the sample within a nanometre of a short one's place."""
    afm = ideal(drift_nm_per_s=0.2, drift_random_walk_nm_per_sqrt_s=0.02)
    inst = DriftCompensatedInstrument(afm, DriftSettings(tolerance_nm=0.5))
    inst.start(center_nm=(0.0, 0.0), size_nm=800.0)
    short = inst.scan_image((100.0, 50.0), 120.0, 48, 2.0)
    n = len(inst.measurements)
    long_ = inst.scan_image((100.0, 50.0), 120.0, 96, 0.25)  # 384 s of lines
    assert len(inst.measurements) - n >= 2
    starts = long_.line_start_s
    assert starts is not None and np.any(np.diff(starts) > 1.5 * long_.line_time_s)
    fwd, _ = long_.pixel_times_s()
    np.testing.assert_allclose(fwd[:, 0], starts)
    error = np.hypot(*(true_image_position(afm.truth, long_)
                       - true_image_position(afm.truth, short)))  # fmt: skip
    assert error < 1.0, f"{error:.2f} nm"


def test_a_landmark_that_was_pushed_is_never_trusted(session):
    afm, inst = session
    lm = inst.landmarks[0]
    c = lm.center_nm + lm.offset_nm  # where it is on the sample
    inst.move_to(float(c[0] - 40.0), float(c[1]), 1000.0)
    inst.push(float(c[0] + 30.0), float(c[1]), 200.0)  # 30 nm to the right
    m = inst.measure()
    assert 0 in m.replaced
    if m.drift_nm is not None:  # trusted only from the landmark that stayed
        assert np.max(np.abs(m.drift_nm - (true_drift(afm) - inst.reference_nm))) < 3.0
    assert len(inst.landmarks) >= 1


def test_a_landmark_missed_by_its_window_is_not_trusted():
    afm = ideal()
    settings = LandmarkSettings()
    overview = afm.scan_image((0.0, 0.0), 600.0, 128, 2.0)
    c = choose_landmarks(find_particles(overview, trace="mean"), settings)[0]
    lm = take_template(afm, c + 12.0, settings)  # recentred on the particle
    assert lm is not None
    assert np.max(np.abs(find_particles(lm.template, trace="mean").positions_nm[0]
                         - lm.center_nm)) < 2.0  # fmt: skip
    good = sight(afm, lm, (3.0, -2.0), settings)  # a prediction 3.6 nm off: measured
    assert good.drift_nm is not None and np.max(np.abs(good.drift_nm)) < 0.5
    for a in np.arange(4) * np.pi / 2:  # 40 nm off: refused, never a wrong drift
        bad = sight(afm, lm, 40.0 * np.array([np.cos(a), np.sin(a)]), settings)
        assert bad.drift_nm is None and bad.reason


class MoveLog:
    """An instrument that records its moves and forwards everything else."""

    def __init__(self, inner):
        self.inner, self.moves = inner, []

    def move_to(self, x, y, speed):
        self.moves.append((x, y))
        return self.inner.move_to(x, y, speed)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def test_every_window_is_entered_by_the_same_final_move():
    """``approach_nm``: the window's first pixel is reached from the same point before it
    (below and to the left), wherever the tip was; 0 goes straight there; a negative
    approach is refused."""
    afm = MoveLog(ideal())
    c = np.array([40.0, -30.0])
    first = c - 0.5 * 64.0 * (1 - 1 / 32)
    for start in ((300.0, 200.0), (-250.0, 100.0)):
        afm.inner.move_to(*start, 1000.0)
        afm.moves.clear()
        scan_window(afm, c, LandmarkSettings(approach_nm=150.0))
        np.testing.assert_allclose(afm.moves, [first - 150.0, first])
    afm.moves.clear()
    scan_window(afm, c, LandmarkSettings())
    np.testing.assert_allclose(afm.moves, [first])
    with pytest.raises(ValueError, match="approach_nm"):
        LandmarkSettings(approach_nm=-1.0)


def particle_area(inst):
    """The centre of a 120 nm area about a particle of an overview, away from the landmarks."""
    p = find_particles(inst.scan_image((0.0, 0.0), 500.0, 96, 4.0), trace="mean").positions_nm
    marks = np.array([lm.center_nm for lm in inst.landmarks])
    far = [q for q in p if np.min(np.hypot(*(marks - q).T)) > 150.0]
    return (float(far[0][0]), float(far[0][1]))


def true_drift_over(afm, img):
    """The true drift about the middle of an image (the scanner's drift at its end, less
    half an image's worth at the drift's rate: this test's drift is steady)."""
    fwd, _ = img.pixel_times_s()
    half = 0.5 * (float(np.max(fwd)) - float(np.min(fwd)))
    rate = afm.config.scanner.drift_nm_per_s
    a = math.radians(afm.config.scanner.drift_direction_deg)
    return true_drift(afm) - half * rate * np.array([math.cos(a), math.sin(a)])


def tracked(afm):
    """Tracking started with tolerances loose enough that no landmark is due in a minute."""
    inst = DriftCompensatedInstrument(afm, DriftSettings(tolerance_nm=5.0,
                                                         image_tolerance_nm=10.0))  # fmt: skip
    inst.start(center_nm=(0.0, 0.0), size_nm=800.0)
    return inst


def test_an_area_imaged_again_is_a_drift_sighting_that_costs_no_time():
    """``scan_area``: the first image of an area is its reference; the next one measures the
    drift less the reference's own miss (against the truth, within the registration's
    precision) without adding to the time spent measuring; another raster under the same
    name is refused."""
    afm = ideal(drift_nm_per_s=0.2)
    inst = tracked(afm)
    reference = true_drift(afm)
    area = particle_area(inst)
    first = inst.scan_area("A", area, 120.0, 48, 4.0)
    miss = true_drift_over(afm, first) - reference - inst.areas["A"].offset_nm
    n, busy = len(inst.measurements), inst.measuring_s
    inst.wait(20.0)
    img = inst.scan_area("A", area, 120.0, 48, 4.0)
    new = inst.measurements[n:]
    assert [m.area for m in new] == ["A"], "the wait's measurement or the sighting missing"
    m = new[0]
    assert m.duration_s == 0.0 and inst.measuring_s == busy
    assert m.drift_nm is not None
    truth = true_drift_over(afm, img) - reference
    assert np.max(np.abs(m.drift_nm - (truth - miss))) < 0.2
    assert inst.estimate.t_s == m.t_s  # taken into the estimate
    with pytest.raises(ValueError, match="must have the same raster"):
        inst.scan_area("A", area, 120.0, 64, 4.0)


def test_an_area_that_changed_is_not_taken_for_drift():
    """A particle pushed out of an area between two of its images: the second is recorded
    with its reason and the estimate is left as it was."""
    afm = ideal(drift_nm_per_s=0.05)
    inst = tracked(afm)
    area = particle_area(inst)
    first = inst.scan_area("A", area, 120.0, 48, 4.0)
    p = find_particles(first, trace="mean").positions_nm
    c = p[np.argmin(np.hypot(*(p - np.asarray(area)).T))]
    inst.move_to(float(c[0] - 40.0), float(c[1]), 1000.0)
    inst.push(float(c[0] + 90.0), float(c[1]), 200.0)
    estimate = inst.estimate
    inst.scan_area("A", area, 120.0, 48, 4.0)
    m = inst.measurements[-1]
    assert m.area == "A" and m.drift_nm is None and m.sightings[0].reason
    assert inst.estimate is estimate


def test_tracking_survives_a_restart(tmp_path, session):
    afm, inst = session
    path = tmp_path / "tracking.npz"
    inst.scan_area("here", (-80.0, 20.0), 100.0, 32, 4.0)  # an area's reference goes too
    inst.save(path)
    again = DriftCompensatedInstrument.load(path, afm)
    assert len(again.landmarks) == len(inst.landmarks)
    ((name, ref),) = again.areas.items()
    assert name == "here"
    np.testing.assert_array_equal(ref.template.forward_nm,
                                  inst.areas["here"].template.forward_nm)  # fmt: skip
    np.testing.assert_array_equal(ref.offset_nm, inst.areas["here"].offset_nm)
    # the measurement noise learnt from the sightings goes on from where it was
    assert inst.sighting_spread is not None
    assert again.sighting_spread == inst.sighting_spread
    assert (
        again.measurement_sigma_nm
        == inst.measurement_sigma_nm
        != inst.settings.noise.measurement_nm
    )
    t = inst.time_s + 100.0
    np.testing.assert_allclose(again.drift_nm(t), inst.drift_nm(t))
    np.testing.assert_allclose(again.landmarks[0].template.forward_nm,
                               inst.landmarks[0].template.forward_nm)  # fmt: skip
    m = again.measure()
    assert m.drift_nm is not None
    (tmp_path / "bad.npz").write_bytes(b"not a state")
    with pytest.raises(ValueError, match="not a readable drift-tracking state"):
        DriftCompensatedInstrument.load(tmp_path / "bad.npz", afm)


def test_warm_up_drift_decays_as_configured():
    w, tau = 0.3, 120.0
    afm = ideal(drift_warmup_nm_per_s=w, drift_warmup_time_s=tau, drift_direction_deg=0.0)
    afm.wait(360.0)
    expected = w * tau * (1 - math.exp(-360.0 / tau))
    np.testing.assert_allclose(true_drift(afm), [expected, 0.0], rtol=1e-6, atol=1e-9)
    cfg = load_config({"scanner": {"drift_warmup_nm_per_s": 0.3}})
    assert cfg.drifts and not load_config("cpr5-nodrift").drifts


def test_a_long_wait_is_measured_during_it():
    """A 5-minute wait (Table I's settling) on a scanner drifting 0.2 nm/s is measured
    between its pieces, and the tip stays over its point of the sample; held in one piece,
    the prediction would have gone 60 nm past the landmarks' 64 nm windows."""
    afm = ideal(drift_nm_per_s=0.2, drift_random_walk_nm_per_sqrt_s=0.02)
    inst = DriftCompensatedInstrument(afm, DriftSettings(tolerance_nm=0.5))
    inst.start(center_nm=(0.0, 0.0), size_nm=800.0)
    inst.move_to(50.0, -30.0, 1000.0)
    n = len(inst.measurements)
    rec = inst.wait(300.0)
    assert len(inst.measurements) - n >= 3
    assert np.all(np.diff(rec.t_s) > 0) and np.ptp(rec.command_nm, axis=0).max() == 0.0
    on_sample = afm.truth.last_record_positions_nm + afm.truth.last_record_drift_nm
    first = inst.measurements[n]
    later = [m for m in inst.measurements[n + 1 :] if m.drift_nm is not None]
    assert later and first.drift_nm is not None
    # every piece held the same sample point: the last piece's true sample position is
    # where the first measurement's drift put the tip, within the filter's accuracy
    assert np.max(np.ptp(on_sample, axis=0)) < 1.0, np.ptp(on_sample, axis=0)


def test_an_uncertain_prediction_is_searched_for_before_it_is_sighted():
    """Five minutes without a measurement on a scanner drifting 0.2 nm/s, the filter told
    the drift may wander 2 nm/sqrt(s): the prediction is 60 nm off, beyond the landmark
    windows, and uncertain by about as much. The landmarks are looked for in a wider
    window first and the drift measured within a nanometre, not lost."""
    afm = ideal(drift_nm_per_s=0.2)
    noise = replace(DriftSettings().noise, position_nm_per_sqrt_s=2.0)
    inst = DriftCompensatedInstrument(afm, DriftSettings(noise=noise, learn_noise_after=10**6))
    inst.start(center_nm=(0.0, 0.0), size_nm=800.0)
    d0 = true_drift(afm)
    afm.wait(300.0)  # the wrapped instrument, behind the compensator's back
    assert np.max(np.abs(inst.drift_nm(inst.inner.time_s))) < 10.0  # it does not know
    m = inst.measure()
    assert m.drift_nm is not None and not m.replaced
    err = np.max(np.abs(m.drift_nm - (true_drift(afm) - d0)))
    assert err < 1.5, f"{err:.2f} nm off after {np.hypot(*(true_drift(afm) - d0)):.0f} nm"


def test_a_push_that_waits_for_a_measurement_starts_where_it_was_asked():
    """A push due a drift measurement measures first, then goes back to its start with Z
    feedback on: never a push dragged from the landmark the tip was measuring at."""
    afm = ideal(drift_nm_per_s=0.2)
    # the prior measurement noise (not one learnt from a single measurement) keeps the
    # uncertainty after the wait above the tolerance
    settings = DriftSettings(tolerance_nm=0.5, learn_measurement_noise=False)
    inst = DriftCompensatedInstrument(afm, settings)
    inst.start(center_nm=(0.0, 0.0), size_nm=800.0)
    inst.move_to(100.0, -50.0, 1000.0)
    afm.wait(120.0)  # behind the compensator's back: the push is due a measurement
    pushed = []
    run = afm.run

    def logged(commands, **kw):
        if not kw.get("z_feedback", True):
            pushed.append(np.asarray(commands)[0] + inst.drift_nm(afm.time_s))
        return run(commands, **kw)

    afm.run = logged  # type: ignore[method-assign]
    n = len(inst.measurements)
    inst.push(160.0, -50.0, 200.0)
    assert len(inst.measurements) > n and len(pushed) == 1
    # within what the estimate before the measurement knew of where the tip was
    assert np.hypot(*(pushed[0] - (100.0, -50.0))) < 3.0, pushed[0]
