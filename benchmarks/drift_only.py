"""The drift session's "drift only" against no compensation and both, over sample seeds.

"Drift only" is the drift compensator around the uncompensated scanner
(``DriftSettings.uncompensated()``): it measures the scanner's own error at its landmarks
and sizes its windows and filter from it. "Both" needs a creep-and-hysteresis model; the
sensorless identification on a drifting scanner is refused on some seeds' y axis (the
drift across its line; docs/drift.md), so this benchmark gives "both" the model family
fitted to the TRUE extension of ``cpr5-nodrift`` (as the tests do): it shows what
the drift compensator does around a good model, not what identification on this scanner
gives. "None" and "drift only" use no model.

For each seed: the final and the worst image error (true and measured, nm), the time spent
measuring, the scanner error drift only measured at its landmarks; then the median and the
worst over the seeds. About 20 s per seed and method for 10 minutes::

    python benchmarks/drift_only.py --minutes 10 --seeds 1 2 3
"""

from __future__ import annotations

import argparse

import numpy as np

from piezocomp.experiments import drift_session as D
from piezocomp.experiments.methods import IdentificationSettings, MethodModels
from piezocomp.experiments.virtual_identification import fit_on_truth
from piezocomp.model import ScannerModel2D
from piezocomp.virtual_afm import VirtualAFM, load_config

METHODS = ("uncompensated", "drift_only", "both")


def truth_models() -> MethodModels:
    st = IdentificationSettings()
    axes = []
    for axis in ("x", "y"):
        afm = VirtualAFM("cpr5-nodrift", seed=1)
        axes.append(fit_on_truth(afm, st.config(afm.range_nm), axis, st.oracle_orders))
    return MethodModels({"compensated": ScannerModel2D(*axes)})


def _stat(values: list[float]) -> str:
    a = np.asarray([v for v in values if v is not None and np.isfinite(v)])
    if not a.size:
        return "n/a"
    return f"{np.median(a):6.1f} / {np.max(a):6.1f}" + (
        "" if a.size == len(values) else f" ({a.size} of {len(values)})"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="cpr5")
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    args = p.parse_args()
    models = truth_models()
    settings = D.DriftSessionSettings(minutes=args.minutes, area_nm=600.0)
    rows: dict[str, list[D.DriftSessionResult]] = {m: [] for m in METHODS}
    for seed in args.seeds:
        config = load_config(args.preset).with_seed(seed)
        for m in METHODS:
            r = D.run_method(m, VirtualAFM(config, seed=seed), models, settings)
            rows[m].append(r)
            err = "" if r.scanner_error_nm is None else (
                f", landmarks' scanner error {r.scanner_error_nm[0]:.1f} / "
                f"{r.scanner_error_nm[1]:.1f} nm")  # fmt: skip
            stop = f", STOPPED: {r.stopped}" if r.stopped else ""
            print(f"seed {seed} {m:5s}: final {r.true_final_error_nm or float('nan'):6.1f} true, "
                  f"{r.final_error_nm or float('nan'):6.1f} measured; worst "
                  f"{r.true_max_error_nm or float('nan'):6.1f} true; "
                  f"{100 * r.overhead_fraction:4.1f} % measuring{err}{stop}")  # fmt: skip
    print(f"\n{args.preset}, {args.minutes:g}-minute sessions, seeds {args.seeds}: "
          "median / worst over seeds, nm")  # fmt: skip
    for m in METHODS:
        rs = rows[m]
        print(f"  {m:5s}: final true {_stat([r.true_final_error_nm for r in rs])}, "
              f"final measured {_stat([r.final_error_nm for r in rs])}, "
              f"worst true {_stat([r.true_max_error_nm for r in rs])}")  # fmt: skip


if __name__ == "__main__":
    main()
