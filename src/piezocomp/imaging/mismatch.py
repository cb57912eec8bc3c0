"""Trace/retrace mismatch of a raster image: how far the forward and backward traces of each
line are shifted against each other.

The per-line shift is measured by normalised cross-correlation with a parabolic sub-pixel
peak (:func:`line_shifts_nm`) and summarised by the median of its absolute value and the
inter-quartile range over lines (:class:`MismatchStats`). Section IV's loop correction
(:mod:`.loop_correction`) is judged by it, before and after.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly

__all__ = [
    "MismatchStats",
    "detrend_rows",
    "line_shifts_nm",
    "mismatch_stats",
]


def detrend_rows(img: NDArray[np.float64]) -> NDArray[np.float64]:
    """Remove a straight line from every row (tilt and offset)."""
    nx = img.shape[1]
    x = np.linspace(-1.0, 1.0, nx)
    basis = np.stack([np.ones(nx), x], axis=1)
    coef, *_ = np.linalg.lstsq(basis, img.T, rcond=None)
    return img - (basis @ coef).T


def line_shifts_nm(
    forward_nm: ArrayLike,
    backward_nm: ArrayLike,
    pixel_nm: float,
    *,
    max_shift_nm: float,
) -> NDArray[np.float64]:
    """Per-line shift of the forward trace against the backward trace (nm).

    For each line, both traces are detrended (a straight line removed) and their normalised
    cross-correlation over the overlapping samples is evaluated at every integer lag up to
    ``max_shift_nm``; the shift is the parabolic vertex through the best lag and its two
    neighbours (sub-pixel).

    Parameters
    ----------
    forward_nm, backward_nm : array_like, shape (ny, nx)
        Forward and backward images on the same position grid (backward stored left to right).
    pixel_nm : float
        Pixel size along the fast axis (nm).
    max_shift_nm : float
        Largest shift searched (nm).

    Returns
    -------
    ndarray, shape (ny,)
        Shift ``s`` (nm) such that ``forward(x) ~ backward(x - s)``: positive when features
        appear further along the line on the forward trace. NaN for a line whose correlation
        has no interior maximum (a flat line, or a shift beyond ``max_shift_nm``).
    """
    f = as_finite_array("forward_nm", forward_nm, ndim=2)
    b = as_finite_array("backward_nm", backward_nm, ndim=2)
    if f.shape != b.shape:
        raise ValueError(
            f"forward_nm and backward_nm must have the same shape. Got {f.shape} and {b.shape}."
        )
    px = check_finite_scalar("pixel_nm", pixel_nm)
    if px <= 0:
        raise ValueError(f"pixel_nm must be > 0. Got {px}.")
    ms = check_finite_scalar("max_shift_nm", max_shift_nm)
    ny, nx = f.shape
    max_lag = int(np.ceil(ms / px)) + 1
    max_lag = min(max_lag, nx // 3)
    if max_lag < 1:
        raise ValueError(f"max_shift_nm ({ms}) must be at least one pixel ({px} nm).")
    f = detrend_rows(f)
    b = detrend_rows(b)
    lags = np.arange(-max_lag, max_lag + 1)
    corr = np.full((ny, lags.size), np.nan)
    for k, lag in enumerate(lags):
        # forward(x) against backward(x - lag): overlap x in [max(0, lag), nx + min(0, lag))
        fs = f[:, max(0, lag) : nx + min(0, lag)]
        bs = b[:, max(0, -lag) : nx - max(0, lag)]
        fs = fs - fs.mean(axis=1, keepdims=True)
        bs = bs - bs.mean(axis=1, keepdims=True)
        den = np.sqrt(np.sum(fs * fs, axis=1) * np.sum(bs * bs, axis=1))
        with np.errstate(invalid="ignore", divide="ignore"):
            corr[:, k] = np.sum(fs * bs, axis=1) / den
    out = np.full(ny, np.nan)
    valid = np.all(np.isfinite(corr), axis=1)
    best = np.argmax(np.where(np.isfinite(corr), corr, -np.inf), axis=1)
    interior = valid & (best > 0) & (best < lags.size - 1)
    rows = np.flatnonzero(interior)
    c0 = corr[rows, best[rows]]
    cm = corr[rows, best[rows] - 1]
    cp = corr[rows, best[rows] + 1]
    curv = cm - 2.0 * c0 + cp
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.where(curv < 0, 0.5 * (cm - cp) / curv, 0.0)
    out[rows] = (lags[best[rows]] + np.clip(off, -0.5, 0.5)) * px
    return out


@dataclass(frozen=True)
class MismatchStats:
    """Trace/retrace mismatch over the lines of an image.

    Attributes
    ----------
    shifts_nm : ndarray, shape (ny,)
        Per-line shift (nm), NaN where it could not be measured.
    median_abs_nm : float
        Median over lines of ``|shift|`` (nm): the mismatch.
    median_nm : float
        Median of the signed shift (nm).
    iqr_nm : float
        Inter-quartile range of the signed shift over lines (nm): the spread.
    p90_abs_nm : float
        90th percentile of ``|shift|`` over lines (nm): the worst lines.
    lines : int
        Lines with a measured shift.
    """

    shifts_nm: NDArray[np.float64]
    median_abs_nm: float
    median_nm: float
    iqr_nm: float
    p90_abs_nm: float
    lines: int

    def to_dict(self) -> dict[str, float | int]:
        """The scalar figures, JSON-ready."""
        return {
            "median_abs_nm": self.median_abs_nm,
            "median_nm": self.median_nm,
            "iqr_nm": self.iqr_nm,
            "p90_abs_nm": self.p90_abs_nm,
            "lines": self.lines,
        }


def mismatch_stats(shifts_nm: ArrayLike) -> MismatchStats:
    """Summarise per-line shifts: median ``|shift|``, signed median and IQR (NaN lines skipped)."""
    s = np.asarray(shifts_nm, dtype=float).ravel()
    good = s[np.isfinite(s)]
    if good.size == 0:
        raise ValueError("no line gave a measurable trace/retrace shift.")
    q1, q3 = np.percentile(good, [25.0, 75.0])
    return MismatchStats(
        shifts_nm=readonly(s),
        median_abs_nm=float(np.median(np.abs(good))),
        median_nm=float(np.median(good)),
        iqr_nm=float(q3 - q1),
        p90_abs_nm=float(np.percentile(np.abs(good), 90.0)),
        lines=int(good.size),
    )
