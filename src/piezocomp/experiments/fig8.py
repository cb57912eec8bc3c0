"""Fig. 8 of the paper: forward and backward ramps over a line of particles.

A desired trajectory of one axis (x) runs forward and backward along a line that crosses
six particles: first one large cycle (it sets the compensator's initial conditions in the
paper), then ramps between turning points of varied extent on either side of the particles.
Applied directly, the traces of topography against the desired extension fall apart
(Fig. 8b); through the compensator they coincide (Fig. 8c). The figure here: where each
particle's peak lies on each ramp, and the spread of those positions over the ramps (nm),
measured on the topography as the paper shows it and, on a simulator, true: the spread of
the true tip positions each time a ramp's desired extension crossed the particle's
position.

The line is chosen in an overview image of the experiment's area: the row through the most particles
(:func:`~piezocomp.imaging.features.particles_near_line`), of which the six nearest the origin are
followed (all of them if the best line has fewer, at least ``min_particles``); each ramp's peaks are
paired with them (:func:`~piezocomp.identification.acquisition.peaks.pair_peaks`). A particle whose
peak is missing or ambiguous on a ramp (an uncompensated tip may leave the line, or its traces shift
by more than the particles' spacing) has no measured position there; its spread is then over the
ramps that saw it."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar
from piezocomp.experiments.contract import Outcome, Plan, Trial, finite_or_none, succeeded
from piezocomp.experiments.methods import MethodModels, instrument_for
from piezocomp.experiments.results import Fig8, Fig8Method
from piezocomp.experiments.truth import Truth
from piezocomp.identification.acquisition.peaks import find_peaks, pair_peaks
from piezocomp.imaging.features import find_particles, particles_near_line
from piezocomp.instrument import Instrument
from piezocomp.virtual_afm import AFMConfig, VirtualAFM

__all__ = [
    "NAME",
    "Fig8Result",
    "Fig8Settings",
    "plan",
    "run",
    "run_trial",
    "summarise",
]

NAME = "fig8"

LINE_TOLERANCE_NM = 8.0
"""A particle counts on a line passing this close to its apex (its peak still shows at the
apex's position along the line)."""

MATCH_SHIFT_NM = 150.0
"""Largest shift between a ramp's peaks and the overview's particles that may still pair."""


@dataclass(frozen=True)
class Fig8Settings:
    """The experiment of Fig. 8.

    Parameters
    ----------
    speed_nm_per_s : float
        Ramp speed.
    half_length_nm : float
        The ramps stay within ``+-half_length_nm`` of the origin along x.
    n_ramps : int
        Ramps after the initial cycles (alternately forward and backward).
    initial_cycles : int
        Large cycles over the whole line before the ramps: the first sets the compensator's
        initial conditions, as in the paper; the others let the slow axis settle on the
        line.
    n_particles : int
        Particles followed (the paper's six): the line's nearest the origin, or all of them
        if it has fewer.
    min_particles : int
        The fewest particles a line may have.
    overview_pixels, overview_line_rate_hz
        The overview image (``2 half_length_nm`` wide) in which the line is chosen.
    seed : int
        Seed of the turning points.
    min_prominence_nm : float
        Smallest peak of a particle on a ramp.
    sample_step_nm : float
        Largest step of the desired extension between two samples: the ramps are sampled
        at ``min(T, sample_step_nm / speed)`` so that a particle's peak spans enough
        samples to be located to a fraction of a nanometre.
    """

    speed_nm_per_s: float = 1000.0
    half_length_nm: float = 600.0
    n_ramps: int = 8
    initial_cycles: int = 3
    n_particles: int = 6
    min_particles: int = 4
    overview_pixels: int = 192
    overview_line_rate_hz: float = 0.5
    seed: int = 0
    min_prominence_nm: float = 3.0
    sample_step_nm: float = 2.0

    def __post_init__(self) -> None:
        for name in ("speed_nm_per_s", "half_length_nm", "overview_line_rate_hz",
                     "min_prominence_nm", "sample_step_nm"):  # fmt: skip
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        for name, low in (("n_ramps", 2), ("initial_cycles", 1), ("n_particles", 1),
                          ("min_particles", 1), ("overview_pixels", 16), ("seed", 0)):  # fmt: skip
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"{name} must be an integer >= {low}. Got {v!r}.")


@dataclass(frozen=True)
class Fig8Result:
    """Peaks of the particles on every ramp.

    Attributes
    ----------
    settings : Fig8Settings
    line_nm : float
        y of the line, relative to the origin.
    particles_nm : ndarray, shape (k,)
        The followed particles' x on the first ramp, relative to the origin.
    ramps_x_nm, ramps_height_nm : tuple of ndarray
        Desired x (relative to the origin) and topography of each ramp.
    peaks_nm : ndarray, shape (n_ramps, k)
        Each particle's peak on each ramp (desired x; NaN where not found).
    true_positions_nm : ndarray, shape (n_ramps, k), or None
        Where the tip truly was (x, sample frame) each time a ramp's desired x crossed a
        followed particle's position.
    """

    settings: Fig8Settings
    line_nm: float
    particles_nm: NDArray[np.float64]
    ramps_x_nm: tuple[NDArray[np.float64], ...] = field(repr=False)
    ramps_height_nm: tuple[NDArray[np.float64], ...] = field(repr=False)
    peaks_nm: NDArray[np.float64] = field(repr=False)
    true_positions_nm: NDArray[np.float64] | None = field(default=None, repr=False)

    @property
    def spread_nm(self) -> NDArray[np.float64]:
        """Per particle: the spread (max - min) of its peak over the ramps that saw it, nm
        (NaN if fewer than half of them did)."""
        return _spread(self.peaks_nm)

    @property
    def measured_spread_nm(self) -> float:
        """The largest spread over the particles whose peak was seen on at least half the
        ramps, when they are at least half the particles; else NaN (the tip lost most of
        them: a spread over the few left would flatter it)."""
        spread = self.spread_nm
        ok = np.isfinite(spread)
        if not ok.any() or 2 * int(ok.sum()) < spread.size:
            return float("nan")
        return float(np.max(spread[ok]))

    @property
    def true_spread_nm(self) -> NDArray[np.float64] | None:
        """Per particle: the spread of the true tip positions at its desired position over
        the ramps, nm."""
        return None if self.true_positions_nm is None else _spread(self.true_positions_nm)

    @property
    def seen(self) -> NDArray[np.intp]:
        """Per particle: on how many ramps its peak was found."""
        return np.asarray(np.isfinite(self.peaks_nm).sum(axis=0))


def _spread(peaks: NDArray[np.float64]) -> NDArray[np.float64]:
    n = np.isfinite(peaks).sum(axis=0)
    filled = np.where(np.isfinite(peaks), peaks, np.nan)
    with np.errstate(all="ignore"):
        hi = np.nanmax(np.where(n >= 2, filled, 0.0), axis=0, initial=-np.inf)
        lo = np.nanmin(np.where(n >= 2, filled, 0.0), axis=0, initial=np.inf)
    return np.where(2 * n >= peaks.shape[0], hi - lo, np.nan)


def run(
    instrument: Instrument,
    settings: Fig8Settings,
    *,
    origin_nm: tuple[float, float] = (0.0, 0.0),
    truth: Truth | None = None,
) -> Fig8Result:
    """Run Fig. 8's experiment on ``instrument`` (raw or compensated), coordinates relative
    to ``origin_nm``.

    Raises
    ------
    ValueError
        If no line in the overview crosses ``n_particles`` particles.
    """
    s = settings
    o = np.asarray(origin_nm, dtype=float)
    L = s.half_length_nm
    overview = instrument.scan_image((float(o[0]), float(o[1])), 2.0 * L, s.overview_pixels,
                                     s.overview_line_rate_hz)  # fmt: skip
    found = find_particles(overview, trace="mean")
    margin = 0.15 * L
    line, along = particles_near_line(
        found, axis="x", extent_nm=(o[0] - L + margin, o[0] + L - margin),
        tolerance_nm=max(LINE_TOLERANCE_NM, 0.75 * overview.pixel_nm),
    )  # fmt: skip
    if along.size < s.min_particles:
        raise ValueError(
            f"no line of the overview crosses {s.min_particles} particles within "
            f"+-{L - margin:g} nm (at most {along.size}): lengthen the line or lower "
            "min_particles."
        )
    chosen = np.sort(along[np.argsort(np.abs(along - o[0]))[: s.n_particles]])
    lo_p, hi_p = chosen[0] - o[0], chosen[-1] - o[0]
    rng = np.random.default_rng(s.seed)
    right = rng.uniform(hi_p + 0.5 * (L - hi_p), L, s.n_ramps)
    left = rng.uniform(-L, lo_p - 0.5 * (lo_p + L), s.n_ramps)
    turns = [right[i // 2] if i % 2 == 0 else left[i // 2] for i in range(s.n_ramps)]
    T = min(float(instrument.sample_period_s), s.sample_step_nm / s.speed_nm_per_s)
    step = s.speed_nm_per_s * T
    # to the line's left end, the large cycles, then the ramps (turning points alternate)
    instrument.move_to(float(o[0] - L), line, s.speed_nm_per_s)
    path = [-L, *([L, -L] * s.initial_cycles), *turns]
    pieces, bounds = [], []
    n0 = 0
    for a, b in itertools.pairwise(path):
        n = max(2, int(np.ceil(abs(b - a) / step)))
        seg = np.linspace(a, b, n + 1)[1:]
        pieces.append(seg)
        bounds.append((n0, n0 + n))
        n0 += n
    x = np.concatenate(pieces)
    rec = instrument.run(np.column_stack([o[0] + x, np.full(x.size, line)]), sample_period_s=T)
    ramp_idx = bounds[2 * s.initial_cycles :]
    xs = tuple(x[a:b] for a, b in ramp_idx)
    hs = tuple(np.asarray(rec.height_nm[a:b]) for a, b in ramp_idx)
    ref = chosen - o[0]
    peaks = np.full((len(xs), ref.size), np.nan)
    for i, (xr, hr) in enumerate(zip(xs, hs, strict=True)):
        pk = find_peaks(xr, hr, min_prominence_nm=s.min_prominence_nm).position_nm
        if pk.size:
            ir, ip = pair_peaks(ref, pk, max_shift_nm=MATCH_SHIFT_NM)
            peaks[i, ir] = pk[ip]
    true_pos = None if truth is None else _true_positions(truth, rec.t_s, x, ramp_idx, ref)
    return Fig8Result(s, line - float(o[1]), ref, xs, hs, peaks, true_pos)


def _true_positions(
    truth: Truth,
    t_s: NDArray[np.float64],
    x: NDArray[np.float64],
    ramp_idx: list[tuple[int, int]],
    ref: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Per ramp, the true tip x (sample frame) when the desired x is at each followed
    particle's position: the same desired extension should always be the same place."""
    true_x = truth.positions_at(t_s)[:, 0]
    out = np.full((len(ramp_idx), ref.size), np.nan)
    for i, (a, b) in enumerate(ramp_idx):
        xr, tr = x[a:b], true_x[a:b]
        o = np.argsort(xr)
        out[i] = np.interp(ref, xr[o], tr[o], left=np.nan, right=np.nan)
    return out


# ---------------------------------------------------------------- in piezocomp reproduce
def plan(p: Plan) -> list[Trial]:
    """One run per method at the paper's speed."""
    st = Fig8Settings(speed_nm_per_s=p.paper_speed_nm_per_s)
    return [Trial(NAME, m, st, True) for m in p.methods]


def run_trial(trial: Trial, config: AFMConfig, seed: int, models: MethodModels) -> Fig8Result:
    """The ramps on a fresh virtual AFM, scored against its truth."""
    afm = VirtualAFM(config, seed=seed)
    inst, origin = instrument_for(trial.method, afm, models)
    return run(inst, trial.settings, origin_nm=origin, truth=afm.truth)


def summarise(p: Plan, outcomes: list[Outcome]) -> dict[str, Any]:
    """``fig8``: each method's spread of the peaks over the ramps (largest and per
    particle, measured and true), and how many ramps saw each particle."""
    f8: dict[str, Fig8Method] = {}
    for t, r in succeeded(outcomes, NAME):
        spread, true = r.spread_nm, r.true_spread_nm
        f8[t.method] = {
            "spread_nm": finite_or_none(r.measured_spread_nm),
            "particles_measured": int(np.isfinite(spread).sum()),
            "true_spread_nm": finite_or_none(np.nanmax(true))
            if np.any(np.isfinite(true))
            else None,
            "per_particle_nm": [finite_or_none(v) for v in spread],
            "true_per_particle_nm": [finite_or_none(v) for v in true],
            "ramps_seeing_each_particle": [int(v) for v in r.seen],
            "ramps": int(r.peaks_nm.shape[0]),
        }
    section: Fig8 = {"speed_nm_per_s": p.paper_speed_nm_per_s, "methods": f8}
    return {"fig8": section}
