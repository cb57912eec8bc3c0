"""Scoring a model file on a fresh virtual AFM, without the identification that made it."""

from __future__ import annotations

import dataclasses

import pytest

from piezocomp.experiments.scoring import score_model_on_truth
from piezocomp.virtual_afm import VirtualAFM


def test_score_model_on_truth_tells_a_good_model_from_a_wrong_one(oracle_models):
    good = score_model_on_truth(VirtualAFM("cpr5-nodrift", seed=1), oracle_models.x, "x")
    # the model family fitted to the truth: about a nanometre over +-1000 nm (the family's
    # floor on cpr5, docs/virtual_afm.md)
    assert good["validation_max_error_nm"] < 3.0 and good["scale"] == pytest.approx(1.0, abs=0.01)
    m = oracle_models.x  # the same model 5 % too long: every term of eq (14) scaled
    wrong = dataclasses.replace(m, gain=m.gain * 1.05, weights=m.weights * 1.05,
                                creep_gains=m.creep_gains * 1.05)  # fmt: skip
    bad = score_model_on_truth(VirtualAFM("cpr5-nodrift", seed=1), wrong, "x")
    assert bad["validation_max_error_nm"] > 10 * good["validation_max_error_nm"]
    assert bad["validation_max_error_after_scale_nm"] < 3.0  # 5 % of scale, removed


def test_score_model_on_truth_needs_a_fresh_instrument(oracle_models):
    afm = VirtualAFM("cpr5-nodrift", seed=1)
    afm.wait(0.1)
    with pytest.raises(ValueError, match="fresh virtual AFM"):
        score_model_on_truth(afm, oracle_models.x, "x")


def test_oracle_on_the_record_alone_runs_no_extra_record(oracle_models):
    """``extra_record=False`` fits the identification's record only (the half hour of long
    holds the default oracle adds is never run), and is still a fit to the truth."""
    from piezocomp.experiments.methods import IdentificationSettings
    from piezocomp.experiments.virtual_identification import ORACLE_TURNS, fit_on_truth

    st = IdentificationSettings()
    afm = VirtualAFM("cpr5-nodrift", seed=1)
    model = fit_on_truth(afm, st.config(afm.range_nm), "x", st.oracle_orders, extra_record=False)
    full = VirtualAFM("cpr5-nodrift", seed=1)
    fit_on_truth(full, st.config(full.range_nm), "x", st.oracle_orders)
    # the extra record is ORACLE_TURNS turns with holds: many minutes more of scanner time
    assert full.time_s - afm.time_s > ORACLE_TURNS * 10.0
    score = score_model_on_truth(VirtualAFM("cpr5-nodrift", seed=1), model, "x")
    best = score_model_on_truth(VirtualAFM("cpr5-nodrift", seed=1), oracle_models.x, "x")
    assert score["validation_max_error_nm"] < 2 * best["validation_max_error_nm"] + 1.0
