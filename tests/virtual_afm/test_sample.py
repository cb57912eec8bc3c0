"""Tip dilation against the analytic geometry."""

import numpy as np
from numpy.testing import assert_allclose

from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm.sample import Particles, Substrate, topography


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
