"""Why Fig. 9's error changes with the move speed: drift against the scanner's own dynamics.

Fig. 9 images an area, follows a 4.4 um path and images the area again; its error is the
offset between the two images. ``reproduce``'s speed sweep shows the compensated error
falling as the speed rises on the drifting ``cpr5``. This runs the experiment with the model
family fitted to the scanner's TRUE extension (a diagnosis, not an identification: the
identification's own errors stay out) on ``cpr5`` and on its drift-free twin
``cpr5-nodrift``, at the lowest and the highest speed of the sweep, compensated and not: if
the fall is drift over the slower path's longer time, it is absent without drift.

About 30 s a seed on an idle two-core machine::

    python benchmarks/fig9_speed_drift.py --seeds 1 2 --json fig9_speed.json
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from piezocomp._atomic import atomic_write_text
from piezocomp.experiments import fig9
from piezocomp.experiments.contract import Trial
from piezocomp.experiments.methods import IdentificationSettings, MethodModels
from piezocomp.experiments.virtual_identification import fit_on_truth
from piezocomp.model import ScannerModel2D
from piezocomp.virtual_afm import VirtualAFM, load_config

PRESETS = ("cpr5", "cpr5-nodrift")
METHODS = ("compensated", "uncompensated")


def oracle(seed: int) -> MethodModels:
    """The model family fitted to the true extension of ``cpr5-nodrift`` (both axes)."""
    st = IdentificationSettings()
    axes = []
    for axis in ("x", "y"):
        afm = VirtualAFM("cpr5-nodrift", seed=seed)
        axes.append(fit_on_truth(afm, st.config(afm.range_nm), axis, st.oracle_orders))
    return MethodModels({"compensated": ScannerModel2D(*axes)})


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--speeds", type=float, nargs="+", default=[250.0, 2000.0])
    ap.add_argument("--json", type=Path, help="write the rows and their median over the seeds")
    a = ap.parse_args()
    rows = []
    for seed in a.seeds:
        models = oracle(seed)
        for preset in PRESETS:
            config = load_config(preset).with_seed(seed)
            for v in a.speeds:
                for m in METHODS:
                    st = fig9.Fig9Settings(speed_nm_per_s=v)
                    r = fig9.run_trial(Trial(fig9.NAME, m, st), config, seed, models)
                    rows.append(
                        {
                            "seed": seed,
                            "preset": preset,
                            "method": m,
                            "speed_nm_per_s": v,
                            "true_error_nm": r.true_error_nm,
                            "error_nm": r.error_nm,
                        }
                    )
                    print(
                        f"seed {seed} {preset:13s} {m:13s} {v:6g} nm/s: true "
                        f"{r.true_error_nm:.2f} nm, measured {r.error_nm:.2f}",
                        flush=True,
                    )
    median = []
    for preset in PRESETS:
        for m in METHODS:
            for v in a.speeds:
                vals = sorted(
                    r["true_error_nm"]
                    for r in rows
                    if (r["preset"], r["method"], r["speed_nm_per_s"]) == (preset, m, v)
                )
                mid = 0.5 * (vals[(len(vals) - 1) // 2] + vals[len(vals) // 2])
                median.append(
                    {"preset": preset, "method": m, "speed_nm_per_s": v, "true_error_nm": mid}
                )
                print(f"median over seeds {a.seeds}: {preset} {m} {v:g} nm/s {mid:.2f} nm")
    if a.json:
        cmd = shlex.join(
            [
                "python",
                "benchmarks/fig9_speed_drift.py",
                "--seeds",
                *map(str, a.seeds),
                "--speeds",
                *(f"{v:g}" for v in a.speeds),
            ]
        )
        data = {"command": cmd, "seeds": a.seeds, "rows": median, "per_seed": rows}
        atomic_write_text(a.json, json.dumps(data, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
