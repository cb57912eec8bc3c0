"""Several particle lines for one model: does more topography narrow the shape error?

An experiment toward the issue-4 target (cpr5 batch model <= 0.5 nm), kept so it can be
rerun. The sensorless pipeline (:func:`~piezocomp.identification.sensorless.identify_axis`)
runs on the usual line; then, on the same instrument, on lines found by overviews centred
``--slow`` nm away (their own line search, settling and record). The working batch model
of the first line is then refined on all records at once
(``sensorless._joint_rounds``: :func:`~piezocomp.identification.batch.refine` with ``extra``
segments), each line's ``h`` re-indexed by the shared model every round. The pipeline does
the same with ``SensorlessConfig.extra_lines``; this benchmark scores on a copy of the
instrument taken before the other lines, which the pipeline cannot. Both models get the scale of
a 278 nm grating (:mod:`~piezocomp.identification.reference`) and are scored on the first
line's validation trajectory against the TRUE extension.

Usage::

    python benchmarks/identify_two_lines.py [--preset cpr5] [--seed 1] [--slow 1000 -1000]
        [--rounds 6]

Prints one JSON document (max error, nm, offset removed; after scale in ``*_after_scale``).
"""

from __future__ import annotations

import argparse
import copy
import json
import time
import warnings
from dataclasses import replace

from piezocomp.afm import Grating, VirtualAFM
from piezocomp.identification.frames import mapped
from piezocomp.identification.reference import fit_scale, measure_grating
from piezocomp.identification.sensorless import (
    SensorlessConfig,
    _joint_rounds,
    identify_axis,
    score_on_truth,
)

T = 0.008


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="cpr5")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--slow", type=float, nargs="+", default=[1000.0])
    p.add_argument("--rounds", type=int, default=6)
    a = p.parse_args()
    afm = VirtualAFM.from_preset(a.preset, seed=a.seed, sample_period_s=T)
    # the first line alone (the pipeline's own second line off), then the others
    cfg = SensorlessConfig(calibration_span_nm=afm.range_nm, extra_lines=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = identify_axis(afm, cfg, "x")
        snapshot = copy.deepcopy(afm)  # the scanner as the first line left it, for scoring
        quick = replace(cfg, orders=((first.orders.n_play, first.orders.n_creep),))
        others = [
            identify_axis(afm, replace(quick, center_nm=(0.0, s), reindex_rounds=0), "x")
            for s in a.slow
        ]
    single, profile = first.working_models()["batch"]
    t0 = time.perf_counter()
    joint, _ = _joint_rounds(
        single, [(i.u_nm, i.height_nm) for i in [first, *others]], T,
        replace(cfg, joint_rounds=a.rounds), first.waveform, first.fit_mask,
        first.creep_start_nm, profile,
    )  # fmt: skip
    joint_s = time.perf_counter() - t0
    lab = VirtualAFM.from_preset(a.preset, seed=a.seed, sample_period_s=T, grating=Grating())
    record = measure_grating(lab, 278.0)
    scaled = {}
    for name, m in (("single_line", single), ("joint", joint)):
        fit = fit_scale(m, record)
        scaled[name] = mapped(m, fit.alpha, 0.0)
    score = score_on_truth(snapshot, first, scaled)
    print(json.dumps({
        "preset": a.preset, "seed": a.seed,
        "lines": [{"slow_nm": i.line.slow_nm, "particles": i.line.n_particles}
                  for i in [first, *others]],
        "orders": [first.orders.n_play, first.orders.n_creep],
        "joint_refine_s": round(joint_s, 1),
        **{name: {"max": round(score[name]["validation_max_error_nm"], 3),
                  "max_after_scale": round(score[name]["validation_max_error_after_scale_nm"], 3)}
           for name in scaled},
    }, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
