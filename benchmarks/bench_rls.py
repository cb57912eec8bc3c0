"""Throughput of the sensorless RLS (eqs 16-20) at the orders the pipeline tries.

A Fig. 7a waveform (the pipeline's default: +-500 nm at 250 nm/s, T = 8 ms, 13 500 samples fitted),
heights from a known profile of 30 particles, the model of the pipeline's start (its creep spectrum,
``IdentifyConfig().estimation.orders`` and ``creep_tau_range_s``, and play operators over the span).
For each order it times one pass of :func:`piezocomp.identification.estimation.rls.rls` with the
pipeline's settings (``IdentifyConfig().estimation.rls_settings``: creep gains, gain, weights and
offset free) and with the continuation's (``rls_continue``: the same with the robust update, no
eigenvalue check), compilation excluded (best of ``--repeat``). Prints one JSON document.

Run: ``python benchmarks/bench_rls.py [--repeat 5]`` (a few seconds).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np

from piezocomp.identification.acquisition.waveforms import identification_waveform
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.estimation.candidates import creep_spectrum, thresholds_over_span
from piezocomp.identification.estimation.rls import rls
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.model import ModelState, ScannerModel, simulate

T = 0.008


def _record() -> tuple[np.ndarray, np.ndarray, HeightProfile]:
    wf = identification_waveform(0.0, 1000.0, 250.0, T, rng=0)
    u = wf.u_nm[:13_500]
    rng = np.random.default_rng(1)
    grid = np.linspace(-800, 800, 6401)
    h = sum(15 * np.exp(-0.5 * ((grid - c) / 12) ** 2) for c in rng.uniform(-560, 560, 30))
    prof = HeightProfile.from_samples(grid, h, lam=1e-8, step_nm=0.25)
    truth = _model(16)
    y, _ = simulate(truth, u, T, ModelState.at_rest(truth, u[0]))
    z = np.asarray(prof(y)) + 0.1 * rng.standard_normal(u.size)
    return u, z, prof


def _model(n_play: int) -> ScannerModel:
    cfg = IdentifyConfig().estimation
    taus = creep_spectrum(cfg.orders[0][1], cfg.creep_tau_range_s)
    return ScannerModel(
        offset_nm=0.0,
        gain=0.7,
        thresholds_nm=thresholds_over_span(n_play, 1000.0),
        weights=np.full(n_play, 0.25 / n_play),
        creep_time_constants_s=taus,
        creep_gains=np.full(taus.size, 0.01),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    u, z, prof = _record()
    cfg = IdentifyConfig().estimation
    assert cfg.rls_continue is not None
    out: dict[str, dict[str, float]] = {}
    runs = (("candidates", cfg.rls_settings), ("continuation", cfg.rls_continue))
    for n_play in (16, 32):
        start = _model(n_play)
        for name, settings in runs:
            one = replace(settings, passes=1)
            rls(u, z, prof, start, T, settings=one)  # compile
            best = float("inf")
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                rls(u, z, prof, start, T, settings=one)
                best = min(best, time.perf_counter() - t0)
            out[f"{n_play} play, {name}"] = {
                "s_per_pass": round(best, 4),
                "samples_per_s": round(u.size / best),
                "passes": settings.passes,
                "s_for_all_passes": round(best * settings.passes, 2),
            }
    print(json.dumps({"record_samples": int(u.size), "orders": out}, indent=2))


if __name__ == "__main__":
    main()
