"""Throughput of the core kernels (``piezocomp bench``).

Measures, for ``N_c = 2`` and ``N_H = 8``: forward and inverse samples per second on a
long trajectory (compilation excluded: every kernel is called once first), the
plain-Python reference inverse (:mod:`piezocomp.testing.reference`) in the same run, and
one streaming :meth:`~piezocomp.inverse.Compensator.step` of one sample; then the forward and
inverse of the same model with the creep coupling of eq (2') and the four dead zones of eq (8')
that ``piezocomp fit`` places (``--dead-zones``) (:func:`bench_asymmetric_model`).
"""

from __future__ import annotations

import platform
import time
from dataclasses import replace
from typing import Any

import numpy as np

from piezocomp.inverse import Compensator, compensate
from piezocomp.model import ScannerModel, simulate
from piezocomp.operators._kernels import warm_up
from piezocomp.testing import reference

__all__ = ["MAX_SAMPLES", "bench_asymmetric_model", "bench_model", "run_core_benchmark"]

MAX_SAMPLES = 20_000_000
"""Longest trajectory timed (a few arrays of this length must fit in memory)."""


def bench_model() -> ScannerModel:
    """A typical identified model with the paper's orders (N_c = 2, N_H = 8)."""
    return ScannerModel(
        offset_nm=1.5,
        gain=0.62,
        thresholds_nm=np.linspace(60.0, 480.0, 8),
        weights=np.array([0.06, 0.05, 0.04, 0.035, 0.03, 0.025, 0.02, 0.015]),
        creep_time_constants_s=np.array([0.5, 20.0]),
        creep_gains=np.array([0.02, 0.04]),
    )


def bench_asymmetric_model() -> ScannerModel:
    """:func:`bench_model` with a creep coupling (eq 2') and four dead zones (eq 8')."""
    return replace(
        bench_model(),
        creep_coupling=0.5,
        dead_zones_nm=np.array([-180.0, -90.0, 90.0, 180.0]),
        dead_zone_gains=np.array([0.08, -0.05, 0.06, -0.04]),
    )


def _best_of(fn: Any, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run_core_benchmark(
    n_samples: int = 1_000_000, reference_samples: int = 20_000, repeat: int = 5
) -> dict[str, Any]:
    """Run the core benchmark; return its figures as a JSON-ready dict."""
    for name, n in (("n_samples", n_samples), ("reference_samples", reference_samples)):
        if not 1 <= n <= MAX_SAMPLES:
            raise ValueError(f"{name} must be at least 1 and at most {MAX_SAMPLES:.0e}. Got {n}.")
    reference_samples = min(reference_samples, n_samples)
    warm_up()
    model = bench_model()
    T = 0.008
    rng = np.random.default_rng(0)
    t = np.arange(n_samples) * T
    yd = 450 * np.sin(2 * np.pi * 0.5 * t) * np.cos(2 * np.pi * 0.031 * t)
    yd += np.cumsum(rng.standard_normal(n_samples)) * 0.5
    u = compensate(model, yd, T).command_nm
    t_fwd = _best_of(lambda: simulate(model, u, T), repeat)
    t_inv = _best_of(lambda: compensate(model, yd, T), repeat)
    yr = yd[:reference_samples].tolist()
    args = (
        model.offset_nm,
        model.gain,
        model.thresholds_nm.tolist(),
        model.weights.tolist(),
        model.creep_time_constants_s.tolist(),
        model.creep_gains.tolist(),
        T,
    )
    t_ref = _best_of(lambda: reference.inverse(yr, *args), 1)
    comp = Compensator(model, T)
    n_steps = min(n_samples, 200_000)
    step = comp.step
    ys = yd[:n_steps].tolist()

    def stream() -> None:
        comp.reset()
        for v in ys:
            step(v)

    t_step = _best_of(stream, 3)
    asym = bench_asymmetric_model()
    u_asym = compensate(asym, yd, T).command_nm
    t_fwd_asym = _best_of(lambda: simulate(asym, u_asym, T), repeat)
    t_inv_asym = _best_of(lambda: compensate(asym, yd, T), repeat)
    return {
        "n_samples": n_samples,
        "n_play": model.n_play,
        "n_creep": model.n_creep,
        "forward_samples_per_s": n_samples / t_fwd,
        "inverse_samples_per_s": n_samples / t_inv,
        "reference_inverse_samples_per_s": reference_samples / t_ref,
        "reference_samples": reference_samples,
        "inverse_speedup_over_reference": (n_samples / t_inv) / (reference_samples / t_ref),
        "stream_step_us": t_step / n_steps * 1e6,
        "asymmetric_dead_zones": asym.n_dead_zones,
        "asymmetric_forward_samples_per_s": n_samples / t_fwd_asym,
        "asymmetric_inverse_samples_per_s": n_samples / t_inv_asym,
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
