"""Landmarks: small images of particles that do not move, where drift is measured.

A landmark is a window of a few tens of nanometres about an isolated particle, imaged once
as a template. Imaged again later at the place where the drift estimate says it now is, its
translation against the template (sub-pixel cross-correlation,
:func:`~piezocomp.imaging.registration.image_displacement`) is what the estimate missed. The windows
are scanned through whatever instrument the drift compensator wraps: through the creep and
hysteresis compensator, the measurement sees drift, not scanner error.

A landmark that vanished (no particle in its window), matches badly, or moved (pushed by the
tip: its shift disagrees with the others' and the estimate's) is reported so that it can be
replaced, never trusted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.imaging.features import FoundParticles, find_particles
from piezocomp.imaging.registration import image_displacement
from piezocomp.instrument import Instrument, ScanImage

__all__ = [
    "Landmark",
    "LandmarkSettings",
    "Sighting",
    "choose_landmarks",
    "registered",
    "scan_window",
    "search",
    "sight",
    "take_template",
]


@dataclass(frozen=True)
class LandmarkSettings:
    """How landmarks are chosen and imaged.

    Parameters
    ----------
    window_nm : float
        Side of a landmark's window.
    pixels, line_rate_hz : int, float
        Its image (default 32 pixels at 8 lines/s: 4 s, 2 nm pixels).
    speed_nm_per_s : float
        Speed of the moves to and from the landmarks.
    count : int
        Landmarks kept (more than one tells a landmark that moved from drift).
    clearance_nm : float
        No other particle within this of a landmark's centre (the window shows it alone).
    spacing_nm : float
        Landmarks at least this far apart.
    max_match_error : float
        Largest normalised error of a registration that is trusted (0: a perfect match).
    search_nm : float or None
        Side of the wider window a new landmark is looked for in before its template is
        taken (:func:`search`; ``None``: none, the window itself). For a scanner whose
        images of one place disagree by more than a fraction of the window: an
        uncompensated scanner's overview and its windows.
    approach_nm : float
        Every window is entered by the same final move: from ``approach_nm`` before its first
        pixel along both axes (below and to the left) to that pixel, so that the scanner's
        hysteresis comes to each image of a landmark on the same branch and its error there
        repeats between sightings (0: straight from wherever the tip was).
    """

    window_nm: float = 64.0
    pixels: int = 32
    line_rate_hz: float = 8.0
    speed_nm_per_s: float = 1000.0
    count: int = 2
    clearance_nm: float = 60.0
    spacing_nm: float = 150.0
    max_match_error: float = 0.6
    search_nm: float | None = None
    approach_nm: float = 0.0

    def __post_init__(self) -> None:
        for name in ("window_nm", "line_rate_hz", "speed_nm_per_s", "clearance_nm",
                     "max_match_error"):  # fmt: skip
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        if self.search_nm is not None and not (
            check_finite_scalar("search_nm", self.search_nm) > self.window_nm
        ):
            raise ValueError(
                f"search_nm must be None or > window_nm ({self.window_nm:g}). Got {self.search_nm}."
            )
        for name in ("spacing_nm", "approach_nm"):
            if check_finite_scalar(name, getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0. Got {getattr(self, name)}.")
        for name, low in (("pixels", 8), ("count", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"{name} must be an integer >= {low}. Got {v!r}.")


@dataclass(frozen=True)
class Landmark:
    """A landmark: its window and template.

    Attributes
    ----------
    center_nm : ndarray, shape (2,)
        Centre of the window when the template was taken (the wrapped instrument's frame).
    template : ScanImage
    t_s : float
        Mean time of the template's pixels, s.
    offset_nm : ndarray, shape (2,)
        The drift (relative to the session's reference) when the template was taken: 0 for
        the first landmarks, the estimate for a later one.
    offset_var_nm2 : ndarray, shape (2,)
        The variance of that offset.
    """

    center_nm: NDArray[np.float64]
    template: ScanImage = field(repr=False)
    t_s: float
    offset_nm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    offset_var_nm2: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "center_nm", readonly(as_finite_array("center_nm", self.center_nm))
        )
        object.__setattr__(
            self, "offset_nm", readonly(as_finite_array("offset_nm", self.offset_nm))
        )
        object.__setattr__(
            self, "offset_var_nm2", readonly(as_finite_array("offset_var_nm2", self.offset_var_nm2))
        )


@dataclass(frozen=True)
class Sighting:
    """One landmark imaged again.

    Attributes
    ----------
    t_s : float
        Mean time of the image's pixels, s.
    drift_nm : ndarray, shape (2,) or None
        The drift it measures (relative to the session's reference); ``None`` if the
        landmark was not seen (``reason`` says why).
    var_nm2 : ndarray, shape (2,)
        The variance that comes with it from the landmark's own offset.
    match_error : float
        The registration's normalised error.
    reason : str
        Empty, or why the sighting is not to be trusted.
    image : ScanImage
    """

    t_s: float
    drift_nm: NDArray[np.float64] | None
    var_nm2: NDArray[np.float64]
    match_error: float
    reason: str
    image: ScanImage = field(repr=False)


def choose_landmarks(
    particles: FoundParticles,
    settings: LandmarkSettings,
    *,
    count: int | None = None,
    avoid_nm: ArrayLike = (),
    avoid_radius_nm: float = 100.0,
    near_nm: tuple[float, float] | None = None,
    taken_nm: ArrayLike = (),
) -> list[NDArray[np.float64]]:
    """Particles fit to be landmarks: alone in their window (``clearance_nm``), away from
    the points to avoid (particles to push, their targets), ``spacing_nm`` apart from each
    other and from landmarks already taken; the nearest to ``near_nm`` first."""
    p = particles.positions_nm
    n = settings.count if count is None else int(count)
    avoid = np.asarray(avoid_nm, dtype=float).reshape(-1, 2)
    taken = [np.asarray(t, dtype=float) for t in np.asarray(taken_nm, dtype=float).reshape(-1, 2)]
    order = np.arange(p.shape[0])
    if near_nm is not None:
        order = np.argsort(np.hypot(*(p - np.asarray(near_nm)).T))
    chosen: list[NDArray[np.float64]] = []
    for i in order:
        c = p[i]
        others = np.delete(p, i, axis=0)
        if others.size and np.min(np.hypot(*(others - c).T)) < settings.clearance_nm:
            continue
        if avoid.size and np.min(np.hypot(*(avoid - c).T)) < avoid_radius_nm:
            continue
        if any(np.hypot(*(c - q)) < settings.spacing_nm for q in [*chosen, *taken]):
            continue
        chosen.append(np.array(c))
        if len(chosen) == n:
            break
    return chosen


def scan_window(
    instrument: Instrument, center_nm: ArrayLike, settings: LandmarkSettings
) -> ScanImage:
    """Move to a window's first pixel (from ``settings.approach_nm`` before it) and image it."""
    c = as_finite_array("center_nm", center_nm).reshape(2)
    half = 0.5 * settings.window_nm * (1 - 1 / settings.pixels)
    first = c - half
    if settings.approach_nm > 0:
        start = first - settings.approach_nm
        instrument.move_to(float(start[0]), float(start[1]), settings.speed_nm_per_s)
    instrument.move_to(float(first[0]), float(first[1]), settings.speed_nm_per_s)
    return instrument.scan_image(
        (float(c[0]), float(c[1])), settings.window_nm, settings.pixels, settings.line_rate_hz
    )


def take_template(
    instrument: Instrument,
    center_nm: ArrayLike,
    settings: LandmarkSettings,
    offset_nm: ArrayLike = (0.0, 0.0),
    offset_var_nm2: ArrayLike = (0.0, 0.0),
) -> Landmark | None:
    """Image a new landmark's template: a window centred on the particle found nearest to
    ``center_nm`` (imaged again centred when it is off-centre). ``None`` if the window holds
    no particle.

    With ``settings.search_nm``, the particle is first looked for in that wider window
    (:func:`search`), then imaged in its own.

    ``offset_nm``, ``offset_var_nm2``: the drift estimate now (zero when tracking starts).
    """
    c = as_finite_array("center_nm", center_nm).reshape(2)
    if settings.search_nm is not None:
        found = search(instrument, c, settings, side_nm=settings.search_nm)
        if found is None:
            return None
        c = found
    for _ in range(2):
        img = scan_window(instrument, c, settings)
        found = find_particles(img, trace="mean").positions_nm
        if found.shape[0] == 0:
            return None
        p = found[np.argmin(np.hypot(*(found - c).T))]
        if np.max(np.abs(p - c)) <= settings.window_nm / 8:
            return Landmark(c, img, _mean_time(img), np.asarray(offset_nm, dtype=float),
                            np.asarray(offset_var_nm2, dtype=float))  # fmt: skip
        c = np.asarray(p)
    return None


def search(
    instrument: Instrument,
    center_nm: ArrayLike,
    settings: LandmarkSettings,
    *,
    side_nm: float,
) -> NDArray[np.float64] | None:
    """Look for a landmark's particle in a wide window.

    Images a window of side ``side_nm`` about ``center_nm`` (pixels twice as large as the
    landmark window's: a search, not a measurement; the forward trace, whose particles a
    scanner's hysteresis cannot double) and returns the particle nearest the centre that
    is alone within ``clearance_nm`` and whose own window lies inside the one searched.
    ``None`` if there is none.
    """
    c = as_finite_array("center_nm", center_nm).reshape(2)
    side = check_finite_scalar("side_nm", side_nm)
    if side <= settings.window_nm:
        raise ValueError(f"side_nm must be > window_nm ({settings.window_nm:g}). Got {side}.")
    pitch = 2.0 * settings.window_nm / settings.pixels
    wide = replace(settings, window_nm=side, pixels=max(8, math.ceil(side / pitch)),
                   search_nm=None)  # fmt: skip
    img = scan_window(instrument, c, wide)
    p = find_particles(img, trace="forward").positions_nm
    inside = np.max(np.abs(p - c), axis=1) <= 0.5 * (side - settings.window_nm)
    for i in np.argsort(np.hypot(*(p - c).T)):
        others = np.delete(p, i, axis=0)
        alone = others.size == 0 or np.min(np.hypot(*(others - p[i]).T)) >= settings.clearance_nm
        if inside[i] and alone:
            return np.array(p[i])
    return None


def _mean_time(img: ScanImage) -> float:
    fwd, bwd = img.pixel_times_s()
    return float(0.5 * (np.mean(fwd) + np.mean(bwd)))


def sight(
    instrument: Instrument,
    landmark: Landmark,
    predicted_nm: ArrayLike,
    settings: LandmarkSettings,
) -> Sighting:
    """Image a landmark where the drift estimate ``predicted_nm`` says it is now, and
    measure the drift.

    The window is centred at ``center - (predicted - offset)``; its content's shift against
    the template is what the prediction missed, so the drift is ``predicted + tip offset``.
    """
    pred = as_finite_array("predicted_nm", predicted_nm).reshape(2)
    center = landmark.center_nm - (pred - landmark.offset_nm)
    img = scan_window(instrument, center, settings)
    fwd, bwd = img.pixel_times_s()
    t = float(0.5 * (np.mean(fwd) + np.mean(bwd)))
    tpl = landmark.template
    # the two windows differ by the known shift: registered on the template's grid
    on_grid = ScanImage(img.forward_nm, img.backward_nm, tpl.x_nm, tpl.y_nm, img.line_time_s,
                        img.t_start_s, img.fast_axis)  # fmt: skip
    return registered(t, pred, landmark, on_grid, img, settings)


def registered(
    t: float, pred: NDArray[np.float64], landmark: Landmark, on_grid: ScanImage,
    img: ScanImage, settings: LandmarkSettings,
) -> Sighting:  # fmt: skip
    """The sighting of ``on_grid`` (an image of ``landmark`` on its template's grid, ``img``
    as taken, its pixels' mean time ``t``, the drift ``pred`` its window was placed with):
    registered against the template, the drift ``pred`` plus the tip's offset, or why not."""
    var = landmark.offset_var_nm2
    if len(find_particles(on_grid, trace="mean")) == 0:
        return Sighting(t, None, var, float("nan"),
                        "no particle in the window: the landmark vanished or was pushed away",
                        img)  # fmt: skip
    try:
        d = image_displacement(landmark.template, on_grid, trace="mean")
    except ValueError as exc:
        return Sighting(t, None, var, float("nan"), str(exc), img)
    if d.error > settings.max_match_error:
        return Sighting(t, None, var, d.error,
                        f"the window matches its template badly (error {d.error:.2f})",
                        img)  # fmt: skip
    return Sighting(t, pred + np.asarray(d.tip_offset_nm), var, d.error, "", img)
