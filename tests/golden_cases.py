"""Fixed models, states and trajectories whose forward and inverse outputs (and one linear
stage of the sensor fit) were stored by the code before the creep coupling existed (commit
590d1dc), to check that ``beta = 0`` still gives them bit for bit
(``tests/data/paper_model_golden.npz``, written by :func:`outputs` run on that commit)."""

from __future__ import annotations

import numpy as np

from piezocomp.inverse import compensate
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.sensor.fit import nnls_stage

T = 0.008


def cases(n_cases: int = 6) -> list[tuple[ScannerModel, np.ndarray, np.ndarray]]:
    """``(model, history, trajectory)``: the history sets a non-zero starting state."""
    rng = np.random.default_rng(47)
    out = []
    for _ in range(n_cases):
        nh, nc = int(rng.integers(0, 12)), int(rng.integers(0, 5))
        model = ScannerModel(
            offset_nm=float(rng.uniform(-50, 50)),
            gain=float(rng.uniform(0.05, 2.0)),
            thresholds_nm=np.cumsum(rng.uniform(1.0, 120.0, nh)),
            weights=rng.uniform(1e-3, 0.5, nh),
            creep_time_constants_s=rng.uniform(0.01, 50.0, nc),
            creep_gains=rng.uniform(0.0, 0.3, nc),
        )
        hist = np.cumsum(rng.standard_normal(300)) * 40.0
        t = np.arange(800)
        traj = 400.0 * np.sin(2 * np.pi * t / rng.uniform(20, 200)) * np.exp(-t / 500.0)
        out.append((model, hist, traj + np.cumsum(rng.standard_normal(800)) * 5.0))
    return out


def outputs() -> dict[str, np.ndarray]:
    """Forward ``y`` and inverse ``u`` of every case, from the state after its history."""
    res = {}
    for i, (model, hist, traj) in enumerate(cases()):
        _, state = simulate(model, hist, T)
        res[f"y{i}"], _ = simulate(model, traj, T, state)
        res[f"u{i}"] = compensate(model, traj, T, state).command_nm
    model, hist, traj = cases()[3]
    y, _ = simulate(model, traj, T, ModelState.at_rest(model, traj[0]))
    fitted, *_ = nnls_stage(traj, y + 0.01 * np.sin(np.arange(traj.size)), T,
                            [30.0, 90.0, 200.0], [0.1, 1.0], rows=np.arange(traj.size) > 50,
                            creep_smoothing_nm=0.3, weight_smoothing_nm=0.2)  # fmt: skip
    res["nnls"] = np.concatenate(([fitted.offset_nm, fitted.gain], fitted.weights,
                                  fitted.creep_gains))  # fmt: skip
    return res
