"""Estimators that know only the paper's eq (2) refuse a model with a creep coupling
(eq 2'), in one line, instead of returning a silently wrong result; those that know eq (2')
take it only when asked for its layout (the RLS estimates a coupled start in its own family,
``tests/identification/test_rls.py``)."""

from dataclasses import replace

import numpy as np
import pytest

from piezocomp.identification.estimation.parameters import simulate_with_gradient, theta_from_model
from piezocomp.identification.estimation.reparametrisation import Reparametrisation
from piezocomp.identification.estimation.rls import RLSSettings, rls
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.reference.frames import mapped
from piezocomp.model import ModelState, simulate
from strategies import T, coupled

MATCH = r"^.* handles only the paper's model \(creep_coupling = 0\); this model has creep_coupling = 0\.4\.$"  # noqa: E501


def _one_line(info):
    assert "\n" not in str(info.value)


def test_theta_and_the_sensitivity_kernel_refuse_without_the_coupled_layout():
    m = coupled()
    with pytest.raises(ValueError, match=MATCH) as info:
        theta_from_model(m, T)
    _one_line(info)
    with pytest.raises(ValueError, match=MATCH):
        simulate_with_gradient(m, np.zeros(10), T)
    assert theta_from_model(m, T, coupled=True)[-1] == 0.4
    assert simulate_with_gradient(m, np.zeros(10), T, coupled=True)[1].shape == (10, 15)
    # the batch refinement's coordinates take the coupled layout for a coupled model
    assert Reparametrisation(m, T, ("c", "w"), 1e-9, 1e-9, 1e-3).layout.coupled


def test_rls_frees_a_coupling_from_zero():
    """With "b" free the RLS takes the coupled layout from beta = 0 too (its gradient there is
    the creep of the hysteresis output)."""
    m = replace(coupled(), creep_coupling=0.0)
    prof = HeightProfile(-200.0, 1.0, np.zeros(401), np.zeros(401))
    u = np.linspace(-100, 100, 50)
    res = rls(u, np.zeros(50), prof, m, T, settings=RLSSettings(free=("c", "b")))
    assert res.layout.coupled and res.theta.size == res.layout.size


def test_paper_model_still_accepted():
    m = replace(coupled(), creep_coupling=0.0)
    theta_from_model(m, T)
    simulate_with_gradient(m, np.zeros(10), T)


def test_frame_map_keeps_the_creep_drive():
    """``mapped`` scales the output by alpha: the coupled creep must follow exactly."""
    m = coupled()
    u = 150 * np.sin(np.linspace(0, 20, 400))
    y, _ = simulate(m, u, T, ModelState.at_rest(m, u[0]))
    m2 = mapped(m, 1.3, 7.0)
    y2, _ = simulate(m2, u, T, ModelState.at_rest(m2, u[0]))
    np.testing.assert_allclose(y2, 1.3 * y + 7.0, rtol=1e-12, atol=1e-9)
