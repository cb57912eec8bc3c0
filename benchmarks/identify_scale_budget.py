"""Where the frame SCALE of the sensorless model comes from (issue 4), with the truth for DIAGNOSIS.

With full-range calibration cycles, the scale of the identified model is set by three
factors (``scale`` = true extension / prediction, the slope that
:func:`~piezocomp.identification.sensorless.score_on_truth` removes for its
``*_after_scale`` figures):

``scale = convention * calibration_loop * working_frame``

* ``convention``: the TRUE span of the steady full-range cycle at the calibration speed
  divided by its command span. Section IV's calibration condition assumes it is exactly 1;
  it is a property of how the scanner's nominal sensitivity was defined (the virtual AFM
  defines it by the response ``creep_reference_time_s`` after a step, see
  ``afm/creep.py``), which no sensorless measurement can see. It depends on the speed
  (creep makes a slower cycle wider).
* ``calibration_loop``: the TRUE central slope of that cycle's ascending branch over the
  working span (normalised by its span) divided by the central slope of the calibration
  loop the pipeline fitted (:class:`~piezocomp.identification.pi_loop.PILoop` on eq 23's
  pairs): the error of the calibration loop's shape where the working line lies, which
  eq (23) cannot see (an odd distortion about the loop's centre) and a regulariser picks.
* ``working_frame``: the rest (placing the working line's particles in the calibration
  frame, and the working model's own frame).

``pairs_allow_central_slope`` is what the calibration cycles' pairs themselves say about
that central slope: the 95 % profile-likelihood interval of :func:`central_slope_interval`
(every slope whose best PI loop fits the pairs about as well as the best loop of all). It
is an approximation (the loop's many weights are nuisance parameters, which a one-parameter
profile interval treats as known: on exact PI loops it covered the true slope in 99 % of
draws with 24 pairs but only 53-59 % with 100), and is printed to show how wide the
data leave the slope, not as a calibrated error bar.

Nothing here feeds back into identification. Usage::

    python benchmarks/identify_scale_budget.py [--preset cpr5] [--seeds 1 2 3]
        [--speeds 500 679 1000 2000] [--config '{"calibration_loop": "pi-loo"}']

Prints one JSON line per seed.
"""

from __future__ import annotations

import argparse
import copy
import json
import warnings
from typing import Any

import numpy as np
from scipy.optimize import nnls
from scipy.stats import f as f_dist

from piezocomp.afm import VirtualAFM
from piezocomp.identification.pi_loop import _ramps, _stacked_pair_rows
from piezocomp.identification.sensorless import (
    SensorlessConfig,
    _command,
    _fit_pi_loop,
    _fit_pi_loop_loo,
    identify_axis,
    score_on_truth,
)
from piezocomp.identification.waveforms import identification_waveform


def central_slope_interval(
    pairs: Any, u_min: float, u_max: float, window: tuple[float, float], level: float = 0.95
) -> tuple[float, float, float]:
    """(low, high, least-squares) mean slope of a PI loop's ascending branch over ``window``
    allowed by eq (23)'s pairs: the profile likelihood of the slope, with the calibration
    condition and the slope as heavily weighted rows of the non-negative least squares, and
    the bound ``RSS_min (1 + F(1, n - p; level) / (n - p))`` (``p`` active weights)."""
    n_thr = 48
    h = 0.5 * (u_max - u_min)
    r = h * np.arange(n_thr) / n_thr
    a_mat = _stacked_pair_rows(pairs, u_min, u_max, r)
    n = a_mat.shape[0]
    cal = np.maximum(h - r, 0.0) / h
    uu = np.linspace(window[0], window[1], 201)
    ramps = _ramps(uu - u_min, 2.0 * r)
    x = uu - uu.mean()
    slope = x @ (ramps - ramps.mean(axis=0)) / (x @ x)

    def fit(k: float | None) -> tuple[np.ndarray, float]:
        rows = [cal] if k is None else [cal, slope]
        rhs = [1.0] if k is None else [1.0, k]
        m = np.vstack([a_mat, 1e5 * np.array(rows)])
        w, _ = nnls(m, np.concatenate([np.zeros(n), 1e5 * np.array(rhs)]), maxiter=50 * n_thr)
        return w, float(np.sum((a_mat @ w) ** 2))

    w0, rss0 = fit(None)
    k0 = float(slope @ w0)
    dof = max(n - int(np.count_nonzero(w0 > 0)), 1)
    bound = rss0 * (1.0 + float(f_dist.ppf(level, 1, dof)) / dof)
    ratio = slope / cal

    def edge(limit: float) -> float:
        inner, outer = k0, limit + 1e-6 * (k0 - limit)
        if fit(outer)[1] <= bound:
            return outer
        for _ in range(40):
            mid = 0.5 * (inner + outer)
            inner, outer = (mid, outer) if fit(mid)[1] <= bound else (inner, mid)
        return 0.5 * (inner + outer)

    return edge(float(ratio.min())), edge(float(ratio.max())), k0


def true_cycle(
    afm: VirtualAFM, ident: Any, cfg: SensorlessConfig, speed: float
) -> tuple[float, float]:
    """(span ratio, normalised central slope over the working span) of the TRUE steady
    full-range cycle at ``speed`` on the identification line (a copy of the instrument)."""
    a = copy.deepcopy(afm)
    cal = ident.calibration.loop
    centre = 0.5 * (cal.u_min_nm + cal.u_max_nm)
    cwf = identification_waveform(
        centre, cal.u_max_nm - cal.u_min_nm, speed, ident.sample_period_s,
        n_steady=cfg.n_steady, n_decaying=0, n_random=0,
    )  # fmt: skip
    a.move_to(cwf.u_nm[0], ident.line.slow_nm, speed)
    rec = a.run(_command(ident.axis, cwf.u_nm, ident.line.slow_nm))
    k = 0 if ident.axis == "x" else 1
    y = np.asarray(a.truth.last_record_positions_nm)[:, k]
    u = np.asarray(rec.command_nm)[:, k]
    s = cwf.ascending(cfg.n_steady - 1)
    us, ys = u[s], y[s]
    ratio = (ys[-1] - ys[0]) / (us[-1] - us[0])
    w = ident.loop.loop
    inside = (us >= w.u_min_nm) & (us <= w.u_max_nm)
    return float(ratio), float(np.polyfit(us[inside], ys[inside], 1)[0] / ratio)


def run(
    preset: str, seed: int, speeds: list[float], overrides: dict[str, Any] | None = None
) -> dict[str, Any]:
    afm = VirtualAFM.from_preset(preset, seed=seed, sample_period_s=0.008)
    cfg = SensorlessConfig(calibration_span_nm=afm.range_nm, **(overrides or {}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident = identify_axis(afm, cfg, "x")
    if ident.calibration is None:
        return {"preset": preset, "seed": seed, "error": "calibration cycles not used"}
    observed = score_on_truth(copy.deepcopy(afm), ident, {"batch": ident.batch_model})["batch"]
    speed = cfg.calibration_speed_nm_per_s
    if speed is None:  # the instrument's calibration record, as identify_axis uses it
        scan = afm.calibration_scan
        speed = 1000.0 if scan is None else scan.speed_nm_per_s
    convention, k_true = true_cycle(afm, ident, cfg, speed)
    cal = ident.calibration
    fit_pi = _fit_pi_loop_loo if cfg.calibration_loop == "pi-loo" else _fit_pi_loop
    pi = fit_pi(cal.all_pairs, cal.loop.u_min_nm, cal.loop.u_max_nm)
    w = ident.loop.loop
    uu = np.linspace(w.u_min_nm, w.u_max_nm, 201)
    k_est = float(np.polyfit(uu, pi.ascending(uu), 1)[0])
    loop_term = k_true / k_est
    lo, hi, k_ls = central_slope_interval(
        cal.all_pairs, cal.loop.u_min_nm, cal.loop.u_max_nm, (w.u_min_nm, w.u_max_nm)
    )
    scale = float(observed["scale"])
    return {
        "preset": preset,
        "seed": seed,
        "calibration_speed_nm_per_s": round(speed, 1),
        "scale": round(scale, 4),
        "convention": round(convention, 4),
        "calibration_loop": round(loop_term, 4),
        "working_frame": round(scale / (convention * loop_term), 4),
        "scale_if_convention_held": round(scale / convention, 4),
        "central_slope_true_vs_fitted": [round(k_true, 4), round(k_est, 4)],
        "pairs_allow_central_slope": [round(lo, 4), round(hi, 4)],
        "central_slope_least_squares": round(k_ls, 4),
        "calibration_pairs": int(sum(len(a) for a, _ in cal.all_pairs)),
        "batch_max_nm": round(float(observed["validation_max_error_nm"]), 2),
        "batch_max_after_scale_nm": round(
            float(observed["validation_max_error_after_scale_nm"]), 2
        ),
        "convention_by_speed": {
            f"{v:g}": round(true_cycle(afm, ident, cfg, v)[0], 4) for v in speeds
        },
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="cpr5")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    p.add_argument("--speeds", type=float, nargs="+", default=[500.0, 679.0, 1000.0, 2000.0])
    p.add_argument("--config", default="{}", help="SensorlessConfig overrides (JSON object)")
    a = p.parse_args()
    over = json.loads(a.config)
    for seed in a.seeds:
        print(json.dumps(run(a.preset, seed, a.speeds, over)), flush=True)


if __name__ == "__main__":
    main()
