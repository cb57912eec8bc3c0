"""Test-wide settings.

Hypothesis runs without deadlines (numba compiles on first call). On CI (``CI`` set) the
examples are derandomised, so a run is reproducible and a landing is never decided by a
lucky draw; local runs keep exploring new examples.
"""

import os

import pytest
from hypothesis import settings

settings.register_profile("piezocomp", deadline=None, max_examples=60, print_blob=True)
settings.register_profile("ci", parent=settings.get_profile("piezocomp"), derandomize=True)
settings.load_profile("ci" if os.environ.get("CI") else "piezocomp")


@pytest.fixture(scope="session")
def oracle_models():
    """The model family fitted to the TRUE extension of the virtual cpr5 scanner (seed 1),
    over the span and speeds ``piezocomp reproduce`` identifies with: a compensator for
    tests of what uses a model (positioning, experiments), fitted in about a second. Not an
    identification: tests of identification use the sensorless pipeline."""
    from piezocomp.experiments.methods import IdentificationSettings
    from piezocomp.experiments.virtual_identification import fit_on_truth
    from piezocomp.model import ScannerModel2D
    from piezocomp.virtual_afm import VirtualAFM

    st = IdentificationSettings()
    axes = []
    for axis in ("x", "y"):
        afm = VirtualAFM("cpr5-nodrift", seed=1)
        axes.append(fit_on_truth(afm, st.config(afm.range_nm), axis, st.oracle_orders))
    return ScannerModel2D(*axes)
