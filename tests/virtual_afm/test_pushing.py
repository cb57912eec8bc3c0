"""Pushing: the tidy model (friction cone), each particle's own friction, and pushes that fail
in the three ways the manipulation literature reports, reproducibly and in pieces."""

from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm import VirtualAFM, load_config
from piezocomp.virtual_afm import _kernels as K
from piezocomp.virtual_afm.config import SampleConfig
from piezocomp.virtual_afm.pushing import (
    ROLL_RELEASE_NM,
    PushParams,
    PushState,
    end_push,
    push,
    push_particles,
)
from piezocomp.virtual_afm.sample import Particles

TIP = TipGeometry(10.0, 20.0)
C = float(TIP.contact_distance(7.5, 1.0))
LINE = np.column_stack([np.linspace(0, 300, 301), np.zeros(301)])


def test_central_push_carries_the_particle_to_the_end_of_the_path():
    parts = Particles(np.array([[100.0, 0.0], [100.0, 200.0]]), np.array([15.0, 15.0]))
    out, n = push_particles(LINE, parts, TIP, 1.0)
    assert n > 0
    assert_allclose(out.xy_nm[0], [300.0 + C, 0.0], atol=1e-6)
    assert_allclose(out.xy_nm[1], parts.xy_nm[1])  # not touched: does not move


@pytest.mark.parametrize("offset", [5.0, -5.0])
def test_off_centre_push_moves_the_particle_sideways(offset):
    parts = Particles(np.array([[100.0, offset]]), np.array([15.0]))
    path = np.column_stack([np.linspace(0, 150, 151), np.zeros(151)])
    out, _ = push_particles(path, parts, TIP, 1.0)
    moved = out.xy_nm[0] - parts.xy_nm[0]
    assert moved[0] > 10 and np.sign(moved[1]) == np.sign(offset) and abs(moved[1]) > 1
    assert np.hypot(*(out.xy_nm[0] - [150.0, 0.0])) >= C - 1e-9  # left where the tip is not


@pytest.mark.parametrize("offset", [0.5, 3.0, -4.0])
def test_with_friction_a_near_central_push_carries_the_particle_straight(offset):
    """Within the friction cone (atan 0.3 = 16.7 deg) the particle moves with the tip and
    keeps its lateral position: it ends one contact distance ahead of where the tip stops."""
    parts = Particles(np.array([[100.0, offset]]), np.array([15.0]))
    path = np.column_stack([np.linspace(0, 400, 401), np.zeros(401)])
    out, _ = push_particles(path, parts, TIP, 1.0, friction=0.3)
    assert_allclose(out.xy_nm[0], [400.0 + np.sqrt(C * C - offset * offset), offset], atol=0.05)


def test_with_friction_an_off_centre_push_still_slides_off():
    parts = Particles(np.array([[100.0, 8.0]]), np.array([15.0]))  # 27 deg off: outside
    path = np.column_stack([np.linspace(0, 400, 401), np.zeros(401)])
    out, _ = push_particles(path, parts, TIP, 1.0, friction=0.3)
    assert out.xy_nm[0, 0] < 200.0 and abs(out.xy_nm[0, 1]) > 10.0


def _mix(z):
    m = (1 << 64) - 1
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & m
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & m
    return z ^ (z >> 31)


def _uniform(key, particle, engagement, slot):
    """Plain-Python oracle of the kernels' counter-based draw (splitmix64 chained)."""
    m, g = (1 << 64) - 1, 0x9E3779B97F4A7C15
    z = _mix((key + g * (particle + 1)) & m)
    z = _mix((z + g * (engagement + 1)) & m)
    z = _mix((z + g * (slot + 1)) & m)
    return (z >> 11) / 2.0**53


def test_the_draws_are_a_hash_of_key_particle_engagement_and_slot():
    key = 0xDEADBEEFCAFEBABE
    for args in [(0, 0, 0), (3, 7, 1), (123456, 2, 6)]:
        assert K.uniform(np.uint64(key), *args) == _uniform(key, *args)
    u = np.array([K.uniform(np.uint64(key), i, 0, 0) for i in range(20000)])
    assert 0 <= u.min() and u.max() < 1
    assert abs(u.mean() - 0.5) < 0.01 and abs(u.var() - 1 / 12) < 0.003


def _one(rate_name, rate=1.0, **kw):
    parts = Particles(np.array([[100.0, 0.0]]), np.array([15.0]))
    params = replace(PushParams.uniform(1, 0.3), **{rate_name: rate}, **kw)
    out, state, _ = push(LINE, parts, TIP, params, PushState.initial(1), 1.0)
    return parts, out, state, params


def test_a_stuck_particle_stays_where_it_was():
    parts, out, state, _ = _one("stuck_rate")
    assert_array_equal(out.xy_nm, parts.xy_nm)  # the tip rode over it
    assert state.counts.stuck == 1 and state.counts.engagements == 1
    assert state.on_surface.all()


def test_a_particle_that_rolls_off_leaves_the_tips_path_early():
    _, out, state, _ = _one("roll_rate")
    x, y = out.xy_nm[0]
    assert state.counts.rolled_off == 1
    assert C <= abs(y) <= 2 * C + 1e-6  # beside the path, out of the tip's reach
    assert 100.0 <= x <= 100.0 + ROLL_RELEASE_NM + C  # within its first 50 nm of travel


@pytest.mark.parametrize("drop", [0.0, 1.0])
def test_a_picked_up_particle_leaves_the_surface_and_is_lost_or_dropped(drop):
    _, out, state, params = _one("pickup_rate", drop_fraction=drop)
    assert state.counts.picked_up == 1 and not state.on_surface[0] and state.held == (0,)
    out, state = end_push(out, TIP, params, state, 1.0)
    assert state.held == () and not state.touching.any()
    if drop:
        assert state.on_surface[0] and state.counts.dropped == 1
        assert np.hypot(*(out.xy_nm[0] - LINE[-1])) <= C  # near the tip's last position
    else:
        assert not state.on_surface[0] and state.counts.lost == 1


def _field(n=400, seed=0):
    rng = np.random.default_rng(seed)
    ys = np.arange(n) * 60.0
    xy = np.column_stack([rng.uniform(80, 120, n), ys])
    return Particles(xy, np.full(n, 15.0)), ys


def _push_each(parts, ys, params, state, pieces=1):
    """Push every particle of the field once, each along its own line, the line in pieces."""
    for y in ys:
        path = np.column_stack([np.linspace(0, 300, 301), np.full(301, y)])
        for chunk in np.array_split(np.arange(301), pieces):
            a = max(chunk[0] - 1, 0)  # each piece starts where the tip is
            parts, state, _ = push(path[a : chunk[-1] + 1], parts, TIP, params, state, 1.0)
        parts, state = end_push(parts, TIP, params, state, 1.0)
    return parts, state


def test_failure_rates_are_what_was_asked_and_a_push_in_pieces_is_the_same_push():
    parts, ys = _field()
    params = replace(PushParams.uniform(len(parts), 0.3), stuck_rate=0.2, roll_rate=0.1,
                     pickup_rate=0.1, drop_fraction=0.5, key=12345)  # fmt: skip
    one, s1 = _push_each(parts, ys, params, PushState.initial(len(parts)))
    c = s1.counts
    assert c.engagements == len(parts)
    for got, rate in ((c.stuck, 0.2), (c.rolled_off, 0.1), (c.picked_up, 0.1)):
        assert abs(got / len(parts) - rate) < 4 * np.sqrt(rate * (1 - rate) / len(parts))
    assert c.dropped + c.lost == c.picked_up
    cut, s2 = _push_each(parts, ys, params, PushState.initial(len(parts)), pieces=7)
    assert_allclose(cut.xy_nm, one.xy_nm, atol=1e-9)
    assert s2.counts == c
    assert_array_equal(s2.on_surface, s1.on_surface)
    again, _ = _push_each(parts, ys, params, PushState.initial(len(parts)))
    assert_array_equal(again.xy_nm, one.xy_nm)  # the same sample fails the same way
    other, _ = _push_each(parts, ys, replace(params, key=54321), PushState.initial(len(parts)))
    assert not np.array_equal(other.xy_nm, one.xy_nm)


def test_each_particle_has_its_own_friction_drawn_per_sample():
    parts, _ = _field(2000)
    cfg = SampleConfig(tip_friction=0.3, tip_friction_spread=0.5, seed=3)
    mu = PushParams.from_config(cfg, parts).friction
    assert np.median(mu) == pytest.approx(0.3, rel=0.05)
    assert np.std(np.log(mu)) == pytest.approx(0.5, rel=0.05)
    assert_array_equal(PushParams.from_config(cfg, parts).friction, mu)  # reproducible
    assert not np.array_equal(PushParams.from_config(replace(cfg, seed=4), parts).friction, mu)
    flat = PushParams.from_config(replace(cfg, tip_friction_spread=0.0), parts).friction
    assert_allclose(flat, 0.3)


def test_a_slippery_particle_slides_off_where_a_sticky_one_is_carried():
    parts = Particles(np.array([[100.0, 2.5], [100.0, 300.0 + 2.5]]), np.array([15.0, 15.0]))
    params = PushParams(np.array([0.05, 0.8]))  # 2.9 and 38.7 degree friction cones
    for k, y in enumerate((0.0, 300.0)):
        path = np.column_stack([np.linspace(0, 300, 301), np.full(301, y)])
        out, _, _ = push(path, parts, TIP, params, PushState.initial(2), 1.0)
        end = out.xy_nm[k]
        if k == 0:
            assert end[0] < 250.0  # offset 8.5 deg from the normal: outside 2.9 degrees
        else:
            assert end[0] == pytest.approx(300.0 + np.sqrt(C * C - 2.5**2), abs=0.05)


def test_push_parameters_and_rates_are_checked():
    with pytest.raises(ValueError, match="must be <= 1"):
        PushParams(np.zeros(1), stuck_rate=0.6, roll_rate=0.6)
    with pytest.raises(ValueError, match="friction must be >= 0"):
        PushParams(np.array([-0.1]))
    with pytest.raises(ValueError, match=r"sample.push_stuck_rate \+ push_roll_rate"):
        load_config({"sample": {"push_stuck_rate": 0.5, "push_pickup_rate": 0.6}})
    with pytest.raises(ValueError, match=r"sample\.push_roll_rate must be in"):
        load_config({"sample": {"push_roll_rate": 1.5}})
    with pytest.raises(ValueError, match="describe the 2 particles"):
        two = Particles(np.array([[0.0, 0.0], [0.0, 50.0]]), np.full(2, 15.0))
        push(LINE, two, TIP, PushParams.uniform(1), PushState.initial(1), 1.0)


def _afm(**rates):
    sample = {"push_stuck_rate": 0.0, "push_roll_rate": 0.0, "push_pickup_rate": 0.0, **rates}
    sample["particle_positions_nm"] = [[0.0, 500.0], [300.0, 500.0]]
    cfg = {"scanner": {"creep": 0.0, "position_noise_nm": 0.0, "position_flicker_nm": 0.0},
           "sample": sample}  # fmt: skip
    return VirtualAFM.from_config(cfg)


def test_cpr5_pushes_fail_at_its_rates():
    s = load_config("cpr5-nodrift").sample
    assert (s.push_stuck_rate, s.push_roll_rate, s.push_pickup_rate) == (0.03, 0.02, 0.01)
    assert s.tip_friction_spread > 0


def test_on_the_instrument_a_lost_particle_leaves_the_images_and_the_truth():
    afm = _afm(push_pickup_rate=1.0, push_drop_fraction=0.0)
    afm.push(0.0, 800.0, 1000.0)
    img = afm.scan_image((0.0, 600.0), 800.0, 64, 2.0)
    assert len(afm.truth.particles()) == 1  # the other one is gone
    assert_allclose(afm.truth.particles().xy_nm, [[300.0, 500.0]])
    near_first = np.abs(img.x_nm) < 40
    assert np.nanmax(img.forward_nm[:, near_first]) < 3.0  # nothing left where it was
    assert afm.truth.push_state.counts.lost == 1


def test_on_the_instrument_a_push_in_pieces_is_one_push():
    whole, cut = _afm(push_roll_rate=0.5), _afm(push_roll_rate=0.5)
    r0 = whole.truth.tip.radius_nm
    u = np.column_stack([np.linspace(0, 40, 100), np.linspace(0, 800, 101)[1:]])
    whole.run(u, z_feedback=False)
    for a, b in ((0, 5), (5, 6), (6, 100)):
        cut.run(u[a:b], z_feedback=False)
    for afm in (whole, cut):
        afm.wait(0.0)  # Z feedback back on: the push ends, the tip has worn once
        assert afm.truth.tip.radius_nm == pytest.approx(r0 + 0.02)
    assert_allclose(cut.truth.particles().xy_nm, whole.truth.particles().xy_nm, atol=1e-9)
    assert cut.truth.push_state.counts == whole.truth.push_state.counts
