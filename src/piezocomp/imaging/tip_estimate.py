"""The tip's apex radius estimated from images of particles (what a user's software must learn).

A particle of radius ``R`` imaged by a sphere-ended cone of apex radius ``r`` appears as the
particle dilated by the tip (:class:`~piezocomp.tip.TipGeometry`): its apparent height is
``2R`` whatever the tip, and its apparent width grows with ``r`` (``2 sqrt(R r)`` at the
substrate while the sphere touches). So the apparent profile of each particle, with ``R``
from its measured height, fixes ``r``: :func:`estimate_tip_radius` fits it to every
particle's pixels on its own and takes the median, with the spread between particles as its
uncertainty. The cone's half-angle is taken from the tip's datasheet; it matters only for
particles larger than the apex. This is the "particles of known size" method of tip
characterisation; blind reconstruction needs no particle model but a sharper image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

from piezocomp._validation import check_finite_scalar
from piezocomp.imaging.features import FoundParticles, level, trace_heights
from piezocomp.instrument import ScanImage
from piezocomp.tip import TipGeometry

__all__ = ["RADIUS_BOUNDS_NM", "TipEstimate", "estimate_tip_radius"]

RADIUS_BOUNDS_NM = (0.5, 100.0)
"""The apex radii searched, nm."""

MIN_PIXELS = 12
"""Fewest pixels on a particle's flanks for its own estimate."""


@dataclass(frozen=True)
class TipEstimate:
    """What :func:`estimate_tip_radius` found.

    Attributes
    ----------
    radius_nm : float
        The median of the particles' estimates.
    std_nm : float
        Its standard error from their spread (1.25 x mean absolute deviation / sqrt(n)).
    per_particle_nm : tuple of float
        Each usable particle's estimate.
    half_angle_deg : float
        The cone half-angle assumed.
    """

    radius_nm: float
    std_nm: float
    per_particle_nm: tuple[float, ...]
    half_angle_deg: float

    @property
    def tip(self) -> TipGeometry:
        """The estimated tip."""
        return TipGeometry(self.radius_nm, self.half_angle_deg)


def estimate_tip_radius(
    image: ScanImage,
    particles: FoundParticles,
    *,
    half_angle_deg: float = 20.0,
    trace: str = "mean",
) -> TipEstimate:
    """The apex radius that makes the particles' apparent profiles in ``image``.

    Parameters
    ----------
    image : ScanImage
        Pixels at known positions (a compensated image: true lengths).
    particles : FoundParticles
        The particles found in it (:func:`~piezocomp.imaging.features.find_particles`); their
        apex heights are their diameters.
    half_angle_deg : float
        The cone's half-angle (the tip's datasheet), degrees in (0, 90).
    trace : {"forward", "backward", "mean"}

    Raises
    ------
    ValueError
        If no particle has :data:`MIN_PIXELS` pixels on its flanks clear of the others.
    """
    ang = check_finite_scalar("half_angle_deg", half_angle_deg)
    if not 0 < ang < 90:
        raise ValueError(f"half_angle_deg must be in (0, 90). Got {ang}.")
    z = level(trace_heights(image, trace))
    xx, yy = np.meshgrid(np.asarray(image.x_nm), np.asarray(image.y_nm))
    pos, heights = particles.positions_nm, particles.heights_nm
    estimates = []
    for k in range(len(particles)):
        R = 0.5 * float(heights[k])
        reach = 2.0 * math.sqrt(R * RADIUS_BOUNDS_NM[1] / 4) + 2 * R  # beyond any foot
        d = np.hypot(xx - pos[k, 0], yy - pos[k, 1])
        near = d < reach  # the others' distances only where they matter
        px, py, d_k, z_k = xx[near], yy[near], d[near], z[near]
        others = np.delete(pos, k, axis=0)
        if others.shape[0]:  # nearer this particle than any other
            d_o = np.hypot(px[:, None] - others[:, 0], py[:, None] - others[:, 1]).min(axis=1)
            own = d_k < d_o - 2 * R
            d_k, z_k = d_k[own], z_k[own]
        if d_k.size < MIN_PIXELS:
            continue
        r = _fit_one(d_k, z_k, R, ang)
        if r is not None:
            estimates.append(r)
    if not estimates:
        raise ValueError(
            f"no particle of the {len(particles)} found has {MIN_PIXELS} pixels on its flanks "
            "clear of the others: image an area with separate particles, at a finer pixel"
        )
    a = np.asarray(estimates)
    med = float(np.median(a))
    std = float(1.25 * np.mean(np.abs(a - med)) / math.sqrt(a.size)) if a.size > 1 else math.nan
    return TipEstimate(med, std, tuple(float(v) for v in a), ang)


def _fit_one(
    d: NDArray[np.float64], z: NDArray[np.float64], R: float, half_angle_deg: float
) -> float | None:
    """The radius whose dilated sphere fits one particle's pixels (None at a bound)."""

    def cost(r: float) -> float:
        model = np.maximum(TipGeometry(r, half_angle_deg).apparent_height(d, R), 0.0)
        return float(np.sum((z - model) ** 2))

    lo, hi = RADIUS_BOUNDS_NM
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 0.01})
    r = float(res.x)
    if not lo * 1.01 < r < hi * 0.99:
        return None
    return r
