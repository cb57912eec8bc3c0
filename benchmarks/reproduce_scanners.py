"""The paper's experiments on virtual scanners the package was not tuned on.

Runs ``piezocomp reproduce --quick``'s experiments (Table I at 1 um/s with 5 experiments per
distance, Fig. 9 at every speed, Fig. 8, two Fig. 10 assemblies, and on these drifting
scanners the 5-minute drift session) for the uncompensated and default methods on each
scanner below, over one or more sample seeds, and prints one line per scanner and seed: the
worst Table I row and the Fig. 9 error at 1 um/s (true, nm) uncompensated, with creep and
hysteresis compensated (``compensated``) and with drift compensated too (``both``, the
default on a drifting scanner), Fig. 10's success of each, the session's worst true error
with ``both`` and its share of time measuring, and the exit status ``reproduce`` would give.
With several seeds, the median and worst over them follow.

Scanners (TOML keys over ``cpr5``'s, so each drifts as ``cpr5`` does, 0.05 nm/s plus a
random walk of 0.02 nm/sqrt(s)): hysteresis 2 % (``gentle``), 8 % and 15 %; creep 1 %, 10 %
and 20 %; 10 nm particles with 0.3 nm height noise; 20 nm particles with 0.05 nm noise; a
scanner with 1 % x-y cross-coupling (which the per-axis model neglects, as the paper does);
``untuned drift``, the gentle scanner drifting in another way (0.08 nm/s at 120 degrees,
a random walk of 0.03 nm/sqrt(s)); and scanners whose creep is made otherwise, not only
larger or smaller: 60 % of it relaxing the hysteresis' domains (``cpr5``: 35 %), none of it
(linear creep, the paper's family), the domains relaxing only through modes of 10 s and
slower (outside the extended family), a creep spectrum of 0.01-300 s (``cpr5``: 0.001-1800
s); and a blunt, wide tip (20 nm apex, 35 degree cone, drawn within +-30 % and +-8 degrees).

About 7 minutes per scanner and seed on two cores; ``--load`` prints earlier ``--json``
files together, with the median and worst over all their seeds::

    python benchmarks/reproduce_scanners.py [--only NAME ...] [--seeds 1 2 3] [--json FILE]
    python benchmarks/reproduce_scanners.py --load seeds12.json seeds34.json
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from piezocomp.experiments.reproduce import ReproduceSettings, reproduce
from piezocomp.experiments.samples import headline, statistics
from piezocomp.io import atomic_write_text
from piezocomp.virtual_afm import load_config
from piezocomp.virtual_afm.config import AFMConfig

SCANNERS: dict[str, dict[str, dict[str, Any]]] = {
    "gentle (h 2 %, c 1 %)": {"scanner": {"hysteresis": 0.02, "hysteresis_small": 0.005,
                                          "creep": 0.01}},
    "h 8 %, c 10 %": {"scanner": {"hysteresis": 0.08, "hysteresis_small": 0.02, "creep": 0.10}},
    "h 15 %, c 20 %, asym 0.1": {"scanner": {"hysteresis": 0.15, "hysteresis_small": 0.03,
                                             "hysteresis_asymmetry": 0.1, "creep": 0.20}},
    "h 12 %, c 5 %": {"scanner": {"creep": 0.05}},
    "h 5 %, c 15 %": {"scanner": {"hysteresis": 0.05, "hysteresis_small": 0.015,
                                  "creep": 0.15}},
    "10 nm particles, noise 0.3": {"sample": {"particle_diameter_nm": 10.0,
                                              "particle_diameter_std_nm": 0.7,
                                              "height_noise_nm": 0.3}},
    "20 nm particles, noise 0.05": {"sample": {"particle_diameter_nm": 20.0,
                                               "height_noise_nm": 0.05,
                                               "particles_per_um2": 100.0}},
    "cross-coupling 1 %": {"scanner": {"cross_coupling": 0.01}},
    "untuned drift": {"scanner": {"hysteresis": 0.02, "hysteresis_small": 0.005,
                                  "creep": 0.01, "drift_nm_per_s": 0.08,
                                  "drift_direction_deg": 120.0,
                                  "drift_random_walk_nm_per_sqrt_s": 0.03}},
    "domains 60 % of the creep": {"scanner": {"creep_domain_fraction": 0.6}},
    "no domain creep": {"scanner": {"creep_domain_fraction": 0.0}},
    "domains from 10 s": {"scanner": {"creep_domain_tau_min_s": 10.0}},
    "creep 0.01-300 s": {"scanner": {"creep_tau_min_s": 0.01, "creep_tau_max_s": 300.0}},
    "blunt wide tip (20 nm, 35 deg)": {"sample": {"tip_radius_nm": 20.0,
                                                  "tip_half_angle_deg": 35.0}},
}  # fmt: skip


def config(changes: dict[str, dict[str, Any]]) -> AFMConfig:
    base = load_config("cpr5")
    mapping = {
        "scanner": {**_fields(base.scanner), **changes.get("scanner", {})},
        "sample": {**_fields(base.sample), **changes.get("sample", {})},
    }
    return load_config(mapping)


def _fields(obj: Any) -> dict[str, Any]:
    from dataclasses import asdict

    return {k: v for k, v in asdict(obj).items() if v != ()}


def one(name: str, changes: dict[str, dict[str, Any]], seed: int, workers: int) -> dict[str, Any]:
    s = ReproduceSettings(
        config=config(changes), source=name, methods=("uncompensated", "compensated"),
        seed=seed, workers=workers,
    ).quick_run()  # fmt: skip
    t0 = time.perf_counter()
    res = reproduce(s, progress=False).results
    fatal = [f for f in res["failures"]
             if f["experiment"] != "identification" or f["method"] == "compensated"]  # fmt: skip
    return {
        "scanner": name,
        "seed": seed,
        "headline": headline(res),
        "exit_status": 1 if fatal else 0,
        "failures": [
            f"{f['experiment']}/{f['method']} ({f['settings']}): {f['error']}"
            for f in res["failures"]
        ],
        "seconds": time.perf_counter() - t0,
    }


def _f(v: float | None, pc: bool = False) -> str:
    if v is None:
        return "    -"
    return f"{100 * v:4.0f}%" if pc else f"{v:5.2f}"


def _line(label: str, h: dict[str, Any]) -> str:
    u, c, b = h["uncompensated"], h["compensated"], h["both"]
    return (
        f"{label:34s} T1 {_f(u['table1_true_nm'])} {_f(c['table1_true_nm'])} "
        f"{_f(b['table1_true_nm'])} | F9 {_f(u['fig9_true_nm'])} {_f(c['fig9_true_nm'])} "
        f"{_f(b['fig9_true_nm'])} | F10 {_f(c['fig10_true_success'], True)} "
        f"{_f(b['fig10_true_success'], True)} | session {_f(b['session_true_worst_nm'])} "
        f"{_f(b['session_measuring'], True)}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=list(SCANNERS), help="scanners to run")
    ap.add_argument("--seeds", nargs="+", type=int, default=[1], help="sample seeds")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", help="write the lines as JSON to this file too")
    ap.add_argument(
        "--load", nargs="+", type=Path, metavar="JSON",
        help="print the runs of earlier --json files, with their median and worst over the "
        "seeds, instead of running",
    )  # fmt: skip
    a = ap.parse_args()
    saved: dict[tuple[str, int], dict[str, Any]] = {}
    for path in a.load or []:
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            runs = data["runs"] if isinstance(data, dict) else data  # older files: the list
            saved |= {(r["scanner"], int(r["seed"])): r for r in runs}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            ap.error(f"--load takes files of --json. {path}: {exc}")
    results = []
    print(
        "true errors, nm: Table I worst d and Fig. 9 at 1 um/s (uncompensated, compensated, "
        "both); Fig. 10 success (compensated, both); session worst with both (measuring)"
    )
    for name in a.only or SCANNERS:
        runs = []
        seeds = sorted(s for n, s in saved if n == name) if a.load else a.seeds
        for seed in seeds:
            r = saved[name, seed] if a.load else one(name, SCANNERS[name], seed, a.workers)
            runs.append(r)
            status = "" if r["exit_status"] == 0 else f"  exit 1: {len(r['failures'])} failed"
            print(_line(f"{name} (seed {seed})", r["headline"]) + status, flush=True)
            for text in r["failures"]:
                print(f"    failed: {text}")
        if len(runs) > 1:
            st = statistics([r["headline"] for r in runs])
            for k in ("median", "worst"):
                figures = {m: {f: v[k] for f, v in by.items()} for m, by in st.items()}
                print(_line(f"{name} ({k} of {len(runs)})", figures), flush=True)
        results += runs
    ok = sum(r["exit_status"] == 0 for r in results)
    print(f"{ok} of {len(results)} runs would exit 0 (no failed part)")
    if a.json:
        command = shlex.join(["python", "benchmarks/reproduce_scanners.py", *sys.argv[1:]])
        data = {"command": command, "seeds": sorted({r["seed"] for r in results}),
                "runs": results}  # fmt: skip
        atomic_write_text(a.json, json.dumps(data, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
