"""The line's slide across its particles, measured on dithered settling cycles.

The synthetic records are the mathematics only (caps of known shape sliding at a known
rate); the virtual AFM test scores the measurement against the simulator's drift.
"""

import numpy as np
import pytest

from piezocomp.identification.acquisition.drift_across_line import (
    CrossDrift,
    cross_line_drift,
    dither_offsets,
)


def _record(rate, dither, n_cycles=40, m=400, noise=0.05, seed=0, slide=None):
    """Settling cycles over 1000 nm (m samples per trace, 0.02 s each) of a line crossing
    five caps whose cross offsets slide at ``rate`` nm/s of slow command (or by
    ``slide(t)``, 0 at the start of the second half)."""
    rng = np.random.default_rng(seed)
    T = 0.02
    up = np.linspace(-500.0, 500.0, m + 1)
    cycle = np.concatenate([up, up[::-1][1:]])
    u = np.concatenate([cycle[:1], *([cycle[1:]] * n_cycles)])
    t = np.arange(u.size) * T
    steps = dither_offsets(n_cycles, dither)
    s = np.concatenate([[0.0], np.repeat(steps, 2 * m)])
    centres = np.array([-300.0, -120.0, 40.0, 210.0, 380.0])
    offsets = np.array([-6.0, 3.0, 5.0, -2.0, -8.0])  # at the start of the second half
    radius = 25.0
    t_half = t[(n_cycles // 2) * 2 * m]
    z = np.zeros(u.size)
    for c, d in zip(centres, offsets, strict=True):
        moved = rate * (t - t_half) if slide is None else slide(t) - slide(t_half)
        x = d + s - moved  # where the line crosses this cap
        top = np.sqrt(np.clip(radius**2 - x**2, 0.0, None))
        z += top * np.exp(-0.5 * ((u - c) / 6.0) ** 2)
    z += noise * rng.standard_normal(u.size)
    slow = 100.0 + s
    return u, z, t, slow, 2 * m


@pytest.mark.parametrize("rate", [-0.04, 0.0, 0.03])
def test_rate_recovered_with_its_sign(rate):
    u, z, t, slow, per = _record(rate, dither=3.0)
    found = cross_line_drift(u, z, t, slow, per, min_prominence_nm=3.0)
    assert isinstance(found, CrossDrift)
    assert found.particles == 5
    assert found.rate_nm_per_s == pytest.approx(rate, abs=0.004)
    assert found.residual_nm < 0.2
    moving = abs(rate) > 0
    assert found.significant(found.end_s, 200.0) == moving
    assert found.creep_nm == 0.0  # no time of a last move given: a steady slide
    if moving:
        assert found.still_residual_nm > 3 * found.residual_nm


def test_without_dither_nothing_is_claimed():
    u, z, t, slow, per = _record(-0.04, dither=0.0)
    assert cross_line_drift(u, z, t, slow, per, min_prominence_nm=3.0) is None


def test_too_few_cycles():
    u, z, t, slow, per = _record(0.02, dither=3.0, n_cycles=6)
    assert cross_line_drift(u, z, t, slow, per, min_prominence_nm=3.0) is None


def test_creep_after_a_move_told_from_drift():
    """A slide that is a drift plus the logarithmic creep of a move at t = -200 s: both
    recovered, and so is the slide over the next minutes (what the record follows)."""
    truth = CrossDrift(0.0, 0, 0.0, 0.0, 0.0, drift_nm_per_s=-0.02, creep_nm=20.0,
                       since_s=-200.0, t0_s=0.0)  # fmt: skip
    u, z, t, slow, per = _record(0.0, dither=3.0, slide=truth.slide_nm)
    found = cross_line_drift(u, z, t, slow, per, min_prominence_nm=3.0, since_s=-200.0)
    assert found is not None
    assert found.creep_nm != 0.0
    end = float(t[-1])
    for dt in (100.0, 300.0):
        assert found.moved_nm(end, dt) == pytest.approx(truth.moved_nm(end, dt), abs=0.5)
    steady = cross_line_drift(u, z, t, slow, per, min_prominence_nm=3.0)
    assert steady is not None
    assert abs(steady.moved_nm(end, 300.0) - truth.moved_nm(end, 300.0)) > 1.0


def test_dither_offsets():
    s = dither_offsets(5, 2.0)
    assert s.tolist() == [-2.0, 0.0, -2.0, 0.0, 0.0]
    assert dither_offsets(4, 2.0)[-1] == 0.0


def test_virtual_afm_drift_across_the_line_followed():
    """Scored against the simulator's drift: on cpr5 the y line is crossed by the
    sample's x drift (and the x axis' creep); the settling cycles measure it with its sign,
    and the record's slow command follows it."""
    from piezocomp.experiments.methods import IdentificationSettings
    from piezocomp.identification.acquisition.recording import record_axis
    from piezocomp.virtual_afm import VirtualAFM, load_config

    afm = VirtualAFM(load_config("cpr5"), seed=1)
    cfg = IdentificationSettings().config(afm.range_nm, extra_lines=0)
    d0, t0 = np.array(afm.truth.scanner_state.drift_nm), afm.time_s
    records = record_axis(afm, cfg.acquisition, "y", loop_degree=cfg.loop.degree)
    rate_true = (np.array(afm.truth.scanner_state.drift_nm) - d0)[0] / (afm.time_s - t0)
    found = records.cross_drift
    assert found is not None and found.particles >= 3
    # The tip drifts one way, the slow command follows the other way (plus the x axis' own
    # creep, a few thousandths of a nm/s by then).
    assert found.rate_nm_per_s == pytest.approx(-rate_true, abs=0.01)
    assert found.followed
    # followed, the line's profile barely changes over the record
    assert records.line_stability is not None
    assert records.line_stability.height_change_rms_nm < 1.5


def test_no_dither_no_following():
    from piezocomp.experiments.methods import IdentificationSettings
    from piezocomp.identification.acquisition.recording import record_axis
    from piezocomp.virtual_afm import VirtualAFM, load_config

    afm = VirtualAFM(load_config("cpr5"), seed=1)
    cfg = IdentificationSettings().config(afm.range_nm, extra_lines=0, cross_dither_nm=0.0)
    records = record_axis(afm, cfg.acquisition, "y", loop_degree=cfg.loop.degree)
    assert records.cross_drift is None
