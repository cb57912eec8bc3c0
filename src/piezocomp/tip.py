"""The tip's shape: a sphere-ended cone, as seen in images and met by particles.

Geometry (all nm). The tip is a cone of half-angle ``theta`` ending in a sphere of radius
``r`` tangent to it. A particle of radius ``R`` resting on the plane is touched at lateral
distance ``d`` between the tip axis and its centre with the sphere while
``d <= (R + r) cos(theta)`` (apex height ``z = R + sqrt((R + r)^2 - d^2) - r``) and with
the cone flank beyond (``z = R + (R + r)/sin(theta) - r - d/tan(theta)``). Images are the
surface dilated by this shape; a push plans its contact with it. Both the virtual AFM and the
manipulation planner use this geometry, each with its own radius: the planner's is estimated
from images, never read from the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import check_finite_scalar

__all__ = ["TipGeometry"]


@dataclass(frozen=True)
class TipGeometry:
    """Sphere-ended cone.

    Parameters
    ----------
    radius_nm : float
        Apex radius, nm (> 0).
    half_angle_deg : float
        Cone half-angle, degrees, in (0, 90).
    """

    radius_nm: float = 10.0
    half_angle_deg: float = 20.0

    def __post_init__(self) -> None:
        r = check_finite_scalar("tip_radius_nm", self.radius_nm)
        a = check_finite_scalar("tip_half_angle_deg", self.half_angle_deg)
        if r <= 0:
            raise ValueError(f"tip_radius_nm must be > 0. Got {r}.")
        if not 0 < a < 90:
            raise ValueError(f"tip_half_angle_deg must be in (0, 90). Got {a}.")
        object.__setattr__(self, "radius_nm", r)
        object.__setattr__(self, "half_angle_deg", a)

    @property
    def trig(self) -> tuple[float, float, float]:
        """``(sin, cos, tan)`` of the cone's half-angle."""
        t = math.radians(self.half_angle_deg)
        return math.sin(t), math.cos(t), math.tan(t)

    def apparent_height(self, d_nm: ArrayLike, particle_radius_nm: float) -> NDArray[np.float64]:
        """Apex height of the tip touching one particle at lateral distance ``d_nm`` (may be
        negative where the tip would touch the plane first: clip at 0 for the image)."""
        d = np.abs(np.asarray(d_nm, dtype=float))
        R, r = float(particle_radius_nm), self.radius_nm
        sin_t, cos_t, tan_t = self.trig
        rr = R + r
        sphere = R + np.sqrt(np.maximum(rr * rr - d * d, 0.0)) - r
        cone = R + rr / sin_t - r - d / tan_t
        return np.where(d <= rr * cos_t, sphere, cone)

    def surface_height(self, s_nm: ArrayLike) -> NDArray[np.float64]:
        """Height of the tip's surface above its apex at lateral distance ``s_nm`` from its
        axis: ``r - sqrt(r^2 - s^2)`` on the sphere (``|s| <= r cos(theta)``), then the
        cone, rising ``1 / tan(theta)`` per nm."""
        s = np.abs(np.asarray(s_nm, dtype=float))
        r = self.radius_nm
        sin_t, cos_t, tan_t = self.trig
        sphere = r - np.sqrt(np.maximum(r * r - s * s, 0.0))
        cone = r * (1.0 - sin_t) + (s - r * cos_t) / tan_t
        return np.where(s <= r * cos_t, sphere, cone)

    def contact_distance(
        self, particle_radius_nm: ArrayLike, z_nm: ArrayLike = 0.0
    ) -> NDArray[np.float64]:
        """Lateral distance between tip axis and particle centre at which the tip, apex at
        height ``z_nm`` (``0 <= z < 2R``; one per particle or one for all), touches the
        particle (inverse of :meth:`apparent_height`)."""
        R = np.asarray(particle_radius_nm, dtype=float)
        z_nm = np.asarray(z_nm, dtype=float)
        r = self.radius_nm
        sin_t, _, tan_t = self.trig
        rr = R + r
        z_t = R + rr * sin_t - r  # apex height at the sphere/cone transition
        cone = (R + rr / sin_t - r - z_nm) * tan_t
        sphere = np.sqrt(np.maximum(rr * rr - (z_nm - R + r) ** 2, 0.0))
        return np.where(z_nm >= z_t, sphere, cone)
