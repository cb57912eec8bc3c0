"""Drift tracking on a scanner without creep-and-hysteresis compensation ("drift only").

The landmarks are then imaged through the raw scanner, whose own error at a landmark is
measured (:mod:`piezocomp.drift.scanner_error`) and sizes the windows, the search and the
filter. These tests fail if that path regresses: the error's arithmetic, a landmark found
far from where the overview shows it, the tracker following a known drift within a bound
set by the error it measured, and the state surviving a restart.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezocomp.drift.compensated import DriftCompensatedInstrument, DriftSettings
from piezocomp.drift.landmarks import LandmarkSettings, Sighting, choose_landmarks, take_template
from piezocomp.drift.scanner_error import (
    MAX_WINDOW_FACTOR,
    SIGMAS,
    ScannerError,
    grown_window_nm,
    sized,
)
from piezocomp.imaging.features import find_particles
from piezocomp.instrument import ScanImage
from piezocomp.virtual_afm import VirtualAFM, load_config

BLANK = ScanImage(np.zeros((2, 2)), np.zeros((2, 2)), np.arange(2.0), np.arange(2.0), 1.0)


def seen(x, y):
    return Sighting(0.0, np.array([x, y]), np.zeros(2), 0.1, "", BLANK)


def missed():
    return Sighting(0.0, None, np.zeros(2), float("nan"), "no particle in the window", BLANK)


def scanner(hysteresis, creep, **drift):
    cfg = load_config("cpr5-nodrift")
    s = replace(cfg.scanner, hysteresis=hysteresis, hysteresis_small=hysteresis / 4,
                creep=creep, **drift)  # fmt: skip
    return VirtualAFM(replace(cfg, scanner=s), seed=3)


def true_drift(afm):
    return np.asarray(afm.truth.scanner_state.drift_nm)


def test_the_error_is_the_pooled_spread_of_repeated_sightings():
    """Two landmarks, three rounds: each landmark's sightings about its own mean, pooled
    over 4 degrees of freedom; a landmark missed in a round counts for what was seen."""
    rounds = [[seen(1.0, 0.0), seen(10.0, 5.0)], [seen(3.0, 0.0), missed()],
              [seen(2.0, 3.0), seen(14.0, 5.0)]]  # fmt: skip
    e = ScannerError.from_rounds(rounds)
    assert e is not None and e.dof == 3 and e.sightings == 5
    sx = np.sqrt(((1 - 2) ** 2 + 0 + (3 - 2) ** 2 + 2 * 2**2) / 3)
    sy = np.sqrt((1 + 1 + 4 + 0) / 3)
    np.testing.assert_allclose(e.sigma_nm, [sx, sy])
    assert e.window_nm == pytest.approx(3 * SIGMAS * max(sx, sy))
    assert ScannerError.from_rounds([[seen(1.0, 1.0), missed()]]) is None
    # covariance matching: an innovation adds its square less the prediction's variance
    more = e.with_innovations([[4.0, 0.0]], [1.0, 1.0])
    np.testing.assert_allclose(more.sum_sq_nm2, e.sum_sq_nm2 + np.array([15.0, -1.0]))
    assert more.dof == 4 and more.sightings == 6
    with pytest.raises(ValueError, match="dof"):
        ScannerError(np.ones(2), 0, 0)


def test_the_settings_are_sized_from_the_error():
    base = DriftSettings.uncompensated()
    e = ScannerError(np.array([9.0, 64.0]) * 4, 4, 5)  # sigma 3 and 8 nm
    w = grown_window_nm(base, 64.0, e, missed=False)
    assert w == pytest.approx(np.ceil(3 * SIGMAS * 8.0))  # a 3-sigma shift in a third of it
    s = sized(base, e, w)
    assert s.landmarks.window_nm == w and s.landmarks.pixels == base.landmarks.pixels
    assert s.landmarks.search_nm >= 2 * w
    assert s.noise.measurement_nm == pytest.approx(8.0)
    assert s.tolerance_nm == pytest.approx(8.0) and s.image_tolerance_nm >= 16.0
    grown = replace(s, landmarks=replace(s.landmarks, window_nm=100.0))
    assert grown_window_nm(grown, 64.0, e, missed=True) == 200.0  # a miss doubles it
    assert grown_window_nm(grown, 64.0, e, missed=False) == 100.0  # never shrinks
    huge = ScannerError(np.array([1e4, 1e4]), 1, 2)
    assert grown_window_nm(base, 64.0, huge, missed=True) == MAX_WINDOW_FACTOR * 64.0
    assert grown_window_nm(base, 64.0, None, missed=True) == 128.0


def test_the_compensated_defaults_are_unchanged():
    """The creep-and-hysteresis-compensated path (``DriftSettings()``) does none of this."""
    d = DriftSettings()
    assert not d.measure_scanner_error and d.overview_trace == "mean"
    assert d.landmarks.search_nm is None and d.landmarks.window_nm == 64.0
    u = DriftSettings.uncompensated()
    assert u.measure_scanner_error and u.overview_trace == "forward" and u.noise.order == 2
    with pytest.raises(ValueError, match="search_nm"):
        LandmarkSettings(search_nm=32.0)
    with pytest.raises(ValueError, match="overview_trace"):
        DriftSettings(overview_trace="both")


def test_a_landmark_far_from_where_the_overview_shows_it_is_found_by_a_search():
    """The overview of an uncompensated scanner can place a particle tens of nanometres
    from where a small window finds it: 47 nm off, a search of 256 nm finds it and
    centres the template on it."""
    afm = scanner(0.0, 0.0)
    settings = LandmarkSettings()
    overview = afm.scan_image((0.0, 0.0), 600.0, 128, 2.0)
    c = choose_landmarks(find_particles(overview, trace="mean"), settings)[0]
    off = c + np.array([40.0, -25.0])
    wide = replace(settings, search_nm=256.0)
    lm = take_template(afm, off, wide)
    assert lm is not None
    assert np.max(np.abs(lm.center_nm - c)) < 3.0
    p = find_particles(lm.template, trace="mean").positions_nm
    assert np.min(np.max(np.abs(p - lm.center_nm), axis=1)) < 3.0


def test_drift_only_follows_a_known_drift_within_its_measured_error():
    """A raw scanner with a little hysteresis and creep (2 %, 1 %) drifting 0.1 nm/s: the
    tracker measures its own error at the landmarks when it starts, and over ten minutes
    of moves its estimate follows the true drift (60 nm of it) within three times that
    error (plus the registration's nanometre)."""
    afm = scanner(0.02, 0.01, drift_nm_per_s=0.1, drift_random_walk_nm_per_sqrt_s=0.02)
    inst = DriftCompensatedInstrument(afm, DriftSettings.uncompensated())
    inst.start(center_nm=(0.0, 0.0), size_nm=800.0)
    err = inst.scanner_error
    assert err is not None and err.dof >= 3
    assert inst.settings.noise.measurement_nm == pytest.approx(np.max(err.sigma_nm))
    ref = true_drift(afm) - inst.drift_nm()  # from here on, increments are compared
    t0, worst, moved = inst.time_s, 0.0, 0.0
    rng = np.random.default_rng(1)
    while inst.time_s - t0 < 600.0:
        x, y = rng.uniform(-300, 300, 2)
        inst.move_to(float(x), float(y), 1000.0)
        inst.wait(20.0)
        truth = true_drift(afm) - ref
        worst = max(worst, float(np.max(np.abs(inst.drift_nm() - truth))))
        moved = float(np.hypot(*truth))
    bound = 3.0 * float(np.max(inst.scanner_error.sigma_nm)) + 1.0
    assert moved > 50.0
    assert worst < bound, f"{worst:.2f} nm off, bound {bound:.2f} nm"
    assert len(inst.measurements) >= 4 and all(m.drift_nm is not None for m in inst.measurements)


def test_on_cpr5_the_windows_grow_to_the_error_and_the_state_survives_a_restart(tmp_path):
    """The full ``cpr5`` without its compensator: landmark windows of 64 nm miss their
    landmarks after approaches from the overview's corners; they grow until they do not
    (at most four times), the error measured is several nanometres, and a saved state
    resumes with the same sized settings and error."""
    afm = VirtualAFM(load_config("cpr5-nodrift"), seed=1)
    inst = DriftCompensatedInstrument(afm, DriftSettings.uncompensated())
    inst.start(center_nm=(0.0, 0.0), size_nm=1000.0)
    err = inst.scanner_error
    assert err is not None and np.max(err.sigma_nm) > 2.0
    w = inst.settings.landmarks.window_nm
    assert 64.0 <= w <= MAX_WINDOW_FACTOR * 64.0 and w >= min(err.window_nm, 256.0) - 1
    assert len(inst.landmarks) == DriftSettings.uncompensated().landmarks.count
    inst.save(tmp_path / "t.npz")
    again = DriftCompensatedInstrument.load(tmp_path / "t.npz", afm)
    assert again.settings == inst.settings
    np.testing.assert_array_equal(again.scanner_error.sum_sq_nm2, err.sum_sq_nm2)
    assert again.scanner_error.dof == err.dof
    m = again.measure()
    assert again.scanner_error.sightings > err.sightings or m.drift_nm is None
