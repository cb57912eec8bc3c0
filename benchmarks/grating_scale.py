"""What the grating's scale is worth, and which path to scan it on (DIAGNOSIS: it reads the
virtual AFM's ground truth for its references and scores).

For each seed and axis, the default identification runs once; then the grating is scanned
along each path of :func:`~piezocomp.identification.reference.grating.measure_grating`
(``steady`` cycles, the paper's; ``minor_loops`` with rests), through a wrapper that keeps
the true extension of every command, and for each path:

- ``read_on_truth``: the grating's fit run on the scanner's TRUE extension instead of a
  model's prediction (:func:`~piezocomp.identification.reference.scaling.scale_of_positions`):
  what the measurement itself adds (drift, roughness, noise, the angle), per cent;
- ``own_path``: the slope of the true extension against the model's prediction over the
  grating's own passes, once the model is scaled by that grating (per cent off 1): how well
  the scale fits the path it was measured on;
- ``validation``: the same slope on a fresh validation trajectory with minor loops and rests
  (:func:`~piezocomp.experiments.scoring.score_on_truth`), and that trajectory's largest
  error (nm, offset removed): the scale where it is used;
- ``duration_s``: the grating scan's instrument time.

The default model is scaled by each grating by refitting its factor from the default's
(search +-3 %), which is what the identification's reference stage finds from the model
before its scale. About 3 minutes a seed on two cores::

    python benchmarks/grating_scale.py --seeds 1-10 --json grating.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from error_budget import TruthRecorder

from piezocomp.experiments.methods import IdentificationSettings
from piezocomp.experiments.samples import parse_seeds
from piezocomp.experiments.scoring import score_on_truth
from piezocomp.experiments.virtual_identification import VIRTUAL_PITCH_NM, calibrated
from piezocomp.identification.estimation.prediction import record_state
from piezocomp.identification.reference.frames import mapped
from piezocomp.identification.reference.grating import (
    GRATING_PATHS,
    grating_path_for,
    measure_grating,
)
from piezocomp.identification.reference.scaling import fit_scale, scale_of_positions
from piezocomp.identification.sensorless import identify_axis
from piezocomp.io import atomic_write_text
from piezocomp.model import simulate
from piezocomp.virtual_afm import Grating, VirtualAFM, load_config


def _slope(pred: list[np.ndarray], truth: list[np.ndarray]) -> float:
    """One slope of truth against prediction over several passes, an offset each."""
    p = np.concatenate([v - v.mean() for v in pred])
    t = np.concatenate([v - v.mean() for v in truth])
    return float(p @ t / (p @ p))


def one_axis(preset: str, seed: int, axis: str) -> dict[str, Any]:
    """Each path's figures for one seed and axis."""
    config = load_config(preset).with_seed(seed)
    afm = VirtualAFM(config, seed=seed)
    cfg = calibrated(afm, IdentificationSettings().config(afm.range_nm))
    acq = cfg.acquisition
    k = 0 if axis == "x" else 1
    gratings, truths = {}, {}
    for path in GRATING_PATHS:
        g = TruthRecorder(VirtualAFM(config, sample_period_s=afm.sample_period_s,
                                     grating=Grating(VIRTUAL_PITCH_NM, axis=axis)))  # fmt: skip
        gratings[path] = measure_grating(g, VIRTUAL_PITCH_NM, axis=axis, center_nm=acq.center_nm,
                                         span_nm=acq.span_nm, speed_nm_per_s=acq.speed_nm_per_s,
                                         path=path)  # fmt: skip
        truths[path] = np.concatenate([p[:, k] for _, _, p in g.log])
    ident = identify_axis(
        afm,
        cfg,
        axis,
        reference=gratings[
            grating_path_for(acq.span_nm, VIRTUAL_PITCH_NM, cfg.reference.grating_path)
        ],
    )
    base = ident.batch_model
    models, out = {}, {}
    for path, rec in gratings.items():
        fit = fit_scale(base, rec, search=(0.97, 1.03))
        m = mapped(base, fit.alpha, 0.0)
        models[path] = m
        y, _ = simulate(m, rec.u_nm, rec.sample_period_s, record_state(m, float(rec.u_nm[0])))
        tr = truths[path]
        read = scale_of_positions(tr, rec, search=(0.97, 1.03))
        out[path] = {
            "read_on_truth_percent": 100.0 * (read.alpha - 1.0),
            "own_path_percent": 100.0 * (_slope([y[a:b] for a, b in rec.passes],
                                                [tr[a:b] for a, b in rec.passes]) - 1.0),
            "passes": len(rec.passes),
            "angle_deg": fit.angle_deg,
            "duration_s": rec.duration_s,
        }  # fmt: skip
    score = score_on_truth(afm, ident, models, span_nm=acq.span_nm, center_nm=acq.center_nm[k])
    for path in gratings:
        out[path]["validation_percent"] = 100.0 * (float(score[path]["scale"]) - 1.0)
        out[path]["validation_max_error_nm"] = float(score[path]["validation_max_error_nm"])
    return out


ROWS = (
    ("read_on_truth_percent", "the grating read on the true extension, |%|", "abs"),
    ("own_path_percent", "the model's scale on the grating's own passes, |%|", "abs"),
    ("validation_percent", "the model's scale on the validation trajectory, |%|", "abs"),
    ("validation_max_error_nm", "validation max error, worse axis (nm)", "worse"),
    ("duration_s", "the grating scan (s)", "abs"),
)
"""Each table row: key, label, and how seeds are pooled (every axis' magnitude, or each
seed's worse axis)."""


def table(per_seed: list[dict[str, Any]]) -> dict[str, dict[str, list[float]]]:
    """Median and worst of every row, per path."""
    rows: dict[str, dict[str, list[float]]] = {}
    for key, _, how in ROWS:
        rows[key] = {}
        for path in GRATING_PATHS:
            if how == "worse":
                vals = [max(ax[path][key] for ax in s["axes"].values()) for s in per_seed]
            else:
                vals = [abs(ax[path][key]) for s in per_seed for ax in s["axes"].values()]
            rows[key][path] = [float(np.median(vals)), float(np.max(vals))]
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5")
    ap.add_argument("--seeds", required=True, help="e.g. 1-10")
    ap.add_argument("--axes", default="xy", choices=("x", "y", "xy"))
    ap.add_argument("--json", type=Path, help="also write every figure, with the command, here")
    a = ap.parse_args()
    per_seed: list[dict[str, Any]] = []
    for seed in parse_seeds(a.seeds):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            axes = {ax: one_axis(a.preset, seed, ax) for ax in a.axes}
        per_seed.append({"seed": seed, "axes": axes})
        cells = "  ".join(f"{ax} {p}: {v[p]['validation_max_error_nm']:.2f} nm"
                          for ax, v in axes.items() for p in GRATING_PATHS)  # fmt: skip
        print(f"seed {seed} ({time.perf_counter() - t0:.0f} s): {cells}", flush=True)
    rows = table(per_seed)
    print(f"{'median / worst':58s} " + "  ".join(f"{p:>15s}" for p in GRATING_PATHS))
    for key, label, _ in ROWS:
        cells = "  ".join(f"{rows[key][p][0]:6.3f} / {rows[key][p][1]:6.3f}" for p in GRATING_PATHS)
        print(f"{label:58s} {cells}")
    if a.json is not None:
        out = {"command": "python benchmarks/grating_scale.py " + " ".join(sys.argv[1:]),
               "preset": a.preset, "seeds": per_seed, "rows": rows}  # fmt: skip
        atomic_write_text(a.json, json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
