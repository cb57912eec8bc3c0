"""A long session on a drifting sample: Table I's moves and scans for twenty minutes.

Two areas A and B (117 nm, ``d`` apart, chosen where an overview shows particles, as in
Table I) are visited in turn for ``minutes``, each visit by two random intermediate points
and an image of the area. The error of every image is how far it lies from the first image
of its area: measured by cross-correlation and, on a simulator, true (the mean true tip
position over its pixels). Drift moves the sample under the tip by tens of nanometres in
twenty minutes; creep and hysteresis add what Table I shows. Run on the raw instrument, the
creep-and-hysteresis compensator, the drift compensator and both (they compose by wrapping),
the session shows what each corrects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar
from piezocomp.drift.compensated import DriftCompensatedInstrument, DriftSettings, TrackingLost
from piezocomp.drift.filter import DriftNoise
from piezocomp.experiments.contract import Outcome, Plan, Trial
from piezocomp.experiments.methods import MethodModels, instrument_for
from piezocomp.experiments.results import DriftNoiseSummary, DriftSession, DriftSessionMethod
from piezocomp.experiments.table1 import Table1Settings, candidates
from piezocomp.experiments.truth import Truth, true_image_position
from piezocomp.imaging.features import find_particles
from piezocomp.imaging.registration import image_displacement
from piezocomp.instrument import Instrument, ScanImage
from piezocomp.virtual_afm import AFMConfig, VirtualAFM

__all__ = [
    "DESCRIPTIONS",
    "LIMITATIONS",
    "METHODS",
    "NAME",
    "DriftSessionResult",
    "DriftSessionSettings",
    "plan",
    "run",
    "run_method",
    "run_trial",
    "session_instrument",
    "session_summary",
    "summarise",
    "unresolved_note",
]

NAME = "drift_session"

METHODS = ("both", "compensated", "uncompensated", "drift_only")
"""The four ways the session is run, in the order reports list them (the default first,
as :func:`~piezocomp.experiments.contract.default_first` orders every table): named as Table I names
the same model (``uncompensated``, ``compensated``; ``both`` is Table I's default on a drifting
scanner), in ``results.json``, consoles, reports and figures alike."""

LIMITATIONS = {
    "drift_only": (
        "on the uncompensated scanner every landmark sighting carries the scanner's own "
        "error (the hysteresis of the approach and the creep of where the tip has been), "
        "which drift tracking cannot tell from drift"
    ),
}
"""Methods whose drift tracking may lose its landmarks by design, and why: their session
is reported as far as it went, not as a failure."""

DESCRIPTIONS = {
    "uncompensated": "commands sent as they are",
    "compensated": "the creep-and-hysteresis compensator only (the compensated model)",
    "drift_only": "the drift compensator only, on the uncompensated scanner",
    "both": "the drift compensator wrapped around the creep-and-hysteresis compensator",
}


@dataclass(frozen=True)
class DriftSessionSettings:
    """The session.

    Parameters
    ----------
    minutes : float
        Length of the session (virtual or real time).
    d_nm, speed_nm_per_s, size_nm, pixels, line_rate_hz, area_nm
        As in Table I (:class:`~piezocomp.experiments.table1.Table1Settings`).
    spread : float
        Intermediate points within ``+-spread d`` of the segment between the areas.
    seed : int
        The geometry and the random moves.
    landmark_overview_nm : float
        Side of the overview the drift compensator chooses its landmarks in.
    area_sightings : bool
        With a drift compensator, every image of an area after its first is also a drift
        sighting (:meth:`~piezocomp.drift.compensated.DriftCompensatedInstrument.scan_area`:
        the session leaves its areas as they are); else the landmarks alone measure it.
        The images then scored are the ones the filter was given, so only their true
        errors judge the session fairly.
    """

    minutes: float = 20.0
    d_nm: float = 951.0
    speed_nm_per_s: float = 1000.0
    size_nm: float = 117.0
    pixels: int = 64
    line_rate_hz: float = 2.0
    area_nm: float = 650.0
    spread: float = 0.25
    seed: int = 0
    landmark_overview_nm: float = 1000.0
    area_sightings: bool = False

    def __post_init__(self) -> None:
        for name in ("minutes", "d_nm", "speed_nm_per_s", "size_nm", "line_rate_hz", "area_nm",
                     "landmark_overview_nm"):  # fmt: skip
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        if isinstance(self.pixels, bool) or not isinstance(self.pixels, int) or self.pixels < 8:
            raise ValueError(f"pixels must be an integer >= 8. Got {self.pixels!r}.")
        if not isinstance(self.area_sightings, bool):
            raise ValueError(f"area_sightings must be True or False. Got {self.area_sightings!r}.")

    def table1(self) -> Table1Settings:
        """The Table I settings whose geometry the session uses."""
        return Table1Settings(
            d_nm=self.d_nm, speed_nm_per_s=self.speed_nm_per_s, experiment=self.seed,
            size_nm=self.size_nm, pixels=self.pixels, line_rate_hz=self.line_rate_hz,
            area_nm=self.area_nm, spread=self.spread,
        )  # fmt: skip


@dataclass(frozen=True)
class DriftSessionResult:
    """Every image's error against the first of its area.

    Attributes
    ----------
    settings : DriftSessionSettings
    times_s : ndarray
        Session time of each image after the first of its area (from the session start).
    areas : tuple of str
        ``"A"`` or ``"B"`` for each.
    errors_nm : ndarray
        By cross-correlation (NaN where it could not be measured).
    true_errors_nm : ndarray or None
        True.
    overhead_fraction : float
        Time spent measuring drift (0 without drift compensation).
    measurements : int
        Drift measurements taken.
    scanner_error_nm : ndarray, shape (2,), or None
        The wrapped scanner's error at the landmarks (one sighting's standard deviation, x
        and y) as the drift compensator measured it, when it did (on the uncompensated
        scanner).
    stopped : str
        Empty, or why the session stopped before its end (drift tracking lost its
        landmarks): the images up to then are reported.
    noise : DriftNoise or None
        The drift noise the drift compensator ran with at the end (None without one): the
        generic prior, or what it learnt from its own measurements.
    noise_learnt_from : int
        How many drift measurements the last re-estimation of that noise used (0: never
        re-estimated: the prior).
    """

    settings: DriftSessionSettings
    times_s: NDArray[np.float64]
    areas: tuple[str, ...]
    errors_nm: NDArray[np.float64]
    true_errors_nm: NDArray[np.float64] | None = None
    overhead_fraction: float = 0.0
    measurements: int = 0
    first_images: dict[str, ScanImage] | None = field(default=None, repr=False)
    scanner_error_nm: NDArray[np.float64] | None = None
    stopped: str = ""
    noise: DriftNoise | None = None
    noise_learnt_from: int = 0

    @property
    def max_error_nm(self) -> float:
        """The largest measured error (NaN if one could not be measured)."""
        return float(np.max(self.errors_nm)) if self.errors_nm.size else 0.0

    @property
    def true_max_error_nm(self) -> float | None:
        """The largest true error (None without truth or images)."""
        t = self.true_errors_nm
        return None if t is None or not t.size else float(np.max(t))

    @property
    def final_error_nm(self) -> float | None:
        """The measured error of the last image (None without images; NaN if it could not
        be measured)."""
        return float(self.errors_nm[-1]) if self.errors_nm.size else None

    @property
    def true_final_error_nm(self) -> float | None:
        """The true error of the last image (None without truth or images)."""
        t = self.true_errors_nm
        return None if t is None or not t.size else float(t[-1])


def run(
    instrument: Instrument,
    settings: DriftSessionSettings,
    *,
    origin_nm: tuple[float, float] = (0.0, 0.0),
    truth: Truth | None = None,
) -> DriftSessionResult:
    """Run the session on ``instrument`` (any of the four), coordinates relative to
    ``origin_nm``."""
    s = settings
    t1 = s.table1()
    o = np.asarray(origin_nm, dtype=float)
    overview = instrument.scan_image((float(o[0]), float(o[1])), 2.0 * t1.area_nm,
                                     t1.overview_pixels, t1.overview_line_rate_hz)  # fmt: skip
    g = next(candidates(t1, find_particles(overview, trace="mean").positions_nm - o), None)
    if g is None:
        raise ValueError(f"no pair of areas {s.d_nm:g} nm apart holds particles in the overview.")
    rng = np.random.default_rng([7, s.seed])
    corner = np.full(2, -0.5 * s.size_nm)
    centres = {"A": g.a_nm, "B": g.b_nm}

    def visit(area: str, came_from: str) -> ScanImage:
        a, b = centres[came_from], centres[area]
        for f in np.sort(rng.uniform(0.15, 0.85, 2)):
            p = a + f * (b - a) + rng.uniform(-s.spread * s.d_nm, s.spread * s.d_nm, 2)
            p = np.clip(p, -t1.area_nm, t1.area_nm)
            q = o + p
            instrument.move_to(float(q[0]), float(q[1]), s.speed_nm_per_s)
        start = o + b + corner
        instrument.move_to(float(start[0]), float(start[1]), s.speed_nm_per_s)
        c = (float(o[0] + b[0]), float(o[1] + b[1]))
        if s.area_sightings and isinstance(instrument, DriftCompensatedInstrument):
            return instrument.scan_area(area, c, s.size_nm, s.pixels, s.line_rate_hz)
        return instrument.scan_image(c, s.size_nm, s.pixels, s.line_rate_hz)

    first: dict[str, ScanImage] = {}
    times: list[float] = []
    areas: list[str] = []
    errors: list[float] = []
    true_errors: list[float] = []
    stopped = ""
    # the first images' true positions are read at once: the truth keeps recent samples only
    first_true: dict[str, NDArray[np.float64]] = {}

    def reference(area: str, other: str) -> None:
        first[area] = visit(area, other)
        if truth is not None:
            first_true[area] = true_image_position(truth, first[area])

    try:
        reference("A", "B")
        t_start = first["A"].t_start_s
        reference("B", "A")
        here = "B"
        while True:
            area = "A" if here == "B" else "B"
            img = visit(area, here)
            here = area
            times.append(img.t_start_s - t_start)
            areas.append(area)
            try:
                errors.append(image_displacement(first[area], img).magnitude_nm)
            except ValueError:
                errors.append(float("nan"))
            if truth is not None:
                d = true_image_position(truth, img) - first_true[area]
                true_errors.append(float(np.hypot(*d)))
            if img.t_start_s - t_start >= 60.0 * s.minutes:
                break
    except TrackingLost as exc:  # the images up to here are the result
        stopped = str(exc)
    overhead = float(getattr(instrument, "overhead_fraction", 0.0))
    n_meas = len(getattr(instrument, "measurements", ()))
    err = getattr(instrument, "scanner_error", None)
    learnt = getattr(instrument, "learnt_noise", [])
    return DriftSessionResult(
        s, np.asarray(times), tuple(areas), np.asarray(errors),
        None if truth is None else np.asarray(true_errors), overhead, n_meas, first or None,
        None if err is None else np.asarray(err.sigma_nm), stopped,
        getattr(instrument, "noise", None), learnt[-1][0] if learnt else 0,
    )  # fmt: skip


def run_method(
    method: str,
    afm: VirtualAFM,
    models: MethodModels,
    settings: DriftSessionSettings,
) -> DriftSessionResult:
    """The session of one of :data:`METHODS` on ``afm`` (:func:`session_instrument`, then
    :func:`run`, scored against ``afm``'s truth).

    Drift tracking that loses its landmarks is a failure (:class:`RuntimeError`) for the
    methods that should hold the areas, but a limitation of ``"drift_only"`` by design (see
    :data:`LIMITATIONS`): its session stops and is reported with the images it has (none
    when tracking could not start), ``stopped`` saying why.
    """
    try:
        inst, origin = session_instrument(method, afm, models, settings)
    except TrackingLost as exc:
        if method not in LIMITATIONS:
            raise
        empty = np.zeros(0)
        return DriftSessionResult(settings, empty, (), empty, empty, stopped=str(exc))
    r = run(inst, settings, origin_nm=origin, truth=afm.truth)
    if r.stopped and method not in LIMITATIONS:
        raise RuntimeError(f"drift tracking stopped the session: {r.stopped}")
    return r


def session_instrument(
    method: str,
    afm: VirtualAFM,
    models: MethodModels,
    settings: DriftSessionSettings,
    drift: DriftSettings | None = None,
) -> tuple[Instrument, tuple[float, float]]:
    """The instrument of one of :data:`METHODS` on ``afm`` and the origin of the session's
    coordinates; a drift compensator has started tracking (landmarks chosen in an overview
    of ``landmark_overview_nm`` about the origin), with ``drift`` (default: the defaults,
    :meth:`DriftSettings.uncompensated` for ``"drift_only"``)."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}. Got {method!r}.")
    compensated = method in ("compensated", "both")
    inner, origin = instrument_for("compensated" if compensated else "uncompensated", afm, models)
    if method in ("uncompensated", "compensated"):
        return inner, origin
    if drift is None:
        drift = DriftSettings() if compensated else DriftSettings.uncompensated()
    tracked = DriftCompensatedInstrument(inner, drift)
    tracked.start(center_nm=origin, size_nm=settings.landmark_overview_nm)
    return tracked, origin


def session_summary(settings: DriftSessionSettings, results: dict[str, Any]) -> DriftSession:
    """``results.json``'s ``drift_session``: per method, the largest and the final error
    (true and measured), the time spent measuring drift, the scanner's error at the
    landmarks when the drift compensator measured it, the drift noise it ran with (and how
    many measurements it learnt it from), or the error that stopped the session. A method
    limited by design (:data:`LIMITATIONS`) says so (``limitation``), and why its session
    stopped early if it did (``stopped``): a result, not a failure."""
    methods: dict[str, DriftSessionMethod] = {}
    for m in METHODS:
        r = results.get(m)
        if r is None:
            continue
        if isinstance(r, str):
            methods[m] = {"true_max_error_nm": None, "max_error_nm": None,
                          "measurement_overhead_fraction": None, "error": r}  # fmt: skip
            continue
        meas, final = r.max_error_nm, r.final_error_nm
        methods[m] = {
            "true_max_error_nm": r.true_max_error_nm,
            "max_error_nm": meas if r.errors_nm.size and np.isfinite(meas) else None,
            "measurement_overhead_fraction": r.overhead_fraction,
            "drift_measurements": r.measurements,
            "images": int(r.errors_nm.size),
            "times_s": [float(t) for t in r.times_s],
            "true_errors_nm": None if r.true_errors_nm is None
            else [float(e) for e in r.true_errors_nm],
            "true_final_error_nm": r.true_final_error_nm,
            "final_error_nm": final if final is not None and np.isfinite(final) else None,
            "scanner_error_nm": None if r.scanner_error_nm is None
            else [float(v) for v in r.scanner_error_nm],
            "limitation": LIMITATIONS.get(m),
            "stopped": r.stopped or None,
            "drift_noise": None if r.noise is None else {
                "position_nm_per_sqrt_s": r.noise.position_nm_per_sqrt_s,
                "rate_noise": r.noise.rate_noise, "measurement_nm": r.noise.measurement_nm,
                "order": r.noise.order, "learnt_from_measurements": r.noise_learnt_from,
            },
        }  # fmt: skip
    return {"minutes": settings.minutes, "d_nm": settings.d_nm,
            "speed_nm_per_s": settings.speed_nm_per_s, "descriptions": DESCRIPTIONS,
            "methods": methods}  # fmt: skip


def unresolved_note(noise: DriftNoiseSummary, minutes: float) -> str:
    """``": no wander beyond its sightings' ... nm noise"`` when the learnt drift noise is
    below what its measurements resolve, else ``""``: over the whole session its random
    walk and its rate's noise together would move the drift by less than one sighting's
    noise (the fit then finds none, and its values, however small, say only that).

    The drift a random walk of intensity ``p`` moves in ``T``: ``p sqrt(T)``; a rate noise
    ``r`` on the velocity (order 2) adds ``r sqrt(T^3 / 3)``, on the acceleration (order 3)
    ``r sqrt(T^5 / 20)``, in quadrature.
    """
    t = 60.0 * minutes
    power, k = (3, 3.0) if noise["order"] == 2 else (5, 20.0)
    wander = math.sqrt(noise["position_nm_per_sqrt_s"] ** 2 * t
                       + noise["rate_noise"] ** 2 * t**power / k)  # fmt: skip
    if wander >= noise["measurement_nm"]:
        return ""
    return f": no wander beyond its sightings' {noise['measurement_nm']:.2g} nm noise"


# ---------------------------------------------------------------- in piezocomp reproduce
def plan(p: Plan) -> list[Trial]:
    """The session of each of :data:`METHODS`, when the plan has one and a compensated
    model to run it with."""
    if p.session_minutes <= 0 or "compensated" not in p.methods:
        return []
    st = DriftSessionSettings(minutes=p.session_minutes, area_nm=min(650.0, p.area_half_nm))
    return [Trial(NAME, m, st, True) for m in METHODS]


def run_trial(
    trial: Trial, config: AFMConfig, seed: int, models: MethodModels
) -> DriftSessionResult:
    """The session on a fresh virtual AFM (:func:`run_method`: drift only's limits are
    results)."""
    return run_method(trial.method, VirtualAFM(config, seed=seed), models, trial.settings)


def summarise(p: Plan, outcomes: list[Outcome]) -> dict[str, Any]:
    """``drift_session`` (:func:`session_summary`); nothing when no session ran (none when
    the default method had no usable model)."""
    mine = [(t, r) for t, r in outcomes if t.experiment == NAME]
    if not mine:
        return {}
    return {"drift_session": session_summary(mine[0][0].settings, {t.method: r for t, r in mine})}
