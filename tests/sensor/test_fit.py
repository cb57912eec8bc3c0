"""Sensor-based identification: linear stage, placement, figures, excitation checks.

Exact-model tests check the mathematics (the linear stage is exact when thresholds and
poles are the truth's); the real-record check is in test_piezo_record.py.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose

from piezocomp.identification.acquisition.diagnostics import ExcitationWarning, check_excitation
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.operators.play import play_bank
from piezocomp.sensor.fit import (
    error_figures,
    fit_plain_pi,
    fit_sensor,
    nnls_stage,
    place_thresholds,
    place_time_constants,
    split_record,
)

T = 0.01


def _command(n: int = 3000, centre: float = 300.0, amp: float = 400.0) -> np.ndarray:
    t = np.arange(n) * T
    return centre + amp * np.sin(2 * np.pi * 0.5 * t) * (
        0.3 + 0.7 * np.abs(np.sin(2 * np.pi * 0.03 * t))
    )


TRUTH = ScannerModel(
    offset_nm=-40.0,
    gain=0.6,
    thresholds_nm=[50.0, 120.0, 200.0, 300.0],
    weights=[0.2, 0.1, 0.08, 0.05],
    creep_time_constants_s=[0.3, 3.0],
    creep_gains=[0.05, 0.1],
)


@pytest.mark.parametrize("kind", ["rest", "zero"])
def test_nnls_stage_recovers_exact_linear_parameters(kind):
    u = _command()
    state = ModelState.at_rest(TRUTH, u[0]) if kind == "rest" else ModelState.zeros(TRUTH)
    y, _ = simulate(TRUTH, u, T, state)
    model, floored, reg, names = nnls_stage(
        u, y, T, TRUTH.thresholds_nm, TRUTH.creep_time_constants_s, initial_state=kind
    )
    assert floored == ()
    assert names == ["a", "w1", "w2", "w3", "w4", "c1", "c2"]
    assert reg.shape == (u.size, 7)
    assert_allclose(model.gain, TRUTH.gain, rtol=1e-8)
    assert_allclose(model.weights, TRUTH.weights, rtol=1e-8)
    assert_allclose(model.creep_gains, TRUTH.creep_gains, rtol=1e-7)
    assert_allclose(model.offset_nm, TRUTH.offset_nm, atol=1e-6)


def test_weights_stay_positive_when_least_squares_wants_them_negative():
    u = _command()
    r = np.array([60.0, 150.0])
    z, _ = play_bank(u, r)
    y = 0.8 * u - 0.3 * z[:, 0] + 0.2 * z[:, 1]  # a negative weight: not a feasible PI model
    model, floored, _, _ = nnls_stage(u, y, T, r, [], initial_state="zero")
    assert floored == ("w1",)
    assert np.all(model.weights > 0) and model.gain > 0
    fit = fit_sensor(u, y, T, thresholds_nm=r, n_creep=0, initial_state="zero")
    assert np.all(fit.model.weights > 0) and fit.model.gain > 0
    assert fit.floored_weights == ("w1",)


def test_fit_sensor_reports_fit_and_validation_figures():
    rng = np.random.default_rng(1)
    u = _command(4000)
    y, _ = simulate(TRUTH, u, T, ModelState.at_rest(TRUTH, u[0]))
    sigma = 2.0
    y_noisy = y + sigma * rng.standard_normal(u.size)
    fit = fit_sensor(u, y_noisy, T, n_play=6, n_creep=2, validation_fraction=0.25)
    assert fit.split_index == 3000
    assert fit.validation_errors is not None and fit.nnls_validation_errors is not None
    assert fit.validation_errors.n_samples == 1000
    assert fit.fit_errors.n_samples == 3000
    # placed thresholds differ from the truth's: the linear stage is only approximate,
    # the refinement of thresholds and poles brings the errors to the noise level.
    assert fit.fit_errors.rms_nm < fit.nnls_fit_errors.rms_nm
    assert fit.fit_errors.rms_nm < 1.3 * sigma
    assert fit.validation_errors.rms_nm < 1.5 * sigma
    rng_out = np.ptp(y_noisy)
    assert_allclose(
        fit.validation_errors.rms_percent_of_range,
        100 * fit.validation_errors.rms_nm / rng_out,
    )
    e = fit.predicted_nm - y_noisy
    assert_allclose(fit.validation_errors.max_nm, np.abs(e[3000:]).max())
    summary = fit.summary()
    assert summary["refined"]["validation"]["n_samples"] == 1000
    assert summary["nnls"]["fit"]["rms_nm"] == fit.nnls_fit_errors.rms_nm


def test_the_refined_model_is_kept_when_it_is_better_on_the_held_out_part():
    rng = np.random.default_rng(1)
    u = _command(4000)
    y, _ = simulate(TRUTH, u, T, ModelState.at_rest(TRUTH, u[0]))
    fit = fit_sensor(u, y + 2.0 * rng.standard_normal(u.size), T, n_play=6, n_creep=2)
    assert fit.chosen == "refined" and fit.refinement is not None
    assert fit.model is fit.refinement.model
    assert fit.validation_errors == fit.refined_validation_errors
    assert fit.refined_validation_errors is not None and fit.nnls_validation_errors is not None
    assert fit.refined_validation_errors.rms_nm < fit.nnls_validation_errors.rms_nm
    assert fit.summary()["chosen"] == "refined"


def test_the_linear_model_is_kept_when_the_refinement_is_worse_held_out(monkeypatch):
    """A refinement that predicts the held-out part worse than the linear stage (here one
    whose gain is 5 % off) is reported, not written."""
    from dataclasses import replace

    from piezocomp.identification.estimation import batch

    real = batch.refine

    def worse(model, *args, **kwargs):
        res = real(model, *args, **kwargs)
        return replace(res, model=replace(res.model, gain=1.05 * res.model.gain))

    monkeypatch.setattr(batch, "refine", worse)
    rng = np.random.default_rng(1)
    u = _command(4000)
    y, _ = simulate(TRUTH, u, T, ModelState.at_rest(TRUTH, u[0]))
    fit = fit_sensor(
        u, y + 2.0 * rng.standard_normal(u.size), T, n_play=6, n_creep=2, reference_orders=None
    )
    assert fit.chosen == "linear" and fit.model is fit.nnls_model
    assert fit.validation_errors == fit.nnls_validation_errors
    assert fit.refined_validation_errors is not None and fit.nnls_validation_errors is not None
    assert fit.refined_validation_errors.rms_nm > fit.nnls_validation_errors.rms_nm
    summary = fit.summary()
    assert summary["chosen"] == "linear"
    assert summary["refined"]["validation"] == fit.refined_validation_errors.as_dict()


def test_no_validation_when_fraction_is_zero():
    u = _command(1000)
    y, _ = simulate(TRUTH, u, T)
    fit = fit_sensor(u, y, T, n_play=4, n_creep=0, validation_fraction=0.0, refine=False)
    assert fit.validation_errors is None and fit.refinement is None
    assert fit.model is fit.nnls_model


def test_plain_pi_baseline_is_uniform_and_without_creep():
    u = _command()
    y, _ = simulate(TRUTH, u, T)
    base = fit_plain_pi(u, y, T)
    assert base.model.n_play == 10 and base.model.n_creep == 0
    assert base.refinement is None
    assert_allclose(np.diff(base.model.thresholds_nm), base.model.thresholds_nm[0])
    with pytest.raises(TypeError, match="n_creep"):
        fit_plain_pi(u, y, T, n_creep=2)


def test_placement():
    u = np.array([100.0, 900.0, 100.0])
    r = place_thresholds(u, 7)
    assert_allclose(r, 400.0 * np.arange(1, 8) / 8)
    assert r.max() < 400.0
    tau = place_time_constants(3000, 0.01, 3)
    assert_allclose(tau[[0, -1]], [0.05, 10.0])
    assert place_time_constants(3000, 0.01, 0).size == 0
    with pytest.raises(ValueError, match="constant"):
        place_thresholds(np.ones(5), 3)
    with pytest.raises(ValueError, match="too short"):
        place_time_constants(10, 0.01, 2)


def test_split_record_rules():
    assert split_record(100, 0.25) == 75
    assert split_record(100, split_index=60) == 60
    with pytest.raises(ValueError, match="validation_fraction"):
        split_record(100, 1.0)
    with pytest.raises(ValueError, match="too few"):
        split_record(100, 0.25, warmup_samples=74)


def test_excitation_warning_when_span_is_smaller_than_thresholds():
    u = _command(2000, amp=50.0)  # half span about 50 nm
    y, _ = simulate(TRUTH, u, T)
    with pytest.warns(ExcitationWarning) as caught:
        fit = fit_sensor(u, y, T, thresholds_nm=TRUTH.thresholds_nm, n_creep=0, refine=False,
                         initial_state="rest")  # fmt: skip
    assert any("largest threshold" in str(w.message) for w in caught)
    assert any("largest threshold" in d for d in fit.diagnostics)
    assert any("constant" in d for d in fit.diagnostics)  # idle operators: constant columns


def test_excitation_warning_for_long_time_constant():
    u = _command(1000)
    y, _ = simulate(TRUTH, u, T)
    with pytest.warns(ExcitationWarning) as caught:
        fit_sensor(u, y, T, n_play=4, time_constants_s=[100.0], refine=False)
    assert any("exceed the fitted record" in str(w.message) for w in caught)


def test_no_warning_for_a_well_excited_record():
    u = _command()
    y, _ = simulate(TRUTH, u, T)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExcitationWarning)
        fit = fit_sensor(u, y, T, n_play=8, n_creep=2, refine=False)
    assert fit.diagnostics == ()


def test_check_excitation_finds_constant_and_collinear_columns():
    u = _command(500)
    reg = np.column_stack((u, np.full(u.size, 3.0), 2.0 * u + 1.0))
    found = check_excitation(u, T, regressor=reg, column_names=["a", "w1", "w2"])
    assert any("w1" in f and "constant" in f for f in found)
    assert any("collinear" in f and "a" in f and "w2" in f for f in found)
    assert check_excitation(u, T, regressor=reg[:, :1]) == ()


def test_error_figures():
    e = error_figures(np.array([1.0, -3.0, 2.0]), np.zeros(3), 10.0)
    assert_allclose(e.rms_nm, np.sqrt(14 / 3))
    assert e.max_nm == 3.0
    assert_allclose(e.rms_percent_of_range, 10 * np.sqrt(14 / 3))


def test_the_rest_command_before_a_record_is_found_from_it():
    """A scanner held at -300 nm, then driven from +300 nm: the exact model's linear stage
    (thresholds and poles the truth's) finds the rest command, and with it fits exactly,
    where "rest" (at u[0]) and "zero" do not (mathematics only: the same family)."""
    from piezocomp.sensor.fit import estimate_rest_command

    u = _command(2000)
    y, _ = simulate(TRUTH, u, T, ModelState.at_rest(TRUTH, -300.0))
    rows = np.ones(u.size, bool)
    u_r = estimate_rest_command(
        u, y, T, TRUTH.thresholds_nm, TRUTH.creep_time_constants_s, rows=rows
    )
    assert abs(u_r + 300.0) < 2.0
    rms = {}
    for kind in ("rest", "zero", "estimate"):
        fit = fit_sensor(
            u, y, T, thresholds_nm=TRUTH.thresholds_nm,
            time_constants_s=TRUTH.creep_time_constants_s, initial_state=kind, refine=False,
            reference_orders=None,
        )  # fmt: skip
        rms[kind] = fit.nnls_fit_errors.rms_nm
    assert rms["estimate"] < 0.05 < min(rms["rest"], rms["zero"])
    assert fit.initial_state == "estimate" and abs(fit.rest_command_nm + 300.0) < 2.0
    assert fit.summary()["rest_command_nm"] == fit.rest_command_nm


def test_another_record_is_started_from_its_first_seconds():
    """start_of_record finds the rest command and the sensor's offset of a record the model
    did not see, from its first samples only."""
    from piezocomp.sensor.fit import start_of_record

    u = _command(2000, centre=-100.0)
    y, _ = simulate(TRUTH, u, T, ModelState.at_rest(TRUTH, 250.0))
    u_r, off = start_of_record(TRUTH, u, y + 17.0, T, rows=np.arange(u.size) < 400)
    assert abs(u_r - 250.0) < 2.0 and abs(off + 17.0) < 0.05


def test_the_fit_reports_the_familys_plain_least_squares_and_never_loses_to_it():
    """The reference fit (many placed operators, plain NNLS) is reported beside the fit, and
    the model kept predicts the held-out part no worse than it."""
    from piezocomp.sensor.fit import REFERENCE_ORDERS

    rng = np.random.default_rng(3)
    u = _command(4000)
    y, _ = simulate(TRUTH, u, T, ModelState.at_rest(TRUTH, u[0]))
    y = y + 0.5 * rng.standard_normal(u.size)
    for orders in ((2, 0), (6, 2)):
        fit = fit_sensor(u, y, T, n_play=orders[0], n_creep=orders[1])
        ref = fit.reference
        assert ref is not None and (ref.model.n_play, ref.model.n_creep) == REFERENCE_ORDERS
        assert ref.validation_errors is not None and fit.validation_errors is not None
        assert fit.validation_errors.rms_nm <= ref.validation_errors.rms_nm
        assert fit.summary()["reference"]["n_play"] == REFERENCE_ORDERS[0]
    # a 2-play model without creep cannot follow this record: the reference is kept
    small = fit_sensor(u, y, T, n_play=2, n_creep=0)
    assert small.chosen == "reference" and small.model is small.reference.model


def test_a_bad_initial_state_is_refused_in_one_line():
    with pytest.raises(ValueError, match="initial_state must be 'rest', 'zero', 'estimate'"):
        fit_sensor(_command(1000), _command(1000), T, initial_state="settled")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("orders", "match"),
    [((16,), r"reference_orders must be \(N_H, N_c\)"),
     ((2.5, 3), r"reference_orders\[0\] must be a non-negative integer")],
)  # fmt: skip
def test_bad_reference_orders_are_refused_in_one_line(orders, match):
    with pytest.raises(ValueError, match=match):
        fit_sensor(_command(1000), _command(1000), T, reference_orders=orders)


def test_a_state_only_fit_sensor_resolves_is_refused_elsewhere():
    """'estimate' and 'auto' are resolved by fit_sensor; the functions it calls take a
    resolved state and say which."""
    with pytest.raises(ValueError, match=r"'rest', 'zero' or a command in nm\. Got 'auto'"):
        nnls_stage(_command(500), _command(500), T, [50.0], [1.0], initial_state="auto")
