"""The estimation choices of the sensorless identification, one at a time (issue 4).

For each preset and seed, :func:`~piezocomp.identification.sensorless.identify_axis` runs
with each variant of the ESTIMATION settings (acquisition unchanged: same seed, same
waveform) and :func:`~piezocomp.identification.sensorless.score_on_truth` scores the RLS and
batch models on the validation trajectory against the true extension. Variants:

* ``before``: the settings before the creep changes (orders (8, 2), (16, 3), (32, 4); creep
  poles free in the RLS and the batch step, time constants started over 0.3-30 s; creep
  states started at the record's first command);
* ``creep_start``: the same, creep states started at the line's centre;
* ``fifth_session``: the defaults at the end of the fifth session (creep spectrum of 19
  fixed time constants over 0.05-2000 s, gains only; creep states at the centre; orders
  (16, 19), (32, 19); 20 RLS passes; no smoothness priors);
* ``sixth_session``: the defaults at the end of the sixth session (22 creep modes over
  0.01-2000 s, the smoothness priors in the batch refinement, the RLS continued 140 passes
  with Huber's update and priors);
* ``seventh_session``: the defaults at the end of the seventh session (also the RLS on
  ``h`` re-indexed by its own estimate, the lines weighted by their own residual in the
  joint rounds, and the RLS run on every line);
* ``default``: the current defaults (eighth session: also the final fit over the whole
  record, ``final_rounds`` and ``rls_final_passes``).

``--reference grating`` scans the 278 nm calibration grating first with the same scanner
and scales the models to it, as ``identify_presets.py`` does (default ``none``).

Usage::

    python benchmarks/identify_estimation_variants.py [--presets cpr5] [--seeds 1 2 3]
        [--variants before creep_start fifth_session sixth_session seventh_session default]
        [--calibrate full-range]
        [--reference none]
    python benchmarks/identify_estimation_variants.py --seeds 7 8 9 10 11 12 \
        --variants fifth_session default --reference grating

Prints one JSON line per run (max / rms error in nm, offset removed; ``scale`` and the max
error after removing it).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from typing import Any

from piezocomp.afm import Grating, VirtualAFM
from piezocomp.identification.reference import measure_grating
from piezocomp.identification.rls import RLSSettings
from piezocomp.identification.sensorless import SensorlessConfig, identify_axis, score_on_truth

PITCH_NM = 278.0
_NO_EIGHTH = {"final_rounds": 0, "rls_final_passes": 0}
_NO_SEVENTH = {
    "rls_reindex_rounds": 0,
    "weight_lines": False,
    "rls_lines_passes": 0,
    **_NO_EIGHTH,
}
_NO_SIXTH = {
    "rls_continue": None,
    "creep_smoothing_nm": 0.0,
    "weight_smoothing_nm": 0.0,
    **_NO_SEVENTH,
}

_OLD_RLS = RLSSettings(alpha="unit", p0=0.1, passes=6, k0=3000, free=("c", "p", "a", "w", "y0"))
_OLD = {
    "orders": ((8, 2), (16, 3), (32, 4)),
    "rls_settings": _OLD_RLS,
    "refine_free": ("c", "p", "a", "w", "y0"),
    "creep_tau_range_s": (0.3, 30.0),
    **_NO_SIXTH,
}
_FIFTH = {
    "orders": ((16, 19), (32, 19)),
    "creep_tau_range_s": (0.05, 2000.0),
    "rls_settings": RLSSettings(
        alpha="unit", p0=0.1, passes=20, k0=3000, free=("c", "a", "w", "y0")
    ),
    **_NO_SIXTH,
}
VARIANTS: dict[str, dict[str, Any]] = {
    "before": {**_OLD, "creep_start": "first-command"},
    "creep_start": {**_OLD, "creep_start": "centre"},
    "fifth_session": _FIFTH,
    "sixth_session": _NO_SEVENTH,
    "seventh_session": _NO_EIGHTH,
    "default": {},
}


def run(preset: str, seed: int, variant: str, calibrate: str, reference: str = "none") -> dict:
    afm = VirtualAFM.from_preset(preset, seed=seed, sample_period_s=0.008)
    cal = afm.range_nm if calibrate == "full-range" else None
    cfg = SensorlessConfig(calibration_span_nm=cal, **VARIANTS[variant])
    record = None
    if reference == "grating":
        lab = VirtualAFM.from_preset(
            preset, seed=seed, sample_period_s=0.008, grating=Grating(PITCH_NM, axis="x")
        )
        record = measure_grating(
            lab, PITCH_NM, axis="x", center_nm=cfg.center_nm, span_nm=cfg.span_nm,
            speed_nm_per_s=cfg.speed_nm_per_s,
        )  # fmt: skip
    t0, c0 = time.perf_counter(), time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident = identify_axis(afm, cfg, "x", reference=record)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    score = score_on_truth(afm, ident, {"rls": ident.rls_model, "batch": ident.batch_model})
    out = {"preset": preset, "seed": seed, "variant": variant, "calibrate": calibrate}
    out["reference"] = reference
    for m in ("rls", "batch"):
        s = score[m]
        out[m] = {
            "max": round(s["validation_max_error_nm"], 2),
            "rms": round(s["validation_rms_error_nm"], 2),
            "scale": round(s["scale"], 4),
            "max_after_scale": round(s["validation_max_error_after_scale_nm"], 2),
        }
    out["orders"] = [ident.orders.n_play, ident.orders.n_creep]
    out["heldout_height_rms_nm"] = round(ident.heldout_rms_nm["batch"], 3)
    out["estimation_s"] = round(ident.timing_s["estimation"], 1)
    out["computing_s"] = round(ident.timing_s["total_computing"], 1)
    out["wall_s"] = round(wall, 1)
    out["cpu_s"] = round(cpu, 1)  # identification incl. simulation (other jobs excluded)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--presets", nargs="+", default=["cpr5"])
    p.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--calibrate", choices=("full-range", "span"), default="full-range")
    p.add_argument("--reference", choices=("none", "grating"), default="none")
    a = p.parse_args()
    for preset in a.presets:
        for seed in a.seeds:
            for v in a.variants:
                print(json.dumps(run(preset, seed, v, a.calibrate, a.reference)), flush=True)


if __name__ == "__main__":
    main()
