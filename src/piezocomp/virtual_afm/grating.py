"""A calibration grating: the length reference of a lateral scanner calibration.

Particles give the scanner's loop only up to a smooth odd change of the length scale
(Section IV's symmetry and calibration condition leave the slope inside the span free, see
``docs/identification.md``); AFM practice fixes lengths with a grating of certified pitch.
For spans of about a micrometre the reference is a holographic grating of a few hundred
nanometres pitch (e.g. NT-MDT TDG01, 278 nm), whose profile is close to a sinusoid.

:class:`Grating` is such a sample: parallel lines perpendicular to one axis, height
``h(x) = (H / 2) (1 + cos(2 pi (x - x0) / P))`` along that axis, constant along the other.
The recorded height is the profile dilated by the tip (the apex height of the tip resting
on the surface), computed once per tip over one period on a fine grid.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm.sample import Substrate

__all__ = ["Grating", "grating_topography"]

_TABLE_POINTS = 4096


@dataclass(frozen=True)
class Grating:
    """A 1-D sinusoidal grating (lengths nm).

    Parameters
    ----------
    pitch_nm : float
        True period ``P`` (> 0).
    height_nm : float
        Peak-to-valley height ``H`` (> 0).
    axis : {"x", "y"}
        The axis along which the height varies (the lines run along the other one).
    phase_nm : float
        Position ``x0`` of a crest in the sample frame.
    angle_deg : float
        Rotation of the grating from perpendicular to ``axis``, degrees in (-45, 45): a
        grating mounted by hand is rarely square to the scanner. The profile's coordinate
        is then ``x cos(a) + y sin(a)`` (``axis="x"``) or ``y cos(a) - x sin(a)``
        (``axis="y"``), so the period along the axis is ``P / cos(a)``.
    """

    pitch_nm: float = 278.0
    height_nm: float = 25.0
    axis: str = "x"
    phase_nm: float = 0.0
    angle_deg: float = 0.0

    def __post_init__(self) -> None:
        p = check_finite_scalar("grating pitch_nm", self.pitch_nm)
        h = check_finite_scalar("grating height_nm", self.height_nm)
        x0 = check_finite_scalar("grating phase_nm", self.phase_nm)
        if p <= 0 or h <= 0:
            raise ValueError(f"grating pitch_nm and height_nm must be > 0. Got {p}, {h}.")
        if self.axis not in ("x", "y"):
            raise ValueError(f"grating axis must be 'x' or 'y'. Got {self.axis!r}.")
        object.__setattr__(self, "pitch_nm", p)
        object.__setattr__(self, "height_nm", h)
        object.__setattr__(self, "phase_nm", x0)
        a = check_finite_scalar("grating angle_deg", self.angle_deg)
        if not -45.0 < a < 45.0:
            raise ValueError(f"grating angle_deg must be in (-45, 45). Got {a}.")
        object.__setattr__(self, "angle_deg", a)

    def coordinate(self, positions_nm: NDArray[np.float64]) -> NDArray[np.float64]:
        """The coordinate across the lines at sample-frame positions (n, 2), nm."""
        a = np.radians(self.angle_deg)
        x, y = positions_nm[:, 0], positions_nm[:, 1]
        if self.axis == "x":
            return np.asarray(x * np.cos(a) + y * np.sin(a))
        return np.asarray(y * np.cos(a) - x * np.sin(a))

    def profile(self, x_nm: ArrayLike) -> NDArray[np.float64]:
        """Undilated height (nm) at coordinate ``x_nm`` along :attr:`axis`."""
        x = np.asarray(x_nm, dtype=float)
        return (
            0.5 * self.height_nm * (1.0 + np.cos(2 * np.pi * (x - self.phase_nm) / self.pitch_nm))
        )


@lru_cache(maxsize=16)
def _dilated_table(grating: Grating, tip: TipGeometry) -> NDArray[np.float64]:
    """Dilated profile over one period, ``_TABLE_POINTS`` samples from the crest on:
    ``max_s h(x + s) - t(s)`` with ``t`` the tip's surface height."""
    P = grating.pitch_nm
    dx = P / _TABLE_POINTS
    x = grating.phase_nm + dx * np.arange(_TABLE_POINTS)
    h = grating.profile(x)
    out = h.copy()
    k = 1
    while True:
        t = float(tip.surface_height(k * dx))
        if t > grating.height_nm or k >= _TABLE_POINTS // 2:
            break
        np.maximum(out, np.roll(h, -k) - t, out=out)
        np.maximum(out, np.roll(h, k) - t, out=out)
        k += 1
    return readonly(out)


def grating_topography(
    positions_nm: ArrayLike,
    grating: Grating,
    tip: TipGeometry,
    substrate: Substrate,
    noise_nm: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Tapping-mode height (nm) over ``grating`` at the true tip positions (n, 2): the
    tip-dilated profile (periodic linear interpolation of the table), plus the substrate
    roughness at the tip position and the given noise samples."""
    pos = as_finite_array("positions_nm", positions_nm, ndim=2)
    c = grating.coordinate(pos)
    table = _dilated_table(grating, tip)
    f = ((c - grating.phase_nm) / grating.pitch_nm) % 1.0 * _TABLE_POINTS
    i = np.floor(f).astype(np.intp)
    w = f - i
    z = (1.0 - w) * table[i % _TABLE_POINTS] + w * table[(i + 1) % _TABLE_POINTS]
    if substrate.kx.size:
        ph = np.outer(pos[:, 0], substrate.kx) + np.outer(pos[:, 1], substrate.ky) + substrate.phase
        z = z + np.cos(ph) @ np.asarray(substrate.amplitude_nm)
    if noise_nm is not None:
        z = z + np.asarray(noise_nm, dtype=float)
    return np.asarray(z, dtype=float)
