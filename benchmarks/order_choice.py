"""The choice of the model orders by held-out heights, against the truth (DIAGNOSIS: it
reads the virtual AFM's ground truth to score).

The sensorless identification chooses its orders among ``EstimationConfig.orders`` on the
held-out heights of models that have had only the first re-indexing rounds
(``selection_rounds``), then runs the chosen orders alone through the rest of the chain
(further lines, the drift rounds, the fits over the whole record). For each seed and axis
this benchmark runs the default identification of ``piezocomp reproduce``
(:func:`error_budget.identified`, with its retries), then every candidate order alone through
the whole chain on the same records
(:func:`~piezocomp.identification.sensorless.estimate_axis`), and gives for each:

- ``early_heldout_nm``: its held-out height RMS at the moment of the choice (the
  identification's own trial);
- ``final_heldout_nm``: the held-out height RMS of its final batch model, run alone (the
  figure a choice on the final models would read; no ground truth);
- ``validation_nm``: that model's validation max error against the truth
  (:func:`~piezocomp.experiments.scoring.score_on_truth`, the error budget's score).

It then says, over every axis, how often the early choice and a choice on the final held-out
heights (the same rule: the largest order within ``order_tolerance`` of the best) pick the
candidate the truth scores best. About 1.5 minutes an axis on an idle two-core machine::

    python benchmarks/order_choice.py --seeds 1-10 --json orders.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))
from error_budget import candidates_alone, identified

from piezocomp.experiments.methods import IdentificationSettings
from piezocomp.experiments.samples import parse_seeds
from piezocomp.experiments.scoring import score_on_truth
from piezocomp.identification.estimation.orders import select_orders
from piezocomp.io import atomic_write_text


def final_choice(final: dict[str, float], tolerance: float) -> str:
    """The identification's own rule (:func:`select_orders`, ``prefer="largest"``) applied to
    the final models' held-out heights, ``final`` keyed ``"NxC"``."""
    pairs = [tuple(int(n) for n in k.split("x")) for k in final]
    sel = select_orders(pairs, lambda nh, nc: (f"{nh}x{nc}", 0.0), final.__getitem__,
                        tolerance=tolerance, prefer="largest")  # fmt: skip
    return str(sel.fitted)


def one_axis(preset: str, seed: int, axis: str) -> dict[str, Any]:
    """Every candidate's early and final held-out heights and truth score on one axis."""
    settings = IdentificationSettings()
    afm, _, cfg, ident = identified(preset, seed, axis, settings)
    early = {f"{t.n_play}x{t.n_creep}": t.validation_error for t in ident.orders.trials}
    runs = {f"{o[0]}x{o[1]}": run for o, run in candidates_alone(ident, cfg).items()}
    models = {k: run.batch_model for k, run in runs.items()}
    final = {k: float(run.estimation.heldout_rms_nm["batch"]) for k, run in runs.items()}
    acq = cfg.acquisition
    score = score_on_truth(afm, ident, models, span_nm=acq.span_nm,
                           center_nm=acq.center_nm[0 if axis == "x" else 1])  # fmt: skip
    truth = {k: float(score[k]["validation_max_error_nm"]) for k in models}
    tol = float(cfg.estimation.order_tolerance)
    return {
        "chosen": f"{ident.orders.n_play}x{ident.orders.n_creep}",
        "early_heldout_nm": early,
        "final_heldout_nm": final,
        "validation_nm": truth,
        "final_choice": final_choice(final, tol) if final else None,
        "truth_choice": min(truth, key=lambda k: truth[k]) if truth else None,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5")
    ap.add_argument("--seeds", required=True, help="e.g. 1-5")
    ap.add_argument("--axes", default="xy", choices=("x", "y", "xy"))
    ap.add_argument("--json", type=Path, help="also write every figure, with the command, here")
    a = ap.parse_args()
    rows: list[dict[str, Any]] = []
    for seed in parse_seeds(a.seeds):
        for axis in a.axes:
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    r = one_axis(a.preset, seed, axis)
                except RuntimeError as exc:
                    print(f"seed {seed} {axis}: failed ({exc})", flush=True)
                    continue
            r.update(seed=seed, axis=axis)
            rows.append(r)
            cells = "  ".join(
                f"{k}: early {r['early_heldout_nm'].get(k, float('nan')):.2f} final "
                f"{r['final_heldout_nm'][k]:.2f} truth {r['validation_nm'][k]:.2f}"
                for k in r["validation_nm"]
            )
            print(f"seed {seed} {axis} ({time.perf_counter() - t0:.0f} s): chosen {r['chosen']}, "
                  f"on final {r['final_choice']}, truth {r['truth_choice']}; {cells}",
                  flush=True)  # fmt: skip
            if a.json is not None:
                out = {"command": "python benchmarks/order_choice.py " + " ".join(sys.argv[1:]),
                       "preset": a.preset, "axes": rows}  # fmt: skip
                atomic_write_text(a.json, json.dumps(out, indent=1) + "\n")
    n = len(rows)
    early_ok = sum(r["chosen"] == r["truth_choice"] for r in rows)
    final_ok = sum(r["final_choice"] == r["truth_choice"] for r in rows)
    print(f"the truth's best candidate chosen: early {early_ok} of {n} axes, "
          f"on the final held-out heights {final_ok} of {n}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
