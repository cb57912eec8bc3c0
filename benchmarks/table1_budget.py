"""Where Table I's error inside the drift compensator comes from: the scanner or the drift
(for DIAGNOSIS: it reads the ground truth).

Each seed's default model (``model.json`` of a ``piezocomp reproduce --quick --seeds`` run,
``--runs DIR``) runs ``both``'s Table I experiments again (the same trials, the same fresh
virtual AFM of the seed), with a recorder between the drift compensator and the compensated
instrument. Every sample the drift compensator sends is a target in the scanner's frame,
``p - D_est`` (``p`` the sample-frame target, ``D_est`` the drift it predicts); the tip truly
goes to ``x + D`` (``x`` the scanner's true extension, ``D`` the true drift), so an image's
sample-frame error, the mean over its pixels, splits exactly into

    e = (x - (p - D_est)) + (D - D_est) = scanner error + drift error.

Table I's figure is the displacement between two images of an area, so each part enters as
its change between the two visits. Printed per seed, then median and worst over the seeds,
each seed's figure as Table I's headline (the larger area's error, mean over a distance's
experiments, at the worst distance): the true error and the sum of the parts (the same: a
check of the samples' matching, not of the split, which holds by construction); each part
alone (the other's change taken as zero); each part's rms change; and the uncentred
correlation (the cosine) of the two parts' changes over every area (negative: the drift
estimate takes out some of the scanner's error, the landmarks' sightings carrying a like
error; its median and largest, the least negative, over the seeds). The scanner's part
alone is what a perfect drift estimate would leave, the rest of the run unchanged; the
drift part alone is no such counterfactual (with a perfect scanner the sightings would
change too)::

    piezocomp reproduce --quick --seeds 1-10 --out runs
    python benchmarks/table1_budget.py --runs runs --seeds 1-10 --json table1_budget.json
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from joblib import Parallel, delayed
from numpy.typing import NDArray

from piezocomp.experiments import table1
from piezocomp.experiments.contract import DRIFT_METHOD
from piezocomp.experiments.methods import MethodModels, drift_tracked, instrument_for
from piezocomp.experiments.reproduce import ReproduceSettings, experiment_plan
from piezocomp.experiments.samples import parse_seeds
from piezocomp.instrument import Record
from piezocomp.io import atomic_write_text
from piezocomp.io.model_files import load_model
from piezocomp.model import ScannerModel2D
from piezocomp.virtual_afm import VirtualAFM, load_config


class Recorder:
    """An instrument that passes everything to ``inner`` (the compensated instrument) and
    keeps, for every sample it runs, the time, the scanner-frame target and (from the
    simulator's truth) the true extension and drift."""

    def __init__(self, inner: Any, truth: Any) -> None:
        self._inner, self._truth = inner, truth
        self.t: list[NDArray[np.float64]] = []
        self.target: list[NDArray[np.float64]] = []
        self.extension: list[NDArray[np.float64]] = []
        self.drift: list[NDArray[np.float64]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def run(self, positions_nm: Any, **kw: Any) -> Record:
        rec = self._inner.run(positions_nm, **kw)
        self.t.append(np.asarray(rec.t_s, dtype=float))
        self.target.append(np.asarray(positions_nm, dtype=float).reshape(-1, 2))
        self.extension.append(self._truth.last_record_extension_nm.copy())
        self.drift.append(self._truth.last_record_drift_nm.copy())
        return rec

    def parts(self, image: Any, center: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """The image's mean scanner error and drift error (nm, each (2,)) over its pixels."""
        t = np.concatenate(self.t)
        fwd, bwd = image.pixel_times_s()
        times = np.concatenate([fwd.ravel(), bwd.ravel()])
        right = np.clip(np.searchsorted(t, times), 1, t.size - 1)
        idx = np.where(np.abs(t[right - 1] - times) <= np.abs(t[right] - times), right - 1, right)
        period = float(np.min(np.diff(t))) if t.size > 1 else 1.0
        if np.max(np.abs(t[idx] - times)) > 1e-3 * period:  # the nearest sample, and exactly it
            raise RuntimeError("an image's pixel times are not among the recorded samples")
        target = np.concatenate(self.target)[idx]
        scanner = (np.concatenate(self.extension)[idx] - target).mean(axis=0)
        d_est = center - target.mean(axis=0)  # p - (p - D_est), p's mean the image's centre
        drift = np.concatenate(self.drift)[idx].mean(axis=0) - d_est
        return scanner, drift


def one_trial(config: Any, seed: int, model: ScannerModel2D, st: table1.Table1Settings,
              period_s: float) -> dict[str, Any]:  # fmt: skip
    """One of ``both``'s Table I experiments, its error split by part."""
    afm = VirtualAFM(config, seed=seed)
    models = MethodModels({"compensated": model}, period_s)
    inner, origin = instrument_for("compensated", afm, models)
    rec = Recorder(inner, afm.truth)
    inst = drift_tracked(rec, origin, 2.0 * st.area_nm)  # type: ignore[arg-type]
    res = table1.run(inst, replace(st, keep_images=True), origin_nm=origin, truth=afm.truth)
    assert res.images is not None
    o = np.asarray(origin)
    out: dict[str, Any] = {"d_nm": st.d_nm, "experiment": st.experiment}
    for area, c in (("A", res.geometry.a_nm), ("B", res.geometry.b_nm)):
        s1, d1 = rec.parts(res.images[f"{area}1"], o + c)
        s2, d2 = rec.parts(res.images[f"{area}2"], o + c)
        out[area] = {
            "true_nm": res.true_error_nm[area] if res.true_error_nm else None,
            "scanner": (s2 - s1).tolist(),
            "drift": (d2 - d1).tolist(),
        }
    return out


def seed_figures(trials: list[dict[str, Any]]) -> dict[str, float]:
    """A seed's Table I figure (the larger area's error, mean over a distance's experiments,
    at the worst distance: the headline's), whole and by part; each part's rms change over
    every area and the correlation of the two parts' changes."""

    def figure(f: Any) -> float:  # the worst distance's mean, as Table I's headline
        by_d: dict[float, list[float]] = {}
        for t in trials:
            by_d.setdefault(t["d_nm"], []).append(max(f(t["A"]), f(t["B"])))
        return float(max(np.mean(v) for v in by_d.values()))

    def norm(v: list[float]) -> float:
        return float(np.hypot(*v))

    sc = [np.asarray(t[a]["scanner"]) for t in trials for a in "AB"]
    dr = [np.asarray(t[a]["drift"]) for t in trials for a in "AB"]
    return {
        "true": figure(lambda a: a["true_nm"]),
        "sum_of_parts": figure(lambda a: norm(np.add(a["scanner"], a["drift"]).tolist())),
        "scanner_alone": figure(lambda a: norm(a["scanner"])),
        "drift_alone": figure(lambda a: norm(a["drift"])),
        "scanner_rms": float(np.sqrt(np.mean([v @ v for v in sc]))),
        "drift_rms": float(np.sqrt(np.mean([v @ v for v in dr]))),
        "correlation": float(np.mean([s @ d for s, d in zip(sc, dr, strict=True)])
                             / max(np.sqrt(np.mean([s @ s for s in sc])
                                           * np.mean([d @ d for d in dr])), 1e-12)),
    }  # fmt: skip


KEYS = ("true", "sum_of_parts", "scanner_alone", "drift_alone", "scanner_rms", "drift_rms",
        "correlation")  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, required=True,
                    help="a reproduce --quick --seeds run (its seed-N/model.json)")  # fmt: skip
    ap.add_argument("--seeds", default="1-3", help="sample seeds, e.g. 1-10")
    ap.add_argument("--preset", default="cpr5")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path, help="write every seed's figures to this file too")
    a = ap.parse_args()
    try:
        seeds = parse_seeds(a.seeds)
        config = load_config(a.preset)
    except ValueError as exc:
        ap.error(str(exc))
    if a.workers < 1:
        ap.error(f"--workers must be at least 1. Got {a.workers}.")
    if a.json is not None and not a.json.resolve().parent.is_dir():
        ap.error(f"--json must be in an existing folder. Got {str(a.json)!r}.")
    models, areas = {}, {}
    for seed in seeds:
        path = a.runs / f"seed-{seed}" / "model.json"
        try:
            m = load_model(path)
            res = json.loads((path.parent / "results.json").read_text(encoding="utf-8"))
            areas[seed] = float(res["table1_settings"]["area_half_width_nm"])
            if res["preset"] != a.preset or not res["quick"]:
                ap.error(f"--runs: {path.parent} is not a --quick run of {a.preset}.")
        except (OSError, ValueError, KeyError, TypeError) as exc:
            ap.error(f"--runs: cannot read seed {seed}'s model and results in {path.parent}: {exc}")
        if not isinstance(m, ScannerModel2D):
            ap.error(f"--runs: {path} is a 1-D model; Table I needs both axes.")
        models[seed] = m
    base = ReproduceSettings(config=config, source=a.preset, seed=seeds[0]).quick_run()
    period = VirtualAFM(config, seed=seeds[0]).sample_period_s
    jobs = []
    for seed in seeds:
        plan = experiment_plan(base, areas[seed])  # Table I's area of the run itself
        for trial in table1.plan(plan):
            if trial.method == DRIFT_METHOD:
                jobs.append((seed, trial.settings))
    print(f"{len(jobs)} experiments of Table I inside the drift compensator", flush=True)
    done = Parallel(n_jobs=a.workers)(
        delayed(one_trial)(config, seed, models[seed], st, period) for seed, st in jobs
    )
    per_seed = {}
    for seed in seeds:
        trials = [r for (s, _), r in zip(jobs, done, strict=True) if s == seed]
        per_seed[seed] = {"trials": trials, "figures": seed_figures(trials)}
        f = per_seed[seed]["figures"]
        print(f"seed {seed}: " + ", ".join(f"{k} {f[k]:.2f}" for k in KEYS), flush=True)
    stats = {
        k: [float(np.median([p["figures"][k] for p in per_seed.values()])),
            float(np.max([p["figures"][k] for p in per_seed.values()]))]
        for k in KEYS
    }  # fmt: skip
    for k in KEYS:
        print(f"{k}: median {stats[k][0]:.2f}, worst {stats[k][1]:.2f} over {len(seeds)} seeds")
    if a.json is not None:
        command = shlex.join(["python", "benchmarks/table1_budget.py", *sys.argv[1:]])
        atomic_write_text(a.json, json.dumps(
            {"command": command, "seeds": list(seeds), "statistics": stats,
             "per_seed": {str(s): p for s, p in per_seed.items()}}, indent=2) + "\n")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
