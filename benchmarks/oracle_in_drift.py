"""The floor of ``both``: the model family fitted to the TRUE extension, inside the drift
compensator (for DIAGNOSIS: it uses ground truth).

For each seed, both axes' ``oracle`` model (the model family fitted to the true extension,
drift left out: :func:`~piezocomp.experiments.virtual_identification.fit_on_truth`) takes the
place of the default model, and ``piezocomp reproduce --quick``'s experiments run with it:
creep and hysteresis compensated alone (``compensated``) and inside the drift compensator
(``both``), with the 5-minute drift session. It prints each seed's headline figures and the
median and worst over the seeds; with ``--runs DIR`` (a ``reproduce --quick --seeds`` run of
the same preset) the default model's ``both`` figures of the same seeds beside them.

What it separates: how far ``both`` is from the paper's figures because the sensorless
identification misses the family's best (default minus oracle), and how far the family and
the drift compensator stay off with a model no identification can beat (the oracle's own
figures). ``--record-only`` fits the oracle on the identification's own record (a few
minutes) without the oracle's extra half hour of long holds: the part of the gap that the
record's length, not the estimation without a sensor, accounts for. About 5-7 minutes a seed
on two cores::

    piezocomp reproduce --quick --seeds 1-10 --out runs
    python benchmarks/oracle_in_drift.py --seeds 1-10 --runs runs
    python benchmarks/oracle_in_drift.py --seeds 1-10 --runs runs --record-only
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from piezocomp.experiments.methods import IdentificationSettings, MethodModels
from piezocomp.experiments.reproduce import ReproduceSettings, reproduce
from piezocomp.experiments.samples import headline, parse_seeds, statistics
from piezocomp.experiments.virtual_identification import fit_on_truth
from piezocomp.io import atomic_write_text
from piezocomp.model import ScannerModel2D
from piezocomp.virtual_afm import VirtualAFM, load_config

FIGURES = (
    ("table1_true_nm", "T1"),
    ("table1_measured_nm", "T1 meas"),
    ("fig9_true_nm", "F9"),
    ("fig10_true_success", "F10"),
    ("session_true_worst_nm", "session"),
    ("session_measuring", "measuring"),
)


def oracle_models(preset: str, seed: int, record_only: bool) -> MethodModels:
    """The oracle of both axes, as the ``compensated`` model: fitted as ``reproduce``'s
    ``oracle`` is, or (``record_only``) on the identification's record alone."""
    config = load_config(preset)
    settings = IdentificationSettings()
    per = {}
    for axis in "xy":
        afm = VirtualAFM(config, seed=seed)
        per[axis] = fit_on_truth(
            afm, settings.config(afm.range_nm), axis, settings.oracle_orders,
            extra_record=not record_only,
        )  # fmt: skip
    T = VirtualAFM(config, seed=seed).sample_period_s
    return MethodModels({"compensated": ScannerModel2D(per["x"], per["y"])}, T)


def one(preset: str, seed: int, workers: int, record_only: bool) -> dict[str, Any]:
    """The headline figures of the quick experiments with the oracle model."""
    s = ReproduceSettings(
        config=load_config(preset), source=preset, methods=("uncompensated", "compensated"),
        seed=seed, workers=workers,
    ).quick_run()  # fmt: skip
    res = reproduce(s, progress=False, models=oracle_models(preset, seed, record_only)).results
    return {"seed": seed, "headline": headline(res), "failures": res["failures"]}


def _f(v: float | None, key: str) -> str:
    if v is None:
        return "     -"
    if key in ("fig10_true_success", "session_measuring"):
        return f"{100 * v:5.0f}%"
    return f"{v:6.2f}"


def _line(label: str, h: dict[str, Any]) -> str:
    cells = " ".join(f"{name} {_f(h.get(k), k)}" for k, name in FIGURES)
    return f"{label:34s} {cells}"


def _default(runs: Path | None, seed: int) -> dict[str, Any] | None:
    if runs is None:
        return None
    path = runs / f"seed-{seed}" / "results.json"
    if not path.exists():
        return None
    return headline(json.loads(path.read_text(encoding="utf-8")))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5")
    ap.add_argument("--seeds", type=parse_seeds, default="1-3", help="sample seeds, e.g. 1-10")
    ap.add_argument("--runs", type=Path, help="a reproduce --quick --seeds run to compare with")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--record-only", action="store_true",
        help="fit the oracle on the identification's record alone (no half hour of long holds)",
    )  # fmt: skip
    ap.add_argument("--json", help="write every seed's figures to this file too")
    a = ap.parse_args()
    try:
        load_config(a.preset)
    except ValueError as exc:
        ap.error(str(exc))
    if a.runs is not None and not a.runs.is_dir():
        ap.error(f"--runs must be the folder of a reproduce --seeds run. Got {str(a.runs)!r}.")
    print("true errors in nm (Table I also measured), Fig. 10 and measuring in % of runs / time")
    out, ours, theirs = [], [], []
    for seed in a.seeds:
        r = one(a.preset, seed, a.workers, a.record_only)
        out.append(r)
        ours.append(r["headline"])
        for m in ("compensated", "both"):
            print(_line(f"seed {seed}, oracle {m}", r["headline"][m]), flush=True)
        d = _default(a.runs, seed)
        if a.runs is not None and d is None:
            print(f"    no {a.runs}/seed-{seed}/results.json to compare with")
        if d is not None:
            theirs.append(d)
            print(_line(f"seed {seed}, default both", d["both"]), flush=True)
        for f in r["failures"]:
            print(f"    failed: {f['experiment']}/{f['method']}: {f['error']}")
    for label, runs in (("oracle", ours), ("default", theirs)):
        if len(runs) < 2:
            continue
        st = statistics(runs)
        for k in ("median", "worst"):
            for m in ("compensated", "both") if label == "oracle" else ("both",):
                fig = {f: v[k] for f, v in st[m].items()}
                print(_line(f"{k} of {len(runs)}, {label} {m}", fig), flush=True)
    if a.json:
        atomic_write_text(a.json, json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
