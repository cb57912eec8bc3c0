"""The sample and the tip: spheres on a rough plane, imaged by a sphere-ended cone.

Geometry (all nm). A particle of radius ``R`` rests on the plane (centre at height ``R``).
The tip is a cone of half-angle ``theta`` ending in a sphere of radius ``r`` tangent to it.
In tapping mode the recorded height is the apex height of the tip resting on the surface,
i.e. the surface dilated by the tip. At lateral distance ``d`` between the tip axis and a
particle centre the tip touches the particle

- with its sphere while ``d <= (R + r) cos(theta)``:
  ``z = R + sqrt((R + r)^2 - d^2) - r``;
- with its cone flank beyond: ``z = R + (R + r)/sin(theta) - r - d/tan(theta)``

(the two agree at the transition). The apparent particle is the part with ``z > 0``; its
full width at the substrate is ``2 d0`` with ``d0 = 2 sqrt(R r)`` when the zero falls on
the spherical part (small ``theta``, ``r > R``) and
``d0 = (R + (R + r)/sin(theta) - r) tan(theta)`` on the cone part.

The substrate is a plane with sub-nm roughness (a sum of random plane waves of 30-600 nm
wavelength), tapping-mode height noise is white and Gaussian. Particles move only when pushed
(:mod:`piezocomp.virtual_afm.pushing`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, readonly
from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm import _kernels as K

__all__ = [
    "Particles",
    "Substrate",
    "topography",
]


@dataclass(frozen=True)
class Particles:
    """Spherical particles on the substrate.

    Attributes
    ----------
    xy_nm : ndarray, shape (n, 2)
        Centre positions in the sample frame, nm.
    diameter_nm : ndarray, shape (n,)
        Diameters, nm (> 0).
    """

    xy_nm: NDArray[np.float64]
    diameter_nm: NDArray[np.float64]

    def __post_init__(self) -> None:
        xy = as_finite_array("particle positions", self.xy_nm)
        if xy.size == 0:
            xy = xy.reshape(0, 2)
        d = as_finite_array("particle diameters", self.diameter_nm, ndim=1)
        if xy.ndim != 2 or xy.shape[1] != 2 or d.shape != (xy.shape[0],):
            raise ValueError(
                f"particles need xy_nm (n, 2) and diameter_nm (n,). Got {xy.shape}, {d.shape}."
            )
        if d.size and d.min() <= 0:
            raise ValueError(f"particle diameters must be > 0. Got {d.min()}.")
        object.__setattr__(self, "xy_nm", readonly(xy))
        object.__setattr__(self, "diameter_nm", readonly(d))

    def __len__(self) -> int:
        return int(self.diameter_nm.size)

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        per_um2: float,
        half_width_nm: float,
        diameter_nm: float = 15.0,
        diameter_std_nm: float = 0.0,
        min_gap_nm: float = 2.0,
    ) -> Particles:
        """Poisson-distributed particles in the square ``+-half_width_nm``, overlapping
        ones (closer than the sum of radii + ``min_gap_nm``) dropped."""
        from scipy.spatial import cKDTree

        area_um2 = (2 * half_width_nm / 1000.0) ** 2
        n = int(rng.poisson(per_um2 * area_um2))
        xy = rng.uniform(-half_width_nm, half_width_nm, size=(n, 2))
        d = diameter_nm + diameter_std_nm * rng.standard_normal(n)
        d = np.clip(d, 0.3 * diameter_nm, None)
        keep = np.ones(n, bool)
        if n:
            tree = cKDTree(xy)
            for i, j in sorted(tree.query_pairs(float(d.max()) + min_gap_nm)):
                if keep[i] and keep[j]:
                    if np.hypot(*(xy[i] - xy[j])) < 0.5 * (d[i] + d[j]) + min_gap_nm:
                        keep[j] = False
        return cls(xy[keep], d[keep])


@dataclass(frozen=True)
class Substrate:
    """Flat substrate with smooth sub-nm roughness: ``sum_j a_j cos(k_j . x + phi_j)``."""

    kx: NDArray[np.float64]
    ky: NDArray[np.float64]
    phase: NDArray[np.float64]
    amplitude_nm: NDArray[np.float64]

    def __post_init__(self) -> None:
        for name in ("kx", "ky", "phase", "amplitude_nm"):
            object.__setattr__(self, name, readonly(getattr(self, name)))

    @classmethod
    def random(cls, rng: np.random.Generator, rms_nm: float, n_waves: int = 24) -> Substrate:
        """Roughness of rms ``rms_nm`` from ``n_waves`` random plane waves (30-600 nm)."""
        lam = np.exp(rng.uniform(np.log(30.0), np.log(600.0), n_waves))
        ang = rng.uniform(0, 2 * np.pi, n_waves)
        ph = rng.uniform(0, 2 * np.pi, n_waves)
        k = 2 * np.pi / lam
        amp = np.full(n_waves, rms_nm * np.sqrt(2.0 / n_waves))
        return cls(k * np.cos(ang), k * np.sin(ang), ph, amp)

    @classmethod
    def flat(cls) -> Substrate:
        """A perfectly flat substrate."""
        z = np.zeros(0)
        return cls(z, z, z, z)


def _cell_list(
    xy: NDArray[np.float64], cell: float
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], float, float, int, int]:
    if xy.shape[0] == 0:
        return (np.zeros(0, np.intp), np.zeros(1, np.intp), np.zeros(1, np.intp), 0.0, 0.0, 1, 1)
    x0 = float(xy[:, 0].min()) - cell
    y0 = float(xy[:, 1].min()) - cell
    ncx = int((xy[:, 0].max() - x0) // cell) + 2
    ncy = int((xy[:, 1].max() - y0) // cell) + 2
    ix = ((xy[:, 0] - x0) // cell).astype(np.intp)
    iy = ((xy[:, 1] - y0) // cell).astype(np.intp)
    cid = iy * ncx + ix
    order = np.argsort(cid, kind="stable")
    counts = np.bincount(cid, minlength=ncx * ncy).astype(np.intp)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)
    return order, start, counts, x0, y0, ncx, ncy


_LAST_CELLS: list[tuple[NDArray[np.float64], float, tuple[Any, ...]]] = []
"""The last particles' cell list (their read-only position array, the cell size, the list):
a run of single samples (the Nanonis emulator's set-points) then sorts the particles once,
not at every sample."""


def _cells_of(xy: NDArray[np.float64], cell: float) -> tuple[Any, ...]:
    last = _LAST_CELLS[0] if _LAST_CELLS else None  # one read: another thread may replace it
    if last is not None and last[0] is xy and last[1] == cell:
        return last[2]
    cells = _cell_list(xy, cell)
    if not xy.flags.writeable:  # an array that cannot change under the cache
        _LAST_CELLS[:] = [(xy, cell, cells)]
    return cells


def topography(
    positions_nm: ArrayLike,
    particles: Particles,
    tip: TipGeometry,
    substrate: Substrate,
    noise_nm: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Tapping-mode height (nm) at the true tip positions ``positions_nm`` (n, 2).

    The height is the maximum of the plane (0) and every tip-dilated particle, plus the
    substrate roughness at the tip position and the given noise samples.
    """
    pos = np.ascontiguousarray(as_finite_array("positions_nm", positions_nm, ndim=2))
    n = pos.shape[0]
    noise = np.zeros(n) if noise_nm is None else np.ascontiguousarray(noise_nm, dtype=float)
    R = 0.5 * np.asarray(particles.diameter_nm)
    reach = float(tip.contact_distance(R, 0.0).max()) if len(particles) else 1.0
    cell = max(reach, 1.0)
    order, start, counts, x0, y0, ncx, ncy = _cells_of(np.asarray(particles.xy_nm), cell)
    xy = np.asarray(particles.xy_nm)[order]
    sin_t, cos_t, tan_t = tip.trig
    out = np.empty(n)
    K.heights_at(
        pos, np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]),
        np.ascontiguousarray(R[order]), start, counts, x0, y0, cell, ncx, ncy,
        tip.radius_nm, sin_t, cos_t, tan_t,
        np.array(substrate.kx), np.array(substrate.ky), np.array(substrate.phase),
        np.array(substrate.amplitude_nm), noise, out,
    )  # fmt: skip
    return out
