"""Hypothesis strategies shared by the core tests: valid models and trajectories."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import strategies as st

from piezocomp.model import ScannerModel

T = 0.008


@st.composite
def models(draw, max_play: int = 10, max_creep: int = 4) -> ScannerModel:
    """Random valid (invertible) models with any orders."""
    nh = draw(st.integers(0, max_play))
    nc = draw(st.integers(0, max_creep))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    thresholds = np.cumsum(rng.uniform(1.0, 120.0, nh))
    return ScannerModel(
        offset_nm=float(rng.uniform(-50, 50)),
        gain=float(rng.uniform(0.05, 2.0)),
        thresholds_nm=thresholds,
        weights=rng.uniform(1e-3, 0.5, nh),
        creep_time_constants_s=rng.uniform(0.01, 50.0, nc),
        creep_gains=rng.uniform(0.0, 0.3, nc),
    )


@st.composite
def trajectories(draw, min_size: int = 1, max_size: int = 600) -> np.ndarray:
    """Trajectories with reversals and minor loops (random walk + decaying oscillation)."""
    n = draw(st.integers(min_size, max_size))
    seed = draw(st.integers(0, 2**32 - 1))
    amplitude = draw(st.floats(1.0, 1500.0))
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    walk = np.cumsum(rng.standard_normal(n)) * amplitude / max(np.sqrt(n), 1.0)
    osc = amplitude * np.sin(2 * np.pi * t / rng.uniform(5, 80)) * np.exp(-t / rng.uniform(50, 800))
    return walk + osc


@st.composite
def coupled_models(draw, max_play: int = 10, max_creep: int = 4) -> ScannerModel:
    """Random valid models of the extended family, creep coupling ``beta`` in (0.01, 1.5)."""
    model = draw(models(max_play, max_creep))
    beta = draw(st.floats(0.01, 1.5))
    return replace(model, creep_coupling=beta)


@st.composite
def asymmetric_models(draw, max_play: int = 10, max_creep: int = 4) -> ScannerModel:
    """Random valid models with one to six dead zones of eq (8'), coupled or not; the gains
    keep every slope of ``S`` at 0.2 or more."""
    model = draw(models(max_play, max_creep))
    beta = draw(st.sampled_from([0.0, 0.4]))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    n_up, n_down = draw(st.integers(0, 3)), draw(st.integers(0, 3))
    if n_up + n_down == 0:
        n_up = 1
    up = np.cumsum(rng.uniform(5.0, 300.0, n_up))
    down = -np.cumsum(rng.uniform(5.0, 300.0, n_down))
    d = np.sort(np.concatenate((down, up)))
    g = np.zeros(d.size)
    for side in (np.flatnonzero(d > 0), np.flatnonzero(d < 0)[::-1]):
        slope = 1.0
        for i in side:  # the next slope anywhere in [0.2, 3]
            new = rng.uniform(0.2, 3.0)
            g[i], slope = new - slope, new
    return replace(model, creep_coupling=beta, dead_zones_nm=d, dead_zone_gains=g)


def coupled() -> ScannerModel:
    """A fixed model of the extended family: four plays, two creep operators, coupling 0.4."""
    return ScannerModel(
        offset_nm=2.0, gain=0.6, thresholds_nm=[20.0, 45.0, 80.0, 120.0],
        weights=[0.08, 0.06, 0.05, 0.03], creep_time_constants_s=np.array([0.3, 5.0]),
        creep_gains=np.array([0.05, 0.08]), creep_coupling=0.4,
    )  # fmt: skip
