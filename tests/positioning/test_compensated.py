"""The compensated instrument: exact on an exact-model plant, refusals, state, entry.

Exact-model plants (:mod:`model_instrument`) check the mathematics only; the virtual AFM
(a different model family) checks that compensation helps where it matters.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from model_instrument import ModelInstrument
from piezocomp.instrument import Instrument
from piezocomp.model import ScannerModel, ScannerModel2D
from piezocomp.positioning.axis_compensation import (
    ModelAxis,
    StaticAxis,
    steady_cycle,
    working_interval,
)
from piezocomp.positioning.compensated import CompensatedInstrument
from piezocomp.virtual_afm import VirtualAFM


def model(gain=0.7, shift=0.0, domain=(-600.0, 600.0)):
    return ScannerModel(
        offset_nm=3.0 + shift,
        gain=gain,
        thresholds_nm=[20.0, 80.0, 200.0, 400.0],
        weights=[0.06, 0.05, 0.04, 0.03],
        creep_time_constants_s=[0.05, 2.0, 60.0],
        creep_gains=[0.02, 0.03, 0.05],
        domain_nm=domain,
        range_nm=5000.0,
    )


@pytest.fixture
def exact():
    m = ScannerModel2D(model(), model(0.65, -4.0))
    plant = ModelInstrument(m, bumps_nm=np.array([[30.0, -20.0], [-60.0, 45.0]]))
    comp = CompensatedInstrument(plant, m)
    comp.initialise()
    return plant, comp


def test_it_is_an_instrument_and_refuses_motion_before_initialise():
    m = ScannerModel2D(model(), model())
    comp = CompensatedInstrument(ModelInstrument(m), m)
    assert isinstance(comp, Instrument)
    with pytest.raises(RuntimeError, match="initialise"):
        comp.move_to(10.0, 10.0, 100.0)


def test_an_exact_model_puts_the_tip_exactly_where_told(exact):
    plant, comp = exact
    plant.true_log.clear()
    rec = comp.move_to(120.0, -80.0, 1000.0)
    comp.wait(3.0)
    comp.push(-100.0, 50.0, 300.0)
    path = np.column_stack([np.linspace(-100, 40, 50), np.linspace(50, 90, 50)])
    comp.run(path, sample_period_s=0.002)
    img = comp.scan_image((0.0, 0.0), 200.0, 32, 2.0)
    true = np.vstack(plant.true_log)
    desired = np.vstack([
        rec.command_nm, np.tile([120.0, -80.0], (375, 1)),
        np.column_stack([np.linspace(120, -100, 1000)[1:], np.linspace(-80, 50, 1000)[1:]]),
    ])  # fmt: skip
    # the record holds the desired positions; the plant followed them to rounding
    assert_allclose(true[: len(rec)], rec.command_nm, atol=1e-6)
    assert_allclose(true[len(rec) : len(rec) + 375], desired[len(rec) : len(rec) + 375], atol=1e-6)
    assert_allclose(plant.true_log[3], path, atol=1e-6)
    # the image's pixels are at true positions: the bumps appear where they truly are
    for bx, by in plant.bumps_nm:
        i, j = np.argmin(np.abs(img.y_nm - by)), np.argmin(np.abs(img.x_nm - bx))
        expected = 10.0 * np.exp(-((img.x_nm[j] - bx) ** 2 + (img.y_nm[i] - by) ** 2) / 128.0)
        assert img.forward_nm[i, j] == pytest.approx(expected, abs=1e-6)
    assert_allclose(img.forward_nm, img.backward_nm, atol=1e-9)  # traces coincide
    assert comp.command_nm == (img.x_nm[0], img.y_nm[-1])  # the raster ends there


def test_the_predicted_state_is_carried_across_calls(exact):
    plant, comp = exact
    comp.move_to(200.0, 100.0, 800.0)
    comp.scan_image((200.0, 100.0), 100.0, 16, 2.0)
    comp.wait(1.0)
    for k in range(2):
        st, pst = comp.states[k], plant.states[k]
        assert_allclose(st.play_nm, pst.play_nm, atol=1e-6)
        assert_allclose(st.creep_nm, pst.creep_nm, atol=1e-6)


def test_a_move_out_of_the_domain_is_refused_and_nothing_moves(exact):
    plant, comp = exact
    before_t, before_u, before_pos = plant._t, plant.command_nm, comp.command_nm
    with pytest.raises(ValueError, match="outside the model's domain"):
        comp.move_to(900.0, 0.0, 1000.0)
    assert plant._t == before_t and plant.command_nm == before_u
    assert comp.command_nm == before_pos


def test_extrapolation_is_allowed_when_asked():
    m = ScannerModel2D(model(), model())
    plant = ModelInstrument(m)
    comp = CompensatedInstrument(plant, m, allow_extrapolation=True)
    comp.initialise()
    comp.move_to(900.0, 0.0, 1000.0)
    assert_allclose(plant.true_log[-1][-1], [900.0, 0.0], atol=1e-6)


def test_commands_beyond_the_slew_limit_are_refused_before_anything_moves():
    m = ScannerModel2D(model(), model())
    plant = ModelInstrument(m, max_speed_nm_per_s=1000.0)
    comp = CompensatedInstrument(plant, m)
    comp.initialise(speed_nm_per_s=500.0)
    t0 = plant._t
    # asked at the limit, the compensated commands must run faster than it (1/a > 1)
    with pytest.raises(ValueError, match="slew limit"):
        comp.move_to(300.0, 0.0, 1000.0)
    assert plant._t == t0


def test_bad_arguments_are_refused_with_the_rule():
    m = ScannerModel2D(model(), model())
    with pytest.raises(TypeError, match="Instrument"):
        CompensatedInstrument(object(), m)
    with pytest.raises(TypeError, match=r"one-axis ScannerModel: identify both axes.*--axis both"):
        CompensatedInstrument(ModelInstrument(m), model())
    with pytest.raises(TypeError, match="ScannerModel2D or a pair"):
        CompensatedInstrument(ModelInstrument(m), "model.json")
    comp = CompensatedInstrument(ModelInstrument(m), m)
    with pytest.raises(ValueError, match="cycles"):
        comp.initialise(cycles=0)
    no_domain = ScannerModel2D(replace(model(), domain_nm=None), model())
    with pytest.raises(ValueError, match="domain"):
        CompensatedInstrument(ModelInstrument(no_domain), no_domain).initialise()
    comp.initialise()
    with pytest.raises(ValueError, match="speed_nm_per_s"):
        comp.move_to(0.0, 0.0, -1.0)
    with pytest.raises(ValueError, match="fast_axis"):
        comp.scan_image((0.0, 0.0), 100.0, 16, 1.0, fast_axis="z")


def test_the_working_area_is_what_the_domain_reaches():
    ax = ModelAxis(model())
    lo, hi = working_interval(ax, 0.008, margin=0.0)
    up, y_up, down, y_down = steady_cycle(ax, 0.008)
    assert lo == pytest.approx(y_down[-1]) and hi == pytest.approx(y_up[-1])
    assert up[-1] == pytest.approx(600.0) and down[-1] == pytest.approx(-600.0)
    lo2, hi2 = working_interval(ax, 0.008)
    assert lo < lo2 < hi2 < hi


def test_a_static_axis_inverts_its_polynomial_and_extends_it_linearly():
    st = StaticAxis(np.array([1e-7, 0.0, 0.9, 2.0]), (-500.0, 500.0))
    y = np.array([-700.0, -100.0, 0.0, 300.0, 800.0])
    u, _ = st.command(None, y, 0.008)
    back, _ = st.follow(None, u, 0.008)
    assert_allclose(back, y, atol=1e-6)
    with pytest.raises(ValueError, match="increasing"):
        StaticAxis(np.array([-1.0, 0.0]), (-1.0, 1.0))


def test_static_from_a_model_is_the_middle_of_its_loop():
    m = model()
    st = StaticAxis.from_model(m, 0.008)
    up, y_up, down, y_down = steady_cycle(ModelAxis(m), 0.008)
    mid = 0.5 * (np.interp(0.0, up, y_up) + np.interp(0.0, down[::-1], y_down[::-1]))
    assert st.follow(None, np.array([0.0]), 0.008)[0][0] == pytest.approx(mid, abs=0.5)


def test_on_the_virtual_afm_a_fitted_model_beats_the_raw_commands_fivefold(oracle_models):
    """Back to the start after a path (Fig. 9's), true error: raw vs compensated with a
    model of the same family fitted to the true extension (a different family from the
    simulator's Preisach scanner and its creep of the switched domains, which sets a floor
    of about a nanometre on this path)."""

    def back_to_start(inst, truth, origin):
        o = np.asarray(origin)
        inst.move_to(*(o + np.array([300.0, 300.0])), 1000.0)
        a = inst.scan_image(tuple(o + np.array([300.0, 300.0])), 150.0, 32, 2.0)
        for p in [(-500, -300), (450, 450), (-400, -400), (300, 300)]:
            inst.move_to(*(o + np.array(p)), 1000.0)
        b = inst.scan_image(tuple(o + np.array([300.0, 300.0])), 150.0, 32, 2.0)
        pa = truth.positions_at(np.stack(a.pixel_times_s())).reshape(-1, 2).mean(0)
        pb = truth.positions_at(np.stack(b.pixel_times_s())).reshape(-1, 2).mean(0)
        return float(np.hypot(*(pb - pa)))

    raw = VirtualAFM("cpr5-nodrift", seed=1)
    e_raw = back_to_start(raw, raw.truth, (0.0, 0.0))
    afm = VirtualAFM("cpr5-nodrift", seed=1)
    comp = CompensatedInstrument(afm, oracle_models)
    comp.initialise()
    centre = np.mean(comp.working_area_nm, axis=1)
    e_comp = back_to_start(comp, afm.truth, tuple(centre))
    assert e_raw > 8.0
    assert e_comp < e_raw / 5
