"""Sensorless identification on drifting scanners, with and without the drift along the line.

For each scanner and seed: the acquisition of ``reproduce``'s identification (one axis, the
grating's scale), then the estimation twice on the same records, without the drift path
(``drift_rounds=0``) and with it (the default), both scored on one validation trajectory over
+-1000 nm against the scanner's own extension (ground truth, drift removed). Printed: the
drift the simulator applied along the line over the identification record (true, nm) and the
extent of the path estimated, whether it was kept, the sample's drift across the line (true;
its sign: the tip's offset) and how far the slow command followed the line's slide (drift
and slow-axis creep, measured on the dithered settling cycles), the held-out heights (nm RMS)
and the validation of the batch model without / with (max and RMS, nm); then the median and
the worst over the seeds of each scanner.

Scanners: ``cpr5`` and ``cpr5-warmup`` (presets), and ``untuned``, one the defaults were
not tuned on: the gentle scanner (hysteresis 2 %, creep 1 %) drifting 0.08 nm/s at 120
degrees with a random walk of 0.03 nm/sqrt(s). About 3-4 minutes per scanner and seed::

    python benchmarks/identify_drift.py [--scanners cpr5 untuned] [--seeds 1 2] [--axis x]
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace
from typing import Any

import numpy as np

from piezocomp.experiments.methods import IdentificationSettings
from piezocomp.experiments.scoring import score_on_truth
from piezocomp.experiments.virtual_identification import grating_reference
from piezocomp.identification.acquisition.recording import record_axis
from piezocomp.identification.sensorless import estimate_axis
from piezocomp.virtual_afm import VirtualAFM, load_config
from piezocomp.virtual_afm.config import AFMConfig


def scanner(name: str) -> AFMConfig:
    if name != "untuned":
        return load_config(name)
    base = load_config("gentle")
    changes = {"drift_nm_per_s": 0.08, "drift_direction_deg": 120.0,
               "drift_random_walk_nm_per_sqrt_s": 0.03}  # fmt: skip
    return replace(base, scanner=replace(base.scanner, **changes))


def run(config: AFMConfig, seed: int, axis: str) -> dict[str, Any]:
    afm = VirtualAFM(config, seed=seed)
    cfg = IdentificationSettings().config(afm.range_nm)
    ref = grating_reference(afm, cfg, axis)
    k = 0 if axis == "x" else 1
    drifts: list[np.ndarray] = []
    across: list[np.ndarray] = []
    run_cmd = afm.run

    def logged(*args: Any, **kwargs: Any) -> Any:  # the true drift of every run (scoring only)
        rec = run_cmd(*args, **kwargs)
        drifts.append(np.array(afm.truth.last_record_drift_nm[:, k]))
        across.append(np.array(afm.truth.last_record_drift_nm[:, 1 - k]))
        return rec

    afm.run = logged  # type: ignore[method-assign]
    records = record_axis(afm, cfg, axis)
    afm.run = run_cmd  # type: ignore[method-assign]
    n = records.u_nm.size
    i_rec = next(i for i, d in enumerate(drifts) if d.size >= n - 1)  # the record (its first
    true = np.concatenate(drifts[i_rec : i_rec + 2])[:n]  # sample may be run alone)
    true_across = np.concatenate(across[i_rec : i_rec + 2])[:n]
    cross = records.cross_drift
    followed = (
        cross.moved_nm(cross.end_s, n * records.sample_period_s)
        if cross is not None and cross.followed else 0.0
    )  # fmt: skip
    without = estimate_axis(records, replace(cfg, drift_rounds=0), reference=ref)
    with_ = estimate_axis(records, cfg, reference=ref)
    models = {"without": without.models["batch"], "with": with_.models["batch"]}
    score = score_on_truth(afm, with_, models, span_nm=2000.0)
    ld = with_.line_drift or {}
    return {
        "true_drift_nm": float(np.ptp(true)),
        "true_across_nm": float(true_across[-1] - true_across[0]),
        "followed_nm": followed,
        "estimated_nm": ld.get("extent_nm"),
        "kept": ld.get("kept", False),
        "heldout": (without.heldout_rms_nm["batch"], with_.heldout_rms_nm["batch"]),
        "max": tuple(score[m]["validation_max_error_nm"] for m in ("without", "with")),
        "rms": tuple(score[m]["validation_rms_error_nm"] for m in ("without", "with")),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scanners", nargs="+", default=["cpr5", "cpr5-warmup", "untuned"])
    p.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    p.add_argument("--axis", choices=("x", "y"), default="x")
    a = p.parse_args()
    warnings.simplefilter("ignore")
    for name in a.scanners:
        rows = []
        for seed in a.seeds:
            t0 = time.perf_counter()
            r = run(scanner(name), seed, a.axis)
            rows.append(r)
            est = "-" if r["estimated_nm"] is None else f"{r['estimated_nm']:.1f}"
            print(
                f"{name} seed {seed} {a.axis}: drift along the line {r['true_drift_nm']:.1f} nm, "
                f"estimated {est} nm (kept {r['kept']}); across it {r['true_across_nm']:+.1f} nm "
                f"of sample drift, slow command followed {r['followed_nm']:+.1f} nm; held-out "
                f"{r['heldout'][0]:.2f} / "
                f"{r['heldout'][1]:.2f} nm; validation max {r['max'][0]:.2f} / {r['max'][1]:.2f}"
                f" nm, rms {r['rms'][0]:.2f} / {r['rms'][1]:.2f} nm (without / with; "
                f"{time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
        for key in ("max", "rms"):
            w0 = [r[key][0] for r in rows]
            w1 = [r[key][1] for r in rows]
            print(
                f"{name} validation {key}: without median {np.median(w0):.2f} worst "
                f"{np.max(w0):.2f} nm; with median {np.median(w1):.2f} worst {np.max(w1):.2f} nm"
            )


if __name__ == "__main__":
    main()
