"""The oracle (the model fitted to the TRUE extension) with the creep coupling of eq (2').

On ``cpr5`` part of the creep is the relaxation of the domains the hysteresis switched: a
physics the model family does not contain, so this is a fit of a different family to the
simulator's truth, scored on a fresh validation trajectory it never saw.
"""

from __future__ import annotations

import pytest

from piezocomp.experiments.methods import IdentificationSettings
from piezocomp.experiments.scoring import score_model_on_truth
from piezocomp.experiments.virtual_identification import fit_on_truth
from piezocomp.virtual_afm import VirtualAFM


@pytest.mark.slow
def test_oracle_chooses_the_coupling_on_cpr5_and_predicts_better():
    st = IdentificationSettings()
    cfg = st.config(VirtualAFM("cpr5-nodrift", seed=1).range_nm)

    def oracle(coupling):
        afm = VirtualAFM("cpr5-nodrift", seed=1)
        return fit_on_truth(afm, cfg, "x", st.oracle_orders, extra_record=False,
                            creep_coupling=coupling)  # fmt: skip

    paper, coupled = oracle(0.0), oracle("fit")
    assert paper.creep_coupling == 0.0
    assert 0.3 < coupled.creep_coupling < 1.2
    score = {
        name: score_model_on_truth(VirtualAFM("cpr5-nodrift", seed=1), m, "x")
        for name, m in (("paper", paper), ("coupled", coupled))
    }
    rms = "validation_rms_error_nm"
    assert score["coupled"][rms] < 0.85 * score["paper"][rms]
