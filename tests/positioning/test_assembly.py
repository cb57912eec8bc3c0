"""Automatic assembly: the planner's geometry, and assemblies on ideal and compensated
scanners."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from piezocomp.positioning.assembly import (
    STAGING_NM,
    AssemblySettings,
    assemble,
    contact_distance,
    match_targets,
    plan_pushes,
)
from piezocomp.positioning.compensated import CompensatedInstrument
from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm import VirtualAFM

IDEAL = {
    "scanner": {"hysteresis": 0.0, "hysteresis_small": 0.0, "creep": 0.0},
    "sample": {"push_stuck_rate": 0.0, "push_roll_rate": 0.0, "push_pickup_rate": 0.0},
}
"""An ideal scanner whose pushes never fail (the geometry of planning alone)."""


def test_the_contact_distance_is_the_tips_geometry():
    tip = TipGeometry(10.0, 20.0)
    assert contact_distance(15.0, 10.0, 20.0, 1.0) == pytest.approx(
        float(tip.contact_distance(7.5, 1.0))
    )
    assert contact_distance(15.0, 10.0, 20.0, 6.0) == pytest.approx(
        float(tip.contact_distance(7.5, 6.0))
    )


def test_a_clear_push_goes_straight_through_the_centre():
    s = AssemblySettings(tip_radius_nm=10.0)
    pushes, blocked = plan_pushes([[0.0, 0.0]], [15.0], [[100.0, 0.0]], [0], s)
    (p,) = pushes
    c = contact_distance(15.0, s.tip_radius_nm, s.tip_half_angle_deg, s.push_height_nm)
    assert_allclose(p.start_nm, [-(c + s.approach_nm), 0.0])
    assert_allclose(p.end_nm, [100.0 - c, 0.0])
    assert blocked == ()


def test_an_obstacle_makes_the_push_go_around_or_wait():
    s = AssemblySettings(tip_radius_nm=10.0)
    # a third particle sits on the straight path: an L-shaped push (two legs) avoids it
    pushes, blocked = plan_pushes([[0.0, 0.0], [50.0, 0.0]], [15.0, 15.0], [[100.0, 40.0]],
                                  [0], s)  # fmt: skip
    assert len(pushes) == 2 and blocked == ()
    assert_allclose(pushes[0].to_nm, [0.0, 40.0])  # up first: along x it would hit it
    assert_allclose(pushes[1].to_nm, [100.0, 40.0])
    for p in pushes:  # neither leg's tip path comes near the obstacle
        a, b = np.asarray(p.start_nm), np.asarray(p.end_nm)
        t = np.clip((np.array([50.0, 0.0]) - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        assert np.hypot(*(a + t * (b - a) - [50.0, 0.0])) > contact_distance(15.0, 10.0, 20.0, 1.0)
    # a particle sitting on the target: nothing can be planned
    pushes, blocked = plan_pushes([[0.0, 0.0], [100.0, 0.0]], [15.0, 15.0], [[100.0, 0.0]], [0], s)
    assert pushes == () and blocked == (0,)


def test_the_order_makes_the_tip_travel_farthest_or_nearest():
    parts = [[-300.0, 0.0], [0.0, 200.0], [280.0, 0.0]]
    targets = [[-300.0, 40.0], [0.0, 240.0], [280.0, 40.0]]
    far, _ = plan_pushes(parts, [15.0] * 3, targets, [0, 1, 2],
                         AssemblySettings(tip_radius_nm=10.0), tip_nm=(-300.0, 0.0))  # fmt: skip
    near, _ = plan_pushes(parts, [15.0] * 3, targets, [0, 1, 2],
                          AssemblySettings(tip_radius_nm=10.0, order="nearest"),
                          tip_nm=(-300.0, 0.0))  # fmt: skip
    with pytest.raises(ValueError, match=r"needs settings\.tip_radius_nm"):
        plan_pushes(parts, [15.0] * 3, targets, [0, 1, 2], AssemblySettings())
    assert [p.particle for p in far] == [2, 0, 1]
    assert [p.particle for p in near] == [0, 1, 2]


def test_a_site_the_order_would_wall_in_is_filled_first():
    # a cell's four corners and its centre, a blunt tip (contact about 24 nm): once the
    # corners are placed no way is left to the centre, so it must be filled before them
    targets = [[-25.0, -25.0], [25.0, -25.0], [-25.0, 25.0], [25.0, 25.0], [0.0, 0.0]]
    parts = [[-150.0, -150.0], [150.0, -150.0], [-150.0, 150.0], [150.0, 150.0], [0.0, -160.0]]
    blunt = AssemblySettings(tip_radius_nm=20.0, tip_half_angle_deg=35.0)
    pushes, blocked = plan_pushes(parts, [15.0] * 5, targets, list(range(5)), blunt)
    assert blocked == ()
    order = [p.particle for p in pushes]
    assert sorted(set(order)) == [0, 1, 2, 3, 4]
    assert order.index(4) < max(order.index(i) for i in range(4))  # before the last corner
    # a sharp tip reaches the centre anyway: the paper's order (farthest first) is kept
    sharp, blocked = plan_pushes(parts, [15.0] * 5, targets, list(range(5)),
                                 replace(blunt, tip_radius_nm=10.0))  # fmt: skip
    assert blocked == () and [p.particle for p in sharp] == [0, 3, 1, 2, 4]


def test_fig10s_cells_are_planned_whole_for_a_blunt_tip():
    # Fig. 10's particle draws onto its two cells: the paper's order alone leaves a centre
    # walled in by its corners for tips of 17 nm and more (draw 1 also needs the order to
    # spare a ready centre: its one free way runs past a corner's particle not yet moved)
    from piezocomp.experiments.fig10 import Fig10Settings, qca_sites, sample_particles

    st = Fig10Settings()
    sites = qca_sites((0.0, 0.0), st.separation_nm, st.cell_half_nm)
    for draw in range(8):
        p = sample_particles(st, draw)
        asg = match_targets(p[:, :2], sites)
        for radius in (10.0, 17.0, 20.0, 26.0):
            s = AssemblySettings(tip_radius_nm=radius)
            pushes, blocked = plan_pushes(p[:, :2], p[:, 2], sites, asg, s)
            assert blocked == (), (draw, radius)
            assert {q.particle for q in pushes} == set(asg.tolist())


def test_targets_are_matched_one_each():
    idx = match_targets([[0, 0], [10, 0], [100, 100]], [[9, 1], [1, 1]])
    assert idx.tolist() == [1, 0]
    assert match_targets([[0, 0]], [[50, 50]], max_distance_nm=10).tolist() == [-1]


def _scattered(n=6, seed=0):
    rng = np.random.default_rng(seed)
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = np.array([rng.uniform(-250, 250), rng.choice([-1, 1]) * rng.uniform(90, 250)])
        if all(np.hypot(*(p - q)) > 60 for q in pts):
            pts.append(p)
    return np.array(pts)


def test_on_an_ideal_scanner_assembly_places_every_particle_within_a_nanometre():
    parts = _scattered()
    afm = VirtualAFM(IDEAL, particles=parts)
    targets = np.array(
        [[-60.0, 0.0], [-20.0, 0.0], [20.0, 0.0], [60.0, 0.0], [0, 40.0], [0, -40.0]]
    )
    res = assemble(afm, targets, center_nm=(0.0, 0.0), size_nm=600.0,
                   settings=AssemblySettings(image_pixels=192))  # fmt: skip
    true = afm.truth.particles().xy_nm
    err = np.hypot(*(true[match_targets(true, targets)] - targets).T)
    assert np.max(err) < 1.0
    assert np.max(res.errors_nm) < 1.0  # the last image says so too
    assert len(res.passes) == 2 and res.n_pushes >= 6
    # the planner learnt the tip from the images, not from the simulator
    for p in res.passes:
        assert p.tip_radius_nm == pytest.approx(afm.truth.tip.radius_nm, abs=1.0)


def test_on_cpr5_compensated_assembly_succeeds_where_raw_commands_fail(oracle_models):
    parts = _scattered(seed=3)
    targets = np.array(
        [[-60.0, 0.0], [-20.0, 0.0], [20.0, 0.0], [60.0, 0.0], [0, 40.0], [0, -40.0]]
    )
    raw = VirtualAFM("cpr5-nodrift", seed=1, particles=parts)
    res_raw = assemble(raw, targets, center_nm=(0.0, 0.0), size_nm=600.0)
    afm = VirtualAFM("cpr5-nodrift", seed=1, particles=parts)
    comp = CompensatedInstrument(afm, oracle_models)
    comp.initialise()
    o = np.mean(comp.working_area_nm, axis=1)
    res = assemble(comp, targets + o, center_nm=tuple(o), size_nm=600.0)
    assert np.max(res.errors_nm) < 3.0  # Fig. 10's tolerance
    assert not np.max(res_raw.errors_nm) < 3.0  # NaN (a site left empty) or far off


def test_bad_requests_are_refused():
    afm = VirtualAFM(IDEAL, particles=_scattered(n=2))
    with pytest.raises(ValueError, match="inside the area"):
        assemble(afm, [[900.0, 0.0]], center_nm=(0.0, 0.0), size_nm=600.0)
    with pytest.raises(ValueError, match="fewer than the 3 targets"):
        assemble(afm, [[0.0, 0.0], [30, 0], [60, 0]], center_nm=(0.0, 0.0), size_nm=600.0,
                 settings=AssemblySettings(image_pixels=64))  # fmt: skip
    with pytest.raises(ValueError, match="order"):
        AssemblySettings(order="random")


def test_the_tip_is_learnt_from_images_and_followed_as_it_blunts():
    """The virtual tip's radius is drawn per sample and blunts with every push; the planner
    estimates it from each pass's image (pixels at true positions: an ideal scanner), and a
    planner told the wrong radius misses where the estimating one does not."""
    from dataclasses import replace

    from piezocomp.virtual_afm import load_config

    blunt = load_config(IDEAL)
    sample = replace(blunt.sample, tip_radius_nm=14.0, tip_blunting_nm_per_push=0.2)
    cfg = replace(blunt, sample=sample)
    parts = _scattered()
    targets = np.array(
        [[-60.0, 0.0], [-20.0, 0.0], [20.0, 0.0], [60.0, 0.0], [0, 40.0], [0, -40.0]]
    )
    afm = VirtualAFM(cfg, particles=parts)
    r0 = afm.truth.tip.radius_nm  # drawn for this sample about 14 nm: ground truth, for scoring
    res = assemble(afm, targets, center_nm=(0.0, 0.0), size_nm=600.0,
                   settings=AssemblySettings(image_pixels=192))  # fmt: skip
    first, second = res.passes
    assert first.tip_radius_nm == pytest.approx(r0, abs=1.0)
    grown = r0 + 0.2 * len(first.pushes)
    assert second.tip_radius_nm == pytest.approx(grown, abs=1.0)
    assert np.max(res.errors_nm) < 1.0
    wrong = VirtualAFM(cfg, particles=parts)
    fixed = AssemblySettings(image_pixels=192, tip_radius_nm=6.0, passes=1)
    told = assemble(wrong, targets, center_nm=(0.0, 0.0), size_nm=600.0, settings=fixed)
    assert not np.nanmax(told.errors_nm) < 1.0


def test_the_tip_radius_of_the_virtual_afm_is_drawn_per_sample():
    from dataclasses import replace

    from piezocomp.virtual_afm import load_config

    cfg = load_config("cpr5-nodrift")
    cfg = replace(cfg, sample=replace(cfg.sample, tip_radius_spread=0.3))
    radii = {VirtualAFM(cfg, seed=s).truth.tip.radius_nm for s in range(1, 9)}
    assert len(radii) == 8 and all(7.0 <= r <= 13.0 for r in radii)
    assert VirtualAFM(cfg, seed=3).truth.tip.radius_nm in radii  # the same sample, the same tip


TARGETS6 = np.array([[-60.0, 0.0], [-20.0, 0.0], [20.0, 0.0], [60.0, 0.0], [0, 40.0], [0, -40.0]])


class _OneParticleStuck:
    """The ideal instrument, except that one particle never moves: a push that reaches it
    rides over it (Z feedback on: nothing moves). A test double; the planner sees only its
    images."""

    def __init__(self, afm, stuck_nm):
        self._afm = afm
        self._stuck = np.asarray(stuck_nm, dtype=float)

    def __getattr__(self, name):
        return getattr(self._afm, name)

    def push(self, x_nm, y_nm, speed_nm_per_s):
        a, b = np.asarray(self._afm.command_nm), np.array([x_nm, y_nm])
        t = np.clip((self._stuck - a) @ (b - a) / max((b - a) @ (b - a), 1e-12), 0, 1)
        if np.hypot(*(a + t * (b - a) - self._stuck)) < 25.0:
            return self._afm.move_to(x_nm, y_nm, speed_nm_per_s)
        return self._afm.push(x_nm, y_nm, speed_nm_per_s)


def test_the_planner_sees_a_particle_that_will_not_move_and_replans_with_another():
    parts = _scattered(n=8)
    stuck = parts[match_targets(parts, TARGETS6)[0]]  # the first target's particle
    afm = VirtualAFM(IDEAL, particles=parts)
    res = assemble(_OneParticleStuck(afm, stuck), TARGETS6, center_nm=(0.0, 0.0),
                   size_nm=600.0, settings=AssemblySettings(image_pixels=192))  # fmt: skip
    # pushed twice where it stayed, then left alone: another particle took its target
    assert res.failures == {"stuck": 2, "off_target": 0, "vanished": 0}
    assert res.recoveries == {"pushed_again": 1, "another_particle": 1, "none": 0}
    assert all(c.target == 0 for c in res.failed_pushes)
    assert np.max(res.errors_nm) < 1.0
    true = afm.truth.particles().xy_nm
    assert np.max(np.hypot(*(true[match_targets(true, TARGETS6)] - TARGETS6).T)) < 1.0
    assert_allclose(true[np.argmin(np.hypot(*(true - stuck).T))], stuck)  # still there
    assert len(res.passes) == 4  # two, one to push it again, one to replace it


@pytest.mark.parametrize(
    ("rate", "kind"),
    [("push_stuck_rate", "stuck"), ("push_roll_rate", "off_target"),
     ("push_pickup_rate", "vanished")],
)  # fmt: skip
def test_when_every_push_fails_the_images_say_how_and_the_assembly_is_not_a_success(rate, kind):
    cfg = {**IDEAL, "sample": {**IDEAL["sample"], rate: 1.0, "push_drop_fraction": 0.0}}
    afm = VirtualAFM(cfg, particles=_scattered(n=8))
    s = AssemblySettings(image_pixels=128, recovery_passes=1)
    res = assemble(afm, TARGETS6, center_nm=(0.0, 0.0), size_nm=600.0, settings=s)
    f = res.failures
    assert f[kind] >= 6 and sum(f.values()) == f[kind]  # every failure of the named kind
    assert len(res.passes) == s.passes + s.recovery_passes  # bounded
    assert res.recoveries["none"] >= 1  # the last pass's failures: no pass left
    assert sum(res.recoveries.values()) == len(res.failed_pushes)
    assert not np.max(res.errors_nm) < 3.0  # NaN (a site without a particle) or far


class _OneParticleSlips(_OneParticleStuck):
    """The ideal instrument, except that the pushes of one particle (``_index`` among the
    true ones) go 8 nm to the side of where they are sent (as if it were slippery, or its
    position badly known): it slides off the tip every time. A test double, as above."""

    def push(self, x_nm, y_nm, speed_nm_per_s):
        a, b = np.asarray(self._afm.command_nm), np.array([x_nm, y_nm])
        here = self._afm.truth.particles().xy_nm[self._index]  # wherever it went (test side)
        t = np.clip((here - a) @ (b - a) / max((b - a) @ (b - a), 1e-12), 0, 1)
        if np.hypot(*(a + t * (b - a) - here)) >= 25.0:
            return self._afm.push(x_nm, y_nm, speed_nm_per_s)
        side = np.array([-(b - a)[1], (b - a)[0]]) / np.hypot(*(b - a)) * 8.0
        self._afm.move_to(*(a + side), speed_nm_per_s)
        return self._afm.push(*(b + side), speed_nm_per_s)


def test_a_particle_that_keeps_sliding_off_is_replaced_by_another():
    parts = _scattered(n=8)
    k = int(match_targets(parts, TARGETS6)[0])
    afm = VirtualAFM(IDEAL, particles=parts)
    inst = _OneParticleSlips(afm, parts[k])
    inst._index = k
    res = assemble(inst, TARGETS6, center_nm=(0.0, 0.0), size_nm=600.0,
                   settings=AssemblySettings(image_pixels=192))  # fmt: skip
    assert res.failures["off_target"] == 2 and res.failures["stuck"] == 0
    assert res.recoveries["pushed_again"] == 1 and res.recoveries["another_particle"] == 1
    assert np.max(res.errors_nm) < 1.0


def test_a_site_walled_in_on_its_straight_and_l_ways_is_reached_by_a_staging_point():
    # Fig. 10's cells placed but one site, its particle lost (picked up by the tip); the one
    # particle left lies far above the left cell: to the bottom-right corner of that cell
    # the straight way and both L-shapes run into placed corners; a way that stages the
    # particle below the site and pushes it up into place is clear
    from piezocomp.experiments.fig10 import Fig10Settings, qca_sites

    st = Fig10Settings()
    sites = qca_sites((0.0, 0.0), st.separation_nm, st.cell_half_nm)
    for k in range(len(sites)):
        parts = np.vstack([np.delete(sites, k, axis=0), [[-280.0, 340.0]]])
        asg = np.array([i if i < k else i - 1 for i in range(len(sites))])
        asg[k] = len(parts) - 1
        pushes, blocked = plan_pushes(parts, [15.0] * len(parts), sites, asg,
                                      AssemblySettings(tip_radius_nm=10.0))  # fmt: skip
        assert blocked == (), k
        assert np.allclose(pushes[-1].to_nm, sites[k]), k
    # the case that failed: site 2 (-125, -25), reached by a staging point beside it
    parts = np.vstack([np.delete(sites, 2, axis=0), [[-280.0, 340.0]]])
    asg = np.array([0, 1, 9, 2, 3, 4, 5, 6, 7, 8])
    pushes, _ = plan_pushes(parts, [15.0] * 10, sites, asg, AssemblySettings(tip_radius_nm=10.0))
    stages = sites[2] + STAGING_NM * np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])
    assert min(np.hypot(*(np.asarray(pushes[-2].to_nm) - q)) for q in stages) < 1e-9
    # a staging point outside the area the pushes may use is not tried (there particles go
    # unseen, or the scanner's range ends): the site is blocked again
    box = ((-130.0, -120.0), (-30.0, -20.0))
    _, blocked = plan_pushes(parts, [15.0] * 10, sites, asg, AssemblySettings(tip_radius_nm=10.0),
                             within_nm=box)  # fmt: skip
    assert blocked == (2,)
    with pytest.raises(ValueError, match="within_nm must be"):
        plan_pushes(parts, [15.0] * 10, sites, asg, AssemblySettings(tip_radius_nm=10.0),
                    within_nm=((0.0, -1.0), (0.0, 1.0)))  # fmt: skip
