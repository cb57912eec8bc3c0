"""The schema of ``results.json``: what each experiment's ``summarise`` writes, and what the
report, the figures and the table over samples read.

One typed dictionary per section, so that the writer (the experiment module) and the
readers (:mod:`~piezocomp.experiments.report`, :mod:`piezocomp.plotting.experiments`,
:mod:`~piezocomp.experiments.samples`) are checked against the same keys. Errors are nm,
times s, rates fractions in [0, 1]; a figure that could not be measured is ``None`` (JSON
has no NaN). ``methods`` maps a method's name
(:data:`~piezocomp.experiments.methods.DESCRIPTIONS`) to its figures.
"""

from __future__ import annotations

from typing import Any, NotRequired, TypedDict, final

__all__ = [
    "LEGACY_SESSION_KEYS",
    "AssemblyOutcome",
    "DriftNoiseSummary",
    "DriftSession",
    "DriftSessionFailed",
    "DriftSessionMethod",
    "DriftSessionRun",
    "Failure",
    "Fig8",
    "Fig8Method",
    "Fig9",
    "Fig9Method",
    "Fig9Speed",
    "Fig10",
    "Fig10Drift",
    "Fig10Method",
    "Paper",
    "PushSummary",
    "Results",
    "Stat",
    "Table1Method",
    "Table1Row",
    "session_methods",
]


class Stat(TypedDict):
    """Mean, standard deviation and count over the trials (``None`` with none finite)."""

    mean: float | None
    std: float | None
    n: int


class Table1Method(TypedDict):
    """One method at one distance and speed: its Table I error, measured and true."""

    max_error_nm: Stat
    true_max_error_nm: Stat


class Table1Row(TypedDict):
    d_nm: float
    speed_nm_per_s: float
    methods: dict[str, Table1Method]


class Fig9Method(TypedDict):
    """The displacement after the loop (measured, true)."""

    error_nm: float | None
    true_error_nm: float | None


class Fig9Speed(TypedDict):
    speed_nm_per_s: float
    methods: dict[str, Fig9Method]


class Fig9(TypedDict):
    """``methods``: at the paper's speed; ``speeds``: at every speed."""

    speed_nm_per_s: float
    methods: dict[str, Fig9Method]
    speeds: list[Fig9Speed]


class Fig8Method(TypedDict):
    """The peaks' spread over the ramps: largest (over the particles seen by at least half
    the ramps) and per particle, measured and true."""

    spread_nm: float | None
    particles_measured: int
    true_spread_nm: float | None
    per_particle_nm: list[float | None]
    true_per_particle_nm: list[float | None]
    ramps_seeing_each_particle: list[int]
    ramps: int


class Fig8(TypedDict):
    speed_nm_per_s: float
    methods: dict[str, Fig8Method]


class PushSummary(TypedDict):
    """Over assemblies: failed pushes their images found, by kind; what the planner did
    about them; failed pushes not recovered (their site still off at the end); passes made;
    what the simulator's pushing truly did (``None`` when unknown)."""

    failed_pushes: dict[str, int]
    recoveries: dict[str, int]
    unrecovered: int
    passes: list[int]
    true_push_counts: dict[str, int] | None


class AssemblyOutcome(TypedDict):
    """One assembly of Fig. 10: truly every particle within the success distance, its worst
    site's true error (``None``: a particle lost, or the assembly stopped by ``error``); by
    its last image, placed or not and the worst site's error there (``None``: a site without
    a particle); the failed pushes its images found that were not recovered; the sites its
    last pass found no clear path to (a blunt tip among placed particles)."""

    true_success: bool
    true_max_error_nm: float | None
    success: NotRequired[bool]
    max_error_nm: NotRequired[float | None]
    unrecovered: NotRequired[int]
    blocked: NotRequired[int]
    error: NotRequired[str]


class Fig10Method(TypedDict):
    """Assemblies: the share that succeeded (by the images, truly), worst site errors,
    pushes, failed pushes by kind and the planner's recoveries."""

    success_rate: float
    true_success_rate: float
    max_error_nm: NotRequired[Stat]
    true_max_error_nm: Stat
    pushes: NotRequired[Stat]
    failed_pushes: NotRequired[dict[str, int]]
    recoveries: NotRequired[dict[str, int]]
    unrecovered: NotRequired[int]
    passes: NotRequired[list[int]]
    true_push_counts: NotRequired[dict[str, int] | None]
    stopped: NotRequired[int]
    assemblies: NotRequired[list[AssemblyOutcome]]


class Fig10(TypedDict):
    trials: int
    success_nm: float
    methods: dict[str, Fig10Method]


class Fig10Drift(TypedDict):
    """Assemblies inside the drift compensator against the compensated ones outside it."""

    trials: int
    methods: dict[str, Fig10Method | None]


class DriftNoiseSummary(TypedDict):
    position_nm_per_sqrt_s: float
    rate_noise: float
    measurement_nm: float
    order: int
    learnt_from_measurements: int


@final
class DriftSessionRun(TypedDict):
    """One method's session: worst and final error of its images (true, measured), the
    share of time measuring drift and the measurements, the error of each image over time,
    the scanner's error its landmarks saw, the drift noise its filter ran with; for a method
    limited by design, the limit and why it stopped early, if it did."""

    true_max_error_nm: float
    max_error_nm: float | None
    measurement_overhead_fraction: float
    drift_measurements: int
    images: int
    times_s: list[float]
    true_errors_nm: list[float] | None
    true_final_error_nm: float | None
    final_error_nm: float | None
    scanner_error_nm: list[float] | None
    limitation: str | None
    stopped: str | None
    drift_noise: DriftNoiseSummary | None


@final
class DriftSessionFailed(TypedDict):
    """A session stopped by an error."""

    true_max_error_nm: None
    max_error_nm: None
    measurement_overhead_fraction: None
    error: str


DriftSessionMethod = DriftSessionRun | DriftSessionFailed


class DriftSession(TypedDict):
    minutes: float
    d_nm: float
    speed_nm_per_s: float
    descriptions: dict[str, str]
    methods: dict[str, DriftSessionMethod]


LEGACY_SESSION_KEYS = {
    "none": "uncompensated",
    "creep_hysteresis": "compensated",
    "drift": "drift_only",
}
"""The drift session's (and ``fig10_drift``'s) method keys before they took the methods' own
names (:data:`~piezocomp.experiments.drift_session.METHODS`); read for one release."""


def session_methods(section: DriftSession | Fig10Drift) -> dict[str, Any]:
    """A drift session's or ``fig10_drift``'s methods by their names, also from a
    ``results.json`` written before they took them (:data:`LEGACY_SESSION_KEYS`)."""
    return {LEGACY_SESSION_KEYS.get(k, k): v for k, v in section["methods"].items()}


class Paper(TypedDict):
    """The paper's own figures: Table I by distance (``[mean, std]`` per method), Fig. 9."""

    table1: dict[str, dict[str, list[float]]]
    fig9: dict[str, float]
    speed_nm_per_s: float


class Failure(TypedDict):
    experiment: str
    method: str
    settings: str
    error: str


class StageTime(TypedDict):
    """The computing one stage of a run took: its jobs (an identification kind over both
    axes, or an experiment's trials), their own wall-clock seconds added up over the
    processes that ran them, and the processor seconds of those processes (their threads
    included)."""

    n: int
    wall_s: float
    cpu_s: float


class Results(TypedDict):
    """``results.json``: the run, the paper's figures, each experiment's section (those inside
    the drift compensator on a drifting scanner only), the identification, the failures."""

    preset: str
    seed: int
    quick: bool
    methods_compared: dict[str, str]
    paper: Paper
    table1: list[Table1Row]
    table1_settings: dict[str, Any]
    fig9: Fig9
    fig8: Fig8
    fig10: Fig10
    fig10_drift: NotRequired[Fig10Drift]
    drift_session: NotRequired[DriftSession]
    identification: dict[str, Any]
    failures: list[Failure]
    timing_s: dict[str, float]
    stages_s: NotRequired[dict[str, StageTime]]
    command: NotRequired[str]
    environment: NotRequired[dict[str, Any]]  # piezocomp.environment.environment()
