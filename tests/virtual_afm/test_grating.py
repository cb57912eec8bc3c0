"""The calibration grating of the virtual AFM: profile, tip dilation, and the instrument."""

from __future__ import annotations

import numpy as np
import pytest

from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm import Grating, VirtualAFM
from piezocomp.virtual_afm.grating import grating_topography
from piezocomp.virtual_afm.sample import Substrate


def _dilation_oracle(grating: Grating, tip: TipGeometry, x: np.ndarray) -> np.ndarray:
    """Plain max over a dense set of tip offsets (the definition of the recorded height)."""
    s = np.linspace(-60.0, 60.0, 24001)
    t = tip.surface_height(s)
    return np.array([np.max(grating.profile(xi + s) - t) for xi in x])


def test_tip_surface_is_sphere_then_cone():
    tip = TipGeometry(10.0, 20.0)
    th = np.radians(20.0)
    assert tip.surface_height(0.0) == 0.0
    s_t = 10.0 * np.cos(th)  # tangent point
    assert tip.surface_height(s_t) == pytest.approx(10.0 * (1 - np.sin(th)))
    # the cone rises 1/tan(theta) per nm beyond the tangent point
    assert tip.surface_height(s_t + 5.0) - tip.surface_height(s_t) == pytest.approx(5 / np.tan(th))
    assert tip.surface_height(-3.0) == tip.surface_height(3.0)


@pytest.mark.parametrize("pitch", [278.0, 60.0])
def test_dilated_heights_match_the_definition(pitch):
    g = Grating(pitch, 25.0, phase_nm=17.0)
    tip = TipGeometry(10.0, 20.0)
    x = np.linspace(-300.0, 300.0, 37)
    pos = np.column_stack([x, np.full_like(x, 123.0)])
    z = grating_topography(pos, g, tip, Substrate.flat())
    np.testing.assert_allclose(z, _dilation_oracle(g, tip, x), atol=0.01)
    assert np.all(z >= g.profile(x) - 1e-5)  # the tip never enters the surface (table: 1e-6)
    # a 60 nm grating is too fine for the tip to reach its valleys
    if pitch == 60.0:
        assert z.min() > 0.3


def test_virtual_afm_with_a_grating_records_the_grating_at_the_true_positions():
    g = Grating(278.0, 25.0, axis="x")
    afm = VirtualAFM.from_preset("gentle", seed=2, sample_period_s=0.008, grating=g)
    assert afm.grating is g and len(afm.truth.particles()) == 0
    afm.move_to(-300.0, 50.0, 500.0)
    u = np.linspace(-300.0, 300.0, 601)
    rec = afm.run(np.column_stack([u, np.full_like(u, 50.0)]))
    pos = afm.truth.last_record_positions_nm
    expected = grating_topography(pos, g, afm.truth.tip, afm.truth.substrate)
    noise = rec.height_nm - expected
    assert np.std(noise) == pytest.approx(afm.config.sample.height_noise_nm, rel=0.2)
    assert np.ptp(rec.height_nm) > 20.0


def test_a_y_grating_varies_along_y_only():
    g = Grating(200.0, 10.0, axis="y")
    tip = TipGeometry()
    pts = np.array([[0.0, 0.0], [137.0, 0.0], [0.0, 50.0], [-80.0, 50.0]])
    z = grating_topography(pts, g, tip, Substrate.flat())
    assert z[0] == pytest.approx(z[1]) and z[2] == pytest.approx(z[3])
    assert z[0] > z[2] + 4.0


def test_grating_refuses_bad_values_and_pushing():
    with pytest.raises(ValueError, match="pitch_nm and height_nm must be > 0"):
        Grating(0.0)
    with pytest.raises(ValueError, match="pitch_nm"):
        Grating(np.nan)
    with pytest.raises(ValueError, match="axis must be 'x' or 'y'"):
        Grating(axis="z")
    with pytest.raises(TypeError, match="grating must be a Grating"):
        VirtualAFM("gentle", grating=278.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="either particles or a grating"):
        VirtualAFM("gentle", grating=Grating(), particles=[[0.0, 0.0]])
    afm = VirtualAFM("gentle", grating=Grating())
    with pytest.raises(ValueError, match="grating sample does not allow"):
        afm.push(10.0, 0.0, 100.0)


def test_a_rotated_grating_is_constant_along_its_lines():
    g = Grating(278.0, 25.0, axis="x", angle_deg=30.0)
    tip = TipGeometry()
    a = np.radians(30.0)
    along = np.array([-np.sin(a), np.cos(a)])  # direction of the lines
    p0 = np.array([40.0, -20.0])
    pts = np.array([p0, p0 + 137.0 * along, p0 - 311.0 * along])
    z = grating_topography(pts, g, tip, Substrate.flat())
    np.testing.assert_allclose(z, z[0], atol=1e-9)
    # along the axis the period is P / cos(angle)
    x = np.array([[0.0, 0.0], [278.0 / np.cos(a), 0.0]])
    zz = grating_topography(x, g, tip, Substrate.flat())
    assert zz[0] == pytest.approx(zz[1], abs=1e-6)
    with pytest.raises(ValueError, match=r"angle_deg must be in \(-45, 45\)"):
        Grating(angle_deg=50.0)
