"""Fig. 10 of the paper: ten particles pushed into two five-particle QCA cells, automatically.

Particles scattered over the area are found in one image, assigned to the ten sites of
two quantum-cellular-automaton cells (each four corners of a square and its centre, after
Lent et al. 1993) and pushed there with no image in between, in the order that makes the
tip travel farthest between pushes (to provoke creep and hysteresis); the whole is done
twice, coarse then fine (:func:`~piezocomp.positioning.assembly.assemble`). Each image also
checks the pushes before it: a push that failed (the particle did not move, went off target
or vanished) is recovered in a further pass, with the same particle or another. Success:
every site holds a particle within ``success_nm`` (3 nm), by the last image as the paper
would judge it and, on a simulator, true; an assembly whose failed pushes left a site empty
or its particle farther is a failure.

The sample is the experiment's own: ``n_particles`` particles (the ten and two spares, as a
real sample has more particles than sites) placed at random (:func:`sample_particles`) in two
bands above and below the cells, so that the cells' sites are free; the scanner is the
instrument's. On a drifting instrument the assembly can run
inside the drift compensator (:func:`with_drift_compensation`), whose landmarks are
particles outside the area worked in (:func:`landmark_particles`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar
from piezocomp.drift.compensated import DriftCompensatedInstrument, DriftSettings
from piezocomp.experiments.contract import (
    DRIFT_METHOD,
    Outcome,
    Plan,
    Trial,
    finite_or_none,
    stats,
    succeeded,
)
from piezocomp.experiments.methods import MethodModels, instrument_for
from piezocomp.experiments.results import (
    AssemblyOutcome,
    Fig10,
    Fig10Drift,
    Fig10Method,
    PushSummary,
)
from piezocomp.experiments.truth import Truth
from piezocomp.instrument import Instrument
from piezocomp.positioning.assembly import AssemblyResult, AssemblySettings, assemble, match_targets
from piezocomp.positioning.push_check import FAILURES
from piezocomp.virtual_afm import AFMConfig, VirtualAFM

__all__ = [
    "NAME",
    "Fig10Result",
    "Fig10Settings",
    "Fig10Trial",
    "assemblies",
    "failure_summary",
    "landmark_particles",
    "outcome_text",
    "plan",
    "qca_sites",
    "run",
    "run_trial",
    "sample_particles",
    "summarise",
    "with_drift_compensation",
]

NAME = "fig10"

LANDMARK_MARGIN_NM = 150.0
"""Landmark particles lie this far outside the area worked in (beyond the push paths)."""


@dataclass(frozen=True)
class Fig10Settings:
    """The experiment of Fig. 10.

    Parameters
    ----------
    area_nm : float
        Side of the square area imaged and worked in.
    separation_nm : float
        Distance between the two cells' centres (along x).
    cell_half_nm : float
        Half the side of a cell's square (corner to centre: ``sqrt(2)`` times it).
    n_particles : int
        Particles of the sample (at least the 10 sites; more leave spares to replace a
        particle that a failed push lost or that will not move).
    band_nm : (float, float)
        The sample's particles lie at ``lo <= |y| <= hi`` from the area's centre, and
        within ``hi`` of it along x.
    min_spacing_nm : float
        Smallest distance between two of the sample's particles.
    success_nm : float
        A particle within this of its site is placed.
    assembly : AssemblySettings
    """

    area_nm: float = 900.0
    separation_nm: float = 300.0
    cell_half_nm: float = 25.0
    n_particles: int = 12
    band_nm: tuple[float, float] = (120.0, 380.0)
    min_spacing_nm: float = 60.0
    success_nm: float = 3.0
    assembly: AssemblySettings = field(default_factory=AssemblySettings)

    def __post_init__(self) -> None:
        for name in ("area_nm", "separation_nm", "cell_half_nm", "min_spacing_nm",
                     "success_nm"):  # fmt: skip
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        lo, hi = (check_finite_scalar("band_nm", v) for v in self.band_nm)
        if not 0 <= lo < hi <= 0.5 * self.area_nm:
            raise ValueError(
                f"band_nm must satisfy 0 <= lo < hi <= area_nm / 2. Got {self.band_nm}."
            )
        if (
            isinstance(self.n_particles, bool)
            or not isinstance(self.n_particles, int)
            or (self.n_particles < 10)
        ):
            raise ValueError(f"n_particles must be an integer >= 10. Got {self.n_particles!r}.")


@dataclass(frozen=True)
class Fig10Result:
    """One assembly.

    Attributes
    ----------
    settings : Fig10Settings
    sites_nm : ndarray, shape (10, 2)
        The targets, instrument frame.
    assembly : AssemblyResult
        What was done, and the errors by the last image (:attr:`AssemblyResult.errors_nm`).
    true_errors_nm : ndarray, shape (10,), or None
        True distance of each site's particle from it (the frames aligned by the offset
        between the first image's particles and the true ones).
    true_push_counts : dict of str to int, or None
        What the simulator's pushing did (engagements, stuck, rolled off, picked up,
        dropped, lost), when the caller read it from its ground truth: for scoring the
        planner's detection, never seen by it.
    """

    settings: Fig10Settings
    sites_nm: NDArray[np.float64]
    assembly: AssemblyResult = field(repr=False)
    true_errors_nm: NDArray[np.float64] | None = None
    true_push_counts: dict[str, int] | None = None

    @property
    def max_error_nm(self) -> float:
        """Largest distance of a particle from its site by the last image (NaN: a site
        without a particle)."""
        return self.assembly.max_error_nm

    @property
    def success(self) -> bool:
        """Every site holds its particle within ``success_nm``, by the last image."""
        return bool(self.max_error_nm <= self.settings.success_nm)

    @property
    def unrecovered(self) -> int:
        """Failed pushes whose site did not end with a particle within ``success_nm`` (by the
        last image)."""
        err = self.assembly.errors_nm
        ok = np.isfinite(err) & (err <= self.settings.success_nm)
        return sum(not ok[c.target] for c in self.assembly.failed_pushes)

    @property
    def blocked(self) -> int:
        """Sites the last pass could not plan a push to, for want of a clear path
        (:attr:`~piezocomp.positioning.assembly.PassResult.blocked`)."""
        return len(self.assembly.passes[-1].blocked) if self.assembly.passes else 0

    @property
    def true_max_error_nm(self) -> float | None:
        """The largest true error."""
        return None if self.true_errors_nm is None else float(np.max(self.true_errors_nm))

    @property
    def true_success(self) -> bool | None:
        """Every particle truly within ``success_nm`` of its site."""
        t = self.true_max_error_nm
        return None if t is None else bool(t <= self.settings.success_nm)


def qca_sites(
    center_nm: tuple[float, float], separation_nm: float, half_nm: float
) -> NDArray[np.float64]:
    """The ten sites of two five-dot QCA cells (corners and centre of a square of side
    ``2 half_nm``) whose centres lie ``separation_nm`` apart along x about ``center_nm``."""
    unit = np.array([[0.0, 0.0], [-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    cells = []
    for side in (-0.5, 0.5):
        c = np.asarray(center_nm, dtype=float) + np.array([side * separation_nm, 0.0])
        cells.append(c + half_nm * unit)
    return np.vstack(cells)


def sample_particles(settings: Fig10Settings, seed: int) -> NDArray[np.float64]:
    """The experiment's sample: ``(x, y, diameter)`` of ``n_particles`` particles, sample
    frame, in the bands of ``band_nm`` about 0, at least ``min_spacing_nm`` apart (15 +- 1 nm
    diameters)."""
    s = settings
    rng = np.random.default_rng([10, seed])
    lo, hi = s.band_nm
    out: list[NDArray[np.float64]] = []
    for _ in range(100000):
        if len(out) == s.n_particles:
            break
        p = np.array([rng.uniform(-hi, hi), rng.choice([-1, 1]) * rng.uniform(lo, hi)])
        if all(np.hypot(*(p - q)) >= s.min_spacing_nm for q in out):
            out.append(p)
    else:  # pragma: no cover - the bands hold far more than the default count
        raise ValueError("the bands cannot hold n_particles particles min_spacing_nm apart.")
    d = 15.0 + rng.normal(0.0, 1.0, s.n_particles)
    return np.column_stack([np.array(out), d])


def landmark_particles(settings: Fig10Settings) -> NDArray[np.float64]:
    """``(x, y, diameter)`` of four particles that no assembly moves: one beyond each corner
    of the area, :data:`LANDMARK_MARGIN_NM` outside it (the drift compensator's landmarks)."""
    r = 0.5 * settings.area_nm + LANDMARK_MARGIN_NM
    xy = np.array([[-r, -r], [r, -r], [r, r], [-r, r]])
    return np.column_stack([xy, np.full(4, 15.0)])


def with_drift_compensation(
    inner: Instrument, settings: Fig10Settings, origin_nm: tuple[float, float]
) -> DriftCompensatedInstrument:
    """``inner`` inside the drift compensator, tracking landmarks outside the area worked in:
    an overview reaching :data:`LANDMARK_MARGIN_NM` beyond the area, every point of the area
    avoided."""
    half = 0.5 * settings.area_nm
    g = np.arange(-half, half + 1e-9, 50.0)
    area = np.array([[x, y] for x in g for y in g]) + np.asarray(origin_nm)
    tracked = DriftCompensatedInstrument(inner, DriftSettings())
    tracked.start(center_nm=origin_nm, size_nm=settings.area_nm + 4 * LANDMARK_MARGIN_NM,
                  avoid_nm=area, avoid_radius_nm=60.0)  # fmt: skip
    return tracked


def run(
    instrument: Instrument,
    settings: Fig10Settings,
    *,
    origin_nm: tuple[float, float] = (0.0, 0.0),
    truth: Truth | None = None,
) -> Fig10Result:
    """Assemble the two cells about ``origin_nm`` on ``instrument`` (raw or compensated)."""
    s = settings
    sites = qca_sites(origin_nm, s.separation_nm, s.cell_half_nm)
    before = None if truth is None else np.array(truth.particles().xy_nm)
    result = assemble(
        instrument, sites, center_nm=origin_nm, size_nm=s.area_nm, settings=s.assembly
    )
    true_errors = None
    if truth is not None and before is not None:
        offset = _frame_offset(result.passes[0].found.positions_nm, before)
        after = np.array(truth.particles().xy_nm)
        idx = match_targets(after, sites + offset)
        true_errors = np.full(sites.shape[0], np.inf)
        ok = idx >= 0
        true_errors[ok] = np.hypot(*(after[idx[ok]] - (sites[ok] + offset)).T)
    return Fig10Result(s, sites, result, true_errors)


def failure_summary(results: list[Fig10Result]) -> PushSummary:
    """Over assemblies: the failed pushes their images found, by kind; what the planner did
    about them; how many were not recovered (their site not within ``success_nm`` at the
    end); the passes made; and, when known, what the simulator's pushing truly did."""
    asm = [r.assembly for r in results]
    true = [r.true_push_counts for r in results if r.true_push_counts is not None]
    return {
        "failed_pushes": {k: sum(a.failures[k] for a in asm) for k in FAILURES},
        "recoveries": {k: sum(a.recoveries[k] for a in asm) for k in asm[0].recoveries}
        if asm else {},
        "unrecovered": sum(r.unrecovered for r in results),
        "passes": [len(a.passes) for a in asm],
        "true_push_counts": {k: sum(t[k] for t in true) for k in true[0]} if true else None,
    }  # fmt: skip


def _frame_offset(found: NDArray[np.float64], true: NDArray[np.float64]) -> NDArray[np.float64]:
    """Offset from the instrument's frame to the sample's: the mean of ``true - found`` over
    the particles the first image showed, matched one to one (after centring both sets)."""
    shift = true.mean(axis=0) - found.mean(axis=0)
    idx = match_targets(true, found + shift)
    ok = idx >= 0
    return np.asarray((true[idx[ok]] - found[ok]).mean(axis=0))


# ---------------------------------------------------------------- in piezocomp reproduce
@dataclass(frozen=True)
class Fig10Trial:
    """One assembly: the experiment's settings and the seed of its sample's particles."""

    settings: Fig10Settings
    sample: int


def plan(p: Plan) -> list[Trial]:
    """``fig10_trials`` assemblies per method (each keeps its first and last image, for the
    report's figure), and on a drifting scanner as many inside the drift compensator."""
    methods = (*p.methods, DRIFT_METHOD) if p.drift_compensated else p.methods
    return [
        Trial(NAME, m, Fig10Trial(Fig10Settings(), k), True)
        for m in methods
        for k in range(p.fig10_trials)
    ]


def run_trial(trial: Trial, config: AFMConfig, seed: int, models: MethodModels) -> Fig10Result:
    """One assembly on a fresh virtual AFM whose particles are the trial's sample (with
    landmarks outside the area on a drifting scanner, for every method alike), scored
    against its truth; what the simulator's pushing truly did is kept."""
    st, k = trial.settings.settings, trial.settings.sample
    sample = sample_particles(st, k)
    if config.drifts:
        sample = np.vstack([sample, landmark_particles(st)])
    afm = VirtualAFM(config, seed=seed, particles=sample)
    drift = trial.method == DRIFT_METHOD
    inst, origin = instrument_for("compensated" if drift else trial.method, afm, models)
    if drift:
        inst = with_drift_compensation(inst, st, origin)
    out = run(inst, st, origin_nm=origin, truth=afm.truth)
    out = replace(out, true_push_counts=asdict(afm.truth.push_state.counts))
    images = out.assembly.images  # heavy: the first and the last, for the report's figure
    kept = (images[0], images[-1]) if trial.keep and images else ()
    return replace(out, assembly=replace(out.assembly, images=kept))


def assemblies(outcomes: list[Any]) -> list[AssemblyOutcome]:
    """Each assembly of one method in trial order (results or error texts): truly
    succeeded or not, and its worst site's true error (``None``: a particle lost, or the
    assembly stopped by an error, which is then given); placed or not by its last image,
    the worst site's error there, its failed pushes left unrecovered and the sites its last
    pass found no clear path to."""
    out: list[AssemblyOutcome] = []
    for r in outcomes:
        if isinstance(r, str):
            out.append({"true_success": False, "true_max_error_nm": None, "error": r})
        else:
            out.append({"true_success": bool(r.true_success),
                        "true_max_error_nm": finite_or_none(r.true_max_error_nm),
                        "success": r.success, "max_error_nm": finite_or_none(r.max_error_nm),
                        "unrecovered": r.unrecovered, "blocked": r.blocked})  # fmt: skip
    return out


def outcome_text(r: Fig10Method) -> str:
    """A method's assemblies in words, as the console and the report give them: how many of
    how many truly succeeded, the worst site of the failed ones and how many of those their
    last image judged placed (the instrument's error, not a push, failed them), from its
    ``assemblies``; the rate alone for a ``results.json`` without them."""
    runs = r.get("assemblies")
    if runs is None:
        return f"{100 * r['true_success_rate']:.0f} % truly succeeded"
    ok = sum(a["true_success"] for a in runs)
    text = f"{ok} of {len(runs)} truly succeeded ({100 * ok / max(len(runs), 1):.0f} %)"
    failed = [a for a in runs if not a["true_success"]]
    if not failed:
        return text
    stopped = sum("error" in a for a in failed)
    errs = [a["true_max_error_nm"] for a in failed if "error" not in a]
    parts = []
    if any(e is None for e in errs):
        parts.append("a particle lost")
    if finite := [e for e in errs if e is not None]:
        parts.append(f"worst site truly {max(finite):.2f} nm off")
    if stopped:
        parts.append(f"{stopped} stopped by an error")
    if unseen := sum(bool(a.get("success")) for a in failed):
        parts.append(f"{unseen} placed by its last image")
    if blocked := sum(a.get("blocked", 0) for a in failed):
        parts.append(f"{blocked} site{'s' * (blocked > 1)} no clear push could reach")
    return f"{text}; of the {len(failed)} failed: " + ", ".join(parts)


def summarise(p: Plan, outcomes: list[Outcome]) -> dict[str, Any]:
    """``fig10``: each method's share of assemblies that succeeded (judged by its images and
    truly), errors, pushes and failures; on a drifting scanner ``fig10_drift``, the
    assemblies inside the drift compensator against the compensated ones outside it."""
    ok = succeeded(outcomes, NAME)
    f10: dict[str, Fig10Method] = {}
    for m in p.methods:
        rs = [r for t, r in ok if t.method == m]
        mine = [r for t, r in outcomes if t.experiment == NAME and t.method == m]
        if rs:
            pushes = failure_summary(rs)
            f10[m] = {
                "success_rate": float(np.mean([r.success for r in rs])),
                "true_success_rate": float(np.mean([bool(r.true_success) for r in rs])),
                "max_error_nm": stats([r.max_error_nm for r in rs]),
                "true_max_error_nm": stats([r.true_max_error_nm for r in rs]),
                "pushes": stats([r.assembly.n_pushes for r in rs]),
                **pushes,
                "assemblies": assemblies(mine),
            }
    section: Fig10 = {
        "trials": p.fig10_trials,
        "success_nm": Fig10Settings().success_nm,
        "methods": f10,
    }
    out: dict[str, Any] = {"fig10": section}
    if p.drifts:
        both = [r for t, r in outcomes if t.experiment == NAME and t.method == DRIFT_METHOD]
        done = [r for r in both if not isinstance(r, str)]  # the rest stopped with an error
        inside: Fig10Drift = {
            "trials": len(both),
            "methods": {
                "compensated": f10.get("compensated"),
                "both": None if not both else {
                    "success_rate": sum(r.success for r in done) / len(both),
                    "true_success_rate": sum(bool(r.true_success) for r in done) / len(both),
                    "max_error_nm": stats([r.max_error_nm for r in done]),
                    "true_max_error_nm": stats([r.true_max_error_nm for r in done]),
                    "pushes": stats([r.assembly.n_pushes for r in done]),
                    **failure_summary(done),
                    "stopped": len(both) - len(done),
                    "assemblies": assemblies(both),
                },
            },
        }  # fmt: skip
        out["fig10_drift"] = inside
    return out
