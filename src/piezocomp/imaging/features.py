"""Particles in images: where the round features of a scan are, to a fraction of a pixel.

The paper's experiments and its automatic manipulation rest on locating nanoparticles in
AFM images (Secs. IV-V): a particle's apex is the one point of its image that every scan
sees at the same place. :func:`find_particles` levels the image (a plane fitted to the
substrate), finds the local maxima that rise above ``min_height_nm``
(:func:`skimage.feature.peak_local_max`) and refines each to a fraction of a pixel by the
vertex of a quadratic surface fitted by least squares to the pixels near its apex (there the
image of a sphere dilated by the tip is a paraboloid; a window of +-8 nm averages the
height noise over many pixels). Positions are in the image's frame: nominal
commands for a raw instrument, true nanometres for a compensated one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from skimage.feature import peak_local_max

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.instrument import ScanImage

__all__ = ["FoundParticles", "find_particles", "level", "particles_near_line", "trace_heights"]


@dataclass(frozen=True)
class FoundParticles:
    """Particles found in an image.

    Attributes
    ----------
    positions_nm : ndarray, shape (n, 2)
        ``(x, y)`` of each apex in the image's frame, nm.
    heights_nm : ndarray, shape (n,)
        Apex height above the levelled substrate, nm (about the particle's diameter).
    """

    positions_nm: NDArray[np.float64]
    heights_nm: NDArray[np.float64]

    def __post_init__(self) -> None:
        p = readonly(np.asarray(self.positions_nm, dtype=float).reshape(-1, 2))
        h = readonly(np.asarray(self.heights_nm, dtype=float).reshape(-1))
        if h.size != p.shape[0]:
            raise ValueError(f"one height per position: got {p.shape[0]} and {h.size}.")
        object.__setattr__(self, "positions_nm", p)
        object.__setattr__(self, "heights_nm", h)

    def __len__(self) -> int:
        return int(self.heights_nm.size)


def level(heights_nm: ArrayLike, *, rounds: int = 3, clip_nm: float = 1.0) -> NDArray[np.float64]:
    """Heights above a plane fitted to the substrate.

    The plane is fitted by least squares to every pixel, then again to the pixels within
    ``clip_nm`` of the previous plane (the particles drop out), ``rounds`` times.
    """
    z = as_finite_array("heights_nm", heights_nm, ndim=2)
    ny, nx = z.shape
    yy, xx = np.mgrid[0:ny, 0:nx]
    a = np.column_stack([np.ones(z.size), xx.ravel(), yy.ravel()])
    keep = np.ones(z.size, bool)
    plane = np.zeros(z.size)
    for _ in range(max(1, int(rounds))):
        coef, *_ = np.linalg.lstsq(a[keep], z.ravel()[keep], rcond=None)
        plane = a @ coef
        resid = z.ravel() - plane
        new = resid < clip_nm
        if new.sum() < 3:
            break
        keep = new
    return np.asarray((z.ravel() - plane).reshape(ny, nx))


def trace_heights(image: ScanImage, trace: str = "forward") -> NDArray[np.float64]:
    """One trace of an image: ``"forward"``, ``"backward"`` or ``"mean"`` (both averaged:
    for images whose traces coincide, a compensated instrument's or after loop
    correction)."""
    if not isinstance(image, ScanImage):
        raise TypeError(f"image must be a ScanImage. Got {type(image).__name__}.")
    if trace == "forward":
        return np.asarray(image.forward_nm)
    if trace == "backward":
        return np.asarray(image.backward_nm)
    if trace == "mean":
        return 0.5 * (np.asarray(image.forward_nm) + np.asarray(image.backward_nm))
    raise ValueError(f"trace must be 'forward', 'backward' or 'mean'. Got {trace!r}.")


APEX_HALF_WIDTH_NM = 8.0
"""Half-width of the window about a maximum in which its apex is fitted."""

APEX_DEPTH_NM = 3.0
"""The apex fit uses the pixels within this of the maximum's height (near its apex the image
of a 15 nm sphere dilated by a 10 nm tip is a paraboloid to a few hundredths of a nm)."""


def _vertex(z: NDArray[np.float64], i: int, j: int, half: int) -> tuple[float, float]:
    """Sub-pixel (row, column) of the apex near pixel ``(i, j)``: the vertex of a quadratic
    surface fitted by least squares to the pixels of the ``(2 half + 1)^2`` window about it
    that lie within :data:`APEX_DEPTH_NM` of its height. The pixel itself if the fit has no
    maximum within a pixel of it."""
    r0, r1 = max(i - half, 0), min(i + half + 1, z.shape[0])
    c0, c1 = max(j - half, 0), min(j + half + 1, z.shape[1])
    w = z[r0:r1, c0:c1]
    yy, xx = np.mgrid[r0 - i : r1 - i, c0 - j : c1 - j]
    sel = w >= z[i, j] - APEX_DEPTH_NM
    if sel.sum() < 6:
        return float(i), float(j)
    x, y, h = xx[sel].astype(float), yy[sel].astype(float), w[sel]
    a = np.column_stack([np.ones_like(x), x, y, x * x, y * y, x * y])
    c, *_ = np.linalg.lstsq(a, h, rcond=None)
    _, bx, by, cxx, cyy, cxy = c
    det = 4 * cxx * cyy - cxy * cxy
    if not (cxx < 0 and det > 0):
        return float(i), float(j)
    ox = (cxy * by - 2 * cyy * bx) / det
    oy = (cxy * bx - 2 * cxx * by) / det
    if abs(ox) > 1 or abs(oy) > 1:
        return float(i), float(j)
    return i + float(oy), j + float(ox)


def find_particles(
    image: ScanImage,
    *,
    trace: str = "forward",
    min_height_nm: float = 3.0,
    min_separation_nm: float = 12.0,
) -> FoundParticles:
    """Particles (local maxima at least ``min_height_nm`` above the substrate) of an image.

    Parameters
    ----------
    image : ScanImage
    trace : {"forward", "backward", "mean"}
        Which trace to read (:func:`trace_heights`).
    min_height_nm : float
        Smallest apex height above the levelled substrate (> 0).
    min_separation_nm : float
        Smallest distance between two particles' apexes (>= 0); of two closer maxima the
        higher is kept.

    Returns
    -------
    FoundParticles
        Sorted by y, then x. Maxima on the image's border are not reported (their shape is
        cut).
    """
    raw = trace_heights(image, trace)
    hmin = check_finite_scalar("min_height_nm", min_height_nm)
    if hmin <= 0:
        raise ValueError(f"min_height_nm must be > 0. Got {hmin}.")
    sep = check_finite_scalar("min_separation_nm", min_separation_nm)
    if sep < 0:
        raise ValueError(f"min_separation_nm must be >= 0. Got {sep}.")
    z = level(raw)
    if image.x_nm.size < 3 or image.y_nm.size < 3:
        return FoundParticles(np.zeros((0, 2)), np.zeros(0))
    px = float(np.mean(np.abs(np.diff(image.x_nm))))
    py = float(np.mean(np.abs(np.diff(image.y_nm))))
    distance = max(1, int(sep / max(px, py)))
    half = max(1, round(APEX_HALF_WIDTH_NM / max(px, py)))
    peaks = peak_local_max(z, min_distance=distance, threshold_abs=hmin, exclude_border=1)
    rows, cols, hs = [], [], []
    for i, j in peaks:
        r, c = _vertex(z, int(i), int(j), half)
        rows.append(r)
        cols.append(c)
        hs.append(float(z[i, j]))
    x = np.interp(cols, np.arange(image.x_nm.size), image.x_nm)
    y = np.interp(rows, np.arange(image.y_nm.size), image.y_nm)
    order = np.lexsort((x, y))
    pos = np.column_stack([x, y])[order] if len(rows) else np.zeros((0, 2))
    return FoundParticles(pos, np.asarray(hs)[order] if hs else np.zeros(0))


def particles_near_line(
    particles: FoundParticles,
    *,
    axis: str,
    extent_nm: tuple[float, float],
    tolerance_nm: float = 6.0,
) -> tuple[float, NDArray[np.float64]]:
    """The line (along ``axis``) through the most particles within ``extent_nm``.

    A particle counts if its apex lies within ``tolerance_nm`` of the line across it (a
    scan line that passes that close still peaks at the apex's position along the line).

    Returns
    -------
    slow_nm : float
        Position of the line across ``axis`` (y for an x line): the mean of its particles'.
    along_nm : ndarray
        Positions of those particles along the line, sorted.
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y'. Got {axis!r}.")
    tol = check_finite_scalar("tolerance_nm", tolerance_nm)
    k = 0 if axis == "x" else 1
    p = particles.positions_nm
    lo, hi = (check_finite_scalar("extent_nm", v) for v in extent_nm)
    inside = p[(p[:, k] >= lo) & (p[:, k] <= hi)]
    if inside.shape[0] == 0:
        return float("nan"), np.zeros(0)
    across = inside[:, 1 - k]
    counts = [(np.abs(across - c) <= tol).sum() for c in across]
    best = int(np.argmax(counts))
    sel = np.abs(across - across[best]) <= tol
    return float(np.mean(across[sel])), np.sort(inside[sel, k])
