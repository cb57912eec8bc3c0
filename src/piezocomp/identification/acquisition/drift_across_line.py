"""The sample's drift across the identification line, measured while the tip settles on it,
as a steady drift plus the slow axis' creep since its last large move.

The record reads one line's heights ``h(y)``. When the sample drifts across that line (or
the slow axis still creeps from the moves before), the line slides over the particles' caps
and their peaks rise or fall for a reason no model of the fast axis can explain: the
estimation takes the change for model error, and the held-out heights refuse a model that
is fine. One line cannot tell which way it slides (a cap falls the same way on either side
of its top), so the settling cycles are run with the slow command stepped back by
``dither_nm`` on every other cycle: each particle's height then changes with the step by its
cap's slope, which gives the side.

For one particle, the forward trace's peak height is ``f(s - slide(t))``: ``s`` the cycle's
slow command offset, ``slide`` how far the slow command would have had to move to stay on the
same profile (:class:`CrossDrift`), ``f`` the particle's cross profile (a cubic over the few
nanometres travelled). The slide is common to every particle; for each trial slide the
profiles are linear least squares, and the slide is the one that leaves the smallest residual
(:func:`cross_line_drift`). The record, its check and the calibration cycles are then run
with the slow command following it
(:func:`~piezocomp.identification.acquisition.following.run_following`).

Only :class:`~piezocomp.instrument.Record` data are used: this runs on any instrument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize
from numpy.typing import NDArray

from piezocomp.identification.acquisition.peaks import find_peaks

__all__ = ["FOLLOW_NM", "CrossDrift", "cross_line_drift", "dither_offsets", "unfollowed_reason"]

DITHER_NM = 3.0
"""Default step of the slow command on every other settling cycle (nm): a cap of a 10 nm
particle under a 10 nm tip changes its peak height by a few tenths of a nanometre over it,
several times the height noise, while the slow axis' own creep from a step this small is a
fraction of a nanometre."""

MAX_RATE_NM_PER_S = 0.5
"""Rates searched (slow command nm/s, either way): five times the drift of an AFM warming
up."""

MATCH_NM = 10.0
"""A peak is the same particle as the reference cycle's within this distance along the
line."""


@dataclass(frozen=True)
class CrossDrift:
    """The line's slide across the particles, measured on a dithered settling record.

    The slide is ``v (t - t0) + c ln((t - t_a) / (t0 - t_a))``: the sample's drift (steady
    over minutes) plus the slow axis' creep after its last large move at ``t_a`` (the
    logarithmic creep of a piezo after a step, e.g. Jung & Gweon 2000), in slow command.

    Attributes
    ----------
    rate_nm_per_s : float
        The slide's rate at the end of the record that measured it (slow command nm/s).
    drift_nm_per_s : float
        ``v``: its steady part.
    creep_nm : float
        ``c``: its logarithmic part (0 when ``t_a`` is unknown or the heights do not ask
        for it).
    since_s, t0_s, end_s : float
        ``t_a`` (NaN when unknown), ``t0`` and the end of the measuring window (s).
    followed : bool
        Whether a record's slow command followed the slide (set by the acquisition).
    record_slide_nm : float or None
        How far the slide would move the line over the record that follows (set with
        ``followed``).
    particles : int
        Particles followed over the measuring window.
    residual_nm : float
        RMS of the peak heights about their fitted profiles at ``rate_nm_per_s`` (nm).
    still_residual_nm : float
        The same with the rate held at zero (nm): how much the heights changed.
    window_s : float
        Length of the measuring window (the second half of the settling record), s.
    """

    rate_nm_per_s: float
    particles: int
    residual_nm: float
    still_residual_nm: float
    window_s: float
    drift_nm_per_s: float = 0.0
    creep_nm: float = 0.0
    since_s: float = float("nan")
    t0_s: float = 0.0
    end_s: float = 0.0
    followed: bool = False
    record_slide_nm: float | None = None

    def slide_nm(self, t_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """The slide at session times ``t_s`` (slow command nm, 0 at ``t0``)."""
        t = np.asarray(t_s, float)
        out = self.drift_nm_per_s * (t - self.t0_s)
        if self.creep_nm != 0.0:
            out = out + self.creep_nm * np.log((t - self.since_s) / (self.t0_s - self.since_s))
        return np.asarray(out, float)

    def moved_nm(self, start_s: float, duration_s: float) -> float:
        """How far the line would slide over ``duration_s`` from ``start_s`` (nm)."""
        return float(self.slide_nm(start_s + duration_s) - self.slide_nm(start_s))

    def significant(self, start_s: float, record_s: float) -> bool:
        """Whether the line would slide by more than :data:`FOLLOW_NM` over a record of
        ``record_s`` from ``start_s`` and the slide explains the heights
        (:func:`unfollowed_reason` gives none)."""
        summary = {**self.summary(), "record_slide_nm": self.moved_nm(start_s, record_s)}
        return not unfollowed_reason(summary)

    def summary(self) -> dict[str, float | int | bool | None]:
        """Plain numbers for a summary file."""
        return {
            "rate_nm_per_s": self.rate_nm_per_s,
            "drift_nm_per_s": self.drift_nm_per_s,
            "creep_nm": self.creep_nm,
            "particles": self.particles,
            "residual_nm": self.residual_nm,
            "still_residual_nm": self.still_residual_nm,
            "window_s": self.window_s,
            "followed": self.followed,
            "record_slide_nm": self.record_slide_nm,
        }


FOLLOW_NM = 1.0
"""A record's slow command follows the line's slide when it would move the line by more than
this over the record (nm)."""


def unfollowed_reason(summary: dict[str, Any]) -> str:
    """Why a slide (:meth:`CrossDrift.summary`, with ``record_slide_nm``) is not followed:
    fewer than 3 particles followed, a slide of :data:`FOLLOW_NM` or less over the record, or
    a slide that does not explain the heights (does not halve their residual); ``""`` when it
    is to be followed."""
    n = summary.get("particles", 0)
    if n < 3:
        return f"only {n} particles measured it"
    slide = summary.get("record_slide_nm")
    if slide is None or not abs(slide) > FOLLOW_NM:
        return f"{FOLLOW_NM:g} nm or less over the record"
    if not summary.get("residual_nm", math.inf) < 0.5 * summary.get("still_residual_nm", 0.0):
        return "it does not explain how the heights changed"
    return ""


def dither_offsets(n_cycles: int, dither_nm: float) -> NDArray[np.float64]:
    """Slow command offset of each settling cycle: ``-dither_nm`` on even cycles, 0 on odd
    ones and on the last (so that the slow axis reaches the line from below, as in the line
    search)."""
    s = np.where(np.arange(n_cycles) % 2 == 0, -float(dither_nm), 0.0)
    if n_cycles:
        s[-1] = 0.0
    return s


def _tracks(
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    t_s: NDArray[np.float64],
    offsets_nm: NDArray[np.float64],
    cycle_samples: int,
    min_prominence_nm: float,
) -> list[NDArray[np.float64]]:
    """Each particle's (t, s, height) over the second half of the record's cycles, followed
    by its position along the line (the along-line slide is followed cycle to cycle)."""
    m = cycle_samples // 2
    n_cycles = offsets_nm.size
    rows = []
    for c in range(n_cycles // 2, n_cycles):
        sl = slice(c * cycle_samples, c * cycle_samples + m + 1)
        z = height_nm[sl] - np.median(height_nm[sl])  # the substrate's level (Z drift)
        p = find_peaks(u_nm[sl], z, min_prominence_nm=min_prominence_nm)
        rows.append((float(np.mean(t_s[sl])), float(offsets_nm[c]), p))
    if not rows or not len(rows[0][2]):
        return []
    where = np.array(rows[0][2].position_nm, float)
    out: list[list[tuple[float, float, float]]] = [[] for _ in range(where.size)]
    for t, s, p in rows:
        if not len(p):
            continue
        moved = []
        for i, q in enumerate(where):
            j = int(np.argmin(np.abs(p.position_nm - q)))
            if abs(p.position_nm[j] - q) < MATCH_NM:
                out[i].append((t, s, float(p.height_nm[j])))
                moved.append(p.position_nm[j] - q)
        if moved:  # the particles slide along the line together
            where = where + float(np.median(moved))
    return [np.array(tr) for tr in out if len(tr) >= max(8, len(rows) // 2)]


def _residual(
    params: NDArray[np.float64], tracks: list[NDArray[np.float64]], t0: float, since: float
) -> float:
    """RMS of the heights about each particle's cubic cross profile for the slide
    ``params = (v, c)`` (:class:`CrossDrift`)."""
    v, c = float(params[0]), float(params[1])
    total, dof = 0.0, 0
    for tr in tracks:
        slide = v * (tr[:, 0] - t0)
        if c != 0.0:
            slide = slide + c * np.log((tr[:, 0] - since) / (t0 - since))
        x = tr[:, 1] - slide
        a = np.vander(x - x.mean(), 4)
        coef, *_ = np.linalg.lstsq(a, tr[:, 2], rcond=None)
        total += float(np.sum((a @ coef - tr[:, 2]) ** 2))
        dof += tr.shape[0] - 4
    return float(np.sqrt(total / max(dof, 1)))


def _best_rate(tracks: list[NDArray[np.float64]], t0: float) -> tuple[float, float]:
    """The steady slide ``v`` alone: a grid, then a bounded search about its best point."""
    grid = np.linspace(-MAX_RATE_NM_PER_S, MAX_RATE_NM_PER_S, 201)
    values = [_residual(np.array([v, 0.0]), tracks, t0, 0.0) for v in grid]
    i = int(np.argmin(values))
    best = scipy.optimize.minimize_scalar(
        lambda v: _residual(np.array([v, 0.0]), tracks, t0, 0.0),
        bounds=(grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]), method="bounded",
        options={"xatol": 1e-5},
    )  # fmt: skip
    return float(best.x), float(best.fun)


LOG_GAIN = 0.8
"""The creep term is kept when it brings the residual below this fraction of the steady
slide's alone (otherwise the window cannot tell creep from drift, and the steady slide is
the simpler account)."""


def cross_line_drift(
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    t_s: NDArray[np.float64],
    slow_nm: NDArray[np.float64],
    cycle_samples: int,
    *,
    min_prominence_nm: float = 3.0,
    since_s: float | None = None,
) -> CrossDrift | None:
    """The line's slide across its particles from a dithered settling record.

    Parameters
    ----------
    u_nm, height_nm, t_s : ndarray, shape (n,)
        The fast axis' command, the heights and the session times of the settling record
        (whole cycles of ``cycle_samples`` samples, plus the first sample).
    slow_nm : ndarray, shape (n,)
        The slow axis' command of the same samples; its offset from the last cycle's is the
        cycle's step (:func:`dither_offsets`).
    cycle_samples : int
        Samples per cycle (forward then backward trace).
    min_prominence_nm : float, optional
        Smallest peak counted as a particle (nm).
    since_s : float, optional
        Session time of the slow axis' last large move (e.g. the end of the overview image),
        whose creep the slide then carries as a logarithmic term; ``None``: a steady slide.

    Returns
    -------
    CrossDrift or None
        ``None`` when the record has fewer than 8 cycles, was not dithered, or fewer than 3
        particles can be followed over its second half.
    """
    per = int(cycle_samples)
    n_cycles = (np.asarray(u_nm).size - 1) // per
    if n_cycles < 8:
        return None
    slow = np.asarray(slow_nm, float)
    offsets = np.array([slow[c * per + per // 4] for c in range(n_cycles)]) - slow[-1]
    if np.ptp(offsets) <= 0:
        return None
    tracks = _tracks(
        np.asarray(u_nm, float), np.asarray(height_nm, float), np.asarray(t_s, float),
        offsets, per, min_prominence_nm,
    )  # fmt: skip
    if len(tracks) < 3:
        return None
    t0 = float(min(tr[0, 0] for tr in tracks))
    end = float(max(tr[-1, 0] for tr in tracks))
    v, res = _best_rate(tracks, t0)
    c, since = 0.0, float("nan")
    if since_s is not None and since_s < t0 - 1.0:
        since = float(since_s)
        starts = [np.array([v, 0.0]), np.array([0.0, v * (t0 - since)])]
        step = np.array([[0.0, 0.0], [0.01, 0.0], [0.0, 0.01 * (t0 - since)]])
        options = {"xatol": 1e-5, "fatol": 1e-6}
        fits = [
            scipy.optimize.minimize(
                _residual,
                x0,
                args=(tracks, t0, since),
                method="Nelder-Mead",
                options={**options, "initial_simplex": x0 + step},
            )
            for x0 in starts
        ]
        best = min(fits, key=lambda f: float(f.fun))
        if float(best.fun) < LOG_GAIN * res:
            v, c, res = float(best.x[0]), float(best.x[1]), float(best.fun)
    rate = v + (c / (end - since) if c != 0.0 else 0.0)
    return CrossDrift(
        rate_nm_per_s=rate, particles=len(tracks), residual_nm=res,
        still_residual_nm=_residual(np.zeros(2), tracks, t0, 0.0), window_s=end - t0,
        drift_nm_per_s=v, creep_nm=c, since_s=since, t0_s=t0, end_s=end,
    )  # fmt: skip
