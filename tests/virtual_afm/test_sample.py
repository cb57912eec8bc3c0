"""Tip dilation against the analytic geometry; pushing."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm.sample import Particles, Substrate, push_particles, topography


def _profile(tip, R, xs):
    parts = Particles(np.array([[0.0, 0.0]]), np.array([2 * R]))
    pos = np.column_stack([xs, np.zeros_like(xs)])
    return topography(pos, parts, tip, Substrate.flat())


def _width(xs, h):
    above = xs[h > 1e-9]
    return above.max() - above.min()


def test_sphere_imaged_by_a_sphere_has_the_analytic_profile_and_width():
    R, r = 7.5, 10.0
    tip = TipGeometry(r, 5.0)  # the zero of the profile falls on the spherical part
    xs = np.linspace(-40, 40, 160001)
    h = _profile(tip, R, xs)
    assert_allclose(h.max(), 2 * R, atol=1e-9)  # apex over the centre: 2R
    inside = np.abs(xs) < 15
    assert_allclose(h[inside], np.sqrt((R + r) ** 2 - xs[inside] ** 2) - r + R, atol=1e-9)
    # zero of sqrt((R+r)^2 - d^2) + R - r: d0 = sqrt((R+r)^2 - (r-R)^2) = 2 sqrt(R r)
    assert_allclose(_width(xs, h), 2 * 2 * np.sqrt(R * r), atol=1e-3)


def test_cone_flank_width():
    R, r, theta = 7.5, 10.0, 20.0
    t = np.radians(theta)
    xs = np.linspace(-60, 60, 240001)
    h = _profile(TipGeometry(r, theta), R, xs)
    d0 = (R + (R + r) / np.sin(t) - r) * np.tan(t)
    assert_allclose(_width(xs, h), 2 * d0, atol=1e-3)
    tip = TipGeometry(r, theta)
    for z in (0.0, 1.0, 5.0, 12.0):
        d = tip.contact_distance(R, z)
        assert_allclose(tip.apparent_height(d, R), z, atol=1e-9)


def test_central_push_carries_the_particle_to_the_end_of_the_path():
    tip = TipGeometry(10.0, 20.0)
    parts = Particles(np.array([[100.0, 0.0], [100.0, 200.0]]), np.array([15.0, 15.0]))
    path = np.column_stack([np.linspace(0, 300, 301), np.zeros(301)])
    out, n = push_particles(path, parts, tip, 1.0)
    c = tip.contact_distance(7.5, 1.0)
    assert n > 0
    assert_allclose(out.xy_nm[0], [300.0 + c, 0.0], atol=1e-6)
    assert_allclose(out.xy_nm[1], parts.xy_nm[1])  # not touched: does not move


@pytest.mark.parametrize("offset", [5.0, -5.0])
def test_off_centre_push_moves_the_particle_sideways(offset):
    tip = TipGeometry(10.0, 20.0)
    parts = Particles(np.array([[100.0, offset]]), np.array([15.0]))
    path = np.column_stack([np.linspace(0, 150, 151), np.zeros(151)])
    out, _ = push_particles(path, parts, tip, 1.0)
    moved = out.xy_nm[0] - parts.xy_nm[0]
    assert moved[0] > 10 and np.sign(moved[1]) == np.sign(offset) and abs(moved[1]) > 1
    c = tip.contact_distance(7.5, 1.0)
    assert np.hypot(*(out.xy_nm[0] - [150.0, 0.0])) >= c - 1e-9  # left where the tip is not


@pytest.mark.parametrize("offset", [0.5, 3.0, -4.0])
def test_with_friction_a_near_central_push_carries_the_particle_straight(offset):
    """Within the friction cone (atan 0.3 = 16.7 deg) the particle moves with the tip and
    keeps its lateral position: it ends one contact distance ahead of where the tip stops."""
    tip = TipGeometry(10.0, 20.0)
    c = float(tip.contact_distance(7.5, 1.0))
    parts = Particles(np.array([[100.0, offset]]), np.array([15.0]))
    path = np.column_stack([np.linspace(0, 400, 401), np.zeros(401)])
    out, _ = push_particles(path, parts, tip, 1.0, friction=0.3)
    assert_allclose(out.xy_nm[0], [400.0 + np.sqrt(c * c - offset * offset), offset], atol=0.05)


def test_with_friction_an_off_centre_push_still_slides_off():
    tip = TipGeometry(10.0, 20.0)
    parts = Particles(np.array([[100.0, 8.0]]), np.array([15.0]))  # 27 deg off: outside
    path = np.column_stack([np.linspace(0, 400, 401), np.zeros(401)])
    out, _ = push_particles(path, parts, tip, 1.0, friction=0.3)
    assert out.xy_nm[0, 0] < 200.0 and abs(out.xy_nm[0, 1]) > 10.0
