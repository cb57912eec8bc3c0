"""The drift session of ``both`` under other drift-filter settings, with the models a
``piezocomp reproduce --seeds`` run identified.

For each seed, the default model that run saved (``DIR/seed-N/model.json``) is put inside
the drift compensator on a fresh virtual AFM of that sample, and the session of
``reproduce`` (two areas 951 nm apart visited in turn, each visit imaged) runs for
``--minutes`` with the drift settings given here; it prints the worst and the last image's
true error, the share of the time spent measuring drift and the number of measurements,
then the median and worst over the seeds. With the defaults and ``--minutes 5`` it gives
the ``both`` session of ``reproduce --quick`` again, to the digit.

What it varies: the filter's measurement noise (``--measurement-nm``, the prior of
``DriftNoise``: 0.5 nm by default), the tolerances that decide when to measure, and
whether the drift's noise is learnt from the session's measurements. About a minute a
seed for a 20-minute session on two cores::

    piezocomp reproduce --quick --seeds 1-10 --out runs
    python benchmarks/drift_filter.py --runs runs --seeds 1-10 --minutes 20
    python benchmarks/drift_filter.py --runs runs --seeds 1-10 --minutes 20 --measurement-nm 1.5
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from piezocomp.drift.filter import DriftSettings
from piezocomp.experiments import drift_session as D
from piezocomp.experiments.methods import MethodModels
from piezocomp.experiments.samples import parse_seeds
from piezocomp.io import load_model
from piezocomp.virtual_afm import VirtualAFM, load_config


def settings(a: argparse.Namespace) -> DriftSettings:
    """The drift settings asked for, on the defaults."""
    s = DriftSettings()
    noise = (
        s.noise if a.measurement_nm is None else replace(s.noise, measurement_nm=a.measurement_nm)
    )
    changes = {"noise": noise}
    if a.tolerance_nm is not None:
        changes["tolerance_nm"] = a.tolerance_nm
    if a.image_tolerance_nm is not None:
        changes["image_tolerance_nm"] = a.image_tolerance_nm
    if a.no_learning:
        changes["learn_noise_after"] = 0
    if a.learn_measurement is not None:
        changes["learn_measurement_noise"] = a.learn_measurement == "on"
    return replace(s, **changes)


def one(run: Path, seed: int, minutes: float, drift: DriftSettings) -> D.DriftSessionResult:
    """The ``both`` session of one seed of ``run``."""
    folder = run / f"seed-{seed}"
    res = json.loads((folder / "results.json").read_text(encoding="utf-8"))
    model = load_model(folder / "model.json")
    config = load_config(res["preset"]).with_seed(seed)
    area = min(650.0, res["table1_settings"]["area_half_width_nm"])
    st = D.DriftSessionSettings(minutes=minutes, area_nm=area)
    afm = VirtualAFM(config, seed=seed)
    inst, origin = D.session_instrument("both", afm, MethodModels({"compensated": model}), st,
                                        drift)  # fmt: skip
    return D.run(inst, st, origin_nm=origin, truth=afm.truth)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", required=True, type=Path, help="a reproduce --seeds folder")
    ap.add_argument("--seeds", required=True, help="e.g. 1-10")
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--measurement-nm", type=float, help="DriftNoise.measurement_nm")
    ap.add_argument("--tolerance-nm", type=float, help="DriftSettings.tolerance_nm")
    ap.add_argument("--image-tolerance-nm", type=float, help="DriftSettings.image_tolerance_nm")
    ap.add_argument("--no-learning", action="store_true", help="keep the drift noise's prior")
    ap.add_argument("--learn-measurement", choices=("on", "off"),
                    help="DriftSettings.learn_measurement_noise")  # fmt: skip
    a = ap.parse_args()
    drift = settings(a)
    worst, measuring = [], []
    for seed in parse_seeds(a.seeds):
        r = one(a.runs, seed, a.minutes, drift)
        if r.true_errors_nm is None or not r.true_errors_nm.size:
            print(f"seed {seed}: no image ({r.stopped or 'tracking stopped'})", flush=True)
            continue
        worst.append(r.true_max_error_nm)
        measuring.append(r.overhead_fraction)
        print(f"seed {seed}: worst {r.true_max_error_nm:.2f} nm, last {r.true_final_error_nm:.2f} "
              f"nm, {100 * r.overhead_fraction:.0f} % measuring, {r.measurements} measurements, "
              f"{r.true_errors_nm.size} images", flush=True)  # fmt: skip
    if worst:
        print(f"over {len(worst)} seeds: worst image {np.median(worst):.2f} / {max(worst):.2f} nm "
              f"(median / worst), measuring {100 * np.median(measuring):.0f} % / "
              f"{100 * max(measuring):.0f} %")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
