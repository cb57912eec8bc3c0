"""Table I of the paper: the error of going back to an area after random moves.

Protocol (Sec. V): two areas ``A`` and ``B`` of 117 x 117 nm whose centres are ``d`` apart.
The tip scans ``A``, moves to ``B``'s bottom-left corner along several random straight
segments, scans ``B``, goes back to ``A`` the same way, scans it again, then ``B`` again.
The error is the larger of the displacements between the two images of ``A`` and between
the two of ``B``, measured by image cross-correlation as the paper did
(:func:`~piezocomp.imaging.registration.image_displacement`) and, on a simulator, against the
ground truth.

The paper leaves the geometry open; here (as the ``cpr5`` preset was calibrated): the A-B
midpoint lies within ``+-mid_nm`` of the experiment's origin, the direction is random, every
leg has two random intermediate points within ``+-spread d`` of the A-B segment (three
straight segments), and before the first image of ``A`` the tip arrives from ``B`` (a scan of
``B``, then random moves), as in the middle of a series of experiments. Every point stays
within ``+-area_nm`` of the origin. Areas are chosen where particles are, as a user would:
an overview image of the experiment's area is taken first, and the first candidate
geometry (a fixed sequence for each ``experiment`` number) whose two areas each hold
``min_particles`` particles in it is used; the tip rests at the origin for ``settle_s``
before the experiment starts. An uncompensated instrument may come back to an
area and find none of them in its image: that area's error is then not measurable.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar
from piezocomp.experiments.contract import (
    DRIFT_METHOD,
    Outcome,
    Plan,
    Trial,
    plain,
    shown_methods,
    stats,
    succeeded,
)
from piezocomp.experiments.methods import MethodModels, trial_instrument
from piezocomp.experiments.results import Table1Method, Table1Row
from piezocomp.experiments.truth import Truth, true_displacement
from piezocomp.imaging.features import find_particles
from piezocomp.imaging.registration import image_displacement
from piezocomp.instrument import Instrument, ScanImage
from piezocomp.virtual_afm import AFMConfig, VirtualAFM

__all__ = [
    "DRIFT_MARGIN_NM",
    "NAME",
    "PAPER",
    "Table1Settings",
    "Table1Trial",
    "candidate_geometry",
    "candidates",
    "plan",
    "run",
    "run_trial",
    "summarise",
]

NAME = "table1"

DRIFT_MARGIN_NM = 100.0
"""Inside the drift compensator, Table I's area keeps up to this much farther inside the
working area (as much as the distance leaves room for: 58 nm at 1150 nm on cpr5): the drift
the compensator follows carries the commands with it (room for 0.3 nm/s, a scanner warming
up, over the five and a half minutes of an experiment)."""

PAPER = {
    645.0: {"uncompensated": (6.45, 0.17), "compensated": (0.76, 0.22)},
    951.0: {"uncompensated": (7.03, 0.84), "compensated": (0.78, 0.28)},
    1150.0: {"uncompensated": (9.53, 0.88), "compensated": (1.01, 0.19)},
}
"""Table I of the paper: maximum error (mean, std over 5 experiments), nm, by distance."""

MAX_CANDIDATES = 500
"""Candidate geometries looked at in the overview before the experiment gives up."""


@dataclass(frozen=True)
class Table1Settings:
    """One experiment of Table I.

    Parameters
    ----------
    d_nm : float
        Distance between the centres of A and B, nm.
    speed_nm_per_s : float
        Speed of the moves between the areas (the paper manipulates at about 1 um/s).
    experiment : int
        Which experiment (the seed of its geometry).
    size_nm, pixels, line_rate_hz
        The area images (the paper's: 117 nm; 64 pixels at 2 lines/s here).
    area_nm : float
        Every point of the experiment stays within ``+-area_nm`` of the origin.
    mid_nm, spread : float
        Geometry: the A-B midpoint within ``+-mid_nm``, intermediate points within
        ``+-spread d`` of the segment.
    overview_pixels, overview_line_rate_hz
        The overview image of ``+-area_nm`` in which the areas are chosen.
    settle_s : float
        Time between the overview and the experiment, the tip resting at the origin (a user
        picks the areas meanwhile; the scanner's creep after the overview settles).
    min_particles : int
        Particles each area must hold in the overview (registration needs features).
    edge_nm : float
        ... at least this far inside the area's image: the overview, a larger scan, places
        particles tens of nm from where an uncompensated instrument's small image finds
        them.
    keep_images : bool
        Keep the four images in the result (for figures).
    """

    d_nm: float = 645.0
    speed_nm_per_s: float = 1000.0
    experiment: int = 0
    size_nm: float = 117.0
    pixels: int = 64
    line_rate_hz: float = 2.0
    area_nm: float = 750.0
    mid_nm: float = 300.0
    spread: float = 0.25
    overview_pixels: int = 128
    overview_line_rate_hz: float = 0.5
    settle_s: float = 300.0
    min_particles: int = 2
    edge_nm: float = 10.0
    keep_images: bool = False

    def __post_init__(self) -> None:
        for name in ("d_nm", "speed_nm_per_s", "size_nm", "line_rate_hz", "area_nm",
                     "overview_line_rate_hz"):  # fmt: skip
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        for name in ("mid_nm", "spread", "edge_nm", "settle_s"):
            if check_finite_scalar(name, getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0. Got {getattr(self, name)}.")
        for name in ("pixels", "overview_pixels", "min_particles", "experiment"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0. Got {v!r}.")
        if self.pixels < 8 or self.overview_pixels < 8:
            raise ValueError("pixels and overview_pixels must be >= 8.")
        if 0.5 * self.d_nm + self.size_nm > self.area_nm:
            raise ValueError(
                f"d_nm / 2 + size_nm = {0.5 * self.d_nm + self.size_nm:g} nm does not fit in "
                f"area_nm = {self.area_nm:g} nm."
            )


@dataclass(frozen=True)
class Geometry:
    """Where an experiment goes, relative to its origin (nm).

    Attributes
    ----------
    a_nm, b_nm : ndarray, shape (2,)
        Centres of A and B.
    legs : tuple of ndarray, shape (3, 2)
        The four legs' way points (B to A, A to B, B to A, A to B), each ending at the
        bottom-left corner of the area it goes to.
    candidate : int
        Its place in the experiment's sequence of candidates.
    """

    a_nm: NDArray[np.float64]
    b_nm: NDArray[np.float64]
    legs: tuple[NDArray[np.float64], ...]
    candidate: int


@dataclass(frozen=True)
class Table1Trial:
    """The result of one experiment.

    Attributes
    ----------
    settings : Table1Settings
    geometry : Geometry
    error_nm : dict
        ``{"A": ..., "B": ...}``: displacement between the two images of each area by
        cross-correlation, nm (NaN where an image held no particle to register: the
        instrument did not put the tip where the overview showed particles).
    true_error_nm : dict or None
        The same from the ground truth (``None`` without one).
    images : dict of str to ScanImage, or None
        ``"A1", "B1", "A2", "B2"`` (with ``keep_images``).
    """

    settings: Table1Settings
    geometry: Geometry
    error_nm: dict[str, float]
    true_error_nm: dict[str, float] | None = None
    images: dict[str, ScanImage] | None = field(default=None, repr=False)

    @property
    def max_error_nm(self) -> float:
        """The paper's figure: the larger of the two areas' errors (NaN if one is)."""
        v = np.array(list(self.error_nm.values()), dtype=float)
        return float(np.max(v))

    @property
    def true_max_error_nm(self) -> float | None:
        """The same, true (``None`` without a ground truth)."""
        return None if self.true_error_nm is None else float(max(self.true_error_nm.values()))


def candidate_geometry(settings: Table1Settings, candidate: int) -> Geometry | None:
    """Candidate ``candidate`` of the experiment's sequence, or ``None`` if a point of it
    leaves ``+-area_nm``."""
    s = settings
    rng = np.random.default_rng([s.experiment, candidate, round(s.d_nm * 1000)])
    phi = rng.uniform(0, 2 * np.pi)
    mid = rng.uniform(-s.mid_nm, s.mid_nm, 2)
    u = np.array([np.cos(phi), np.sin(phi)])
    a, b = mid - 0.5 * s.d_nm * u, mid + 0.5 * s.d_nm * u
    corner = np.full(2, -0.5 * s.size_nm)
    legs = []
    for origin, target in ((b, a), (a, b), (b, a), (a, b)):
        f = np.sort(rng.uniform(0.15, 0.85, 2))
        off = rng.uniform(-s.spread * s.d_nm, s.spread * s.d_nm, (2, 2))
        pts = origin + f[:, None] * (target - origin) + off
        legs.append(np.vstack([pts, target + corner]))
    every = np.vstack([*legs, a + 0.5 * s.size_nm, a - 0.5 * s.size_nm,
                       b + 0.5 * s.size_nm, b - 0.5 * s.size_nm])  # fmt: skip
    if np.max(np.abs(every)) > s.area_nm:
        return None
    return Geometry(a, b, tuple(legs), candidate)


def candidates(settings: Table1Settings, particles_nm: NDArray[np.float64]) -> Iterator[Geometry]:
    """The experiment's candidate geometries, in order, whose areas each hold
    ``min_particles`` of ``particles_nm`` (positions relative to the origin) at least
    ``edge_nm`` inside the image."""
    inner = 0.5 * settings.size_nm - settings.edge_nm
    p = np.asarray(particles_nm, dtype=float).reshape(-1, 2)
    for k in range(MAX_CANDIDATES):
        g = candidate_geometry(settings, k)
        if g is not None and all(
            int(np.sum(np.all(np.abs(p - c) <= inner, axis=1))) >= settings.min_particles
            for c in (g.a_nm, g.b_nm)
        ):
            yield g


def run(
    instrument: Instrument,
    settings: Table1Settings,
    *,
    origin_nm: tuple[float, float] = (0.0, 0.0),
    truth: Truth | None = None,
) -> Table1Trial:
    """Run one experiment of Table I on ``instrument`` (raw or compensated), coordinates
    relative to ``origin_nm``; with ``truth``, score it against the ground truth too."""
    s = settings
    o = np.asarray(origin_nm, dtype=float)
    overview = instrument.scan_image(
        (float(o[0]), float(o[1])), 2.0 * s.area_nm, s.overview_pixels, s.overview_line_rate_hz
    )
    found = find_particles(overview, trace="mean")  # the traces' hysteresis offsets cancel
    corner = np.full(2, -0.5 * s.size_nm)

    def image(center: NDArray[np.float64]) -> ScanImage:
        start = o + center + corner
        instrument.move_to(float(start[0]), float(start[1]), s.speed_nm_per_s)
        c = o + center
        return instrument.scan_image((float(c[0]), float(c[1])), s.size_nm, s.pixels,
                                     s.line_rate_hz)  # fmt: skip

    g = next(candidates(s, found.positions_nm - o), None)
    if g is None:
        raise ValueError(
            f"no pair of areas {s.d_nm:g} nm apart with {s.min_particles} particles each "
            f"was found among {MAX_CANDIDATES} candidates ({len(found)} particles in the "
            "overview): is the sample in the area?"
        )
    instrument.move_to(float(o[0]), float(o[1]), s.speed_nm_per_s)
    instrument.wait(s.settle_s)
    image(g.b_nm)  # the tip comes from B, as after a previous experiment
    shots: dict[str, ScanImage] = {}
    for tag, target, leg in zip(("A1", "B1", "A2", "B2"), (g.a_nm, g.b_nm, g.a_nm, g.b_nm),
                                g.legs, strict=True):  # fmt: skip
        for p in leg[:-1]:  # the last way point is the area's corner, where image() goes
            q = o + p
            instrument.move_to(float(q[0]), float(q[1]), s.speed_nm_per_s)
        shots[tag] = image(target)
    errors = {area: _measured(shots[f"{area}1"], shots[f"{area}2"]) for area in ("A", "B")}
    true = None
    if truth is not None:
        true = {
            area: true_displacement(truth, shots[f"{area}1"], shots[f"{area}2"])
            for area in ("A", "B")
        }
    return Table1Trial(s, g, errors, true, shots if s.keep_images else None)


def _measured(first: ScanImage, second: ScanImage) -> float:
    """Cross-correlation displacement; NaN where an image holds no particle (the match would
    follow the substrate's roughness) or nothing to register."""
    if len(find_particles(first)) == 0 or len(find_particles(second)) == 0:
        return float("nan")
    try:
        return image_displacement(first, second).magnitude_nm
    except ValueError:
        return float("nan")


# ---------------------------------------------------------------- in piezocomp reproduce
def plan(p: Plan) -> list[Trial]:
    """Every method's experiments at each speed and distance (the first at the paper's speed
    and the first distance keeps its images), and on a drifting scanner those at the paper's
    speed inside the drift compensator (:data:`DRIFT_MARGIN_NM` farther inside)."""
    trials = []
    for m in p.methods:
        for v in p.table1_speeds_nm_per_s:
            for d in p.distances_nm:
                for k in range(p.table1_experiments):
                    keep = v == p.paper_speed_nm_per_s and k == 0 and d == p.distances_nm[0]
                    st = Table1Settings(d_nm=d, speed_nm_per_s=v, experiment=k,
                                        area_nm=p.area_half_nm, keep_images=keep)  # fmt: skip
                    trials.append(Trial(NAME, m, st, keep))
    if p.drift_compensated:
        size = Table1Settings().size_nm
        for d in p.distances_nm:  # the margin, as far as the distance leaves room for it
            area = max(p.area_half_nm - DRIFT_MARGIN_NM, min(p.area_half_nm, 0.5 * d + size))
            for k in range(p.table1_experiments):
                st = Table1Settings(d_nm=d, speed_nm_per_s=p.paper_speed_nm_per_s,
                                    experiment=k, area_nm=area)  # fmt: skip
                trials.append(Trial(NAME, DRIFT_METHOD, st))
    return trials


def run_trial(trial: Trial, config: AFMConfig, seed: int, models: MethodModels) -> Table1Trial:
    """One experiment on a fresh virtual AFM, scored against its truth."""
    afm = VirtualAFM(config, seed=seed)
    st = trial.settings
    inst, origin = trial_instrument(trial.method, afm, models, 2.0 * st.area_nm)
    return run(inst, st, origin_nm=origin, truth=afm.truth)


def summarise(p: Plan, outcomes: list[Outcome]) -> dict[str, Any]:
    """``table1``: per speed and distance, each method's error (measured and true: mean,
    standard deviation and count over the experiments); ``table1_settings``."""
    ok = succeeded(outcomes, NAME)
    shown = shown_methods(p, outcomes)
    rows: list[Table1Row] = []
    for v in p.table1_speeds_nm_per_s:
        for d in p.distances_nm:
            sel = {m: [r for t, r in ok if t.method == m and r.settings.speed_nm_per_s == v
                       and r.settings.d_nm == d]
                   for m in shown}  # fmt: skip
            rows.append({
                "d_nm": d,
                "speed_nm_per_s": v,
                "methods": {
                    m: Table1Method(
                        max_error_nm=stats([r.max_error_nm for r in rs]),
                        true_max_error_nm=stats([r.true_max_error_nm for r in rs]),
                    )
                    for m, rs in sel.items()
                },
            })  # fmt: skip
    return {
        "table1": rows,
        "table1_settings": {
            "experiments": p.table1_experiments,
            "area_half_width_nm": p.area_half_nm,
            # the settings every experiment shares (its distance and speed are the rows')
            **{
                k: v
                for k, v in plain(asdict(Table1Settings(area_nm=p.area_half_nm))).items()
                if k not in ("d_nm", "speed_nm_per_s", "experiment")
            },
        },
    }
