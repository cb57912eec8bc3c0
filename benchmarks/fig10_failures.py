"""Why Fig. 10's assemblies fail inside the drift compensator (for DIAGNOSIS: it reads the
virtual AFM's ground truth).

For each seed, both axes are identified as ``piezocomp reproduce`` identifies them (the
default method's model), and Fig. 10's assemblies run inside the drift compensator exactly as
``reproduce`` runs ``both``'s (the same samples, ``--assemblies`` of them: ``reproduce
--quick`` runs 2). With ``--oracle`` the same assemblies run again with the model family
fitted to the true extension in the identified model's place
(:func:`~piezocomp.experiments.virtual_identification.fit_on_truth`), which separates what
the model's error costs from what the pushing and the drift cost.

Per assembly it prints: truly succeeded or not, and by the last image; the worst site's true
error and that site's error by the image; the failed pushes the images found and how many
were left unrecovered; what the simulator's pushing truly did that went wrong (stuck, rolled
off, picked up, dropped, lost). Then it names the failure's kind:

- ``unseen``: the image judged the assembly placed, the truth did not (the site's particle is
  where the instrument thinks the site is, and the instrument is off: positioning or drift);
- ``seen``: the image showed a site not placed (a push that failed and was not recovered);
- ``lost``: a site without any particle at the end;
- ``stopped``: an error stopped the assembly.

``--set SECTION.KEY=VALUE`` changes the preset's configuration (e.g. the blunt wide tip of
``benchmarks/reproduce_scanners.py``: ``--set sample.tip_radius_nm=20 --set
sample.tip_half_angle_deg=35``). About 3 minutes a seed on two cores (5 with ``--oracle``);
with ``--runs DIR`` (a ``reproduce --quick --seeds`` run of the same preset and settings) the
default models it saved are used instead of identifying them again, seconds a seed::

    python benchmarks/fig10_failures.py --seeds 1-10 [--assemblies 2] [--oracle] [--json F]
    python benchmarks/fig10_failures.py --seeds 1-10 --runs DIR
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from joblib import delayed

from piezocomp.experiments.contract import DRIFT_METHOD, Trial
from piezocomp.experiments.fig10 import NAME, Fig10Settings, Fig10Trial, run_trial
from piezocomp.experiments.methods import IdentificationSettings, MethodModels, identification_job
from piezocomp.experiments.parallel import run_parallel
from piezocomp.experiments.samples import parse_seeds
from piezocomp.io import atomic_write_text, load_model
from piezocomp.model import ScannerModel2D
from piezocomp.virtual_afm import VirtualAFM, load_config
from piezocomp.virtual_afm.config import AFMConfig

WRONG = ("stuck", "rolled_off", "picked_up", "dropped", "lost")
"""The simulator's push outcomes that are not a clean push (its ``PushCounts``)."""


def configured(preset: str, changes: tuple[str, ...]) -> AFMConfig:
    """``preset`` with ``SECTION.KEY=VALUE`` changes (values read as TOML: numbers, strings
    in quotes, booleans), each checked as the configuration checks its own."""
    import tomllib
    from dataclasses import replace

    config = load_config(preset)
    for text in changes:
        key, sep, value = text.partition("=")
        section, dot, name = key.strip().partition(".")
        if not sep or not dot or section not in ("scanner", "sample"):
            raise SystemExit(f"--set takes scanner.KEY=VALUE or sample.KEY=VALUE. Got {text!r}.")
        v = tomllib.loads(f"v = {value.strip()}")["v"]
        try:
            part = replace(getattr(config, section), **{name: v})
        except TypeError:
            raise SystemExit(f"--set: {section} has no setting {name!r}.") from None
        except ValueError as exc:
            raise SystemExit(f"--set {text}: {exc}") from None
        config = replace(config, **{section: part})
    return config


def models_of(kind: str, config: AFMConfig, seed: int, workers: int) -> MethodModels:
    """Both axes' model of ``kind`` (``sensorless``: the default method's; ``oracle``) as the
    ``compensated`` model."""
    tasks = [delayed(identification_job)(kind, axis, config, seed, IdentificationSettings())
             for axis in ("x", "y")]  # fmt: skip
    jobs = run_parallel(workers, tasks, "identification", False)
    for job in jobs:
        if "error" in job["summary"]:
            raise RuntimeError(f"seed {seed}, {kind} {job['axis']}: {job['summary']['error']}")
        job["models"] = {
            "compensated": job["models"]["oracle" if kind == "oracle" else "compensated"]
        }
    T = VirtualAFM(config, seed=seed).sample_period_s
    return MethodModels.from_jobs(jobs, T)


def _assembly(trial: Trial, config: AFMConfig, seed: int, models: MethodModels) -> dict[str, Any]:
    try:
        r = run_trial(trial, config, seed, models)
    except Exception as exc:
        return {"kind": "stopped", "error": f"{type(exc).__name__}: {exc}"}
    true = np.asarray(r.true_errors_nm, dtype=float)
    seen = r.assembly.errors_nm
    worst = int(np.argmax(true))
    counts = r.true_push_counts or {}
    ok = bool(r.true_success)
    kind = "placed"
    if not ok:
        if not np.isfinite(true[worst]):
            kind = "lost"
        elif r.success:
            kind = "unseen"
        else:
            kind = "seen"
    return {
        "kind": kind,
        "true_success": ok,
        "image_success": bool(r.success),
        "true_worst_nm": float(true[worst]),
        "worst_site": worst,
        "image_error_there_nm": float(seen[worst]),
        "image_worst_nm": float(np.nanmax(seen)) if np.isfinite(seen).any() else None,
        "true_errors_nm": [float(v) for v in true],
        "failed_pushes": r.assembly.failures,
        "unrecovered": r.unrecovered,
        "blocked": r.blocked,
        "passes": len(r.assembly.passes),
        "pushes": r.assembly.n_pushes,
        "true_wrong_pushes": {k: counts.get(k, 0) for k in WRONG},
    }


def saved_models(runs: Path, seed: int, config: AFMConfig, preset: str) -> MethodModels:
    """The default model a ``reproduce --seeds`` run saved for ``seed`` (``model.json``), as
    the ``compensated`` model: the same as :func:`models_of` identifies, without the time."""
    path = runs / f"seed-{seed}" / "model.json"
    try:
        model = load_model(path)
        res = json.loads((path.parent / "results.json").read_text(encoding="utf-8"))
        made = (res["preset"], res["quick"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SystemExit(f"--runs: cannot read seed {seed}'s model and results: {exc}") from None
    if made != (preset, True):
        raise SystemExit(f"--runs: {path.parent} is not a --quick run of {preset} ({made}).")
    if not isinstance(model, ScannerModel2D):
        raise SystemExit(f"--runs: {path} is a 1-D model; Fig. 10 needs both axes.")
    T = VirtualAFM(config, seed=seed).sample_period_s
    return MethodModels({"compensated": model}, T)


def one(
    config: AFMConfig, seed: int, kind: str, assemblies: int, workers: int,
    runs: Path | None = None, preset: str = "cpr5",
) -> list[dict[str, Any]]:  # fmt: skip
    t0 = time.perf_counter()
    if runs is not None and kind == "sensorless":
        models = saved_models(runs, seed, config, preset)
    else:
        models = models_of(kind, config, seed, workers)
    trials = [Trial(NAME, DRIFT_METHOD, Fig10Trial(Fig10Settings(), k)) for k in range(assemblies)]
    tasks = [delayed(_assembly)(t, config, seed, models) for t in trials]
    out = run_parallel(workers, tasks, "assemblies", False)
    dt = time.perf_counter() - t0
    return [
        {"seed": seed, "model": kind, "sample": k, "seconds": dt, **a} for k, a in enumerate(out)
    ]


def _nm(v: float | None) -> str:
    return "none" if v is None else f"{v:5.2f}"


def _line(a: dict[str, Any]) -> str:
    head = f"seed {a['seed']:3d} {a['model']:10s} sample {a['sample']}: {a['kind']:8s}"
    if a["kind"] == "stopped":
        return f"{head} {a['error']}"
    wrong = ", ".join(f"{k} {v}" for k, v in a["true_wrong_pushes"].items() if v) or "none"
    seen = ", ".join(f"{k} {v}" for k, v in a["failed_pushes"].items() if v) or "none"
    there = a["image_error_there_nm"]
    return (
        f"{head} worst site {a['worst_site']} truly {a['true_worst_nm']:6.2f} nm "
        f"(image {there:5.2f}); image's worst {_nm(a['image_worst_nm'])}; "
        f"failed pushes seen: {seen}, unrecovered {a['unrecovered']}; "
        f"sites no clear path reached {a.get('blocked', 0)}; "
        f"truly wrong pushes: {wrong}; {a['passes']} passes, {a['pushes']} pushes"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5")
    ap.add_argument("--seeds", type=parse_seeds, default=(1,), help="e.g. 1-10 or 1,4,8")
    ap.add_argument("--assemblies", type=int, default=2, help="per seed (reproduce --quick: 2)")
    ap.add_argument("--oracle", action="store_true", help="the truth-fitted model too")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="change the preset's configuration (repeatable)")  # fmt: skip
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--runs", type=Path,
                    help="a reproduce --seeds run of the same preset: its saved default models "
                    "(seed-N/model.json) instead of identifying them here")  # fmt: skip
    ap.add_argument("--json", help="write every assembly's figures to this file too")
    a = ap.parse_args()
    if a.assemblies < 1:
        ap.error(f"--assemblies must be >= 1. Got {a.assemblies}.")
    if a.runs is not None and a.set:
        ap.error("--runs reads the models identified on the preset as it is; --set changes it.")
    config = configured(a.preset, tuple(a.set))
    rows: list[dict[str, Any]] = []
    for seed in a.seeds:
        for kind in ("sensorless", "oracle") if a.oracle else ("sensorless",):
            for r in one(config, seed, kind, a.assemblies, a.workers, a.runs, a.preset):
                rows.append(r)
                print(_line(r), flush=True)
    for kind in dict.fromkeys(r["model"] for r in rows):
        mine = [r for r in rows if r["model"] == kind]
        by = {k: sum(r["kind"] == k for r in mine) for k in ("placed", "unseen", "seen", "lost",
                                                             "stopped")}  # fmt: skip
        print(f"{kind}: {by['placed']} of {len(mine)} truly placed; failed: "
              + ", ".join(f"{k} {v}" for k, v in by.items() if k != "placed"))  # fmt: skip
    if a.json:
        command = "python benchmarks/fig10_failures.py " + " ".join(sys.argv[1:])
        data = {"command": command, "seeds": list(a.seeds), "rows": rows}
        atomic_write_text(a.json, json.dumps(data, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
