"""The length reference: the model's scale from a grating of known pitch."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from piezocomp.identification.acquisition.waveforms import identification_waveform
from piezocomp.identification.estimation.prediction import record_state
from piezocomp.identification.reference.frames import mapped
from piezocomp.identification.reference.grating import (
    MIN_PASS_PITCHES,
    GratingRecord,
    measure_grating,
)
from piezocomp.identification.reference.scaling import (
    angle_findings,
    fit_scale,
    folded,
    scale_of_positions,
)
from piezocomp.model import ScannerModel, simulate
from piezocomp.virtual_afm import Grating, VirtualAFM

T = 0.008
PITCH = 278.0


def _pi_creep_model() -> ScannerModel:
    return ScannerModel(
        offset_nm=3.0,
        gain=0.7,
        thresholds_nm=np.array([50.0, 150.0, 300.0, 600.0]),
        weights=np.array([0.15, 0.1, 0.05, 0.03]),
        creep_time_constants_s=np.array([0.5, 20.0]),
        creep_gains=np.array([0.05, 0.08]),
    )


def _grating_heights(y: np.ndarray, shift_nm: float, rng: np.random.Generator) -> np.ndarray:
    ph = 2 * np.pi * (y - shift_nm) / PITCH
    return 12.5 * (1 + np.cos(ph)) + 0.4 * np.cos(2 * ph + 0.3) + 0.1 * rng.standard_normal(y.size)


def _synthetic_record(
    true: ScannerModel, shifts: tuple[float, ...], span_nm: float = 1000.0
) -> GratingRecord:
    """Heights of a sinusoidal grating at the positions of an exact PI + creep model, one
    line per shift (lines whose grating phase differs, as on a slightly rotated grating)."""
    rng = np.random.default_rng(5)
    wf = identification_waveform(0.0, span_nm, 250.0, T, n_steady=4, n_decaying=0, n_random=0)
    u = np.tile(wf.u_nm, len(shifts))
    y, _ = simulate(true, u, T, record_state(true, float(u[0])))
    n = wf.u_nm.size
    z = np.concatenate(
        [_grating_heights(y[i * n : (i + 1) * n], s, rng) for i, s in enumerate(shifts)]
    )
    passes, lines = [], []
    for i in range(len(shifts)):
        for c in range(1, 4):
            for sl in (wf.ascending(c), wf.descending(c)):
                passes.append((i * n + sl.start, i * n + sl.stop))
                lines.append(i)
    return GratingRecord("x", PITCH, u, z, T, tuple(passes), tuple(lines))


@pytest.mark.parametrize("scale", [0.8, 1.07, 1.25])
def test_recovers_the_scale_of_an_exact_model(scale):
    """Mathematics only: the heights come from the model family itself."""
    true = _pi_creep_model()
    record = _synthetic_record(true, (0.0, 40.0))
    fit = fit_scale(mapped(true, 1.0 / scale, 0.0), record)
    assert fit.alpha == pytest.approx(scale, rel=2e-4)
    assert len(fit.line_alphas) == 2 and fit.n_passes == 12
    assert fit.alpha_std < 1e-3 and fit.residual_rms_nm == pytest.approx(0.1, rel=0.2)
    assert fit.period_nm == pytest.approx(PITCH / scale, rel=2e-4)


@pytest.mark.parametrize("span", [2000.0, 3000.0, 4000.0])
def test_a_multiple_of_the_period_is_not_taken_for_it(span):
    """Mathematics only. Three harmonics of twice the pitch hold every series of the pitch
    itself, and the period search's 3 % grid steps: with the scale 1.0066 the grid point
    nearest twice the period (inside the search window, up to twice the pitch) lies closer
    to it than the grid point nearest the period does, and on long passes that once decided
    it, putting the scale off by a factor 2. The fundamental is taken."""
    true = _pi_creep_model()
    fit = fit_scale(mapped(true, 1.0 / 1.0066, 0.0), _synthetic_record(true, (0.0,), span))
    assert fit.alpha == pytest.approx(1.0066, rel=1e-3)


def test_an_implausible_scale_is_refused():
    from piezocomp.identification.reference.scaling import check_plausible

    true = _pi_creep_model()
    record = _synthetic_record(true, (0.0, 40.0))
    check_plausible(fit_scale(mapped(true, 1.0 / 0.8, 0.0), record))  # 0.8: plausible
    with pytest.raises(ValueError, match=r"outside the plausible 0\.6-1\.4"):
        check_plausible(fit_scale(mapped(true, 1.0 / 1.6, 0.0), record))


def test_prescale_moves_the_search_window_and_not_the_answer():
    """Mathematics only. A model 2.6 times too long puts the grating's period outside the
    search window; told its frame's scale first (``prescale``), the fit finds it, and the
    fit it returns is for the model as given: the same ``alpha``, periods and shifts as a
    fit of the model without the belief where both succeed."""
    true = _pi_creep_model()
    record = _synthetic_record(true, (0.0, 40.0))
    long = mapped(true, 2.6, 0.0)
    with pytest.raises(ValueError, match="period was not found"):
        fit_scale(mapped(true, 2.3, 0.0), record)
    # farther off, a period inside the window fits the heights badly: refused, not returned
    with pytest.raises(ValueError, match=r"leaves 8\.\d\d nm rms of the heights' 8\.\d\d nm"):
        fit_scale(long, record)
    fit = fit_scale(long, record, prescale=1 / 2.5)
    assert fit.alpha == pytest.approx(1 / 2.6, rel=2e-4)
    assert fit.period_nm == pytest.approx(2.6 * PITCH, rel=2e-4)
    x, z, _ = folded(long, record, fit)
    assert np.std(z - fit.profile(x)) == pytest.approx(0.1, rel=0.15)
    a, b = fit_scale(true, record), fit_scale(true, record, prescale=1.1)
    assert b.alpha == pytest.approx(a.alpha, rel=1e-9)
    np.testing.assert_allclose(b.pass_shifts_nm, a.pass_shifts_nm, atol=1e-6)
    np.testing.assert_allclose(b.line_periods_nm, a.line_periods_nm, rtol=1e-9)
    with pytest.raises(ValueError, match=r"prescale must be > 0\. Got 0\.0"):
        fit_scale(true, record, prescale=0.0)


def test_folded_heights_follow_the_fitted_profile():
    """Folded onto one period with the fit's shifts and periods, every pass lies on the
    fitted profile to the noise (0.1 nm); a wrong period smears them."""
    true = _pi_creep_model()
    record = _synthetic_record(true, (0.0, 40.0))
    fit = fit_scale(true, record)
    assert len(fit.pass_shifts_nm) == len(record.passes) and fit.pitch_nm == PITCH
    x, z, line = folded(true, record, fit)
    assert x.min() >= 0.0 and x.max() < PITCH and set(line) == {0, 1}
    assert np.std(z - fit.profile(x)) == pytest.approx(0.1, rel=0.15)
    off = replace(fit, line_periods_nm=tuple(a / 1.01 for a in fit.line_periods_nm))
    x2, z2, _ = folded(true, record, off)
    assert np.std(z2 - fit.profile(x2)) > 0.4  # 1 % off: 0.58 nm
    with pytest.raises(ValueError, match="pass shifts"):
        folded(true, record, replace(fit, pass_shifts_nm=(0.0,)))


def test_one_line_gives_the_fit_standard_error():
    true = _pi_creep_model()
    fit = fit_scale(true, _synthetic_record(true, (0.0,)))
    assert fit.alpha == pytest.approx(1.0, abs=2e-4) and len(fit.line_alphas) == 1
    assert 0 < fit.alpha_std < 1e-4


def test_measure_grating_on_the_virtual_afm_agrees_with_the_true_positions():
    """A model with no hysteresis (y = u) is scaled to the scanner's true slope over the
    passes (least squares with an intercept per pass): the grating sees only heights, the
    check reads the truth. One line's roughness moves the scale by up to ~0.15 % (measured
    0.01 % on seed 3, 0.12 % on seed 4); the bound is 0.2 %."""
    g = VirtualAFM.from_preset(
        "gentle", seed=3, sample_period_s=T, grating=Grating(PITCH, axis="x")
    )
    t0 = g.time_s
    rec = measure_grating(g, PITCH, center_nm=(0.0, 0.0), n_lines=1, n_cycles=4, skip_cycles=1)
    assert len(rec.passes) == 6 and rec.n_lines == 1
    # instrument time of this run; a copy read back from its file was made earlier
    assert rec.measured_in_run and rec.duration_s == pytest.approx(g.time_s - t0)
    assert not GratingRecord.from_dict(rec.to_dict()).measured_in_run
    truth = np.asarray(g.truth.last_record_positions_nm)[:, 0]
    n_move = rec.u_nm.size - truth.size
    num = den = 0.0
    for a, b in rec.passes:
        u, y = rec.u_nm[a:b], truth[a - n_move : b - n_move]
        assert np.ptp(u) == pytest.approx(1000.0, abs=1e-6)
        du = u - u.mean()
        num, den = num + du @ (y - y.mean()), den + du @ du
    fit = fit_scale(ScannerModel(), rec)
    assert fit.alpha == pytest.approx(num / den, rel=2e-3)
    assert fit.alpha < 0.99  # the gentle scanner's +-500 nm cycle is narrower than commanded


class _KeepsExtension:
    """A virtual AFM whose every record's true extension is kept, in order (for checks)."""

    def __init__(self, afm: VirtualAFM) -> None:
        self.afm, self.extension = afm, []

    def __getattr__(self, name):
        attr = getattr(self.afm, name)
        if name not in ("run", "move_to"):
            return attr

        def kept(*args, **kwargs):
            rec = attr(*args, **kwargs)
            self.extension.append(np.array(self.afm.truth.last_record_extension_nm))
            return rec

        return kept


@pytest.mark.parametrize("axis", ["x", "y"])
def test_the_minor_loop_path_reads_the_true_extension(axis):
    """The minor-loop path's passes are its sweeps, monotone, of 70 % of the span and three
    pitches or more, two rising and two falling on every line; the grating's fit run on the
    scanner's true extension (not a model's) reads a scale of 1 within 0.05 %: what the
    measurement itself adds (roughness, noise, the drift between directions)."""
    k = 0 if axis == "x" else 1
    lab = _KeepsExtension(
        VirtualAFM.from_preset("cpr5", seed=3, sample_period_s=T, grating=Grating(PITCH, axis=axis))
    )
    rec = measure_grating(lab, PITCH, axis=axis, span_nm=2000.0, n_lines=2, path="minor_loops")
    lines = np.array(rec.pass_lines)
    for line in set(rec.pass_lines):
        dirs = [
            np.sign(rec.u_nm[b - 1] - rec.u_nm[a])
            for (a, b), j in zip(rec.passes, lines, strict=True)
            if j == line
        ]
        assert dirs.count(1.0) == dirs.count(-1.0) == 2
    for a, b in rec.passes:
        step = np.diff(rec.u_nm[a:b])
        assert np.all(step > 0) or np.all(step < 0)
        assert abs(rec.u_nm[b - 1] - rec.u_nm[a]) >= max(MIN_PASS_PITCHES * PITCH, 1400.0)
    truth = np.concatenate([e[:, k] for e in lab.extension])
    assert truth.size == rec.u_nm.size
    assert scale_of_positions(truth, rec).alpha == pytest.approx(1.0, abs=5e-4)
    with pytest.raises(ValueError, match=r"positions_nm must hold one value per record sample"):
        scale_of_positions(truth[:-1], rec)


def _true_slope(afm: VirtualAFM, rec: GratingRecord, axis: int = 0) -> float:
    """Least-squares slope of the true extension against the command over the passes of
    the LAST line (an intercept per pass)."""
    truth = np.asarray(afm.truth.last_record_positions_nm)[:, axis]
    n_move = rec.u_nm.size - truth.size
    num = den = 0.0
    for a, b in rec.passes:
        if a < n_move:
            continue
        u, y = rec.u_nm[a:b], truth[a - n_move : b - n_move]
        du = u - u.mean()
        num, den = num + du @ (y - y.mean()), den + du @ du
    return num / den


@pytest.mark.parametrize(("axis", "path"), [("x", "steady"), ("y", "steady"), ("x", "minor_loops")])
def test_a_rotated_grating_is_measured_and_corrected(axis, path):
    """A grating 6 degrees off square shows the axis a pitch 0.55 % longer; the lines'
    shifts give the angle (within a degree: the slow axis' own hysteresis moves it less or
    more than its nominal distance between lines) and the scale is corrected to within
    0.2 % of the true slope, on either path. Without the lines' slow commands it is 0.5 %
    off."""
    g = VirtualAFM.from_preset(
        "gentle", seed=3, sample_period_s=T, grating=Grating(PITCH, axis=axis, angle_deg=6.0)
    )
    span = 1000.0 if path == "steady" else 2000.0
    rec = measure_grating(g, PITCH, axis=axis, n_lines=3, span_nm=span, path=path)
    slope = _true_slope(g, rec, 0 if axis == "x" else 1)
    fit = fit_scale(ScannerModel(), rec)
    assert 5.0 < fit.angle_deg < 6.5
    assert fit.alpha == pytest.approx(slope, rel=2e-3)
    # folded with the fit's own periods, every pass lies on the fitted profile
    x, z, _ = folded(ScannerModel(), rec, fit)
    assert np.sqrt(np.mean((z - fit.profile(x)) ** 2)) == pytest.approx(
        fit.residual_rms_nm, rel=1e-6
    )
    blind = fit_scale(ScannerModel(), replace(rec, line_slow_nm=None))
    assert np.isnan(blind.angle_deg)
    assert blind.alpha / slope - 1 < -3e-3
    # a user is told when the angle is large, or could not be measured (one line)
    assert "6.0 degrees off square" in angle_findings(replace(fit, angle_deg=6.0))[0]
    assert angle_findings(replace(fit, angle_deg=4.0)) == []
    one = replace(fit, angle_deg=float("nan"), line_alphas=(fit.alpha,))
    assert "one grating line" in angle_findings(one)[0]


@pytest.mark.parametrize(
    ("angle", "path"), [(0.0, "steady"), (6.0, "steady"), (6.0, "minor_loops")]
)
def test_drift_along_the_axis_is_not_read_as_the_grating_angle(angle, path):
    """Lines are scanned one after the other: a tip drifting 0.35 nm/s along the axis (a
    scanner warming up) shifts the crests between two lines 100 nm apart as much as a
    grating 17 degrees off square would (what the fit read before, putting the 1/cos pitch
    correction 4.6 % off). Each line's passes measure the drift; it is taken out of the
    angle and reported."""
    g0 = VirtualAFM.from_preset("gentle", seed=3, sample_period_s=T)
    scanner = replace(g0.config.scanner, drift_nm_per_s=0.35, drift_direction_deg=0.0)
    g = VirtualAFM(
        replace(g0.config, scanner=scanner),
        seed=3,
        sample_period_s=T,
        grating=Grating(PITCH, angle_deg=angle),
    )
    span = 1000.0 if path == "steady" else 2000.0
    rec = measure_grating(g, PITCH, n_lines=3, span_nm=span, path=path)
    fit = fit_scale(ScannerModel(), rec)
    assert fit.angle_deg == pytest.approx(angle, abs=0.5)
    # the minor loops' histories differ from sweep to sweep, and a model without hysteresis
    # leaves that in the shifts: the rate is read less well (0.374 here), the angle as well
    assert fit.drift_nm_per_s == pytest.approx(0.35, abs=0.02 if path == "steady" else 0.04)
    assert fit.alpha == pytest.approx(_true_slope(g, rec, 0), rel=5e-4)


def test_several_lines_and_their_record():
    g = VirtualAFM.from_preset("gentle", seed=3, sample_period_s=T, grating=Grating(PITCH))
    rec = measure_grating(g, PITCH, n_lines=3, line_spacing_nm=80.0, n_cycles=3, skip_cycles=1)
    # three lines 80 nm apart and the angle line 100 nm from the centre, in slow order
    assert rec.pass_lines == (0,) * 4 + (1,) * 4 + (2,) * 4 + (3,) * 4 and rec.n_lines == 4
    assert rec.line_slow_nm == (-80.0, 0.0, 80.0, 100.0)
    assert g.command_nm[1] == pytest.approx(100.0)  # the last line is +100 nm off the centre
    back = GratingRecord.from_dict(json.loads(json.dumps(rec.to_dict())))
    assert back.passes == rec.passes and back.pass_lines == rec.pass_lines
    np.testing.assert_array_equal(back.u_nm, rec.u_nm)
    fit = fit_scale(ScannerModel(), rec)
    assert len(fit.line_alphas) == 4 and fit.alpha_std < 2e-3


def test_lines_spread_over_the_range_and_a_close_pair_reads_a_large_angle():
    """By default the lines are 1000 nm apart (as far as the other axis' range allows), with
    one more line 100 nm from the centre. Lines that far apart see crests shifted by more
    than half a period at 12 degrees; the close pair unwraps them."""
    g = VirtualAFM.from_preset(
        "gentle", seed=4, sample_period_s=T, grating=Grating(PITCH, angle_deg=12.0)
    )
    rec = measure_grating(g, PITCH, n_lines=3, n_cycles=3, skip_cycles=1)
    assert rec.line_slow_nm == (-1000.0, 0.0, 100.0, 1000.0)
    fit = fit_scale(ScannerModel(), rec)
    assert fit.angle_deg == pytest.approx(12.0, abs=0.7)
    assert fit.alpha == pytest.approx(_true_slope(g, rec, 0), rel=2e-3)
    # a small scanner: the spacing shrinks to fit 90 % of the half range
    small = VirtualAFM(
        replace(g.config, scanner=replace(g.config.scanner, range_nm=2000.0)),
        sample_period_s=T,
        grating=Grating(PITCH),
    )
    rec = measure_grating(small, PITCH, n_lines=5, n_cycles=3, skip_cycles=1)
    assert min(rec.line_slow_nm) == pytest.approx(-900.0) and max(rec.line_slow_nm) == 900.0
    with pytest.raises(ValueError, match=r"outside its range.*line_spacing_nm \(got 600\)"):
        measure_grating(small, PITCH, n_lines=5, line_spacing_nm=600.0)


def test_bad_records_and_arguments_are_refused():
    u = np.linspace(-500.0, 500.0, 200)
    z = np.zeros(200)
    good = dict(axis="x", pitch_nm=PITCH, u_nm=u, height_nm=z, sample_period_s=T)
    with pytest.raises(ValueError, match="u_nm"):
        GratingRecord(**{**good, "u_nm": np.r_[u[:-1], np.nan]}, passes=((0, 100), (100, 200)))
    with pytest.raises(ValueError, match="one length"):
        GratingRecord(**{**good, "height_nm": z[:-1]}, passes=((0, 100), (100, 200)))
    with pytest.raises(ValueError, match=r"pass \[150, 250\)"):
        GratingRecord(**good, passes=((0, 100), (150, 250)))
    with pytest.raises(ValueError, match=">= 2 passes"):
        GratingRecord(**good, passes=((0, 100),))
    with pytest.raises(ValueError, match="pass_lines"):
        GratingRecord(**good, passes=((0, 100), (100, 200)), pass_lines=(0,))
    with pytest.raises(ValueError, match="pitch_nm and sample_period_s must be > 0"):
        GratingRecord(**{**good, "pitch_nm": -1.0}, passes=((0, 100), (100, 200)))
    with pytest.raises(ValueError, match="must hold exactly the keys"):
        GratingRecord.from_dict({"axis": "x"})
    body = GratingRecord(**good, passes=((0, 100), (100, 200))).to_dict()
    body["u_nm"] = body["u_nm"][:10]
    with pytest.raises(ValueError, match="grating record: u_nm and height_nm"):
        GratingRecord.from_dict(body)
    # passes too short for two periods of a coarse grating
    coarse = GratingRecord(**{**good, "pitch_nm": 3000.0}, passes=((0, 100), (100, 200)))
    with pytest.raises(ValueError, match="less than two periods"):
        fit_scale(ScannerModel(), coarse)
    g = VirtualAFM.from_preset("gentle", grating=Grating())
    with pytest.raises(ValueError, match=r"pitch_nm must be > 0\. Got -5\.0"):
        measure_grating(g, -5.0)
    assert g.time_s == 0.0  # refused before anything moved
    with pytest.raises(TypeError, match=r"model must be a ScannerModel\. Got str"):
        fit_scale("model", coarse)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="n_cycles - skip_cycles must be >= 1"):
        measure_grating(g, PITCH, n_cycles=2, skip_cycles=2)
    with pytest.raises(ValueError, match="n_lines must be >= 1"):
        measure_grating(g, PITCH, n_lines=0)
    with pytest.raises(ValueError, match=r"path must be one of .* Got 'zigzag'"):
        measure_grating(g, PITCH, path="zigzag")
    with pytest.raises(ValueError, match=r"n_sweeps must be an even integer >= 2\. Got 3"):
        measure_grating(g, PITCH, span_nm=2000.0, path="minor_loops", n_sweeps=3)
    with pytest.raises(
        ValueError, match=r"span_nm 600 must hold 3 pitches \(278 nm\) in 70% of it"
    ):
        measure_grating(g, PITCH, span_nm=600.0, path="minor_loops")
    assert g.time_s == 0.0


def test_an_rls_model_far_off_is_left_unscaled_with_a_note(monkeypatch):
    import piezocomp.identification.reference.scaling as S

    g = VirtualAFM.from_preset(
        "gentle", seed=3, sample_period_s=T, grating=Grating(PITCH, angle_deg=6.5)
    )
    rec = measure_grating(g, PITCH, n_lines=2, n_cycles=3, skip_cycles=1)
    models = {"rls": ScannerModel(gain=1.01), "batch": ScannerModel()}
    notes: list[str] = []
    fits = S.scale_fits(models, rec, {"rls": 0.3, "batch": 0.2}, notes)
    assert sorted(fits) == ["batch", "rls"] and fits["rls"].alpha < fits["batch"].alpha
    assert len(notes) == 1 and "off square" in notes[0]  # the grating's angle finding
    real = S.fit_scale

    def no_period_for_the_rls(model, record, **kw):  # what fit_scale says of lengths far off
        if model.gain != 1.0:
            raise ValueError("the grating's period was not found in the model's lengths")
        return real(model, record, **kw)

    monkeypatch.setattr(S, "fit_scale", no_period_for_the_rls)
    notes = []
    fits = S.scale_fits(models, rec, {"rls": 4.06, "batch": 0.33}, notes)
    assert list(fits) == ["batch"]
    assert "could not be scaled" in notes[0] and "4.06 nm RMS" in notes[0]
    assert "period was not found" in notes[0] and "off square" in notes[1]
    with pytest.raises(ValueError, match="period was not found"):  # the batch model's raises
        S.scale_fits({"rls": models["batch"], "batch": models["rls"]}, rec, {}, [])


def test_an_rls_far_worse_than_the_batch_model_on_held_out_heights_is_reported():
    from piezocomp.identification.estimation.findings import rls_astray

    assert rls_astray({"rls": 0.44, "batch": 0.13}) == []  # 3.4 times: seed 42, RLS 1.2 nm
    assert rls_astray({"rls": 0.9, "batch": 0.1}) == []  # 9 times but within 1 nm
    (text,) = rls_astray({"rls": 4.06, "batch": 0.33})  # seed 39, RLS 17.6 nm off
    assert "4.06 nm RMS, 12 times the batch model's 0.33 nm" in text
    assert rls_astray({"rls": float("nan"), "batch": 0.3}) == []


def test_a_batch_model_far_worse_than_the_rls_on_held_out_heights_is_reported():
    from piezocomp.identification.estimation.findings import batch_astray

    assert batch_astray({"rls": 0.19, "batch": 0.27}) == []  # 1.42 times: seed 22, 0.54 nm
    assert batch_astray({"rls": 0.2, "batch": 0.9}) == []  # 4.5 times but within 1 nm
    (text,) = batch_astray({"rls": 0.71, "batch": 3.32})  # seed 117, batch 25 nm off
    assert "3.32 nm RMS, 4.7 times the RLS estimate's 0.71 nm" in text
    assert "model_rls.json" in text
    assert batch_astray({"rls": 0.3, "batch": float("inf")}) == []


def test_the_scale_is_searched_where_the_calibration_cycles_put_it():
    """Mathematics only. Heights with a component at twice the pitch (alternate crests of
    unequal height, as unmodelled creep makes them in a model's lengths) fit a period of
    twice the pitch better than the pitch itself: a free search takes it and halves the
    scale. :func:`scale_fits` searches within ``AGREEMENT`` of the frame map's scale
    (the calibration cycles') and finds the grating's."""
    import piezocomp.identification.reference.scaling as S

    true = _pi_creep_model()
    record = _synthetic_record(true, (0.0, 40.0), 2000.0)
    y, _ = simulate(true, record.u_nm, T, record_state(true, float(record.u_nm[0])))
    uneven = replace(record, height_nm=record.height_nm + 4.0 * np.cos(np.pi * y / PITCH))
    model = mapped(true, 1.0 / 1.2, 0.0)
    assert fit_scale(model, uneven).alpha == pytest.approx(1.2 / 2, rel=1e-2)  # the trap
    fits = S.scale_fits({"batch": model, "rls": model}, uneven, {}, [], prescale={"batch": 1.1})
    assert fits["batch"].alpha == pytest.approx(1.2, rel=1e-2)
    # told a scale far off, it finds what agrees with it (a third of the period), and the
    # plausibility check refuses it
    with pytest.raises(ValueError, match=r"gives the model a scale of 0\.400"):
        S.scale_fits({"batch": model, "rls": model}, uneven, {}, [], prescale={"batch": 0.4})


def test_a_poor_fit_says_whether_the_model_is_too_small_or_the_record_suspect():
    from piezocomp.identification.estimation.findings import poor_fit

    assert poor_fit({"batch": 1.2}) == []
    (record,) = poor_fit({"batch": 2.4}, (32, 22))
    assert "Was the line settled" in record and "too small" not in record
    (small,) = poor_fit({"batch": 2.4}, (8, 2))  # --quick's orders: said first
    assert small.index("8 play and 2 creep operators") < small.index("Was the line settled")
    (no_creep,) = poor_fit({"batch": 2.4}, (32, 0))  # a model without creep, by design
    assert "no creep operators" in no_creep and "--quick" not in no_creep
    assert "Was the line settled" not in no_creep


def test_auto_scans_minor_loops_where_the_span_holds_their_sweeps():
    from piezocomp.identification.reference.config import ReferenceConfig
    from piezocomp.identification.reference.grating import grating_path_for

    assert grating_path_for(2000.0, PITCH) == "minor_loops"
    assert grating_path_for(1000.0, PITCH) == "steady"  # 700 nm of sweep < 3 x 278 nm
    assert grating_path_for(1000.0, PITCH, "minor_loops") == "minor_loops"  # then refused
    with pytest.raises(ValueError, match=r"grating_path must be 'auto', .* Got 'zigzag'"):
        ReferenceConfig(grating_path="zigzag")
