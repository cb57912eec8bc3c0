"""``piezocomp reproduce``: the paper's experiments end to end on a virtual AFM.

1. Models: both axes identified without a sensor (the batch model and the RLS estimate),
   once more without creep operators, and fitted to the true extension (the oracle), each
   axis on a fresh virtual AFM of the configuration (:mod:`~piezocomp.experiments.methods`).
2. Trials: Table I, Fig. 9 (both at every speed), Fig. 8 and Fig. 10, for every method, each
   on a fresh virtual AFM of the same configuration and sample seed, through the instrument
   interface only; errors measured as the paper did and, from the ground truth, true.
3. The results gathered into one JSON-ready dictionary (:func:`aggregate`).

Trials run in parallel processes through joblib, or on a Dask cluster through its joblib
backend; a trial that fails is reported with its error, never dropped silently.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from joblib import delayed

from piezocomp.experiments import drift_session, fig8, fig9, fig10, table1
from piezocomp.experiments.methods import (
    DESCRIPTIONS,
    JOBS,
    METHODS,
    IdentificationSettings,
    MethodModels,
    drift_tracked,
    identification_failures,
    identification_job,
    instrument_for,
    working_half_width,
)
from piezocomp.experiments.parallel import backend, run_parallel
from piezocomp.virtual_afm import AFMConfig, VirtualAFM

__all__ = [
    "PAPER_SPEED_NM_PER_S",
    "ReproduceSettings",
    "Reproduction",
    "Trial",
    "aggregate",
    "plan_trials",
    "reproduce",
    "run_trial",
]

PAPER_SPEED_NM_PER_S = 1000.0
"""The paper manipulates at about 1 um/s (Sec. I)."""

TABLE1_MARGIN_NM = 10.0
"""Table I keeps this far inside the smallest working area of the methods."""


@dataclass(frozen=True)
class ReproduceSettings:
    """What ``piezocomp reproduce`` runs.

    Parameters
    ----------
    config : AFMConfig
        The virtual AFM.
    source : str
        Its name (a preset or a file), for the report.
    seed : int
        Sample seed of every trial's virtual AFM (Fig. 10 places its own particles).
    speeds_nm_per_s : tuple of float
        Speeds of Table I and Fig. 9 (the paper's, 1 um/s, is reported first).
    distances_nm : tuple of float
        Table I's distances.
    table1_experiments : int
        Experiments per distance and speed: 20 (the paper averaged 5, whose spread was under
        1 nm; here one experiment's uncompensated error spreads over 3-4 nm, and the mean of
        5 scatters by about 2 nm).
    table1_speeds_nm_per_s : tuple of float or None
        Speeds Table I runs at (``None``: all of ``speeds_nm_per_s``).
    fig10_trials : int
        Assemblies per method.
    methods : tuple of str
    identification : IdentificationSettings
    workers : int or None
        Parallel processes (``None``: one per processor).
    dask_address : str or None
        Run the trials on this Dask scheduler (``tcp://host:port``) instead.
    drift_minutes : float or None
        Length of the drift session (:mod:`~piezocomp.experiments.drift_session`) run with
        and without each compensator; ``None``: 20 minutes (5 in the quick run) when the
        scanner drifts, none otherwise; 0: none.
    quick : bool
        Recorded in the results (the reduced run of :meth:`quick_run`).
    """

    config: AFMConfig
    source: str = "cpr5"
    seed: int = 1
    speeds_nm_per_s: tuple[float, ...] = (250.0, 500.0, 1000.0, 2000.0)
    distances_nm: tuple[float, ...] = (645.0, 951.0, 1150.0)
    table1_experiments: int = 20
    table1_speeds_nm_per_s: tuple[float, ...] | None = None
    fig10_trials: int = 10
    methods: tuple[str, ...] = METHODS
    identification: IdentificationSettings = field(default_factory=IdentificationSettings)
    workers: int | None = None
    dask_address: str | None = None
    drift_minutes: float | None = None
    quick: bool = False

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise ValueError(f"methods must be among {METHODS}. Got {unknown}.")
        for name in ("seed", "table1_experiments", "fig10_trials"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0. Got {v!r}.")
        if self.workers is not None and (isinstance(self.workers, bool) or self.workers < 1):
            raise ValueError(f"workers must be an integer >= 1. Got {self.workers!r}.")
        if self.drift_minutes is not None and not (
            math.isfinite(self.drift_minutes) and 0 <= self.drift_minutes <= 600
        ):
            raise ValueError(f"drift_minutes must be in [0, 600]. Got {self.drift_minutes!r}.")
        if PAPER_SPEED_NM_PER_S not in self.speeds_nm_per_s:
            raise ValueError(f"speeds_nm_per_s must include the paper's {PAPER_SPEED_NM_PER_S:g}.")

    def quick_run(self) -> ReproduceSettings:
        """The reduced run: Table I at the paper's speed only with the paper's 5 experiments
        per distance, two assemblies per method; Fig. 8 and Fig. 9 as in the full run."""
        return replace(
            self,
            table1_experiments=5,
            table1_speeds_nm_per_s=(PAPER_SPEED_NM_PER_S,),
            fig10_trials=2,
            quick=True,
        )

    @property
    def session_minutes(self) -> float:
        """Minutes of the drift session (0: none)."""
        if self.drift_minutes is not None:
            return float(self.drift_minutes)
        if not self.config.drifts:
            return 0.0
        return 5.0 if self.quick else 20.0

    @property
    def ordered_speeds(self) -> tuple[float, ...]:
        """The speeds, the paper's first."""
        rest = sorted(v for v in self.speeds_nm_per_s if v != PAPER_SPEED_NM_PER_S)
        return (PAPER_SPEED_NM_PER_S, *rest)


@dataclass(frozen=True)
class Trial:
    """One experiment of one method on a fresh virtual AFM."""

    experiment: str
    method: str
    settings: Any
    keep: bool = False


@dataclass(frozen=True)
class Reproduction:
    """Everything a run produced: the JSON-ready results and what the figures need."""

    results: dict[str, Any]
    outcomes: list[tuple[Trial, Any]] = field(repr=False)
    models: MethodModels = field(repr=False)


def plan_trials(settings: ReproduceSettings, area_half_nm: float) -> list[Trial]:
    """Every trial of the run: Table I fits in ``+-area_half_nm`` of each method's origin."""
    s = settings
    trials: list[Trial] = []
    t1_speeds = s.ordered_speeds if s.table1_speeds_nm_per_s is None else s.table1_speeds_nm_per_s
    for m in s.methods:
        for v in t1_speeds:
            for d in s.distances_nm:
                for k in range(s.table1_experiments):
                    keep = v == PAPER_SPEED_NM_PER_S and k == 0 and d == s.distances_nm[0]
                    st = table1.Table1Settings(
                        d_nm=d, speed_nm_per_s=v, experiment=k, area_nm=area_half_nm,
                        keep_images=keep,
                    )  # fmt: skip
                    trials.append(Trial("table1", m, st, keep))
        for v in s.ordered_speeds:
            keep = v == PAPER_SPEED_NM_PER_S
            trials.append(
                Trial("fig9", m, fig9.Fig9Settings(speed_nm_per_s=v, keep_images=keep), keep)
            )
        trials.append(
            Trial("fig8", m, fig8.Fig8Settings(speed_nm_per_s=PAPER_SPEED_NM_PER_S), True)
        )
        for k in range(s.fig10_trials):
            trials.append(Trial("fig10", m, (fig10.Fig10Settings(), k), k == 0))
    if s.config.drifts and "compensated" in s.methods:  # inside the drift compensator too
        v = PAPER_SPEED_NM_PER_S
        for d in s.distances_nm:
            for k in range(s.table1_experiments):
                st = table1.Table1Settings(d_nm=d, speed_nm_per_s=v, experiment=k,
                                           area_nm=area_half_nm)  # fmt: skip
                trials.append(Trial("table1", DRIFT_METHOD, st))
        trials.append(Trial("fig9", DRIFT_METHOD, fig9.Fig9Settings(speed_nm_per_s=v)))
        for k in range(s.fig10_trials):
            trials.append(Trial("fig10", DRIFT_METHOD, (fig10.Fig10Settings(), k), k == 0))
    if s.session_minutes > 0 and "compensated" in s.methods:
        ds = drift_session.DriftSessionSettings(minutes=s.session_minutes,
                                                area_nm=min(650.0, area_half_nm))  # fmt: skip
        trials += [Trial("drift_session", m, ds, True) for m in drift_session.METHODS]
    return trials


DRIFT_METHOD = "both"
"""The method name of Table I, Fig. 9 and Fig. 10 run inside the drift compensator (around
``compensated``) on a drifting scanner, as the drift session names it."""


_RUNNERS: dict[str, Callable[..., Any]] = {
    "table1": table1.run,
    "fig9": fig9.run,
    "fig8": fig8.run,
}


def run_trial(
    trial: Trial, config: AFMConfig, seed: int, models: MethodModels
) -> tuple[Trial, Any]:
    """Run one trial; its result, or the text of the error that stopped it."""
    try:
        if trial.experiment == "fig10":
            st, k = trial.settings
            sample = fig10.sample_particles(st, k)
            if config.drifts:  # the same sample for every method: with landmarks outside
                sample = np.vstack([sample, fig10.landmark_particles(st)])
            afm = VirtualAFM(config, seed=seed, particles=sample)
            drift = trial.method == DRIFT_METHOD
            inst, origin = instrument_for("compensated" if drift else trial.method, afm, models)
            if drift:
                inst = fig10.with_drift_compensation(inst, st, origin)
            out: Any = fig10.run(inst, st, origin_nm=origin, truth=afm.truth)
            out = replace(out, true_push_counts=asdict(afm.truth.push_state.counts))
            if not trial.keep:  # the images are heavy: kept for the report's figure only
                out = replace(out, assembly=replace(out.assembly, images=()))
            return trial, out
        afm = VirtualAFM(config, seed=seed)
        if trial.experiment == "drift_session":  # drift only's limits are results
            return trial, drift_session.run_method(trial.method, afm, models, trial.settings)
        if trial.method == DRIFT_METHOD:  # Table I or Fig. 9 inside the drift compensator
            inner, origin = instrument_for("compensated", afm, models)
            st = trial.settings
            size = (
                2.0 * st.area_nm if trial.experiment == "table1"
                else 2.0 * float(np.max(np.abs(fig9.PATH_NM))) + st.size_nm
            )  # fmt: skip
            inst = drift_tracked(inner, origin, size)
            return trial, _RUNNERS[trial.experiment](inst, st, origin_nm=origin, truth=afm.truth)
        inst, origin = instrument_for(trial.method, afm, models)
        return trial, _RUNNERS[trial.experiment](inst, trial.settings, origin_nm=origin,
                                                  truth=afm.truth)  # fmt: skip
    except (ValueError, RuntimeError) as exc:
        return trial, f"{type(exc).__name__}: {exc}"


def reproduce(
    settings: ReproduceSettings, *, progress: bool = True, models: MethodModels | None = None
) -> Reproduction:
    """Identify, run every trial and gather the results (see the module notes).

    ``models`` skips the identification and uses these (tests, or a second run of the
    trials with the same models)."""
    s = settings
    t0 = time.perf_counter()
    T = VirtualAFM(s.config, seed=s.seed).sample_period_s
    with backend(s.dask_address):
        jobs: list[dict[str, Any]] = []
        if models is None:
            jobs = run_parallel(
                s.workers,
                [
                    delayed(identification_job)(kind, axis, s.config, s.seed, s.identification)
                    for kind in sorted({JOBS[m] for m in s.methods if m in JOBS})
                    for axis in ("x", "y")
                ],
                "identification",
                progress,
            )
            models = MethodModels.from_jobs(jobs, T)
        t_ident = time.perf_counter() - t0
        area = min(
            table1.Table1Settings().area_nm, working_half_width(models, T) - TABLE1_MARGIN_NM
        )
        failed = identification_failures(s.methods, jobs)  # never run with a doubtful model
        usable = tuple(m for m in s.methods if m not in failed)
        trials = plan_trials(replace(s, methods=usable), area)
        tasks = [delayed(run_trial)(t, s.config, s.seed, models) for t in trials]
        outcomes = run_parallel(s.workers, tasks, "trials", progress)
    timing = {"identification_s": t_ident, "total_s": time.perf_counter() - t0}
    results = aggregate(s, outcomes, jobs, area, timing)
    results["failures"] = [
        {"experiment": "identification", "method": m, "settings": "", "error": why}
        for m, why in failed.items()
    ] + results["failures"]
    return Reproduction(results, outcomes, models)


# ----------------------------------------------------------------------------- results
def _num(v: Any) -> float | None:
    """A finite float, or None (JSON has no NaN)."""
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _stats(values: list[float]) -> dict[str, Any]:
    a = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if a.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(a.mean()), "std": float(a.std()), "n": int(a.size)}


def aggregate(
    settings: ReproduceSettings,
    outcomes: list[tuple[Trial, Any]],
    jobs: list[dict[str, Any]],
    area_half_nm: float,
    timing: dict[str, float],
) -> dict[str, Any]:
    """The run's results as a JSON-ready dictionary (``results.json``)."""
    s = settings
    ok = [(t, r) for t, r in outcomes if not isinstance(r, str)]
    failures = [
        {"experiment": t.experiment, "method": t.method, "settings": _describe(t), "error": r}
        for t, r in outcomes
        if isinstance(r, str)
    ]
    out: dict[str, Any] = {
        "preset": s.source,
        "seed": s.seed,
        "quick": s.quick,
        "methods_compared": {
            m: DESCRIPTIONS[m]
            for m in (*s.methods, DRIFT_METHOD)
            if m in s.methods or any(t.method == m for t, _ in outcomes)
        },
        "paper": {
            "table1": {str(int(d)): v for d, v in table1.PAPER.items()},
            "fig9": fig9.PAPER,
            "speed_nm_per_s": PAPER_SPEED_NM_PER_S,
        },
    }
    rows = []
    t1_speeds = s.ordered_speeds if s.table1_speeds_nm_per_s is None else s.table1_speeds_nm_per_s
    tracked = any(t.method == DRIFT_METHOD for t, _ in outcomes)
    shown = (*s.methods, DRIFT_METHOD) if tracked else s.methods
    for v in t1_speeds:
        for d in s.distances_nm:
            sel = {m: [r for t, r in ok if t.experiment == "table1" and t.method == m
                       and r.settings.speed_nm_per_s == v and r.settings.d_nm == d]
                   for m in shown}  # fmt: skip
            rows.append({
                "d_nm": d,
                "speed_nm_per_s": v,
                "methods": {
                    m: {
                        "max_error_nm": _stats([r.max_error_nm for r in rs]),
                        "true_max_error_nm": _stats([r.true_max_error_nm for r in rs]),
                    }
                    for m, rs in sel.items()
                },
            })  # fmt: skip
    out["table1"] = rows
    out["table1_settings"] = {
        "experiments": s.table1_experiments,
        "area_half_width_nm": area_half_nm,
        **_plain(asdict(table1.Table1Settings(area_nm=area_half_nm))),
    }
    speeds = []
    for v in s.ordered_speeds:
        methods = {}
        for m in shown:
            rs = [r for t, r in ok if t.experiment == "fig9" and t.method == m
                  and r.settings.speed_nm_per_s == v]  # fmt: skip
            if rs:
                methods[m] = {
                    "error_nm": _num(rs[0].error_nm),
                    "true_error_nm": _num(rs[0].true_error_nm),
                }
        speeds.append({"speed_nm_per_s": v, "methods": methods})
    out["fig9"] = {"speed_nm_per_s": PAPER_SPEED_NM_PER_S, "methods": speeds[0]["methods"],
                   "speeds": speeds}  # fmt: skip
    f8 = {}
    for t, r in ok:
        if t.experiment == "fig8":
            spread, true = r.spread_nm, r.true_spread_nm
            f8[t.method] = {
                "spread_nm": _num(np.max(spread)) if np.all(np.isfinite(spread)) else None,
                "true_spread_nm": _num(np.nanmax(true)) if np.any(np.isfinite(true)) else None,
                "per_particle_nm": [_num(v) for v in spread],
                "true_per_particle_nm": [_num(v) for v in true],
                "ramps_seeing_each_particle": [int(v) for v in r.seen],
                "ramps": int(r.peaks_nm.shape[0]),
            }
    out["fig8"] = {"speed_nm_per_s": PAPER_SPEED_NM_PER_S, "methods": f8}
    f10 = {}
    for m in s.methods:
        rs = [r for t, r in ok if t.experiment == "fig10" and t.method == m]
        if rs:
            f10[m] = {
                "success_rate": float(np.mean([r.success for r in rs])),
                "true_success_rate": float(np.mean([bool(r.true_success) for r in rs])),
                "max_error_nm": _stats([r.max_error_nm for r in rs]),
                "true_max_error_nm": _stats([r.true_max_error_nm for r in rs]),
                "pushes": _stats([r.assembly.n_pushes for r in rs]),
                **fig10.failure_summary(rs),
            }
    out["fig10"] = {"trials": s.fig10_trials, "success_nm": fig10.Fig10Settings().success_nm,
                    "methods": f10}  # fmt: skip
    if s.config.drifts:
        both = [r for t, r in outcomes if t.experiment == "fig10" and t.method == DRIFT_METHOD]
        done = [r for r in both if not isinstance(r, str)]  # the rest stopped with an error
        out["fig10_drift"] = {
            "trials": len(both),
            "methods": {
                "creep_hysteresis": f10.get("compensated"),
                "both": None if not both else {
                    "success_rate": sum(r.success for r in done) / len(both),
                    "true_success_rate": sum(bool(r.true_success) for r in done) / len(both),
                    "true_max_error_nm": _stats([r.true_max_error_nm for r in done]),
                    "stopped": len(both) - len(done),
                },
            },
        }  # fmt: skip
    session = [t.settings for t, _ in outcomes if t.experiment == "drift_session"]
    if session:  # none when the default method had no usable model
        out["drift_session"] = drift_session.summarise(
            session[0], {t.method: r for t, r in outcomes if t.experiment == "drift_session"}
        )
    out["identification"] = _identification(s, jobs)
    out["failures"] = failures
    out["timing_s"] = timing
    return out


def _identification(settings: ReproduceSettings, jobs: list[dict[str, Any]]) -> dict[str, Any]:
    axes: dict[str, dict[str, Any]] = {}
    for job in jobs:
        axes.setdefault(job["axis"], {})[job["kind"]] = job["summary"]
    return {"settings": _plain(asdict(settings.identification)), "axes": axes}


def _plain(d: dict[str, Any]) -> dict[str, Any]:
    """Tuples as lists (JSON)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def _describe(t: Trial) -> str:
    st = t.settings[0] if t.experiment == "fig10" else t.settings
    fields = {k: v for k, v in asdict(st).items() if k in ("d_nm", "speed_nm_per_s", "experiment")}
    if t.experiment == "fig10":
        fields["trial"] = t.settings[1]
    return ", ".join(f"{k}={v}" for k, v in fields.items())
