"""Drift measured on a series of images of the same area (a drift movie).

Scan one area again and again with nothing pushed in it, and the content of each image lies
shifted from the first by the drift of the sample under the tip since then.
:func:`measure_series` finds those shifts by cross-correlation
(:func:`~piezocomp.imaging.registration.image_displacement`) against a reference frame, which moves
on to the latest frame whenever the content has moved more than a sixth of the image from
the reference (so a drift of many image widths is still followed, at the cost of the
registration errors adding up from one reference to the next); :func:`track_series` runs the
drift filter of :mod:`piezocomp.drift.filter` over them, with its noise estimated from the series
itself by maximum likelihood when there are enough frames. This is how to learn how much
an instrument drifts, and the noise to give :class:`~piezocomp.drift.filter.DriftSettings`.

Each frame is dated at its middle (``t_start_s`` plus half its lines): within one frame the
drift also stretches the image along the slow axis, which the shift does not describe.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from piezocomp.drift.filter import DriftEstimate, DriftFilter, DriftNoise, fit_noise
from piezocomp.imaging.registration import MIN_FEATURE_NM, image_displacement
from piezocomp.instrument import ScanImage

__all__ = ["MIN_FRAMES_TO_FIT", "DriftSeries", "frame_time_s", "measure_series", "track_series"]

MIN_FRAMES_TO_FIT = 10
"""Fewest registered frames whose innovations estimate the noise; with fewer the given noise
(or the defaults) is used and the summary says so."""

REFERENCE_STEP = 1.0 / 6.0
"""The reference frame moves on once the content has moved this fraction of the image."""


def frame_time_s(image: ScanImage) -> float:
    """The time a frame is dated at: the mean time of its pixels (both traces; the lines'
    own start times when it was interrupted)."""
    fwd, bwd = image.pixel_times_s()
    return float(0.5 * (np.mean(fwd) + np.mean(bwd)))


@dataclass(frozen=True)
class DriftSeries:
    """Drift over an image series, measured and filtered (both axes, the images' frame).

    Attributes
    ----------
    t_s : ndarray, shape (n,)
        Time of each registered frame (:func:`frame_time_s`), the first frame's included.
    measured_nm : ndarray, shape (n, 2)
        How far the content lies from where it is in the first frame (0 for the first).
    match_error : ndarray, shape (n,)
        The registration's normalised error for each frame (0 for the first).
    filtered_nm, sigma_nm, velocity_nm_per_s : ndarray, shape (n, 2)
        The filter's estimate after each frame, its standard deviation and the drift rate.
    noise : DriftNoise
        The noise the filter ran with.
    noise_fitted : bool
        Whether ``noise`` was estimated from this series (:data:`MIN_FRAMES_TO_FIT`).
    refused : tuple of (int, str)
        Frames (index in the input) that did not register, and why.
    frames : tuple of int
        Index in the input of each registered frame.
    """

    t_s: NDArray[np.float64]
    measured_nm: NDArray[np.float64]
    match_error: NDArray[np.float64]
    filtered_nm: NDArray[np.float64]
    sigma_nm: NDArray[np.float64]
    velocity_nm_per_s: NDArray[np.float64]
    noise: DriftNoise
    noise_fitted: bool
    refused: tuple[tuple[int, str], ...]
    frames: tuple[int, ...] = ()

    @property
    def rate_nm_per_s(self) -> float:
        """Mean drift speed over the series: the distance from the first frame to the last
        (filtered) over the time between them."""
        dt = float(self.t_s[-1] - self.t_s[0])
        if dt <= 0:
            return 0.0
        return float(np.hypot(*(self.filtered_nm[-1] - self.filtered_nm[0])) / dt)


def measure_series(
    images: Sequence[ScanImage], *, trace: str = "forward", min_feature_nm: float = MIN_FEATURE_NM
) -> tuple[list[int], NDArray[np.float64], NDArray[np.float64], list[tuple[int, str]]]:
    """Each frame's content shift from the first, by registration against a moving reference.

    ``min_feature_nm``: the flatness below which a frame holds nothing to register
    (:func:`~piezocomp.imaging.registration.image_displacement`).

    Returns the indices of the frames registered (the first always), their shifts (n, 2),
    their match errors, and the frames refused with the reason. Raises ValueError if fewer
    than two frames are given, their grids differ, or the first frame holds nothing to
    register.
    """
    if len(images) < 2:
        raise ValueError(f"a drift series needs at least 2 frames. Got {len(images)}.")
    first = images[0]
    for k, im in enumerate(images[1:], start=1):
        if im.x_nm.shape != first.x_nm.shape or im.y_nm.shape != first.y_nm.shape:
            raise ValueError(
                f"frame {k} has {im.y_nm.size} x {im.x_nm.size} pixels, the first "
                f"{first.y_nm.size} x {first.x_nm.size}: every frame must have the same grid."
            )
    side = min(float(np.ptp(first.x_nm)), float(np.ptp(first.y_nm)))
    ref, ref_shift = first, np.zeros(2)
    kept, shifts, errors, refused = [0], [np.zeros(2)], [0.0], []
    for k, im in enumerate(images[1:], start=1):
        try:
            d = image_displacement(ref, im, trace=trace, min_feature_nm=min_feature_nm)
        except ValueError as exc:
            refused.append((k, str(exc)))
            continue
        step = np.asarray(d.content_shift_nm, dtype=float)
        kept.append(k)
        shifts.append(ref_shift + step)
        errors.append(float(d.error))
        if np.hypot(*step) > REFERENCE_STEP * side:
            ref, ref_shift = im, ref_shift + step
    return kept, np.array(shifts), np.array(errors), refused


def track_series(
    images: Sequence[ScanImage],
    noise: DriftNoise | None = None,
    *,
    fit: bool = True,
    trace: str = "forward",
    min_feature_nm: float = MIN_FEATURE_NM,
) -> DriftSeries:
    """The drift over ``images`` (:func:`measure_series`), filtered (:class:`DriftFilter`).

    With ``fit`` and at least :data:`MIN_FRAMES_TO_FIT` registered frames the noise is
    estimated from the series (:func:`~piezocomp.drift.filter.fit_noise`, starting from ``noise``);
    otherwise ``noise`` (default :class:`DriftNoise`) is used as given.
    """
    kept, shifts, errors, refused = measure_series(
        images, trace=trace, min_feature_nm=min_feature_nm
    )
    if len(kept) < 2:
        raise ValueError(
            "no frame after the first could be registered against it: "
            + "; ".join(f"frame {k}: {why}" for k, why in refused)
        )
    t = np.array([frame_time_s(images[k]) for k in kept])
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"frame times must increase. Got {t.tolist()} s.")
    start = DriftNoise() if noise is None else noise
    fitted = fit and len(kept) >= MIN_FRAMES_TO_FIT
    used = fit_noise(t, shifts, start).noise if fitted else start
    filt = DriftFilter(used, DriftEstimate.start(float(t[0]), used))  # the first frame: 0
    means, sigmas, rates = [np.zeros(2)], [np.zeros(2)], [np.zeros(2)]
    for k in range(1, t.size):
        filt.measure(float(t[k]), shifts[k])
        e = filt.estimate
        means.append(e.displacement_nm.copy())
        sigmas.append(e.std_nm.copy())
        rates.append(np.asarray(e.mean[:, 1]).copy())
    return DriftSeries(
        t_s=t, measured_nm=shifts, match_error=errors, filtered_nm=np.array(means),
        sigma_nm=np.array(sigmas), velocity_nm_per_s=np.array(rates), noise=used,
        noise_fitted=fitted, refused=tuple(refused), frames=tuple(kept),
    )  # fmt: skip
