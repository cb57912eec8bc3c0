"""What each stage of the identification's instrument time buys: protocols against accuracy.

The default sensorless identification keeps a scanner busy for hours (``summary.json``'s
``instrument_s``): a 128-line overview per line, ten minutes of settling, a second line
with its own overview, a grating. Each protocol below changes one of them (or several) and
is run, per seed and axis, as ``piezocomp reproduce`` identifies its default model
(``sensorless``, calibration over the whole range, scaled by the virtual grating). For each
protocol it prints the instrument minutes (both axes) and two accuracy figures scored on
the ground truth (for scoring only):

- ``valid``: the batch model's validation error against the true extension (max over a
  fresh path with minor loops, after the grating's scale; worst of the two axes);
- ``T1``: with ``--table1``, Table I of ``reproduce --quick`` (the default method: the
  model inside the drift compensator, the worst distance's mean over 5 experiments at
  1 um/s, true error).

Then the median and worst over the seeds and the median paired difference to ``default``.
The ``placebo`` protocol changes nothing that matters (ten more seconds of settling) but
shifts every later noise and drift draw: its paired differences show how large a
difference the seeds alone make, against which the others are read. An identification
that fails is reported (its figures left out). Seeds 1-50 are for design; a protocol is
chosen on them and then measured on 51-60 untouched. Usage::

    python benchmarks/instrument_budget.py --seeds 1-6 --table1 --json budget.json
    python benchmarks/instrument_budget.py --seeds 1-3 --protocols default one-line

About 3 minutes of computing per protocol, seed and both axes with ``--table1``, 1.5
without, spread over ``--workers`` processes.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from joblib import Parallel, delayed

from piezocomp._atomic import atomic_write_text
from piezocomp.experiments import table1
from piezocomp.experiments.contract import DRIFT_METHOD
from piezocomp.experiments.methods import IdentificationSettings, MethodModels
from piezocomp.experiments.reproduce import (
    ReproduceSettings,
    experiment_plan,
    run_trial,
    table1_area,
)
from piezocomp.experiments.samples import parse_seeds
from piezocomp.experiments.scoring import score_on_truth
from piezocomp.experiments.virtual_identification import identify_virtual
from piezocomp.identification.acquisition.instrument_time import with_total
from piezocomp.model import ScannerModel2D
from piezocomp.virtual_afm import VirtualAFM, load_config

PROTOCOLS: dict[str, dict[str, Any]] = {
    "default": {},
    "placebo": {"line_settle_s": 610.0},
    "one-line": {"extra_lines": 0},
    "settle-2min": {"line_settle_s": 120.0},
    "overview-1um/s": {"overview_speed_nm_per_s": 1000.0},
    "overview-64px": {"overview_pixels": 64},
    "short": {
        "extra_lines": 0,
        "line_settle_s": 120.0,
        "overview_speed_nm_per_s": 1000.0,
        "overview_pixels": 64,
    },
}
"""Each protocol's changes to the default configuration of ``reproduce``."""


def identify(preset: str, protocol: str, seed: int, axis: str) -> dict[str, Any]:
    """One axis identified with ``protocol``: its batch model, instrument seconds by stage
    and validation against the truth; or the error that stopped it."""
    warnings.simplefilter("ignore")  # the findings: the validation failures are reported
    afm = VirtualAFM(load_config(preset), seed=seed)
    cfg = IdentificationSettings().config(afm.range_nm, **PROTOCOLS[protocol])
    out: dict[str, Any] = {"protocol": protocol, "seed": seed, "axis": axis}
    try:
        ident = identify_virtual(afm, cfg, axis)
    except (ValueError, RuntimeError) as exc:
        return {**out, "error": str(exc)}
    score = score_on_truth(
        afm, ident, {"batch": ident.batch_model}, span_nm=cfg.acquisition.span_nm,
        center_nm=cfg.acquisition.center_nm[0 if axis == "x" else 1],
    )["batch"]  # fmt: skip
    return {
        **out,
        "model": ident.batch_model,
        "failures": list(ident.validation_failures()),
        "instrument_s": with_total(ident.instrument_s),
        "valid_nm": float(score["validation_max_error_after_scale_nm"]),
    }


def table1_trials(preset: str, seed: int, model: ScannerModel2D) -> list[Any]:
    """The Table I experiments of ``reproduce --quick`` inside the drift compensator."""
    config = load_config(preset)
    s = ReproduceSettings(
        config=config, source=preset, seed=seed, methods=("compensated",)
    ).quick_run()
    models = MethodModels({"compensated": model}, VirtualAFM(config, seed=seed).sample_period_s)
    plan = experiment_plan(s, table1_area(models, models.sample_period_s))
    trials = [t for t in table1.plan(plan) if t.method == DRIFT_METHOD]
    return [(plan, t, config, seed, models) for t in trials]


def table1_figure(plan: Any, outcomes: list[Any]) -> float | None:
    """Table I's headline (worst distance of the mean true error at the paper's speed)."""
    rows = table1.summarise(plan, outcomes)["table1"]
    cells = [
        r["methods"][DRIFT_METHOD]
        for r in rows
        if r["speed_nm_per_s"] == plan.paper_speed_nm_per_s and r["methods"].get(DRIFT_METHOD)
    ]
    vals = [c["true_max_error_nm"]["mean"] for c in cells]
    vals = [float(v) for v in vals if v is not None and np.isfinite(v)]
    return max(vals) if len(vals) == len(plan.distances_nm) else None


def _seeds(text: str) -> tuple[int, ...]:
    try:
        return parse_seeds(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _stat(values: list[float]) -> str:
    if not values:
        return "      -       -"
    return f"{np.median(values):7.2f} {max(values):7.2f}"


def summary_lines(
    preset: str, seeds: tuple[int, ...], protocols: list[str],
    rows: dict[tuple[str, int], dict[str, Any]],
) -> list[str]:  # fmt: skip
    """The printed table: per protocol the minutes, the validation and Table I figures
    (median, worst) and the paired differences to ``default``; then every seed's problems."""
    lines = [
        f"{len(seeds)} seeds of {preset}; minutes of instrument time (both axes), errors in nm "
        "on the ground truth (median, worst); paired: median difference to default (range)",
        f"{'protocol':16s} {'minutes':>8s} {'valid med':>9s} {'worst':>7s} "
        f"{'T1 med':>7s} {'worst':>7s}  paired valid / T1",
    ]
    for p in protocols:
        mine = [rows[(p, s)] for s in seeds]
        mins = [r["minutes"] for r in mine if "minutes" in r]
        val = [r["valid_nm"] for r in mine if "valid_nm" in r and not r["problems"]]
        t1 = [r["table1_nm"] for r in mine if r.get("table1_nm") is not None]
        paired = []
        for key in ("valid_nm", "table1_nm"):
            both = [(rows[(p, s)], rows[("default", s)]) for s in seeds]
            d = [m[key] - b[key] for m, b in both
                 if m.get(key) is not None and b.get(key) is not None
                 and not m["problems"] and not b["problems"]]  # fmt: skip
            paired.append(f"{np.median(d):+.2f} ({min(d):+.2f}..{max(d):+.2f})" if d else "-")
        fails = sum(1 for r in mine if r["problems"])
        failed = f"  ({fails} of {len(mine)} seeds failed)" if fails else ""
        lines.append(
            f"{p:16s} {np.median(mins) if mins else float('nan'):8.0f} {_stat(val):>17s} "
            f"{_stat(t1):>15s}  {paired[0]} / {paired[1]}{failed}"
        )
    for r in rows.values():
        lines += [f"  {r['protocol']} seed {r['seed']}: {why}" for why in r["problems"]]
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5")
    ap.add_argument("--seeds", type=_seeds, default="1-3", help="sample seeds, e.g. 1-6")
    ap.add_argument("--protocols", nargs="+", choices=sorted(PROTOCOLS), default=list(PROTOCOLS))
    ap.add_argument(
        "--table1", action="store_true", help="also Table I inside the drift compensator"
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path, help="write every seed's figures to this file")
    a = ap.parse_args()
    try:
        load_config(a.preset)
    except ValueError as exc:
        ap.error(str(exc))
    if a.workers < 1:
        ap.error(f"--workers must be at least 1. Got {a.workers}.")
    protocols = ["default", *(p for p in a.protocols if p != "default")]
    jobs = [(p, s, ax) for p in protocols for s in a.seeds for ax in "xy"]
    done = Parallel(n_jobs=a.workers)(delayed(identify)(a.preset, *j) for j in jobs)
    by: dict[tuple[str, int], dict[str, Any]] = {}
    for r in done:
        by.setdefault((r["protocol"], r["seed"]), {})[r["axis"]] = r
    rows: dict[tuple[str, int], dict[str, Any]] = {}
    work = []
    for key, axes in by.items():
        bad = [f"{ax}: {r['error']}" for ax, r in axes.items() if "error" in r]
        bad += [f"{ax}: {'; '.join(r['failures'])}" for ax, r in axes.items() if r.get("failures")]
        row: dict[str, Any] = {"protocol": key[0], "seed": key[1], "problems": bad}
        if not any("error" in r for r in axes.values()):
            row["minutes"] = sum(r["instrument_s"]["total"] for r in axes.values()) / 60
            row["stages_min"] = {
                ax: {k: v / 60 for k, v in r["instrument_s"].items()} for ax, r in axes.items()
            }
            row["valid_nm"] = max(r["valid_nm"] for r in axes.values())
            if a.table1 and not bad:
                model = ScannerModel2D(axes["x"]["model"], axes["y"]["model"])
                work += [(key, *t) for t in table1_trials(a.preset, key[1], model)]
        rows[key] = row
    if work:
        outcomes = Parallel(n_jobs=a.workers)(
            delayed(run_trial)(t, config, seed, models) for _, _, t, config, seed, models in work
        )
        grouped: dict[tuple[str, int], list[Any]] = {}
        plans = {}
        for (key, plan, *_), o in zip(work, outcomes, strict=True):
            grouped.setdefault(key, []).append(o)
            plans[key] = plan
        for key, outs in grouped.items():
            rows[key]["table1_nm"] = table1_figure(plans[key], outs)
    lines = summary_lines(a.preset, a.seeds, protocols, rows)
    print("\n".join(lines), flush=True)
    if a.json is not None:
        out = {"command": "python benchmarks/instrument_budget.py " + " ".join(sys.argv[1:]),
               "seeds": list(a.seeds), "summary": lines, "rows": list(rows.values())}  # fmt: skip
        atomic_write_text(a.json, json.dumps(out, indent=1, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
