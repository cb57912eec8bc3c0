"""The 2-D scanner against the definitions of its keys."""

import numpy as np
from numpy.testing import assert_allclose

from piezocomp.virtual_afm import load_config, scanner_params_from_config
from piezocomp.virtual_afm.config import AFMConfig, ScannerConfig
from piezocomp.virtual_afm.preisach import loop_hysteresis
from piezocomp.virtual_afm.scanner import ScannerState, simulate


def _params(**kw):
    """The scanner's keys as given, the rest cpr5's, without noise and with the creep a
    linear filter of the command unless asked (the keys' definitions hold exactly then)."""
    quiet = {"position_noise_nm": 0.0, "position_flicker_nm": 0.0, "creep_domain_fraction": 0.0}
    return scanner_params_from_config(AFMConfig(ScannerConfig(**{**quiet, **kw})))


def test_full_range_cycle_measures_the_hysteresis_key_for_every_preset():
    for name in ("cpr5-nodrift", "gentle", "harsh"):
        s = load_config(name).scanner
        p = _params(hysteresis=s.hysteresis, hysteresis_small=s.hysteresis_small,
                    hysteresis_asymmetry=s.hysteresis_asymmetry, creep=0.0)  # fmt: skip
        h = p.half_range_nm
        ramp = np.linspace(-h, h, 4001)
        u = np.concatenate([ramp[::-1], ramp, ramp[::-1]])
        pos, _ = simulate(p, np.column_stack([u, u]), 0.01, ScannerState.initial(p))
        cyc = slice(4000, 12001)
        for axis in (0, 1):
            measured = loop_hysteresis(u[cyc], pos[cyc, axis]) * (
                np.ptp(pos[cyc, axis]) / p.range_nm
            )
            assert abs(measured / s.hysteresis - 1) < 0.1, (name, measured)


def test_step_measures_the_creep_key_for_every_preset():
    for name in ("cpr5-nodrift", "gentle", "harsh"):
        s = load_config(name).scanner
        p = _params(creep=s.creep, hysteresis=s.hysteresis, hysteresis_small=s.hysteresis_small)
        T = 0.01
        u = np.zeros((10001, 2))
        u[:, 0] = 1000.0
        u[0, 0] = 0.0
        pos, _ = simulate(p, u, T, ScannerState.initial(p))
        measured = (pos[10000, 0] - pos[10, 0]) / 1000.0  # 100 s and 0.1 s after the step
        assert abs(measured / s.creep - 1) < 0.1, (name, measured)


def test_drift_off_is_exactly_zero_and_a_repeated_path_returns_exactly():
    """With drift off (and creep off, which never settles), the drift term is exactly zero
    and, after the memory is wiped by a full-range excursion, the same closed path from
    the same command ends at the same true position: only the scanner's state matters."""
    p = _params(creep=0.0)
    assert not p.drift_on
    h = p.half_range_nm
    rng = np.random.default_rng(0)
    path = np.vstack([np.linspace([0, 0], [h, h], 50), rng.uniform(-800, 800, (40, 2)), [[0, 0]]])
    state = ScannerState.initial(p, (0.0, 0.0))
    pos1, state = simulate(p, path, 0.008, state)
    pos2, state = simulate(p, path, 0.008, state)
    assert np.all(state.drift_nm == 0.0)
    wiped = 49  # from the full-range corner on, the history before it is forgotten
    assert_allclose(pos2[wiped:], pos1[wiped:], atol=1e-9, rtol=0)


def test_constant_drift_and_cross_coupling():
    p = _params(creep=0.0, hysteresis=0.0, drift_nm_per_s=0.5, drift_direction_deg=90.0,
                cross_coupling=0.02)  # fmt: skip
    u = np.column_stack([np.linspace(0, 1000, 1001), np.zeros(1001)])
    pos, st = simulate(p, u, 0.01, ScannerState.initial(p))
    t = 0.01 * (np.arange(1001) + 1)
    assert_allclose(pos[:, 0], u[:, 0], atol=1e-9)  # drift along +y only
    assert_allclose(pos[:, 1], 0.02 * u[:, 0] + 0.5 * t, atol=1e-9)
    assert_allclose(st.drift_nm, [0, 0.5 * 10.01], atol=1e-9)


def test_batch_equals_chunked_stream_with_drift_and_coupling():
    p = scanner_params_from_config(load_config("harsh"))
    u = np.cumsum(np.random.default_rng(5).normal(0, 20, (600, 2)), axis=0)
    s0 = ScannerState.initial(p, (100.0, -50.0))
    full, end = simulate(p, u, 0.008, s0, np.random.default_rng(9))
    rng = np.random.default_rng(9)
    a, s1 = simulate(p, u[:250], 0.008, s0, rng)
    b, s2 = simulate(p, u[250:], 0.008, s1, rng)
    assert_allclose(np.vstack([a, b]), full, atol=1e-9, rtol=0)
    assert_allclose(s2.drift_nm, end.drift_nm, atol=1e-12)


def test_positioning_noise_has_its_keys_rms_and_a_1_over_f_spectrum():
    """White noise of its key's rms per sample; the 1/f part of its key's rms, its power
    spectrum falling as 1/f (slope -1 +- 0.3 on log axes) between 5 mHz and 0.5 Hz; carried
    across calls in the state; off, no random draw is needed."""
    import pytest
    from scipy.signal import welch

    T = 0.05
    u = np.zeros((200_000, 2))
    base, _ = simulate(_params(creep=0.0), u[:10], T, ScannerState.initial(_params()))
    white = _params(creep=0.0, position_noise_nm=0.05)
    pos, _ = simulate(white, u, T, ScannerState.initial(white), np.random.default_rng(1))
    assert np.std(pos - base[0], axis=0) == pytest.approx([0.05, 0.05], rel=0.02)
    pink = _params(creep=0.0, position_flicker_nm=0.2)
    st = ScannerState.initial(pink)
    rng = np.random.default_rng(2)
    parts = []
    for k in range(4):  # streamed in four calls
        p, st = simulate(pink, u[k * 50_000 : (k + 1) * 50_000], T, st, rng)
        parts.append(p[:, 0] - base[0, 0])
    x = np.concatenate(parts)
    assert np.std(x) == pytest.approx(0.2, rel=0.35)  # the slowest process: few correlation times
    f, pxx = welch(x, fs=1 / T, nperseg=2**15)
    band = (f > 5e-3) & (f < 0.5)
    slope = np.polyfit(np.log(f[band]), np.log(pxx[band]), 1)[0]
    assert -1.3 < slope < -0.7, slope
    assert st.flicker_nm.shape == (4, 2) and np.all(st.flicker_nm != 0)
    with pytest.raises(ValueError, match="rng is required"):
        simulate(pink, u[:5], T, ScannerState.initial(pink))


def test_creep_of_the_switched_domains_grows_with_the_step():
    """With ``creep_domain_fraction`` the creep is not a linear filter of the command: a small
    step creeps less, per nm, than a large one (it switches few domains), and a step's creep
    Linear creep (fraction 0) creeps alike."""

    def creep_of(p, step, start=0.0):
        u = np.full((10001, 2), [start + step, 0.0])
        u[0, 0] = start
        pos, _ = simulate(p, u, 0.01, ScannerState.initial(p, (start, 0.0)))
        return (pos[10000, 0] - pos[10, 0]) / step

    linear, domains = _params(), _params(creep_domain_fraction=0.8)
    assert abs(creep_of(linear, 20.0) / creep_of(linear, 2000.0) - 1) < 1e-6
    small, large = creep_of(domains, 20.0), creep_of(domains, 2000.0)
    assert small < 0.8 * large, (small, large)
