"""Model order selection by held-out error."""

from __future__ import annotations

import numpy as np
import pytest

from piezocomp.identification.estimation.orders import OrderTrial, select_orders
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.sensor.fit import SensorFit, place_thresholds
from piezocomp.sensor.orders import select_sensor_orders
from piezocomp.sensor.record import split_record

T = 0.01


def _table_fns(val: dict[tuple[int, int], float]):
    calls: list[tuple[int, int]] = []

    def fit_fn(nh, nc):
        calls.append((nh, nc))
        return (nh, nc), 0.5 * val[(nh, nc)]

    def score_fn(obj):
        return val[obj]

    return fit_fn, score_fn, calls


def test_smallest_model_within_tolerance_wins():
    val = {(4, 0): 2.0, (8, 0): 1.02, (8, 1): 1.0, (16, 2): 0.999}
    fit_fn, score_fn, calls = _table_fns(val)
    sel = select_orders(list(val), fit_fn, score_fn, tolerance=0.05)
    assert (sel.n_play, sel.n_creep) == (8, 0)  # 18 parameters, within 5 % of the best
    assert sel.fitted == (8, 0)
    assert sel.best_validation_error == 0.999
    assert calls == list(val)
    rows = sel.table()
    assert [r["chosen"] for r in rows] == [False, True, False, False]
    assert rows[0]["n_parameters"] == 10 and rows[0]["fit_error"] == 1.0


def test_zero_tolerance_takes_the_best():
    val = {(4, 0): 2.0, (8, 0): 1.02, (16, 2): 0.999}
    fit_fn, score_fn, _ = _table_fns(val)
    sel = select_orders(list(val), fit_fn, score_fn, tolerance=0.0)
    assert (sel.n_play, sel.n_creep) == (16, 2)


def test_largest_model_within_tolerance_wins_when_preferred():
    val = {(16, 22): 1.0, (32, 22): 1.2, (24, 22): 1.3, (48, 22): 5.0}
    fit_fn, score_fn, _ = _table_fns(val)
    sel = select_orders(list(val), fit_fn, score_fn, tolerance=0.25, prefer="largest")
    assert (sel.n_play, sel.n_creep) == (32, 22)  # within 25 %; 48 is not
    assert select_orders(list(val), fit_fn, score_fn, tolerance=0.25).n_play == 16
    # nothing else within the tolerance: the best, whatever the preference
    assert select_orders(list(val), fit_fn, score_fn, tolerance=0.1, prefer="largest").n_play == 16
    with pytest.raises(ValueError, match="prefer"):
        select_orders(list(val), fit_fn, score_fn, prefer="biggest")


def test_duplicates_are_fitted_once_and_bad_input_refused():
    val = {(4, 0): 1.0}
    fit_fn, score_fn, calls = _table_fns(val)
    select_orders([(4, 0), (4, 0)], fit_fn, score_fn)
    assert calls == [(4, 0)]
    with pytest.raises(ValueError, match="at least one"):
        select_orders([], fit_fn, score_fn)
    with pytest.raises(ValueError, match="tolerance"):
        select_orders([(4, 0)], fit_fn, score_fn, tolerance=-1)
    with pytest.raises(ValueError, match="non-finite"):
        select_orders([(4, 0)], fit_fn, lambda obj: float("nan"))


def test_n_parameters_is_eq_15():
    assert OrderTrial(8, 2, 0.0, 0.0).n_parameters == 2 * 2 + 2 * 8 + 2


def _record(with_creep: bool, seed: int):
    """A truth whose thresholds are those placed for N_H = 4 on the selection's fit part."""
    n = 4000
    t = np.arange(n) * T
    u = 300.0 + 400.0 * np.sin(2 * np.pi * 0.5 * t) * (
        0.3 + 0.7 * np.abs(np.sin(2 * np.pi * 0.03 * t))
    )
    inner = split_record(n, 0.25)
    r = place_thresholds(u[:inner], 4)
    truth = ScannerModel(
        offset_nm=10.0,
        gain=0.5,
        thresholds_nm=r,
        weights=[0.25, 0.15, 0.1, 0.05],
        creep_time_constants_s=[2.0] if with_creep else [],
        creep_gains=[0.25] if with_creep else [],
    )
    y, _ = simulate(truth, u, T, ModelState.at_rest(truth, u[0]))
    return u, y + np.random.default_rng(seed).normal(0.0, 0.5, n)


def test_sensor_orders_prefer_the_small_true_model():
    u, y = _record(with_creep=False, seed=2)
    sel = select_sensor_orders(u, y, T, n_play_candidates=(4, 8, 16), n_creep_candidates=(0, 1, 2))
    assert (sel.n_play, sel.n_creep) == (4, 0)
    assert isinstance(sel.fitted, SensorFit)
    assert len(sel.trials) == 9


def test_sensor_orders_add_creep_when_the_data_creep():
    u, y = _record(with_creep=True, seed=3)
    sel = select_sensor_orders(u, y, T, n_play_candidates=(4, 8), n_creep_candidates=(0, 1, 2))
    assert sel.n_creep >= 1
    no_creep = min(t.validation_error for t in sel.trials if t.n_creep == 0)
    assert sel.best_validation_error < 0.5 * no_creep


def test_workers_fit_the_candidates_side_by_side_with_the_same_result():
    val = {(4, 0): 2.0, (8, 0): 1.02, (8, 1): 1.0, (16, 2): 0.999}
    fit_fn, score_fn, calls = _table_fns(val)
    one = select_orders(list(val), fit_fn, score_fn, tolerance=0.05)
    two = select_orders([*val, (8, 0)], fit_fn, score_fn, tolerance=0.05, workers=3)
    assert two.trials == one.trials and two.fitted == one.fitted  # in the candidates' order
    assert sorted(calls) == sorted(list(val) * 2)  # each fitted once per selection
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="workers"):
            select_orders(list(val), fit_fn, score_fn, workers=bad)
