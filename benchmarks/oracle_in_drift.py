"""What the identification costs ``both``: the model family fitted to the TRUE extension,
inside the drift compensator (for DIAGNOSIS: it uses ground truth).

For each seed, both axes' ``oracle`` model (the model family fitted to the true extension,
drift left out: :func:`~piezocomp.experiments.virtual_identification.fit_on_truth`) takes the
place of the default model, and ``piezocomp reproduce --quick``'s experiments run with it:
creep and hysteresis compensated alone (``compensated``) and inside the drift compensator
(``both``), with the 5-minute drift session. It prints each seed's headline figures and the
median and worst over the seeds; with ``--runs DIR`` (a ``reproduce --quick --seeds`` run of
the same preset) the default model's ``both`` figures of the same seeds beside them.

What it separates: how far the sensorless identification is from this fit of the family to
the truth (default minus oracle; the oracle is one fit, orders 32 x 22 with smoothness
priors, not the family's optimum), and how far the drift compensator stays off with the
oracle inside it (the oracle's own figures). ``--record-only`` fits the oracle on the
identification's own record (a few minutes) without the oracle's extra 12 minutes with
holds of up to a minute: the part of the gap that the record's length, not the estimation
without a sensor, accounts for. With ``--runs`` it prints each seed's difference of the
default model to the oracle (median and range over the seeds), with ``--compare`` (an
earlier ``--json`` of this benchmark) each seed's difference to that run. Each seed takes the time
of ``reproduce --quick``'s experiments, its identification left out::

    piezocomp reproduce --quick --seeds 1-10 --out runs
    python benchmarks/oracle_in_drift.py --seeds 1-10 --runs runs --json oracle.json
    python benchmarks/oracle_in_drift.py --seeds 1-10 --runs runs --record-only \
        --compare oracle.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

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
    model = ScannerModel2D(per["x"], per["y"])
    return MethodModels({"compensated": model}, afm.sample_period_s)


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


def _default(runs: Path, seed: int, preset: str) -> tuple[dict[str, Any] | None, str]:
    """The default model's headline figures of ``seed`` in ``runs``, or why there are none."""
    path = runs / f"seed-{seed}" / "results.json"
    try:
        res = json.loads(path.read_text(encoding="utf-8"))
        if res["preset"] != preset or not res["quick"]:
            return None, f"{path} is not a --quick run of {preset}"
        return headline(res), ""
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return None, f"cannot read {path}: {exc}"


def _seeds(text: str) -> tuple[int, ...]:
    try:
        return parse_seeds(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _paired(minus: list[Any], base: list[Any], label: str) -> None:
    """Each seed's difference of ``both`` (``minus`` less ``base``): median and range."""
    for key, name in (("table1_true_nm", "Table I"), ("session_true_worst_nm", "session")):
        d = [m["both"][key] - b["both"][key] for m, b in zip(minus, base, strict=True)
             if m["both"][key] is not None and b["both"][key] is not None]  # fmt: skip
        if d:
            print(f"{label}, both, {name}: median {np.median(d):.2f} nm "
                  f"({min(d):.2f} to {max(d):.2f}) over {len(d)} seeds")  # fmt: skip


def _earlier(path: Path) -> dict[int, Any]:
    """The headline figures by seed of an earlier ``--json`` of this benchmark."""
    return {int(r["seed"]): r["headline"] for r in json.loads(path.read_text(encoding="utf-8"))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5")
    ap.add_argument("--seeds", type=_seeds, default="1-3", help="sample seeds, e.g. 1-10")
    ap.add_argument("--runs", type=Path, help="a reproduce --quick --seeds run to compare with")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--record-only", action="store_true",
        help="fit the oracle on the identification's record alone (not its 12 minutes of holds)",
    )  # fmt: skip
    ap.add_argument("--json", type=Path, help="write every seed's figures to this file too")
    ap.add_argument(
        "--compare", type=Path,
        help="an earlier --json of this benchmark: each seed's difference to it",
    )  # fmt: skip
    a = ap.parse_args()
    try:
        load_config(a.preset)
    except ValueError as exc:
        ap.error(str(exc))
    if a.workers < 1:
        ap.error(f"--workers must be at least 1. Got {a.workers}.")
    if a.runs is not None and not a.runs.is_dir():
        ap.error(f"--runs must be the folder of a reproduce --seeds run. Got {str(a.runs)!r}.")
    if a.json is not None and not a.json.resolve().parent.is_dir():
        ap.error(f"--json must be in an existing folder. Got {str(a.json)!r}.")
    earlier: dict[int, Any] = {}
    if a.compare is not None:
        try:
            earlier = _earlier(a.compare)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            ap.error(f"--compare must be a --json of this benchmark: {exc}")
    print("true errors in nm (Table I also measured), Fig. 10 and measuring in % of runs / time")
    out, theirs, paired = [], [], []
    for seed in a.seeds:
        r = one(a.preset, seed, a.workers, a.record_only)
        out.append(r)
        for m in ("compensated", "both"):
            print(_line(f"seed {seed}, oracle {m}", r["headline"][m]), flush=True)
        if a.runs is not None:
            d, why = _default(a.runs, seed, a.preset)
            if d is None:
                print(f"    no default figures to compare with: {why}")
            else:
                theirs.append(d)
                paired.append(r["headline"])
                print(_line(f"seed {seed}, default both", d["both"]), flush=True)
        for f in r["failures"]:
            print(f"    failed: {f['experiment']}/{f['method']}: {f['error']}")
    for label, runs in (("oracle", [r["headline"] for r in out]), ("default", theirs)):
        if len(runs) < 2:
            continue
        st = statistics(runs)
        for k in ("median", "worst"):
            for m in ("compensated", "both") if label == "oracle" else ("both",):
                fig = {f: v[k] for f, v in st[m].items()}
                print(_line(f"{k} of {len(runs)}, {label} {m}", fig), flush=True)
        rates = [h["both"]["fig10_true_success"] for h in runs]
        done = [x for x in rates if x is not None]
        share = (
            f"{sum(done) / len(done):.0%} of the assemblies of {len(done)} seeds"
            if done
            else "none ran"
        )
        print(f"{label} both, Fig. 10: {share}")
    _paired(theirs, paired, f"default minus {'record-only ' if a.record_only else ''}oracle")
    both = [(r["headline"], earlier[r["seed"]]) for r in out if r["seed"] in earlier]
    if both:
        _paired([m for m, _ in both], [b for _, b in both], f"this run minus {a.compare}")
    if a.json is not None:
        atomic_write_text(a.json, json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
