"""VirtualAFM: the instrument interface, limits, determinism, the ground-truth door."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from piezocomp.instrument import Instrument, Record, ScanImage
from piezocomp.virtual_afm import VirtualAFM


@pytest.fixture(scope="module")
def gentle():
    return VirtualAFM.from_preset("gentle", seed=4)


def test_implements_the_protocol(gentle):
    assert isinstance(gentle, Instrument)
    assert gentle.range_nm == 5000.0 and gentle.sample_period_s == 0.008


def test_out_of_range_or_too_fast_commands_are_refused_and_nothing_happens():
    afm = VirtualAFM.from_preset("gentle")
    t0, u0, p0 = afm.time_s, afm.command_nm, afm.truth.tip_position_nm()
    with pytest.raises(ValueError, match="outside the scanner range"):
        afm.run(np.array([[0.0, 0.0], [2600.0, 0.0]]))
    with pytest.raises(ValueError, match="slew limit"):
        afm.run(np.array([[0.0, 0.0], [0.0, 500.0]]))
    with pytest.raises(ValueError, match="speed_nm_per_s"):
        afm.move_to(100.0, 0.0, 1e9)
    assert (afm.time_s, afm.command_nm, afm.truth.tip_position_nm()) == (t0, u0, p0)


def test_deterministic_for_a_seed():
    def session(seed):
        afm = VirtualAFM.from_preset("harsh", seed=seed)
        r1 = afm.move_to(400.0, -300.0, 1000.0)
        img = afm.scan_image((400.0, -300.0), 200.0, 16, 8.0)
        return r1.height_nm, img.forward_nm, afm.truth.particles().xy_nm

    a, b, c = session(7), session(7), session(8)
    for x, y in zip(a, b, strict=True):
        assert_array_equal(x, y)
    assert not np.array_equal(a[2], c[2])


def test_record_and_image_shapes_and_ground_truth(gentle):
    r = gentle.move_to(200.0, 100.0, 1000.0)
    assert isinstance(r, Record) and len(r) == 28
    assert_allclose(r.command_nm[-1], [200.0, 100.0])
    assert gentle.truth.last_record_positions_nm.shape == (28, 2)
    assert_allclose(np.diff(r.t_s), 0.008)
    img = gentle.scan_image((200.0, 100.0), 300.0, 32, 4.0)
    assert isinstance(img, ScanImage) and img.forward_nm.shape == (32, 32)
    fwd, bwd = gentle.truth.last_image_positions_nm
    assert fwd.shape == bwd.shape == (32, 32, 2)
    assert_allclose(img.line_time_s, 0.25)


def test_forward_and_backward_traces_are_offset_on_cpr5():
    """Fig. 2: a 910 nm line at 2 Hz shows the particles at different places forward and
    backward (hysteresis + creep); the true offset is tens of nm on cpr5."""
    afm = VirtualAFM.from_preset("cpr5-nodrift")
    img = afm.scan_image((0.0, 0.0), 910.0, 64, 2.0)
    fwd, bwd = afm.truth.last_image_positions_nm
    offset = np.abs(fwd[..., 0] - bwd[..., 0]).max()
    assert 10.0 < offset < 200.0
    assert img.forward_nm.max() > 10.0  # particles are seen


def test_a_y_fast_image_holds_y_traces_in_its_columns():
    """Scan angle 90 degrees (the y axis' overview): columns are y lines, the hysteresis
    offset between forward and backward is along y, and the arrays stay (ny, nx)."""
    afm = VirtualAFM.from_preset("cpr5-nodrift")
    img = afm.scan_image((0.0, 0.0), 910.0, 64, 2.0, fast_axis="y")
    fwd, bwd = afm.truth.last_image_positions_nm
    assert img.forward_nm.shape == fwd.shape[:2] == (64, 64)
    # along a column (fixed x pixel) the true y rises; x hardly moves
    col = fwd[:, 10]
    assert np.all(np.diff(col[:, 1]) > 0)
    assert np.ptp(col[:, 0]) < 0.2 * np.ptp(col[:, 1])
    y_offset = np.median(np.abs(fwd[..., 1] - bwd[..., 1]))
    x_offset = np.median(np.abs(fwd[..., 0] - bwd[..., 0]))  # slow-axis creep only
    assert 10.0 < y_offset < 200.0 and x_offset < 0.05 * y_offset
    # the heights are the sample seen at those true positions: the same particles as an
    # x-fast image of the area, transposed roles
    assert img.forward_nm.max() > 10.0
    with pytest.raises(ValueError, match="fast_axis"):
        afm.scan_image((0.0, 0.0), 910.0, 8, 2.0, fast_axis="z")


def test_height_noise_and_particles_stay_put_while_imaging():
    cfg = {"sample": {"roughness_nm": 0.0, "particle_positions_nm": [[1000.0, 1000.0]]}}
    afm = VirtualAFM.from_config(cfg, seed=2)
    r = afm.wait(8.0)
    assert_allclose(r.height_nm.std(), 0.1, rtol=0.1)
    afm.move_to(1000.0, 1000.0, 2000.0)
    afm.scan_image((1000.0, 1000.0), 100.0, 16, 4.0)
    assert_array_equal(afm.truth.particles().xy_nm, [[1000.0, 1000.0]])


def test_push_moves_a_particle_along_the_true_path():
    cfg = {"scanner": {"creep": 0.0, "position_noise_nm": 0.0, "position_flicker_nm": 0.0},
           "sample": {"particle_positions_nm": [[0.0, 500.0]], "push_stuck_rate": 0.0,
                      "push_roll_rate": 0.0, "push_pickup_rate": 0.0}}  # fmt: skip
    afm = VirtualAFM.from_config(cfg)
    tip = afm.truth.tip  # as it was during the push; it wears with it
    r = afm.push(0.0, 800.0, 1000.0)
    assert np.all(np.isnan(r.height_nm))
    end = afm.truth.tip_position_nm()
    xy = afm.truth.particles().xy_nm[0]
    z_met = afm.truth.push_params.z_push_nm(afm.config.sample.push_height_nm)[0]
    assert z_met != afm.config.sample.push_height_nm  # drawn per particle, hidden
    assert abs(z_met - afm.config.sample.push_height_nm) <= afm.config.sample.push_height_spread_nm
    contact = tip.contact_distance(7.5, z_met)
    assert_allclose(xy, [end[0], end[1] + contact], atol=1e-6)  # carried ahead of the tip
    blunting = afm.config.sample.tip_blunting_nm_per_push
    afm.move_to(0.0, 700.0, 1000.0)  # Z feedback back on: the push has ended, the tip worn
    assert afm.truth.tip.radius_nm == pytest.approx(tip.radius_nm + blunting)


def test_one_run_equals_the_same_commands_in_pieces():
    def heights(pieces):
        afm = VirtualAFM.from_preset("harsh", seed=11)
        u = np.column_stack([np.linspace(0, 300, 90), np.linspace(0, -200, 90)])
        recs = [afm.run(u[a:b]) for a, b in pieces]
        return np.concatenate([r.height_nm for r in recs]), afm.truth.tip_position_nm()

    h1, p1 = heights([(0, 90)])
    h2, p2 = heights([(0, 1), (1, 40), (40, 90)])
    assert_allclose(h2, h1, atol=1e-9)
    assert_allclose(p2, p1, atol=1e-9)


def test_too_fast_image_is_refused_with_the_reason():
    afm = VirtualAFM.from_preset("gentle")
    with pytest.raises(ValueError, match="lower line_rate_hz or size_nm"):
        afm.scan_image((0.0, 0.0), 5000.0, 64, 10.0)
    with pytest.raises(ValueError, match="outside the scanner range"):
        afm.scan_image((2400.0, 0.0), 500.0, 16, 1.0)


def test_run_at_another_period_and_with_z_feedback_off():
    cfg = {"scanner": {"creep": 0.0}, "sample": {"particle_positions_nm": [[0.0, 100.0]]}}
    afm = VirtualAFM.from_config(cfg)
    u = np.column_stack([np.zeros(50), np.linspace(0.0, 50.0, 50)])
    r = afm.run(u, sample_period_s=0.001)
    assert_allclose(np.diff(r.t_s), 0.001)
    assert afm.time_s == pytest.approx(0.05)
    down = np.column_stack([np.zeros(100), np.linspace(51.0, 250.0, 100)])
    r = afm.run(down, sample_period_s=0.01, z_feedback=False)
    assert np.all(np.isnan(r.height_nm))
    assert afm.truth.particles().xy_nm[0, 1] > 150.0  # pushed
    with pytest.raises(ValueError, match="sample_period_s"):
        afm.run(u, sample_period_s=0.0)


def test_true_positions_are_found_by_the_times_of_records_and_pixels():
    afm = VirtualAFM.from_preset("cpr5-nodrift", seed=2)
    r = afm.move_to(100.0, 50.0, 1000.0)
    assert_allclose(afm.truth.positions_at(r.t_s), afm.truth.last_record_positions_nm)
    img = afm.scan_image((100.0, 50.0), 80.0, 16, 4.0, fast_axis="y")
    fwd, bwd = img.pixel_times_s()
    pf, pb = afm.truth.last_image_positions_nm
    assert_allclose(afm.truth.positions_at(fwd), pf)
    assert_allclose(afm.truth.positions_at(bwd), pb)
    with pytest.raises(ValueError, match="no true position logged"):
        afm.truth.positions_at([r.t_s[0] + 0.5 * afm.sample_period_s])


def test_truth_reports_the_drift_inside_each_position():
    """Positions less the reported drift are the drift-free scanner's (a steady drift draws
    no random number, so both runs see the same noise), for records, pushes and images."""
    from dataclasses import replace

    from piezocomp.virtual_afm import load_config

    base = load_config("cpr5-nodrift")
    drifting = replace(base, scanner=replace(base.scanner, drift_nm_per_s=0.05))
    still, moving = VirtualAFM(base, seed=3), VirtualAFM(drifting, seed=3)
    for afm in (still, moving):
        afm.move_to(200.0, -100.0, 500.0)
        afm.wait(30.0)
    r0 = still.move_to(-300.0, 50.0, 800.0)
    moving.move_to(-300.0, 50.0, 800.0)
    own = moving.truth.last_record_positions_nm - moving.truth.last_record_drift_nm
    assert_allclose(own, still.truth.last_record_positions_nm, atol=1e-9)
    assert moving.truth.last_record_drift_nm.shape == (len(r0), 2)
    assert np.hypot(*moving.truth.last_record_drift_nm[-1]) == pytest.approx(
        0.05 * r0.t_s[-1], rel=0.01
    )
    assert_array_equal(still.truth.last_record_drift_nm, 0.0)
    still.scan_image((0.0, 0.0), 100.0, 16, 4.0)
    moving.scan_image((0.0, 0.0), 100.0, 16, 4.0)
    own = moving.truth.last_record_positions_nm - moving.truth.last_record_drift_nm
    assert_allclose(own, still.truth.last_record_positions_nm, atol=1e-9)


def test_the_tip_angle_and_the_push_heights_are_drawn_per_sample_and_particle():
    from piezocomp.virtual_afm.config import SampleConfig
    from piezocomp.virtual_afm.worked_sample import drawn_tip

    angles = {drawn_tip(SampleConfig(seed=s)).half_angle_deg for s in range(1, 30)}
    assert len(angles) == 29 and 12 <= min(angles) < 15 and 25 < max(angles) <= 28
    assert drawn_tip(SampleConfig(tip_half_angle_spread_deg=0.0)).half_angle_deg == 20.0
    afm = VirtualAFM.from_config("cpr5", seed=3)
    z = afm.truth.push_params.z_push_nm(1.0)
    assert z.size == len(afm.truth.particles()) and 0.5 <= z.min() < 0.6 and 1.4 < z.max() <= 1.5
    # never below the substrate, whatever the setting
    assert afm.truth.push_params.z_push_nm(0.2).min() == 0.0
    with pytest.raises(ValueError, match="push_height_nm \\+ push_height_spread_nm"):
        SampleConfig(push_height_nm=14.8)
    with pytest.raises(ValueError, match="tip_half_angle_spread_deg must lie in"):
        SampleConfig(tip_half_angle_deg=85.0)
