"""Measured figures are measured: each experiment scored with a truth displaced by a known
amount its images do not show (:mod:`displaced_truth`). The measured figure must stay that
of the images (it agrees with the real truth), the true one must follow the displaced truth:
a measured figure formed from the truth, or a true one from the images, fails here. Outside
and inside the drift compensator; the models are fitted to the simulator's truth (these
check the experiments' bookkeeping, not the identification)."""

from __future__ import annotations

import numpy as np
import pytest

from displaced_truth import DisplacedAFM, DisplacedTruth
from piezocomp.experiments import fig8, fig9, fig10, table1
from piezocomp.experiments.contract import DRIFT_METHOD, Trial
from piezocomp.experiments.methods import MethodModels
from piezocomp.experiments.truth import true_displacement
from piezocomp.positioning.compensated import CompensatedInstrument
from piezocomp.virtual_afm import VirtualAFM, load_config


def displaced_compensated(models, velocity, **afm_kw):
    afm = VirtualAFM("cpr5-nodrift", seed=1, **afm_kw)
    comp = CompensatedInstrument(afm, models)
    comp.initialise()
    truth = DisplacedTruth(afm.truth, lambda: afm.time_s, velocity)
    return afm, comp, tuple(np.mean(comp.working_area_nm, axis=1)), truth


def check_pair(measured, true, first, second, real, displaced, shift_at_least_nm):
    """measured == registration of the images (agrees with the real truth), true == the
    displaced truth's, the two truths ``shift_at_least_nm`` apart."""
    real_nm = true_displacement(real, first, second)
    displaced_nm = true_displacement(displaced, first, second)
    assert abs(displaced_nm - real_nm) > shift_at_least_nm  # the test can tell them apart
    assert true == pytest.approx(displaced_nm, abs=1e-9)
    assert measured == pytest.approx(real_nm, abs=0.5)


def test_table1_measured_follows_the_images_and_true_the_truth(oracle_models):
    s = table1.Table1Settings(d_nm=951.0, experiment=1, pixels=48, overview_pixels=96,
                              settle_s=60.0, keep_images=True)  # fmt: skip
    afm, comp, o, truth = displaced_compensated(oracle_models, (0.1, 0.05))
    r = table1.run(comp, s, origin_nm=o, truth=truth)
    for area in ("A", "B"):
        first, second = r.images[f"{area}1"], r.images[f"{area}2"]
        check_pair(r.error_nm[area], r.true_error_nm[area], first, second, afm.truth, truth,
                   5.0)  # fmt: skip
    assert r.max_error_nm < 1.5 < 5.0 < r.true_max_error_nm


def test_fig9_measured_follows_the_images_and_true_the_truth(oracle_models):
    s = fig9.Fig9Settings(pixels=64, keep_images=True)
    afm, comp, o, truth = displaced_compensated(oracle_models, (0.5, -0.5))
    r = fig9.run(comp, s, origin_nm=o, truth=truth)
    before, after = r.images
    check_pair(r.error_nm, r.true_error_nm, before, after, afm.truth, truth, 5.0)
    assert r.error_nm < 1.5 < 5.0 < r.true_error_nm


def test_fig8_measured_spread_follows_the_peaks_and_true_the_truth(oracle_models):
    s = fig8.Fig8Settings(n_ramps=4)
    _, comp, o, truth = displaced_compensated(oracle_models, (5.0, 0.0))
    r = fig8.run(comp, s, origin_nm=o, truth=truth)
    # the ramps take about a second each: the displaced truth moves 5 nm a second
    assert np.max(r.spread_nm) < 3.0
    assert np.nanmax(r.true_spread_nm) > 8.0
    assert r.measured_spread_nm == pytest.approx(np.max(r.spread_nm))


def test_fig10_measured_success_follows_the_image_and_true_the_truth(oracle_models):
    s = fig10.Fig10Settings()
    _, comp, o, truth = displaced_compensated(
        oracle_models, (0.05, 0.0), particles=fig10.sample_particles(s, 2)
    )  # an assembly the images show a success (test_experiments' draw)
    res = fig10.run(comp, s, origin_nm=o, truth=truth)
    # the assembly lasts minutes: its particles, truly, end tens of nm from their sites
    assert res.success and res.max_error_nm < s.success_nm
    assert res.true_max_error_nm > 3 * s.success_nm and not res.true_success


@pytest.fixture
def displaced_simulator(monkeypatch):
    """Every experiment's ``run_trial`` makes a :class:`DisplacedAFM`; they are returned."""
    DisplacedAFM.made = []
    for module in (table1, fig9, fig10):
        monkeypatch.setattr(module, "VirtualAFM", DisplacedAFM)
    return DisplacedAFM.made


def test_inside_the_drift_compensator_measured_follows_the_images(
    oracle_models, displaced_simulator
):
    """Table I, Fig. 9 and Fig. 10 on cpr5 (drifting) inside the drift compensator, as
    ``reproduce`` runs them (``run_trial``), each on a simulator whose truth is displaced."""
    cfg = load_config("cpr5")
    models = MethodModels({"compensated": oracle_models})
    st1 = table1.Table1Settings(d_nm=645.0, experiment=0, area_nm=650.0, keep_images=True)
    r1 = table1.run_trial(Trial(table1.NAME, DRIFT_METHOD, st1), cfg, 1, models)
    afm = displaced_simulator[-1]
    for area in ("A", "B"):
        first, second = r1.images[f"{area}1"], r1.images[f"{area}2"]
        check_pair(r1.error_nm[area], r1.true_error_nm[area], first, second, afm.truth.real,
                   afm.truth, 5.0)  # fmt: skip

    st9 = fig9.Fig9Settings(keep_images=True)
    r9 = fig9.run_trial(Trial(fig9.NAME, DRIFT_METHOD, st9), cfg, 1, models)
    afm = displaced_simulator[-1]
    before, after = r9.images
    check_pair(r9.error_nm, r9.true_error_nm, before, after, afm.truth.real, afm.truth, 5.0)

    st10 = fig10.Fig10Trial(fig10.Fig10Settings(), 0)
    r10 = fig10.run_trial(Trial(fig10.NAME, DRIFT_METHOD, st10), cfg, 1, models)
    assert r10.success and not r10.true_success
    assert r10.max_error_nm < st10.settings.success_nm < r10.true_max_error_nm / 3
