"""The scanner's own error at the landmarks, measured: how wide to look, how much to trust.

Through the creep-and-hysteresis compensator two images of one landmark agree within the
registration's precision, and drift is all that moves it. A scanner driven without that
compensator puts the tip somewhere else at every visit: the hysteresis of the moves that
led there and the creep of where the tip has been over the last minutes, tens of
nanometres on ``cpr5``, different at every approach. A window of a few tens of nanometres
placed where the drift estimate says then misses its landmark, and each sighting that does
register carries that error: to the landmarks it looks like drift.

That error is measured, not assumed (:class:`ScannerError`):

- when tracking starts (:func:`calibrate`), each landmark is imaged again after the tip has
  come from each corner of the overview in turn, and the spread of those sightings about
  each landmark's mean is a first estimate (the drift of that minute included: on the
  safe side);
- then every sighting adds its innovation: its miss of the filter's prediction, less the
  prediction's own variance (covariance matching), so the estimate follows the error the
  scanner makes in the work actually done.

It sizes the rest (:func:`sized`): the landmark window (a shift of :data:`SIGMAS` standard
deviations stays within the third of the window that registration accepts; up to
:data:`MAX_WINDOW_FACTOR` times the settings' window), the search for a new landmark, the
filter's measurement noise and gate, and the tolerance (the drift is not measured again
before its uncertainty is that of one measurement: the error is largely the same at every
landmark, so averaging them does not reduce it). A window that still misses its
landmark doubles (:func:`grown_window_nm`).

What it cannot do: tell drift from the part of the scanner's error that every landmark
shares (creep of where the tip has been). That part is followed as drift; the drift
session's "drift only" row shows what is left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.drift.filter import MIN_MEASUREMENT_NM, DriftSettings
from piezocomp.drift.landmarks import Landmark, Sighting, sight
from piezocomp.instrument import Instrument

__all__ = [
    "MAX_WINDOW_FACTOR",
    "SIGMAS",
    "ScannerError",
    "approach_points",
    "calibrate",
    "grown_window_nm",
    "resized",
    "round_drifts",
    "sized",
]

SIGMAS = 3.0
"""Standard deviations of the scanner's error a landmark window must capture."""

MAX_WINDOW_FACTOR = 4.0
"""A landmark window grows to at most this many times the settings' (same pixel count)."""


@dataclass(frozen=True)
class ScannerError:
    """The scanner's error at a landmark, as measured (see the module notes).

    Attributes
    ----------
    sum_sq_nm2 : ndarray, shape (2,)
        Sum of the squared deviations of the sightings (x, y), nm^2.
    dof : int
        Their degrees of freedom (>= 1).
    sightings : int
        Sightings that went into it.
    """

    sum_sq_nm2: NDArray[np.float64]
    dof: int
    sightings: int

    def __post_init__(self) -> None:
        s = readonly(as_finite_array("sum_sq_nm2", self.sum_sq_nm2).reshape(2))
        if np.any(s < 0):
            raise ValueError(f"sum_sq_nm2 must be >= 0. Got {s.tolist()}.")
        object.__setattr__(self, "sum_sq_nm2", s)
        for name, low in (("dof", 1), ("sightings", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"{name} must be an integer >= {low}. Got {v!r}.")

    @classmethod
    def from_rounds(cls, rounds: list[list[Sighting]]) -> ScannerError | None:
        """From repeated sightings of the same landmarks (one list per round, one entry
        per landmark): each landmark's sightings about their mean, pooled. ``None`` if no
        landmark was seen twice."""
        sq, n, dof = np.zeros(2), 0, 0
        for i in range(max((len(r) for r in rounds), default=0)):
            z = np.array([r[i].drift_nm for r in rounds
                          if i < len(r) and r[i].drift_nm is not None])  # fmt: skip
            if z.shape[0] >= 2:
                sq += np.sum((z - z.mean(axis=0)) ** 2, axis=0)
                n += z.shape[0]
                dof += z.shape[0] - 1
        return cls(sq, dof, n) if dof else None

    @property
    def sigma_nm(self) -> NDArray[np.float64]:
        """Standard deviation of one sighting along x and y, nm (at least
        :data:`~piezocomp.drift.filter.MIN_MEASUREMENT_NM`)."""
        return np.maximum(np.sqrt(self.sum_sq_nm2 / self.dof), MIN_MEASUREMENT_NM)

    @property
    def window_nm(self) -> float:
        """The landmark window that captures a shift of :data:`SIGMAS` standard
        deviations (registration accepts a third of the window)."""
        return float(3.0 * SIGMAS * np.max(self.sigma_nm))

    def with_innovations(
        self, innovations_nm: ArrayLike, predicted_var_nm2: ArrayLike
    ) -> ScannerError:
        """Add sightings' innovations (k, 2) against a prediction of variance
        ``predicted_var_nm2`` (2,): each adds its square less that variance (its expected
        square is the prediction's variance plus the sighting's)."""
        v = as_finite_array("innovations_nm", innovations_nm).reshape(-1, 2)
        p = as_finite_array("predicted_var_nm2", predicted_var_nm2).reshape(2)
        if v.shape[0] == 0:
            return self
        sq = np.maximum(self.sum_sq_nm2 + np.sum(v**2 - p, axis=0), 0.0)
        return ScannerError(sq, self.dof + v.shape[0], self.sightings + v.shape[0])


def approach_points(center_nm: ArrayLike, size_nm: float) -> NDArray[np.float64]:
    """The corners of the square of side ``size_nm`` about ``center_nm`` (4, 2), in turn
    opposite: where the tip comes from before each round of calibration sightings."""
    c = as_finite_array("center_nm", center_nm).reshape(2)
    h = 0.5 * check_finite_scalar("size_nm", size_nm)
    return c + h * np.array([[-1.0, -1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, 1.0]])


def round_drifts(rounds: list[list[Sighting]]) -> list[tuple[float, NDArray[np.float64]]]:
    """Each round of :func:`calibrate` as one drift measurement: the mean time and drift of
    the landmarks it found (a round that found none gives none)."""
    out = []
    for sightings in rounds:
        seen = [g for g in sightings if g.drift_nm is not None]
        if seen:
            z = np.mean([np.asarray(g.drift_nm) for g in seen], axis=0)
            out.append((float(np.mean([g.t_s for g in seen])), np.asarray(z, dtype=float)))
    return out


def calibrate(
    instrument: Instrument,
    landmarks: list[Landmark],
    settings: DriftSettings,
    points_nm: ArrayLike,
) -> list[list[Sighting]]:
    """Sight every landmark again after the tip came from each of ``points_nm`` (one round
    per point). Tracking has just started: the windows are placed with no drift. Returns
    the sightings, one list per round."""
    ls = settings.landmarks
    rounds = []
    for q in as_finite_array("points_nm", points_nm, ndim=2):
        instrument.move_to(float(q[0]), float(q[1]), ls.speed_nm_per_s)
        rounds.append([sight(instrument, lm, np.zeros(2), ls) for lm in landmarks])
    return rounds


def grown_window_nm(settings: DriftSettings, base_nm: float, error: ScannerError | None,
                    missed: bool) -> float:  # fmt: skip
    """The landmark window after a measurement: large enough for ``error``
    (:attr:`ScannerError.window_nm`; none yet: no condition), twice as large when a
    window ``missed`` its landmark, never smaller than now nor larger than
    :data:`MAX_WINDOW_FACTOR` times ``base_nm``."""
    now = settings.landmarks.window_nm
    need = 0.0 if error is None else math.ceil(error.window_nm)
    want = max(now, need, 2.0 * now if missed else 0.0)
    return float(min(want, MAX_WINDOW_FACTOR * base_nm))


def sized(settings: DriftSettings, error: ScannerError, window_nm: float) -> DriftSettings:
    """The settings sized from the measured scanner error (see the module notes): the
    landmark window ``window_nm`` (same pixel count), a search for a new landmark at
    least twice that, the measurement noise the error's larger axis (one sighting's, and
    one measurement's: the error is largely the same at every landmark, the creep of where
    the tip has been, and averaging landmarks does not reduce it), the tolerances at least
    that."""
    ls = settings.landmarks
    sigma = float(np.max(error.sigma_nm))
    tol = max(settings.tolerance_nm, sigma)
    return replace(
        settings,
        landmarks=replace(
            ls, window_nm=float(window_nm), search_nm=max(ls.search_nm or 0.0, 2.0 * window_nm)
        ),
        noise=replace(settings.noise, measurement_nm=sigma),
        tolerance_nm=tol,
        image_tolerance_nm=max(settings.image_tolerance_nm, 2.0 * tol),
    )


def resized(
    settings: DriftSettings, base: DriftSettings, error: ScannerError | None, missed: bool
) -> tuple[DriftSettings, bool]:
    """The settings after a measurement of the scanner error, from the settings before any
    sizing ``base`` (:func:`sized`; with no error yet only the window, :func:`grown_window_nm`),
    and whether the landmark window grew (its templates must then be taken again)."""
    w = grown_window_nm(settings, base.landmarks.window_nm, error, missed)
    grew = w > settings.landmarks.window_nm
    if error is not None:
        return sized(base, error, w), grew
    ls = settings.landmarks
    grown = replace(ls, window_nm=w, search_nm=max(ls.search_nm or 0.0, 2.0 * w))
    return replace(settings, landmarks=grown), grew
