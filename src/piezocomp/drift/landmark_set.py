"""The landmarks a drift-compensated instrument tracks, and where their replacements come from.

A :class:`LandmarkSet` holds the landmarks in use, the particles of the overview tracking
started from (replacements are chosen among them), the points landmarks keep away from
(particles about to be pushed, their targets) and the places of landmarks retired. Its
methods image new landmarks where the drift estimate says the overview's particles now are
(:func:`piezocomp.drift.landmarks.take_template`), and sight the ones in use, first looking
for them in a wider window when the estimate has become too uncertain for their own
(:func:`sight_all`).

:func:`trusted` says which sightings of one measurement agree with one another (or, a single
one, with the prediction).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from piezocomp.drift.filter import DriftEstimate, DriftSettings
from piezocomp.drift.landmarks import (
    Landmark,
    LandmarkSettings,
    Sighting,
    choose_landmarks,
    search,
    sight,
    take_template,
)
from piezocomp.imaging.features import FoundParticles
from piezocomp.instrument import Instrument

__all__ = ["RISK_SIGMA", "LandmarkSet", "clock", "safe_sigma_nm", "trusted"]

RISK_SIGMA = 3.0
"""Standard deviations of the predicted drift a landmark window must hold: a prediction
more uncertain than :func:`safe_sigma_nm` is measured before it can lose the landmarks, and
a landmark sighted with one is first looked for in a wider window."""

MAX_SEARCH_WINDOWS = 8
"""Largest search window, in landmark windows (a prediction more uncertain than that is
tracking lost, not a search)."""


def clock(instrument: Instrument) -> float:
    """Session time of ``instrument``'s next sample (its ``time_s``), s.

    Raises
    ------
    TypeError
        If the instrument tells no time (drift compensation predicts the drift at every
        sample).
    """
    t = getattr(instrument, "time_s", None)
    if t is None:
        raise TypeError(
            "drift compensation needs the wrapped instrument's clock: a time_s property "
            "(session time of its next sample)."
        )
    return float(t)


def safe_sigma_nm(settings: LandmarkSettings) -> float:
    """The largest standard deviation of the predicted drift a landmark window can take:
    :data:`RISK_SIGMA` of them within a quarter of the window (the particle stays well
    inside the window its template is registered in)."""
    return settings.window_nm / (4.0 * RISK_SIGMA)


@dataclass
class LandmarkSet:
    """The landmarks in use and the overview's particles their replacements come from.

    Attributes
    ----------
    landmarks : list of Landmark
    particles : FoundParticles or None
        The overview's particles, in sample coordinates at the drift's reference.
    avoid_nm : ndarray, shape (k, 2)
        Points landmarks keep ``avoid_radius_nm`` away from.
    avoid_radius_nm : float
    retired : list of ndarray
        Places (sample coordinates) of landmarks given up: never chosen again.
    areas : dict of str to Landmark
        The references of the areas of the work whose images are drift sightings
        (:meth:`~piezocomp.drift.compensated.DriftCompensatedInstrument.scan_area`): each
        area's first image as its template, its centre in sample coordinates, its offset
        the mean drift its pixels were placed with.
    """

    landmarks: list[Landmark] = field(default_factory=list)
    particles: FoundParticles | None = None
    avoid_nm: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    avoid_radius_nm: float = 100.0
    retired: list[NDArray[np.float64]] = field(default_factory=list)
    areas: dict[str, Landmark] = field(default_factory=dict)

    @classmethod
    def chosen(
        cls,
        instrument: Instrument,
        particles: FoundParticles,
        settings: LandmarkSettings,
        near_nm: tuple[float, float],
        avoid_nm: NDArray[np.float64],
        avoid_radius_nm: float,
    ) -> LandmarkSet:
        """The first landmarks: the overview's particles fit to be one, nearest
        ``near_nm`` first (:func:`choose_landmarks`), each templated by ``instrument``
        (those it could not image are left out: the set may be empty).

        Raises
        ------
        ValueError
            If no particle of the overview is fit to be a landmark.
        """
        picks = choose_landmarks(particles, settings, avoid_nm=avoid_nm,
                                 avoid_radius_nm=avoid_radius_nm, near_nm=near_nm)  # fmt: skip
        if not picks:
            raise ValueError(
                "no particle of the overview is fit to be a landmark (alone within "
                f"{settings.clearance_nm:g} nm, away from the points to avoid): image a "
                "larger area."
            )
        landmarks = [lm for c in picks if (lm := take_template(instrument, c, settings))]
        return cls(landmarks, particles, avoid_nm, avoid_radius_nm)

    def _avoid_all(self) -> NDArray[np.float64]:
        return np.vstack([self.avoid_nm.reshape(-1, 2), *self.retired])

    def _taken(self, skip: int | None = None) -> list[NDArray[np.float64]]:
        return [lm.center_nm + lm.offset_nm for j, lm in enumerate(self.landmarks) if j != skip]

    def _templated(
        self, instrument: Instrument, at: Callable[[float], DriftEstimate],
        place_nm: NDArray[np.float64], settings: LandmarkSettings,
    ) -> Landmark | None:  # fmt: skip
        """A landmark for the overview's particle at ``place_nm``, templated where the drift
        estimate says it is now (its offset: the estimate at the template's time)."""
        now = at(clock(instrument)).displacement_nm
        lm = take_template(instrument, place_nm - now, settings)
        if lm is None:
            return None
        est = at(lm.t_s)
        return replace(lm, offset_nm=est.displacement_nm, offset_var_nm2=est.cov[:, 0, 0])

    def reacquire(
        self, instrument: Instrument, settings: DriftSettings,
        at: Callable[[float], DriftEstimate],
    ) -> bool:  # fmt: skip
        """New landmarks up to ``settings.landmarks.count`` among the overview's particles;
        whether any landmark is left."""
        ls = settings.landmarks
        need = ls.count - len(self.landmarks)
        picks = [] if self.particles is None or need <= 0 else choose_landmarks(
            self.particles, ls, count=need, avoid_nm=self._avoid_all(),
            avoid_radius_nm=max(self.avoid_radius_nm, ls.clearance_nm), taken_nm=self._taken(),
        )  # fmt: skip
        for c in picks:
            lm = self._templated(instrument, at, c, ls)
            if lm is not None:
                self.landmarks.append(lm)
        return bool(self.landmarks)

    def replace(
        self, index: int, instrument: Instrument, settings: DriftSettings,
        at: Callable[[float], DriftEstimate],
    ) -> None:  # fmt: skip
        """Replace landmark ``index`` by the next fit particle of the overview near it (the
        landmark is dropped if none can be imaged)."""
        old = self.landmarks[index]
        self.retired.append(np.asarray(old.center_nm + old.offset_nm))
        if self.particles is None:
            del self.landmarks[index]
            return
        ls = settings.landmarks
        avoid = self._avoid_all()
        for _ in range(3):
            picks = choose_landmarks(
                self.particles, ls, count=1, avoid_nm=avoid,
                avoid_radius_nm=max(self.avoid_radius_nm, ls.clearance_nm),
                near_nm=tuple(old.center_nm), taken_nm=self._taken(skip=index),
            )  # fmt: skip
            if not picks:
                break
            lm = self._templated(instrument, at, picks[0], ls)
            if lm is not None:
                self.landmarks[index] = lm
                return
            avoid = np.vstack([avoid, picks[0]])
            self.retired.append(np.asarray(picks[0]))
        del self.landmarks[index]

    def retake_all(
        self, instrument: Instrument, settings: DriftSettings,
        at: Callable[[float], DriftEstimate],
    ) -> bool:  # fmt: skip
        """Take every landmark's template again with ``settings`` (a grown window), where
        the estimate says it is (a landmark not found is dropped), then reacquire up to the
        count; whether any landmark is left."""
        for i in reversed(range(len(self.landmarks))):
            lm = self.landmarks[i]
            here = lm.center_nm + lm.offset_nm  # the particle's place at the reference
            new = self._templated(instrument, at, here, settings.landmarks)
            if new is None:
                self.retired.append(np.asarray(here))
                del self.landmarks[i]
                continue
            # the template's centre is where the particle showed now; keep it
            self.landmarks[i] = new
        return self.reacquire(instrument, settings, at)

    def sight_all(
        self, instrument: Instrument, settings: LandmarkSettings,
        at: Callable[[float], DriftEstimate],
    ) -> list[Sighting]:  # fmt: skip
        """Sight every landmark where the estimate says it is now.

        When the prediction's uncertainty is beyond :func:`safe_sigma_nm` (a long time with
        no measurement), each landmark's particle is first looked for in a window wide
        enough for :data:`RISK_SIGMA` of it (at most :data:`MAX_SEARCH_WINDOWS` landmark
        windows), and the sighting is centred on what was found.
        """
        out = []
        for lm in self.landmarks:
            pred = at(clock(instrument))
            guess = pred.displacement_nm
            sigma = float(np.max(pred.std_nm))
            if sigma > safe_sigma_nm(settings):
                side = min(settings.window_nm + 2.0 * RISK_SIGMA * sigma,
                           MAX_SEARCH_WINDOWS * settings.window_nm)  # fmt: skip
                found = search(instrument, lm.center_nm - (guess - lm.offset_nm), settings,
                               side_nm=side)  # fmt: skip
                if found is not None:  # the particle shows at center - (drift - offset)
                    guess = lm.center_nm - found + lm.offset_nm
            out.append(sight(instrument, lm, guess, settings))
        return out


def trusted(
    sightings: list[Sighting], at: Callable[[float], DriftEstimate], settings: DriftSettings
) -> list[int]:
    """Indices of the sightings to trust: seen, and within ``gate_sigma`` measurement noises
    of their median (two or more), or a single one within ``gate_sigma`` standard deviations
    of the prediction ``at`` its time."""
    seen = [i for i, g in enumerate(sightings) if g.drift_nm is not None]
    if not seen:
        return []
    sig_m = settings.noise.measurement_nm
    if len(seen) >= 2:
        zs = np.array([sightings[i].drift_nm for i in seen])
        med = np.median(zs, axis=0)
        spread = [np.max(np.abs(zs[k] - med)) for k in range(len(seen))]
        return [i for i, d in zip(seen, spread, strict=True) if d <= settings.gate_sigma * sig_m]
    g = sightings[seen[0]]
    predicted = at(g.t_s)
    std = np.sqrt(predicted.cov[:, 0, 0] + sig_m**2 + g.var_nm2)
    miss = np.abs(np.asarray(g.drift_nm) - predicted.displacement_nm)
    return [seen[0]] if np.all(miss <= settings.gate_sigma * std) else []
