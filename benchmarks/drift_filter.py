"""The drift session of ``both`` under other drift-filter settings and other models: what
limits it.

For each seed, the default model (the one a ``piezocomp reproduce --seeds`` run saved,
``--runs DIR``; without it, identified here as ``reproduce`` identifies it) is put inside the
drift compensator on a fresh virtual AFM of that sample, and the session of ``reproduce``
(two areas 951 nm apart visited in turn, each visit imaged) runs for ``--minutes`` with the
drift settings given here; it prints the worst and the last image's true error, the share
of the time spent measuring drift and the number of measurements, then the median and worst
over the seeds. With ``--runs``, the defaults and ``--minutes 5`` it gives the ``both``
session of ``reproduce --quick`` again, to the digit.

What it varies: the filter's measurement noise (``--measurement-nm``, the prior of
``DriftNoise``: 0.5 nm by default), the tolerances that decide when to measure, whether the
drift's noise is learnt from the session's measurements, the final move each landmark
window is entered by (``--approach-nm``), and the method (``--method drift_only``: the
scanner driven without compensation). ``--variants`` runs several sessions of each seed in
turn (DIAGNOSIS, ground truth): ``identified`` (the default model), ``oracle`` (the model
family fitted to the true extension in its place), ``ideal`` (the sample's scanner with its
creep and hysteresis switched off, the drift compensator straight on it: what drift
tracking alone leaves) and ``approach=NM``. For every session it also finds, from the
truth, how far each sighting's drift is from the sample's true drift since tracking
started: the spread of that error between the sightings of one landmark about their mean
(what the filter cannot tell from drift; ``--sighting-errors`` prints it by seed), pooled
over the landmarks and both axes. ``--json PATH`` writes every figure. About a minute a
seed for a 20-minute session on two cores (and 90 s a seed to identify without ``--runs``)::

    piezocomp reproduce --quick --seeds 1-10 --out runs
    python benchmarks/drift_filter.py --runs runs --seeds 1-10 --minutes 20
    python benchmarks/drift_filter.py --runs runs --seeds 1-10 --minutes 20 --measurement-nm 1.5
    python benchmarks/drift_filter.py --seeds 1-10 --variants identified approach=400 oracle ideal
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp.drift.compensated import DriftCompensatedInstrument, TrackingLost
from piezocomp.drift.filter import DriftSettings
from piezocomp.experiments import drift_session as D
from piezocomp.experiments.methods import IdentificationSettings, MethodModels, identification_job
from piezocomp.experiments.reproduce import table1_area
from piezocomp.experiments.samples import parse_seeds
from piezocomp.experiments.virtual_identification import fit_on_truth
from piezocomp.io import atomic_write_text, load_model
from piezocomp.model import ScannerModel2D
from piezocomp.virtual_afm import AFMConfig, VirtualAFM, load_config


def settings(a: argparse.Namespace) -> DriftSettings:
    """The drift settings asked for, on the defaults (``drift_only``: those of a scanner driven
    without compensation, :meth:`DriftSettings.uncompensated`)."""
    s = DriftSettings.uncompensated() if a.method == "drift_only" else DriftSettings()
    noise = (
        s.noise if a.measurement_nm is None else replace(s.noise, measurement_nm=a.measurement_nm)
    )
    changes = {"noise": noise}
    if a.tolerance_nm is not None:
        changes["tolerance_nm"] = a.tolerance_nm
    if a.image_tolerance_nm is not None:
        changes["image_tolerance_nm"] = a.image_tolerance_nm
    if a.no_learning:
        changes["learn_noise_after"] = 0
    if a.learn_measurement is not None:
        changes["learn_measurement_noise"] = a.learn_measurement == "on"
    if a.approach_nm is not None:
        changes["landmarks"] = replace(s.landmarks, approach_nm=a.approach_nm)
    return replace(s, **changes)


class DriftLog:
    """The virtual AFM, forwarded; for DIAGNOSIS, the sample's true drift at every sample of
    every record it returns (never shown to the code under test)."""

    def __init__(self, afm: VirtualAFM) -> None:
        self.afm = afm
        self.times: list[np.ndarray] = []
        self.drifts: list[np.ndarray] = []

    def __getattr__(self, name: str) -> object:
        attr = getattr(self.afm, name)
        if not callable(attr):
            return attr

        def logged(*args: object, **kwargs: object) -> object:
            out = attr(*args, **kwargs)
            t = getattr(out, "t_s", None)
            d = self.afm.truth.last_record_drift_nm
            if t is not None and len(d) == np.size(t):
                self.times.append(np.asarray(t, dtype=float))
                self.drifts.append(np.asarray(d, dtype=float))
            return out

        return logged

    def drift_over(self, image: object) -> np.ndarray | None:
        """The mean true drift over an image's pixel times (``None`` if not logged)."""
        t = np.concatenate(self.times)
        d = np.concatenate(self.drifts)
        order = np.argsort(t)
        t, d = t[order], d[order]
        fwd, bwd = image.pixel_times_s()  # type: ignore[attr-defined]
        px = np.concatenate([np.ravel(fwd), np.ravel(bwd)])
        if px.min() < t[0] or px.max() > t[-1]:
            return None
        return np.array([np.interp(px, t, d[:, k]).mean() for k in range(2)])


def sighting_errors(inst: DriftCompensatedInstrument, log: DriftLog) -> tuple[float, float]:
    """The spread of each landmark's sighting errors about their mean and their RMS (nm,
    pooled over landmarks and axes): sighting's drift minus the true drift since the
    landmark's template (the template's own drift estimate added back)."""
    by_landmark: dict[tuple[int, int], list[np.ndarray]] = {}
    epoch: dict[int, int] = {}
    for m in inst.measurements:
        if m.area:  # an image of the work, not a landmark
            continue
        for i, sg in enumerate(m.sightings):
            true_now = log.drift_over(sg.image)
            if sg.drift_nm is not None and true_now is not None and not sg.reason:
                by_landmark.setdefault((i, epoch.get(i, 0)), []).append(
                    np.asarray(sg.drift_nm) - true_now
                )
        for i in m.replaced:
            epoch[i] = epoch.get(i, 0) + 1
    # the drift at the reference (tracking start) is a constant of every error: the spread
    # about each landmark's mean does not depend on it
    dev = [e - np.mean(es, axis=0) for es in by_landmark.values() if len(es) > 1 for e in es]
    allv = [e - np.mean([x for es in by_landmark.values() for x in es], axis=0)
            for es in by_landmark.values() for e in es]  # fmt: skip
    spread = float(np.sqrt(np.mean(np.square(dev)))) if dev else float("nan")
    rms = float(np.sqrt(np.mean(np.square(allv)))) if allv else float("nan")
    return spread, rms


def seed_models(
    run: Path | None, preset: str, seed: int
) -> tuple[ScannerModel2D, AFMConfig, float]:
    """The default model of one seed, its sample's configuration and the session's area
    half-width: as ``run`` (a ``reproduce --seeds`` folder) saved them, or, without one,
    identified here as ``reproduce`` does (both axes, its identification settings; the area
    inside that model's working area, :func:`~piezocomp.experiments.reproduce.table1_area`)."""
    if run is not None:
        folder = run / f"seed-{seed}"
        res = json.loads((folder / "results.json").read_text(encoding="utf-8"))
        config = load_config(res["preset"]).with_seed(seed)
        model = load_model(folder / "model.json")
        return model, config, min(650.0, res["table1_settings"]["area_half_width_nm"])
    config = load_config(preset).with_seed(seed)
    jobs = [identification_job("sensorless", ax, config, seed, IdentificationSettings())
            for ax in "xy"]  # fmt: skip
    T = VirtualAFM(config, seed=seed).sample_period_s
    models = MethodModels.from_jobs(jobs, T)
    if "compensated" not in models.models:
        raise SystemExit(f"seed {seed}: the identification failed ({jobs[0]['summary']})")
    only = MethodModels({"compensated": models.models["compensated"]}, T)
    return models.models["compensated"], config, min(650.0, table1_area(only, T))


def oracle_model(config: AFMConfig, seed: int) -> ScannerModel2D:
    """Both axes' model family fitted to the TRUE extension as ``reproduce``'s ``oracle``
    (DIAGNOSIS: ground truth)."""
    ident = IdentificationSettings()
    per = {}
    for axis in "xy":
        afm = VirtualAFM(config, seed=seed)
        per[axis] = fit_on_truth(afm, ident.config(afm.range_nm), axis, ident.oracle_orders,
                                 creep_coupling=ident.oracle_coupling)  # fmt: skip
    return ScannerModel2D(per["x"], per["y"])


def one(
    model: ScannerModel2D,
    config: AFMConfig,
    area_nm: float,
    seed: int,
    minutes: float,
    drift: DriftSettings,
    *,
    method: str = "both",
    ideal: bool = False,
    areas: bool = False,
) -> tuple[D.DriftSessionResult, tuple[float, float, float]]:
    """The session of ``method`` on a fresh virtual AFM of ``config`` with ``model``, its
    sighting errors (:func:`sighting_errors`) and the measurement noise it ended with;
    ``ideal``: the drift compensator straight on the sample's scanner with its creep and
    hysteresis switched off (DIAGNOSIS: what drift alone leaves); ``areas``: the session's
    images of its areas are drift sightings too (``DriftSessionSettings.area_sightings``)."""
    st = D.DriftSessionSettings(minutes=minutes, area_nm=area_nm, area_sightings=areas)
    if ideal:
        off = {"hysteresis": 0.0, "hysteresis_small": 0.0, "creep": 0.0}
        config = replace(config, scanner=replace(config.scanner, **off))
    afm = VirtualAFM(config, seed=seed)
    log = DriftLog(afm)
    if ideal:
        inst, origin = DriftCompensatedInstrument(log, drift), (0.0, 0.0)  # type: ignore[arg-type]
        inst.start(center_nm=origin, size_nm=st.landmark_overview_nm)
    else:
        inst, origin = D.session_instrument(method, log, MethodModels({"compensated": model}),
                                            st, drift)  # type: ignore[arg-type]  # fmt: skip
    result = D.run(inst, st, origin_nm=origin, truth=afm.truth)
    assert isinstance(inst, DriftCompensatedInstrument)
    return result, (*sighting_errors(inst, log), inst.measurement_sigma_nm)


VARIANTS = ("identified", "oracle", "ideal", "areas")
"""``--variants``: the default model (saved or identified), the truth-fitted one, the
scanner without creep and hysteresis, the default model with the session's images of its
areas as drift sightings too; ``approach=NM``: the default model with
``LandmarkSettings.approach_nm = NM``; ``tolerance=NM``: with ``DriftSettings.tolerance_nm =
NM`` and the image tolerance in the defaults' ratio to it (the trade of time for accuracy);
``fixed-order``: the drift's order kept as the prior's (``DriftSettings.learn_order`` off);
``joint-fit``: the drift's noise fitted with a measurement noise of its own
(``DriftSettings.learn_given_sigma`` off).
Joined by ``+`` they combine (``areas+tolerance=0.75``)."""


def variant_drift(name: str, drift: DriftSettings) -> DriftSettings:
    """The drift settings of variant ``name`` (its parts joined by ``+``) on ``drift``."""
    for part in name.split("+"):
        if part.startswith("approach="):
            nm = float(part.split("=", 1)[1])
            drift = replace(drift, landmarks=replace(drift.landmarks, approach_nm=nm))
        elif part.startswith("tolerance="):  # both tolerances, in the defaults' ratio
            nm = float(part.split("=", 1)[1])
            ratio = drift.image_tolerance_nm / drift.tolerance_nm
            drift = replace(drift, tolerance_nm=nm, image_tolerance_nm=ratio * nm)
        elif part == "fixed-order":  # the drift's order kept as the prior's
            drift = replace(drift, learn_order=False)
        elif part == "joint-fit":  # the drift's noise fitted with a measurement noise
            drift = replace(drift, learn_given_sigma=False)
        elif part not in VARIANTS:
            raise SystemExit(
                f"--variants: {part!r} is not one of {VARIANTS}, approach=NM, tolerance=NM, "
                "fixed-order or joint-fit."
            )
    return drift


def stats(values: list[float]) -> list[float] | None:
    """Median and worst, or ``None`` with no value."""
    return [float(np.median(values)), float(max(values))] if values else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--runs", type=Path, help="a reproduce --seeds folder (without: each seed identified here)"
    )
    ap.add_argument("--preset", default="cpr5", help="without --runs: the sample preset")
    ap.add_argument("--seeds", required=True, help="e.g. 1-10")
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--measurement-nm", type=float, help="DriftNoise.measurement_nm")
    ap.add_argument("--tolerance-nm", type=float, help="DriftSettings.tolerance_nm")
    ap.add_argument("--image-tolerance-nm", type=float, help="DriftSettings.image_tolerance_nm")
    ap.add_argument("--no-learning", action="store_true", help="keep the drift noise's prior")
    ap.add_argument("--learn-measurement", choices=("on", "off"),
                    help="DriftSettings.learn_measurement_noise")  # fmt: skip
    ap.add_argument("--approach-nm", type=float, help="LandmarkSettings.approach_nm")
    ap.add_argument(
        "--method",
        choices=("both", "drift_only"),
        default="both",
        help="the session's method (drift_only: the uncompensated scanner)",
    )
    ap.add_argument(
        "--variants",
        nargs="+",
        default=["identified"],
        help="identified, oracle, ideal, approach=NM, tolerance=NM (see VARIANTS)",
    )
    ap.add_argument(
        "--sighting-errors",
        action="store_true",
        help="also print each seed's sighting errors against the true drift",
    )
    ap.add_argument("--json", type=Path, help="also write every figure, with the command, here")
    a = ap.parse_args()
    base = settings(a)
    for name in a.variants:
        variant_drift(name, base)  # every name checked before anything runs
    seeds = parse_seeds(a.seeds)
    per_seed = {seed: seed_models(a.runs, a.preset, seed) for seed in seeds}
    out: dict[str, Any] = {"command": "python benchmarks/drift_filter.py " + " ".join(sys.argv[1:]),
                           "variants": {}}  # fmt: skip
    for name in a.variants:
        drift = variant_drift(name, base)
        worst, measuring, spreads, sigmas, rows = [], [], [], [], []
        print(f"== {name}", flush=True)
        for seed in seeds:
            model, config, area = per_seed[seed]
            parts = name.split("+")
            if "oracle" in parts:
                model = oracle_model(config, seed)
            try:
                r, (spread, rms, sigma) = one(model, config, area, seed, a.minutes, drift,
                                       method=a.method, ideal="ideal" in parts,
                                       areas="areas" in parts)  # fmt: skip
            except TrackingLost as exc:  # tracking could not start: a result, said
                print(f"seed {seed}: no image (tracking could not start: {exc})", flush=True)
                rows.append({"seed": seed, "stopped": str(exc)})
                continue
            row: dict[str, Any] = {"seed": seed, "sighting_spread_nm": spread,
                                   "measurement_sigma_nm": sigma}  # fmt: skip
            sigmas.append(sigma)
            if a.sighting_errors:
                print(f"seed {seed}: sightings off the true drift by {spread:.2f} nm about each "
                      f"landmark's mean, {rms:.2f} nm RMS", flush=True)  # fmt: skip
            if np.isfinite(spread):
                spreads.append(spread)
            if r.true_errors_nm is None or not r.true_errors_nm.size:
                print(f"seed {seed}: no image ({r.stopped or 'tracking stopped'})", flush=True)
                rows.append({**row, "stopped": r.stopped or "tracking stopped"})
                continue
            worst.append(r.true_max_error_nm)
            measuring.append(r.overhead_fraction)
            rows.append({**row, "worst_image_nm": r.true_max_error_nm,
                         "measuring": r.overhead_fraction})  # fmt: skip
            print(f"seed {seed}: worst {r.true_max_error_nm:.2f} nm, last "
                  f"{r.true_final_error_nm:.2f} nm, {100 * r.overhead_fraction:.0f} % measuring, "
                  f"{r.measurements} measurements, {r.true_errors_nm.size} images",
                  flush=True)  # fmt: skip
        if worst:
            print(f"over {len(worst)} seeds: worst image {np.median(worst):.2f} / "
                  f"{max(worst):.2f} nm (median / worst), measuring "
                  f"{100 * np.median(measuring):.0f} % / {100 * max(measuring):.0f} %")  # fmt: skip
        if spreads:
            print(f"sightings' spread about each landmark's mean: {np.median(spreads):.2f} / "
                  f"{max(spreads):.2f} nm (median / worst)")  # fmt: skip
        out["variants"][name] = {
            "seeds": rows, "worst_image_nm": stats(worst), "measuring": stats(measuring),
            "sighting_spread_nm": stats(spreads), "measurement_sigma_nm": stats(sigmas),
            "images_from": len(worst),
        }  # fmt: skip
    if a.json is not None:
        atomic_write_text(a.json, json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
