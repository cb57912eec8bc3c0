"""Where the sensorless identification loses accuracy, stage by stage (DIAGNOSIS: it reads the
virtual AFM's ground truth to build its references and scores).

For each seed and axis, the default identification of ``piezocomp reproduce`` runs on a
virtual AFM (on another line when a record fails, as ``reproduce`` records again), through a
wrapper that keeps, for this benchmark only, the true extension of every command it sends;
then each stage's output is replaced, one at a time, by its
counterpart made from the truth, and every model is scored on one fresh validation
trajectory against the true extension
(:func:`~piezocomp.experiments.scoring.score_on_truth`: max error, nm, offset removed):

- ``identified``: the default model (the batch model, scaled by the grating);
- ``identified, true scale``: the same with its scale error against the truth removed (what
  the grating's scale and the calibration frame leave);
- ``identified_rls``: the RLS estimate of the same identification (eqs 16-20, the chain's
  own), scaled the same way: what the recursive estimator leaves against the batch one;
- ``orders on truth``: the estimation stage run again on the same records with each other
  candidate order alone (one that fails, or fails its own validation, left out), and the
  model that scores best on the truth kept, the identified one standing for its own orders
  (it is the run with every candidate, which can differ from its orders run alone: the RLS
  chain's start and the drift rounds see them all): about what choosing the orders by
  held-out heights costs;
- ``true loop``: the estimation stage run again, unchanged, on the loop stage's output made
  from the truth (``f_a`` fitted to the true steady branches of part A, ``h(y)`` indexed by
  it), the model then put on the true loop's span (:func:`span_frame`, as the pipeline puts a
  model whose ``h`` it re-indexed on its own loop's): what the loop of Section IV and its
  ``h`` cost;
- ``truth fit, record only`` (paper's family, and extended family with ``beta`` chosen on
  held-out truth): the model family fitted to the true extension of the identification
  waveform run from rest (the oracle of ``reproduce`` without its 12 minutes of extra record,
  :func:`~piezocomp.experiments.virtual_identification.fit_on_truth`); the gap from
  ``identified`` to it is what the estimation from heights loses on a record like this;
- ``truth fit`` (extended family, with the extra record): ``reproduce``'s ``oracle``;
- ``identified, no drift``: the same seed's identification on its drift-free twin
  (``--no-drift-twin PRESET``, default ``cpr5-nodrift``), scored on its own trajectory: what
  the drift along and across the line costs the identification.

The table gives, for each row, the median and worst over the seeds of the worse axis of each
seed (Table I moves both). About 5 minutes a seed on two cores::

    python benchmarks/error_budget.py --seeds 1-10 --json budget.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp.experiments.methods import IdentificationSettings, retry_lines
from piezocomp.experiments.samples import parse_seeds
from piezocomp.experiments.scoring import score_on_truth
from piezocomp.experiments.virtual_identification import fit_on_truth, identify_virtual
from piezocomp.identification.estimation.drift_rounds import drift_rounds
from piezocomp.identification.estimation.prediction import predicted_forward_trace
from piezocomp.identification.estimation.problem import EstimationProblem
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.loop.symmetric import SymmetricLoop
from piezocomp.identification.reference.frames import mapped, span_frame
from piezocomp.identification.result import AxisIdentification
from piezocomp.identification.sensorless import estimate_axis
from piezocomp.io import atomic_write_text
from piezocomp.model import ScannerModel
from piezocomp.virtual_afm import VirtualAFM, load_config

ROWS = (
    ("identified", "identified (the default model)"),
    ("identified_true_scale", "identified, its scale error removed"),
    ("identified_rls", "the RLS estimate of the same identification"),
    ("identified_truth_orders", "identified, its orders chosen on the truth"),
    ("true_loop", "identified from the true loop and h(y)"),
    ("fit_record_paper", "truth fit of the record, paper's family"),
    ("fit_record_extended", "truth fit of the record, extended family"),
    ("fit_oracle", "truth fit with 12 min more record (reproduce's oracle)"),
    ("identified_no_drift", "identified on the drift-free twin"),
)
"""The budget's rows: key and label."""


class TruthRecorder:
    """A virtual AFM, forwarded; keeps (command, heights, true extension) of every record it
    returns, for the benchmark only (the identification never sees it)."""

    def __init__(self, afm: VirtualAFM) -> None:
        self.afm = afm
        self.log: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self.afm, name)
        if name not in ("run", "move_to", "wait"):
            return attr

        def kept(*args: Any, **kwargs: Any) -> Any:
            rec = attr(*args, **kwargs)
            ext = self.afm.truth.last_record_extension_nm
            self.log.append((np.array(rec.command_nm), np.array(rec.height_nm), np.array(ext)))
            return rec

        return kept

    def true_extension(self, u: np.ndarray, z: np.ndarray, k: int) -> np.ndarray:
        """The true extension of the logged samples whose commands on axis ``k`` are ``u``
        and whose heights are ``z`` (the record, wherever it was sent in parts)."""
        cmd = np.concatenate([c[:, k] for c, _, _ in self.log])
        height = np.concatenate([h for _, h, _ in self.log])
        pos = np.concatenate([p[:, k] for _, _, p in self.log])
        n = u.size
        for i in np.flatnonzero(cmd[: cmd.size - n + 1] == u[0]):
            if np.array_equal(cmd[i : i + n], u) and np.array_equal(height[i : i + n], z):
                return pos[i : i + n]
        raise LookupError("the identification record is not in the log")


def true_loop(ident: AxisIdentification, y: np.ndarray, degree: int = 11) -> SymmetricLoop:
    """The point-symmetric loop (eq 23's form) fitted by least squares to the TRUE steady
    branches of part A."""
    wf, u = ident.waveform, ident.u_nm
    lo, hi = wf.u_min_nm, wf.u_max_nm
    us, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
    rows, rhs = [], []
    for c in range(1, wf.n_steady):
        for sl, sign in ((wf.ascending(c), 1.0), (wf.descending(c), -1.0)):
            s = (u[sl] - us) / h
            v = np.vander(sign * s, degree + 1, increasing=True)
            rows.append(np.column_stack([np.ones(s.size), sign * h * v]))
            rhs.append(y[sl])
    coef, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    return SymmetricLoop(coef[1:], lo, hi, us, coef[0])


def from_true_loop(ident: AxisIdentification, y: np.ndarray, cfg: Any) -> ScannerModel:
    """The estimation stage, as the pipeline runs it (drift rounds included), on the loop
    stage's output made from the truth."""
    tl = true_loop(ident, y)
    wf, u, z = ident.waveform, ident.u_nm, ident.height_nm
    heights = np.array([z[wf.ascending(c)] for c in range(1, wf.n_steady)])
    loop = replace(ident.loop, loop=tl,
                   profile=HeightProfile.from_loop(tl, u[wf.ascending(1)], heights))  # fmt: skip
    problem = EstimationProblem.from_records(ident.records, loop, cfg.estimation, cfg.rounds)
    est = problem.estimate()
    drift = drift_rounds(problem, est)
    shift0 = None
    if drift.kept and drift.estimation is not None:
        est, shift0 = drift.estimation, drift.shifts[0]
    if est.batch_profile is loop.profile:  # in the true loop's frame: the truth's
        return est.batch_model
    # h re-indexed by the model: the model lives in its own frame; put it on the true loop's
    # span, as the pipeline puts it on its own loop's without calibration cycles
    fwd = wf.forward_traces
    y_fwd = predicted_forward_trace(est.batch_model, u, ident.sample_period_s, fwd,
                                    problem.creep_start_nm, shift0)  # fmt: skip
    return mapped(est.batch_model, *span_frame(tl, u[fwd[0]], y_fwd))


def identified(
    preset: str, seed: int, axis: str, settings: IdentificationSettings
) -> tuple[VirtualAFM, TruthRecorder, Any, AxisIdentification]:
    """The default identification of ``reproduce`` (recorded again on the lines of
    :func:`~piezocomp.experiments.methods.retry_lines` when a record fails, as ``reproduce``
    does), with the virtual AFM it ran on, its truth log and the configuration of its line."""
    config = load_config(preset).with_seed(seed)
    range_nm = float(config.scanner.range_nm)
    why = ""
    for _, cfg in retry_lines(settings.config(range_nm), axis):
        afm = VirtualAFM(config, seed=seed)
        rec = TruthRecorder(afm)
        try:
            ident = identify_virtual(rec, cfg, axis)  # type: ignore[arg-type]
        except (ValueError, RuntimeError) as exc:
            why = str(exc)
            continue
        if not (failed := ident.validation_failures()):
            return afm, rec, cfg, ident
        why = "; ".join(failed)
    raise RuntimeError(f"seed {seed}, axis {axis}: no usable model on any line (last: {why})")


def candidates_alone(
    ident: AxisIdentification, cfg: Any, skip: tuple[int, int] | None = None
) -> dict[tuple[int, int], AxisIdentification]:
    """Each candidate order of ``cfg`` (but ``skip``) run alone through the whole estimation
    on ``ident``'s records, by its orders; one that fails alone, or fails its own
    validation, is not a choice and is left out."""
    out = {}
    for o in cfg.estimation.orders:
        o = (int(o[0]), int(o[1]))
        if o == skip:
            continue
        alone = replace(cfg, estimation=replace(cfg.estimation, orders=(o,)))
        try:
            run = estimate_axis(ident.records, alone, reference=ident.reference_record)
        except (ValueError, RuntimeError):
            continue
        if not run.validation_failures():
            out[o] = run
    return out


def one_axis(preset: str, twin: str | None, seed: int, axis: str) -> dict[str, float]:
    """Every row's validation max error (nm) of one seed and axis."""
    settings = IdentificationSettings()
    config = load_config(preset).with_seed(seed)
    afm, rec, cfg, ident = identified(preset, seed, axis, settings)
    y = rec.true_extension(ident.u_nm, ident.height_nm, 0 if axis == "x" else 1)
    orders = (ident.orders.n_play, ident.orders.n_creep)
    models = {"identified": ident.batch_model, "identified_rls": ident.rls_model,
              "true_loop": from_true_loop(ident, y, cfg)}  # fmt: skip
    for key, coupling, extra in (("fit_record_paper", 0.0, False),
                                 ("fit_record_extended", "fit", False),
                                 ("fit_oracle", settings.oracle_coupling, True)):  # fmt: skip
        models[key] = fit_on_truth(VirtualAFM(config, seed=seed), cfg, axis,
                                   orders if not extra else settings.oracle_orders,
                                   creep_coupling=coupling, extra_record=extra)  # fmt: skip
    # the orders row: every other candidate alone, through the whole chain, on the same
    # records; the identified model stands for its own orders (the batch model's, which a
    # restart of the batch chain may have changed from the selection's)
    own = (ident.batch_model.n_play, ident.batch_model.n_creep)
    for o, run in candidates_alone(ident, cfg, skip=own).items():
        models[f"orders_{o[0]}_{o[1]}"] = run.batch_model
    acq = cfg.acquisition
    where = {"span_nm": acq.span_nm, "center_nm": acq.center_nm[0 if axis == "x" else 1]}
    score = score_on_truth(afm, ident, models, **where)
    out = {k: float(score[k]["validation_max_error_nm"]) for k in models}
    candidates = {"identified": out["identified"]}  # first: a tie is no other choice
    candidates.update({k: v for k, v in out.items() if k.startswith("orders_")})
    best = min(candidates, key=lambda k: candidates[k])
    out["identified_truth_orders"] = candidates[best]
    out["truth_orders_differ"] = float(best != "identified")
    out["identified_true_scale"] = float(score["identified"]["validation_max_error_after_scale_nm"])
    # how far the grating's scale was off: the truth's slope against the prediction, less 1
    out["scale_error_percent"] = 100.0 * (float(score["identified"]["scale"]) - 1.0)
    if twin is not None:
        tafm, _, tcfg, tident = identified(twin, seed, axis, settings)
        tacq = tcfg.acquisition  # its own line (another one if its first record failed)
        s = score_on_truth(tafm, tident, {"m": tident.batch_model}, span_nm=tacq.span_nm,
                           center_nm=tacq.center_nm[0 if axis == "x" else 1])  # fmt: skip
        out["identified_no_drift"] = float(s["m"]["validation_max_error_nm"])
    return out


def budget_rows(per_seed: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Each row's median and worst over the seeds (each seed's worse axis); the grating's scale
    error over every axis; how many axes the truth chose other orders on, of how many."""
    if not per_seed:
        return {}
    scales = [abs(v["scale_error_percent"]) for s in per_seed for v in s["axes"].values()]
    rows: dict[str, list[float]] = {"scale_error_percent": [float(np.median(scales)),
                                                            float(max(scales))]}  # fmt: skip
    differ = sum(int(v["truth_orders_differ"]) for s in per_seed for v in s["axes"].values())
    n_axes = sum(len(s["axes"]) for s in per_seed)
    rows["truth_orders_differ"] = [float(differ), float(n_axes)]
    for key, _ in ROWS:
        values = [s["worse_axis"][key] for s in per_seed if key in s["worse_axis"]]
        if values:
            rows[key] = [float(np.median(values)), float(max(values))]
    return rows


def write_json(
    path: Path, per_seed: list[dict[str, Any]], failed: list[dict[str, Any]], preset: str
) -> None:
    """Every seed's figures, the seeds that failed and the rows so far, with the command,
    atomically."""
    out = {"command": "python benchmarks/error_budget.py " + " ".join(sys.argv[1:]),
           "preset": preset, "seeds": per_seed, "failed": failed,
           "rows": budget_rows(per_seed)}  # fmt: skip
    atomic_write_text(path, json.dumps(out, indent=1) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5")
    ap.add_argument(
        "--no-drift-twin",
        default="cpr5-nodrift",
        help="the preset's drift-free twin ('none': leave that row out)",
    )
    ap.add_argument("--seeds", required=True, help="e.g. 1-10")
    ap.add_argument("--axes", default="xy", choices=("x", "y", "xy"))
    ap.add_argument("--json", type=Path, help="also write every figure, with the command, here")
    a = ap.parse_args()
    twin = None if a.no_drift_twin == "none" else a.no_drift_twin
    per_seed: list[dict[str, Any]] = []
    failed: list[dict[str, Any]] = []
    for seed in parse_seeds(a.seeds):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                axes = {ax: one_axis(a.preset, twin, seed, ax) for ax in a.axes}
            except RuntimeError as exc:  # no usable model on any line: said, not scored
                print(f"seed {seed}: failed ({exc})", flush=True)
                failed.append({"seed": seed, "error": str(exc)})
                continue
        worse = {k: max(v[k] for v in axes.values()) for k in next(iter(axes.values()))
                 if k not in ("scale_error_percent", "truth_orders_differ")
                 and not k.startswith("orders_")}  # fmt: skip
        per_seed.append({"seed": seed, "axes": axes, "worse_axis": worse})
        cells = "  ".join(f"{k} {v:.2f}" for k, v in worse.items())
        print(f"seed {seed} ({time.perf_counter() - t0:.0f} s): {cells}", flush=True)
        if a.json is not None:  # kept after every seed: a long run that stops keeps its seeds
            write_json(a.json, per_seed, failed, a.preset)
    rows = budget_rows(per_seed)
    if not rows:
        print("no seed gave a usable model")
        return 1
    for key, label in ROWS:
        if key in rows:
            print(f"{label:58s} {rows[key][0]:.2f} / {rows[key][1]:.2f} nm")
    print(f"{'the grating scale off by (every axis, |%|)':58s} {rows['scale_error_percent'][0]:.3f}"
          f" / {rows['scale_error_percent'][1]:.3f} %")  # fmt: skip
    differ, n_axes = rows["truth_orders_differ"]
    label = "the truth chose other orders than the heights on"
    print(f"{label:58s} {differ:.0f} of {n_axes:.0f} axes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
