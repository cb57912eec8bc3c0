"""Sensorless identification on the virtual AFM presets, over seeds: the accuracy figures.

For each preset (cpr5-nodrift, gentle, harsh: scanners that do not drift, or not much;
benchmarks/identify_drift.py has the drifting ones) and each calibration (``full-range``:
calibration cycles over the whole range map the model onto the nominal frame; ``span``: the paper's
calibration condition on the working span): the whole procedure through the instrument
interface only (:func:`~piezocomp.identification.sensorless.identify_axis`, default
configuration, orders chosen on held-out data), then
:func:`~piezocomp.experiments.scoring.score_on_truth` on a fresh validation
trajectory with minor loops over +-500 nm against the simulator's true extension.
With ``--reference grating`` (default) a calibration grating of 278 nm pitch is scanned
first with the same scanner (:func:`~piezocomp.identification.reference.grating.measure_grating`)
and the models are scaled to it; the figures without it are reported beside
(``methods_without_reference``). Prints one JSON document.

About 20 s of computing per preset, seed and calibration on two cores (cpr5 seed 1: batch
0.30 nm, RLS 0.95 nm). Usage::

    python benchmarks/identify_presets.py [--presets cpr5-nodrift gentle harsh] [--seed 1]
        [--axis x]
        [--calibrate full-range span] [--reference grating none]
        [--config '{"reindex_rounds": 0}']
    python benchmarks/identify_presets.py --presets cpr5-nodrift --calibrate full-range \
        --seeds 1 2 3

``--config`` overrides settings of :class:`IdentifyConfig` by name (JSON object) to measure a
variant against the default on the same seeds; an object for ``rls_settings``,
``rls_continue`` or ``rls_start`` overrides fields of the default settings (of
``rls_settings`` for ``rls_start``), e.g. ``'{"rls_start": {"clip_nm": 2.0}}'``.
``--more-trajectories N`` also scores the models on N other validation trajectories
(``more_trajectories_max_error_nm``): one trajectory is a small sample (on cpr5
seed 15 the batch model was 0.54 nm off on it and 0.56-1.06 nm on five others).
"""

from __future__ import annotations

import argparse
import copy
import json
import time
import warnings
from dataclasses import asdict, replace
from typing import Any

from piezocomp.experiments.scoring import score_on_truth
from piezocomp.experiments.virtual_identification import calibrated
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.reference.grating import measure_grating
from piezocomp.identification.sensorless import identify_axis
from piezocomp.virtual_afm import Grating, VirtualAFM

PITCH_NM = 278.0


def run_preset(
    name: str,
    seed: int,
    axis: str,
    calibrate: str,
    overrides: dict[str, Any] | None = None,
    reference: str = "grating",
    more_trajectories: int = 0,
) -> dict:
    afm = VirtualAFM.from_preset(name, seed=seed, sample_period_s=0.008)
    # the configuration these figures were measured with: a 1 um span at 125-500 nm/s
    small = {"span_nm": 1000.0, "speed_factors": (0.5, 1.0, 2.0), "calibrate": calibrate}
    cfg = calibrated(afm, IdentifyConfig().updated(**{**small, **(overrides or {})}))
    record = None
    if reference == "grating":
        lab = VirtualAFM.from_preset(
            name, seed=seed, sample_period_s=0.008, grating=Grating(PITCH_NM, axis=axis)
        )
        record = measure_grating(
            lab, PITCH_NM, axis=axis, center_nm=cfg.acquisition.center_nm,
            span_nm=cfg.acquisition.span_nm, speed_nm_per_s=cfg.acquisition.speed_nm_per_s,
        )  # fmt: skip
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ident = identify_axis(afm, cfg, axis, reference=record)
    wall = time.perf_counter() - t0
    models = {"rls": ident.rls_model, "batch": ident.batch_model}
    models |= {f"{m}_unreferenced": v for m, v in (ident.unreferenced_models or {}).items()}
    after = copy.deepcopy(afm) if more_trajectories else None
    score = score_on_truth(afm, ident, models)
    more = {}
    for rng in range(1, int(more_trajectories) + 1):  # other validation trajectories
        sc = score_on_truth(copy.deepcopy(after), ident, {m: models[m] for m in ("rls", "batch")},
                            rng=rng)  # fmt: skip
        for m in ("rls", "batch"):
            more.setdefault(m, []).append(sc[m]["validation_max_error_nm"])
    return {
        "more_trajectories_max_error_nm": more,
        "methods": {m: score[m] for m in ("rls", "batch")},
        "methods_without_reference": {
            m: score[f"{m}_unreferenced"] for m in ("rls", "batch") if record is not None
        },
        "reference": None
        if ident.reference is None
        else {m: asdict(f) for m, f in ident.reference.items()},
        "frame_map": ident.frame_map,
        "rls_frame_map": ident.rls_frame_map,
        "rls_orders": {"n_play": ident.rls.model.n_play, "n_creep": ident.rls.model.n_creep},
        "orders": {"n_play": ident.orders.n_play, "n_creep": ident.orders.n_creep},
        "order_trials": ident.orders.table(),
        "heldout_height_rms_nm": ident.heldout_rms_nm,
        "loop_pairs": int(sum(len(a) for a, _ in ident.loop.all_pairs)),
        "line_particles": ident.line.n_particles,
        "timing_s": {**ident.timing_s, "wall_with_simulation": wall},
        "warnings": sorted({str(w.message) for w in caught}),
    }


def table(results: dict[int, dict]) -> str:
    """Markdown table of the figures per seed (max error, nm; after scale in brackets)."""
    rows = []
    for seed, out in results.items():
        for name, by_cal in out.items():
            for cal, r in by_cal.items():
                m, wo = r["methods"], r["methods_without_reference"]
                cells = [
                    f"{m[k]['validation_max_error_nm']:.2f} "
                    f"({m[k]['validation_max_error_after_scale_nm']:.2f})"
                    for k in ("batch", "rls")
                ]
                before = (
                    f"{wo['batch']['validation_max_error_nm']:.2f} / "
                    f"{wo['rls']['validation_max_error_nm']:.2f}"
                    if wo
                    else "-"
                )
                rows.append(
                    f"| {name} | {cal} | {seed} | {cells[0]} | {m['batch']['scale']:.4f} | "
                    f"{cells[1]} | {before} | {r['timing_s']['total_computing']:.1f} |"
                )
    head = (
        "| preset | calibration, reference | seed | batch (after scale) | batch scale "
        "| RLS (after scale) | batch / RLS without the reference | computing s |\n"
        "|---|---|---|---|---|---|---|---|"
    )
    return "\n".join([head, *rows])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--presets", nargs="+", default=["cpr5-nodrift", "gentle", "harsh"])
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--seeds", type=int, nargs="+", help="several seeds in turn: JSON per seed, then a table"
    )
    p.add_argument("--axis", choices=("x", "y"), default="x")
    p.add_argument("--calibrate", nargs="+", default=["full-range", "span"])
    p.add_argument("--reference", nargs="+", choices=("grating", "none"), default=["grating"])
    p.add_argument("--config", default="{}", help="IdentifyConfig settings by name (JSON object)")
    p.add_argument(
        "--more-trajectories",
        type=int,
        default=0,
        metavar="N",
        help="also score on N other validation trajectories (rng 1..N): one trajectory is a "
        "small sample of a model's error",
    )
    a = p.parse_args()
    over = json.loads(a.config)
    defaults = IdentifyConfig().estimation
    for key in ("rls_settings", "rls_continue", "rls_start"):
        if isinstance(over.get(key), dict):  # fields overriding the default (the candidates')
            base = getattr(defaults, key) or defaults.rls_settings
            over[key] = replace(base, **over[key])
    results = {}
    for seed in a.seeds or [a.seed]:
        results[seed] = {
            name: {
                f"{c}, {r}": run_preset(name, seed, a.axis, c, over, r, a.more_trajectories)
                for c in a.calibrate
                for r in a.reference
            }
            for name in a.presets
        }
        print(json.dumps(results[seed] if not a.seeds else {seed: results[seed]}, indent=2))
    if a.seeds:
        print(table(results), flush=True)


if __name__ == "__main__":
    main()
