"""A scanner whose domains relax through a spectrum of their own
(``creep_domain_tau_min_s``): outside the extended model family, for benchmarks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from piezocomp.virtual_afm import load_config
from piezocomp.virtual_afm.scanner import ScannerState, scanner_params_from_config, simulate

T = 0.01


def _params(tau_min_s: float):
    base = load_config("cpr5-nodrift")
    quiet = replace(base.scanner, creep_domain_tau_min_s=tau_min_s, position_noise_nm=0.0,
                    position_flicker_nm=0.0)  # fmt: skip
    return scanner_params_from_config(replace(base, scanner=quiet))


def _step(p, step_nm: float) -> np.ndarray:
    st = ScannerState.initial(p, (-step_nm / 2, 0.0))
    n = int(120 / T)
    pos, _ = simulate(p, np.column_stack([np.full(n, step_nm / 2), np.zeros(n)]), T, st)
    return pos[:, 0]


def test_the_domains_own_spectrum_keeps_the_creep_and_slows_it():
    """The same creep from 0.1 s to 100 s after a step (the preset's key), small or large,
    but the domains' share arrives only through the slow modes: less of it in the first
    second."""
    assert _params(0.0).domain_creep is None  # every preset: the modes shared
    for step in (20.0, 2000.0):
        shared, own = _step(_params(0.0), step), _step(_params(10.0), step)
        i01, i1, i100 = int(0.1 / T), int(1 / T), int(100 / T)
        assert own[i100] - own[i01] == pytest.approx(shared[i100] - shared[i01], rel=1e-9)
        assert own[i1] - own[i01] < 0.8 * (shared[i1] - shared[i01])


def test_a_run_in_pieces_is_the_run_in_one():
    p = _params(10.0)
    st = ScannerState.initial(p, (0.0, 0.0))
    rng = np.random.default_rng(1)
    cmd = np.cumsum(rng.normal(0, 2.0, (3000, 2)), axis=0)
    whole, _ = simulate(p, cmd, T, st)
    a, mid = simulate(p, cmd[:1234], T, st)
    b, _ = simulate(p, cmd[1234:], T, mid)
    np.testing.assert_allclose(np.vstack([a, b]), whole, rtol=0, atol=1e-9)


def test_a_spectrum_with_no_mode_slow_enough_is_refused():
    with pytest.raises(ValueError, match="creep_domain_tau_min_s = 10000 s leaves no creep mode"):
        _params(1e4)
