"""Error budget of the sensorless identification, with the ground truth for DIAGNOSIS.

Runs :func:`~piezocomp.identification.sensorless.identify_axis` once on a virtual AFM
(through a wrapper that records, for the benchmark only, the true extension of every
command the identification issues), then fits, on the SAME identification record:

(a) ``floor``: our model family to the TRUE ``(u, y)`` (the scanner's extension, the
    sample's drift left out; sensor-based: non-negative least squares for ``a``, ``w_j``,
    ``c_i`` with the pipeline's thresholds over the span and
    creep time constants, which is the optimum of the batch refinement with ``output=None``
    for those groups), same fit samples, same creep start; the best this model family can do
    for this record and these orders (also with 3 poles, with 32 play operators, and with
    the creep states started at the record's first command);
(b) ``true_loop``: the sensorless estimation (RLS of eqs 16-20, then the batch refinement
    with ``output = h``) with ``f_a`` and ``h(y)`` built from the TRUE steady loop of part A,
    which isolates the error of the loop estimate (eqs 21-23); it does not take the line's
    drift out, so on a drifting preset (``cpr5``) its figures hold the drift as well;
(c) ``pipeline``: the full sensorless pipeline (its RLS and batch models);

and scores all of them with
:func:`~piezocomp.experiments.scoring.score_on_truth` on one fresh validation
trajectory (max and rms error against the true extension, offset removed). Nothing here
feeds back into identification: the truth is read only to build (a), (b) and the scores.

About 40 s. Usage::

    python benchmarks/identify_error_budget.py [--preset cpr5-nodrift] [--seed 1]
        [--calibrate full-range|span]

Prints one JSON document.
"""

from __future__ import annotations

import argparse
import copy
import json
import time
import warnings
from dataclasses import replace
from typing import Any

import numpy as np
from error_budget import TruthRecorder as Recorder
from error_budget import true_loop
from scipy.optimize import nnls

from piezocomp.experiments.scoring import score_on_truth
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.estimation.candidates import (
    creep_spectrum,
    initial_from_loop,
    thresholds_over_span,
)
from piezocomp.identification.estimation.chain import estimate
from piezocomp.identification.estimation.config import EstimationConfig
from piezocomp.identification.estimation.parameters import ThetaLayout, simulate_with_gradient
from piezocomp.identification.estimation.prediction import heldout_rms, record_state
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.sensorless import identify_axis
from piezocomp.model import ScannerModel
from piezocomp.virtual_afm import VirtualAFM


class TruthRecorder(Recorder):
    """:class:`error_budget.TruthRecorder` with the instrument interface only (no
    ``calibration_scan``, no simulator attributes): what these figures were measured with."""

    INTERFACE = frozenset({"sample_period_s", "range_nm", "max_speed_nm_per_s", "command_nm",
                           "run", "move_to", "wait", "scan_image", "push"})  # fmt: skip

    def __getattr__(self, name: str) -> Any:
        if name not in self.INTERFACE:
            raise AttributeError(name)
        return super().__getattr__(name)


def sensorless_fit(ident, loop, profile, cfg, nh, nc, T):
    """The pipeline's estimation (RLS from a loop-fitted start, then batch) for one order."""
    est = estimate(
        ident.u_nm,
        ident.height_nm,
        T,
        profile,
        lambda n, taus: initial_from_loop(loop, n, taus.size, time_constants_s=taus),
        fit_mask=ident.fit_mask,
        warmup_samples=2 * ident.waveform.half_cycle_samples,
        options=EstimationConfig(
            orders=((nh, nc),),
            rls_settings=cfg.estimation.rls_settings,
            refine_max_nfev=cfg.estimation.refine_max_nfev,
            refine_free=cfg.estimation.refine_free,
            creep_tau_range_s=cfg.estimation.creep_tau_range_s,
            reindex_rounds=cfg.estimation.reindex_rounds,
            # the batch and RLS of one order alone: none of the research chain's stages
            selection_rounds=None,
            reindex_max_nfev=None,
            rls_continue=None,
            rls_start=None,
            order_tolerance=0.02,
            creep_smoothing_nm=0.0,
            weight_smoothing_nm=0.0,
            rls_reindex_rounds=0,
            batch_restart_ratio=None,
            workers=1,
        ),
        creep_start_nm=ident.creep_start_nm,
        forward_traces=ident.waveform.forward_traces,
    )
    return est.rls.model, est.batch_model


def sensor_fit(u, y, T, fit_mask, warmup, nh, taus, creep_start=None):
    """Floor: NNLS + refine on the TRUE (u, y), thresholds over the span, fixed time constants,
    creep states starting at ``creep_start`` (the pipeline's assumption)."""
    rows = fit_mask.copy()
    rows[:warmup] = False
    r = thresholds_over_span(nh, float(np.ptp(u)))
    unit = ScannerModel(
        thresholds_nm=r,
        weights=np.ones(nh),
        creep_time_constants_s=taus,
        creep_gains=np.ones(taus.size),
    )
    st = record_state(unit, u[0], creep_start)
    _, jac, _ = simulate_with_gradient(unit, u, T, st)
    lay = ThetaLayout(taus.size, nh)
    a = np.column_stack((jac[:, lay.a], jac[:, lay.w], jac[:, lay.c]))[rows]
    mean, b_mean = a.mean(axis=0), y[rows].mean()
    scale = np.linalg.norm(a - mean, axis=0)
    scale[scale <= 0] = 1.0
    coef, _ = nnls((a - mean) / scale, y[rows] - b_mean)
    coef /= scale
    return ScannerModel(
        offset_nm=b_mean - mean @ coef,
        gain=max(coef[0], 1e-9),
        thresholds_nm=r,
        weights=np.maximum(coef[1 : 1 + nh], 1e-9),
        creep_time_constants_s=taus,
        creep_gains=coef[1 + nh :],
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="cpr5-nodrift")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--calibrate", choices=("full-range", "span"), default="full-range")
    a = p.parse_args()
    afm = VirtualAFM.from_preset(a.preset, seed=a.seed, sample_period_s=0.008)
    rec = TruthRecorder(afm)
    # the configuration these figures were measured with: a 1 um span at 125-500 nm/s
    cfg = IdentifyConfig().updated(
        span_nm=1000.0, speed_factors=(0.5, 1.0, 2.0), calibrate=a.calibrate
    )
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident = identify_axis(rec, cfg, "x")
    t_ident = time.perf_counter() - t0
    T = ident.sample_period_s
    u, z = ident.u_nm, ident.height_nm
    y = rec.true_extension(u, z, 0)
    nh, nc = ident.orders.n_play, ident.orders.n_creep
    fit_mask = ident.fit_mask
    warmup = 2 * ident.waveform.half_cycle_samples
    heldout = ~fit_mask
    heldout[:warmup] = False

    models: dict[str, ScannerModel] = {
        "c_pipeline_rls": ident.rls_model,
        "c_pipeline_batch": ident.batch_model,
    }
    info: dict[str, Any] = {"creep_start_nm": ident.creep_start_nm}
    xc = ident.creep_start_nm
    # (a) floors of the model family on the true (u, y); the pipeline's creep start
    spec = creep_spectrum(nc, cfg.estimation.creep_tau_range_s)
    for name, nh_, taus in (
        ("a_floor", nh, spec),
        ("a_floor_3poles", nh, np.geomspace(0.3, 30.0, 3)),
        ("a_floor_32play", 32, spec),
    ):
        models[name] = sensor_fit(u, y, T, fit_mask, warmup, nh_, taus, xc)
    # the same floor with the creep states started at the first command (scored likewise)
    first = {
        "a_floor_first_command": sensor_fit(u, y, T, fit_mask, warmup, nh, spec, None),
        "a_floor_3poles_first_command": sensor_fit(
            u, y, T, fit_mask, warmup, nh, np.geomspace(0.3, 30.0, 3), None
        ),
    }
    # (b) the sensorless estimation with the TRUE loop and h(y) from the true loop
    tl = true_loop(ident, y)
    wf = ident.waveform
    u_f = u[wf.ascending(1)]
    z_f = np.array([z[wf.ascending(c)] for c in range(1, wf.n_steady)])
    prof_true = HeightProfile.from_loop(tl, u_f, z_f)
    m_rls, m_batch = sensorless_fit(ident, tl, prof_true, cfg, nh, nc, T)
    models["b_true_loop_rls"] = m_rls
    models["b_true_loop_batch"] = m_batch
    # loop error of the estimate (working frame mapped by the frame map) against the truth
    alpha, beta = ident.frame_map if ident.rls_frame_map is None else ident.rls_frame_map
    uu = np.linspace(wf.u_min_nm, wf.u_max_nm, 401)
    fa = np.asarray(ident.loop.loop.ascending(uu))
    ft = np.asarray(tl.ascending(uu))
    d = alpha * fa + beta - ft
    best = np.polyfit(fa, ft, 1)
    info["loop_error_nm"] = {
        "max_after_offset": float(np.max(np.abs(d - d.mean()))),
        "max_after_affine": float(np.max(np.abs(ft - np.polyval(best, fa)))),
        "frame_scale_used": alpha,
        "frame_scale_true": float(best[0]),
    }
    info["heldout_height_rms_nm"] = {
        "pipeline_batch": ident.heldout_rms_nm["batch"],
        "true_loop_batch_own_h": heldout_rms(prof_true, m_batch, u, z, T, heldout, xc),
    }
    score = score_on_truth(copy.deepcopy(afm), ident, models)
    score.update(score_on_truth(afm, replace(ident, creep_start_nm=None), first))
    out = {
        "preset": a.preset,
        "seed": a.seed,
        "orders": [nh, nc],
        "identify_s": t_ident,
        "info": info,
        "scores": {
            k: {
                "max": round(v["validation_max_error_nm"], 3),
                "rms": round(v["validation_rms_error_nm"], 3),
                "scale": round(v["scale"], 4),
                "max_after_scale": round(v["validation_max_error_after_scale_nm"], 3),
            }
            for k, v in score.items()
            if isinstance(v, dict)
        },
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
