"""Particles found in images, and images registered, against known truths."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from piezocomp.imaging.features import FoundParticles, find_particles, level, particles_near_line
from piezocomp.imaging.registration import image_displacement
from piezocomp.instrument import ScanImage
from piezocomp.virtual_afm import VirtualAFM


def _blobs(centres, n=64, size=128.0, noise=0.05, seed=0, tilt=0.0):
    """An image of spheres' apex paraboloids (radius 17.5 nm caps, 15 nm high) at
    ``centres``, on a tilted plane with noise."""
    rng = np.random.default_rng(seed)
    ax = (np.arange(n) + 0.5) * size / n - size / 2
    xx, yy = np.meshgrid(ax, ax)
    z = np.zeros_like(xx)
    for cx, cy in centres:
        d2 = (xx - cx) ** 2 + (yy - cy) ** 2
        z = np.maximum(z, 15.0 - 17.5 + np.sqrt(np.maximum(17.5**2 - d2, 0)))
    z = z + tilt * xx + noise * rng.standard_normal(xx.shape)
    return ScanImage(z, z, ax, ax, 1.0)


def test_level_removes_a_plane_under_particles():
    img = _blobs([(0.0, 0.0)], tilt=0.05)
    z = level(img.forward_nm)
    assert abs(np.median(z)) < 0.05 and z.max() > 13


def test_particles_are_found_to_a_fraction_of_a_pixel():
    centres = np.array([[-30.3, 12.7], [25.1, -33.4], [35.8, 40.2]])
    found = find_particles(_blobs(centres, tilt=0.02))
    assert len(found) == 3
    got = found.positions_nm[np.lexsort((found.positions_nm[:, 0], found.positions_nm[:, 1]))]
    want = centres[np.lexsort((centres[:, 0], centres[:, 1]))]
    assert_allclose(got, want, atol=0.25)  # pixels are 2 nm
    assert np.all(found.heights_nm > 13)


def test_no_particles_on_a_flat_image_and_bad_arguments():
    assert len(find_particles(_blobs([]))) == 0
    with pytest.raises(ValueError, match="min_height_nm"):
        find_particles(_blobs([]), min_height_nm=0)
    with pytest.raises(ValueError, match="trace"):
        find_particles(_blobs([]), trace="sideways")


def test_particles_of_a_virtual_image_are_where_the_tip_truly_saw_them():
    afm = VirtualAFM("gentle", seed=2)
    img = afm.scan_image((0.0, 0.0), 400.0, 128, 1.0)
    found = find_particles(img)
    fwd, _ = img.pixel_times_s()
    tip = afm.truth.positions_at(fwd)
    true = afm.truth.particles().xy_nm
    errors = []
    for x, y in found.positions_nm:  # the true tip position at the apex pixel
        i, j = np.argmin(np.abs(img.y_nm - y)), np.argmin(np.abs(img.x_nm - x))
        errors.append(np.min(np.hypot(*(true - tip[i, j]).T)))
    assert len(found) >= 5
    assert np.median(errors) < 2.5  # within a pixel (3.1 nm) of a true centre


def test_a_line_through_particles():
    fp = FoundParticles(np.array([[0, 10.0], [50, 12], [100, 9], [70, 200], [30, 60]]),
                        np.full(5, 15.0))  # fmt: skip
    slow, along = particles_near_line(fp, axis="x", extent_nm=(-10, 120), tolerance_nm=5)
    assert slow == pytest.approx(31 / 3) and along.tolist() == [0, 50, 100]


@pytest.mark.parametrize("shift", [(3.37, -1.21), (-7.9, 4.4), (0.12, 0.05)])
def test_registration_recovers_a_known_shift(shift):
    centres = np.array([[-30.0, 10.0], [20.0, -25.0], [5.0, 35.0]])
    a = _blobs(centres, seed=1)
    b = _blobs(centres + shift, seed=2)
    d = image_displacement(a, b)
    # the taper alone would bias the shift towards zero; shifted back, the remainder is not
    assert_allclose(d.content_shift_nm, shift, rtol=0.01, atol=0.03)
    assert_allclose(d.tip_offset_nm, -np.asarray(d.content_shift_nm))
    assert d.magnitude_nm == pytest.approx(np.hypot(*shift), rel=0.01, abs=0.03)


def test_one_particle_off_centre_in_a_small_window_is_measured_unbiased():
    """A landmark window: one particle, shifted by up to a sixth of the window. A Hann taper
    alone measured a third less."""
    a = _blobs([(0.0, 0.0)], n=32, size=64.0, seed=3)
    for s in (1.0, 4.0, 10.0):
        b = _blobs([(s, -0.6 * s)], n=32, size=64.0, seed=4)
        assert_allclose(image_displacement(a, b).content_shift_nm, (s, -0.6 * s), rtol=0.02,
                        atol=0.05)  # fmt: skip


def test_registration_refuses_what_it_cannot_measure():
    a = _blobs([(0.0, 0.0)])
    with pytest.raises(ValueError, match="flat"):
        image_displacement(a, _blobs([]))
    other = ScanImage(a.forward_nm, a.backward_nm, a.x_nm + 10, a.y_nm, 1.0)
    with pytest.raises(ValueError, match="same grid"):
        image_displacement(a, other)
    far = _blobs([(45.0, 40.0)])  # one particle, far: no shared feature
    with pytest.raises(ValueError, match="share too little"):
        image_displacement(_blobs([(-45.0, -40.0)]), far)
