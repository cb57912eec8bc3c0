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
from collections.abc import Collection
from dataclasses import asdict, dataclass, field, replace
from typing import Any, cast

from joblib import delayed

from piezocomp.experiments import drift_session, fig8, fig9, fig10, table1
from piezocomp.experiments.contract import (
    DRIFT_METHOD,
    Experiment,
    Outcome,
    Plan,
    Trial,
    plain,
)
from piezocomp.experiments.methods import (
    DESCRIPTIONS,
    JOBS,
    METHODS,
    IdentificationSettings,
    MethodModels,
    identification_failures,
    identification_job,
    working_half_width,
    working_half_widths,
)
from piezocomp.experiments.parallel import backend, run_parallel
from piezocomp.experiments.results import Failure, Results, StageTime
from piezocomp.virtual_afm import AFMConfig, VirtualAFM

__all__ = [
    "DRIFT_METHOD",
    "EXPERIMENTS",
    "PAPER_SPEED_NM_PER_S",
    "ReproduceSettings",
    "Reproduction",
    "Trial",
    "aggregate",
    "experiment_plan",
    "plan_trials",
    "reproduce",
    "run_trial",
    "stage_times",
    "table1_area",
    "too_narrow",
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
class Reproduction:
    """Everything a run produced: the JSON-ready results and what the figures need."""

    results: Results
    outcomes: list[Outcome] = field(repr=False)
    models: MethodModels = field(repr=False)


EXPERIMENTS: tuple[Experiment, ...] = (table1, fig9, fig8, fig10, drift_session)
"""The experiments of a run, in the order ``results.json`` and the report list them."""

_BY_NAME: dict[str, Experiment] = {e.NAME: e for e in EXPERIMENTS}


def experiment_plan(settings: ReproduceSettings, area_half_nm: float) -> Plan:
    """What the experiments are asked to run for ``settings`` (all its methods)."""
    s = settings
    t1 = s.ordered_speeds if s.table1_speeds_nm_per_s is None else s.table1_speeds_nm_per_s
    return Plan(
        methods=s.methods,
        speeds_nm_per_s=s.ordered_speeds,
        table1_speeds_nm_per_s=t1,
        distances_nm=s.distances_nm,
        table1_experiments=s.table1_experiments,
        fig10_trials=s.fig10_trials,
        drifts=s.config.drifts,
        session_minutes=s.session_minutes,
        area_half_nm=area_half_nm,
        paper_speed_nm_per_s=PAPER_SPEED_NM_PER_S,
    )


def table1_area(
    models: MethodModels, sample_period_s: float, leave_out: Collection[str] = ()
) -> float:
    """Table I's area half-width: its own, inside every method's working area
    (:data:`TABLE1_MARGIN_NM` inside it), the methods in ``leave_out`` aside."""
    return min(
        table1.Table1Settings().area_nm,
        working_half_width(models, sample_period_s, leave_out) - TABLE1_MARGIN_NM,
    )


def too_narrow(
    models: MethodModels, sample_period_s: float, distances_nm: Collection[float]
) -> dict[str, str]:
    """The methods whose working area cannot hold Table I's largest distance (its two areas
    ``d / 2`` from the centre, each ``size_nm`` across, :data:`TABLE1_MARGIN_NM` inside),
    with why: they are not run, so that one method's narrow area does not stop every
    method's Table I."""
    need = 0.5 * max(distances_nm) + table1.Table1Settings().size_nm
    return {
        m: (
            f"its working area (+-{w:.0f} nm about its centre) cannot hold Table I's largest "
            f"distance ({need:g} nm from the centre and {TABLE1_MARGIN_NM:g} nm inside): not run"
        )
        for m, w in working_half_widths(models, sample_period_s).items()
        if w - TABLE1_MARGIN_NM < need
    }


def plan_trials(settings: ReproduceSettings, area_half_nm: float) -> list[Trial]:
    """Every trial of the run: Table I fits in ``+-area_half_nm`` of each method's origin."""
    p = experiment_plan(settings, area_half_nm)
    return [t for e in EXPERIMENTS for t in e.plan(p)]


def run_trial(trial: Trial, config: AFMConfig, seed: int, models: MethodModels) -> Outcome:
    """Run one trial; its result, or the text of the error that stopped it."""
    try:
        return trial, _BY_NAME[trial.experiment].run_trial(trial, config, seed, models)
    except (ValueError, RuntimeError) as exc:
        return trial, f"{type(exc).__name__}: {exc}"


def _timed_trial(
    trial: Trial, config: AFMConfig, seed: int, models: MethodModels
) -> tuple[Outcome, float, float]:
    """:func:`run_trial` with the wall-clock and processor seconds it took."""
    t0, c0 = time.perf_counter(), time.process_time()
    outcome = run_trial(trial, config, seed, models)
    return outcome, time.perf_counter() - t0, time.process_time() - c0


def stage_times(
    jobs: list[dict[str, Any]], trials: list[tuple[Outcome, float, float]]
) -> dict[str, StageTime]:
    """The computing of each stage of a run (``results.json``'s ``stages_s``): each kind of
    identification (both axes) and each experiment's trials, in the order given (the
    plan's, as :func:`reproduce` gathers them)."""
    out: dict[str, StageTime] = {}

    def add(name: str, wall: float, cpu: float) -> None:
        st = out.setdefault(name, StageTime(n=0, wall_s=0.0, cpu_s=0.0))
        st["n"] += 1
        st["wall_s"] += float(wall)
        st["cpu_s"] += float(cpu)

    for job in jobs:
        summary = job["summary"]
        add(f"identification: {job['kind']}", summary["computing_s"], summary["cpu_s"])
    for (trial, _), wall, cpu in trials:
        add(trial.experiment, wall, cpu)
    return out


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
        failed = identification_failures(s.methods, jobs)  # never run with a doubtful model
        narrow = {m: why for m, why in too_narrow(models, T, s.distances_nm).items()
                  if m in s.methods and m not in failed}  # fmt: skip
        area = table1_area(models, T, leave_out=(*failed, *narrow))
        usable = tuple(m for m in s.methods if m not in failed and m not in narrow)
        trials = plan_trials(replace(s, methods=usable), area)
        tasks = [delayed(_timed_trial)(t, s.config, s.seed, models) for t in trials]
        timed = run_parallel(s.workers, tasks, "trials", progress)
    outcomes = [o for o, _, _ in timed]
    timing = {"identification_s": t_ident, "total_s": time.perf_counter() - t0}
    results = aggregate(s, outcomes, jobs, area, timing)
    results["stages_s"] = stage_times(jobs, timed)
    results["failures"] = (
        [
            Failure(experiment="identification", method=m, settings="", error=why)
            for m, why in failed.items()
        ]
        + [
            Failure(experiment="planning", method=m, settings="", error=why)
            for m, why in narrow.items()
        ]
        + results["failures"]
    )
    return Reproduction(results, outcomes, models)


# ----------------------------------------------------------------------------- results
def aggregate(
    settings: ReproduceSettings,
    outcomes: list[Outcome],
    jobs: list[dict[str, Any]],
    area_half_nm: float,
    timing: dict[str, float],
) -> Results:
    """The run's results as a JSON-ready dictionary (``results.json``): the run, the paper's
    figures, each experiment's sections (its ``summarise``), the identification, the
    failures and the timing."""
    s = settings
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
    plan = experiment_plan(s, area_half_nm)
    for e in EXPERIMENTS:
        out.update(e.summarise(plan, outcomes))
    out["identification"] = _identification(s, jobs)
    out["failures"] = [
        {"experiment": t.experiment, "method": t.method, "settings": _describe(t), "error": r}
        for t, r in outcomes
        if isinstance(r, str)
    ]
    out["timing_s"] = timing
    return cast(Results, out)  # the sections are typed where each experiment writes them


def _identification(settings: ReproduceSettings, jobs: list[dict[str, Any]]) -> dict[str, Any]:
    axes: dict[str, dict[str, Any]] = {}
    for job in jobs:
        axes.setdefault(job["axis"], {})[job["kind"]] = job["summary"]
    return {"settings": plain(asdict(settings.identification)), "axes": axes}


def _describe(t: Trial) -> str:
    st = t.settings
    inner = st.settings if isinstance(st, fig10.Fig10Trial) else st
    fields = {
        k: v for k, v in asdict(inner).items() if k in ("d_nm", "speed_nm_per_s", "experiment")
    }
    if isinstance(st, fig10.Fig10Trial):
        fields["trial"] = st.sample
    return ", ".join(f"{k}={v}" for k, v in fields.items())
