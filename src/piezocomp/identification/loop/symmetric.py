"""The steady, point-symmetric hysteresis loop of one scan line (Section IV, eqs (21)-(23)).

A steady hysteresis loop between the commands ``u_min`` and ``u_max`` is point-symmetric about
its centre ``(u_s, y_s)`` (21): the descending branch is the ascending branch rotated by half a
turn (22),

.. math:: f_d(u) = 2 y_s - f_a(2 u_s - u).

A feature seen at ``u_a`` on the forward (ascending) trace and at ``u_d`` on the backward
(descending) trace sits at one true position, ``f_a(u_a) = f_d(u_d)``, which with (22) reads

.. math:: f_a(u_a) + f_a(2 u_s - u_d) = 2 y_s \\qquad (23)

one linear equation in the coefficients of a polynomial ``f_a`` per feature. The scale is fixed
by the calibration condition ``f_a(u_max) - f_a(u_min) = u_max - u_min``.

Conventions
-----------
* ``u_s = (u_min + u_max) / 2`` (steady symmetric cycle) and ``y_s = u_s``: the true position
  is only known up to a constant, and (23) does not involve it once ``f_a`` is written about
  ``y_s``; the loop's centre is put at the nominal centre. The constant term of ``f_a`` about
  ``y_s`` is then fitted: it is minus half the loop's width at the centre.
* ``f_a(u) = y_s + h P(s)`` with ``h = (u_max - u_min) / 2`` and ``s = (u - u_s) / h`` in
  ``[-1, 1]``; ``P`` is stored by its ascending coefficients (well conditioned).
* What (23) cannot see: if ``f_a`` solves (23), so does ``g(f_a)`` for any odd ``g`` about
  ``y_s`` (an odd distortion of the true axis moves both branches alike). For a curved loop
  the polynomial solutions of a given degree are unique up to scale; for a loop close to a
  pure shift they are not, and :meth:`SymmetricLoop.from_peaks` picks, among the coefficient
  vectors that fit equally well, the one with the least curvature (``int P''(s)^2 ds``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.polynomial import polynomial as npoly
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, as_finite_array, check_finite_scalar, readonly

__all__ = ["SymmetricLoop"]


def _min_slope(coef: NDArray[np.float64]) -> tuple[float, float]:
    """Smallest value of ``P'(s)`` on ``[-1, 1]`` and where it is attained."""
    d1 = npoly.polyder(coef)
    candidates = [-1.0, 1.0]
    if d1.size > 1:
        d2 = npoly.polyder(d1)
        if d2.size and np.any(d2 != 0):
            roots = npoly.polyroots(d2) if d2.size > 1 else np.empty(0)
            real = roots[np.abs(roots.imag) < 1e-9].real
            candidates.extend(float(r) for r in real if -1.0 <= r <= 1.0)
    s = np.array(candidates)
    slope = npoly.polyval(s, d1)
    i = int(np.argmin(slope))
    return float(slope[i]), float(s[i])


def _calibrated_coefficients(
    s_a: NDArray[np.float64],
    s_d: NDArray[np.float64],
    degree: int,
    smoothing: float,
    rcond: float,
) -> NDArray[np.float64]:
    """The coefficients of ``P`` (eq 23 about the centre) from the pairs' scaled commands:
    least squares of ``P(s_a) + P(-s_d) = 0`` with ``P(1) - P(-1) = 2`` met exactly, the
    least-curvature solution where the pairs leave directions free, and an optional
    curvature penalty."""
    powers = np.arange(degree + 1)
    design = s_a[:, None] ** powers + (-s_d[:, None]) ** powers
    # Calibration row: P(1) - P(-1) = 2 -> sum_k c_k (1 - (-1)^k) = 2.
    cal = 1.0 - (-1.0) ** powers
    particular = np.zeros(degree + 1)
    particular[1] = 1.0  # P(s) = s meets the calibration condition
    # Null space of the calibration row: c = particular + N z.
    _, _, vt = np.linalg.svd(cal[None, :])
    null = vt[1:].T
    # Least-curvature metric on z (small identity part keeps it definite).
    gram = _curvature_gram(degree)
    metric = null.T @ gram @ null
    metric += 1e-6 * (np.trace(metric) / metric.shape[0] + 1.0) * np.eye(metric.shape[0])
    chol = np.linalg.cholesky(metric)
    a = design @ null
    b = -design @ particular
    # Substitute z = chol^-T w, so the minimum-norm w is the least-curvature z.
    a_w = np.linalg.solve(chol, a.T).T
    if smoothing > 0:
        # Tikhonov on the curvature: mean residual^2 + smoothing * int P''^2 ds.
        ridge = np.sqrt(smoothing * s_a.size) * np.eye(a_w.shape[1])
        a_w = np.vstack([a_w, ridge])
        b = np.concatenate([b, np.zeros(a_w.shape[1])])
    w, *_ = np.linalg.lstsq(a_w, b, rcond=rcond)
    z = np.linalg.solve(chol.T, w)
    coef = particular + null @ z
    return np.asarray(coef)


def _curvature_gram(degree: int) -> NDArray[np.float64]:
    """Gram matrix ``G[j, k] = int_{-1}^{1} (s^j)'' (s^k)'' ds`` of the monomials."""
    g = np.zeros((degree + 1, degree + 1))
    for j in range(2, degree + 1):
        for k in range(2, degree + 1):
            p = j + k - 4
            if p % 2 == 0:
                g[j, k] = j * (j - 1) * k * (k - 1) * 2.0 / (p + 1)
    return g


@dataclass(frozen=True)
class SymmetricLoop:
    """A steady point-symmetric hysteresis loop, ascending branch a polynomial (eqs (21)-(22)).

    Parameters
    ----------
    coefficients : array_like, shape (degree + 1,)
        Ascending coefficients of ``P`` in ``f_a(u) = y_s + h P((u - u_s) / h)``,
        ``h = (u_max - u_min) / 2`` (dimensionless).
    u_min_nm, u_max_nm : float
        Extremes of the command over the cycle (nominal nm), ``u_min < u_max``.
    u_s_nm : float, optional
        Centre command of the loop (nm). Default ``(u_min + u_max) / 2``, the steady cycle.
    y_s_nm : float, optional
        Centre position of the loop (nm). Default ``u_s_nm`` (see the module notes).

    Raises
    ------
    ValueError
        If ``f_a`` is not strictly increasing over ``[u_min, u_max]``.
    """

    coefficients: NDArray[np.float64]
    u_min_nm: float
    u_max_nm: float
    u_s_nm: float = field(default=np.nan)
    y_s_nm: float = field(default=np.nan)

    def __post_init__(self) -> None:
        coef = as_finite_1d("coefficients", self.coefficients)
        if coef.size < 2:
            raise ValueError(f"coefficients must have at least 2 entries. Got {coef.size}.")
        u_min = check_finite_scalar("u_min_nm", self.u_min_nm)
        u_max = check_finite_scalar("u_max_nm", self.u_max_nm)
        if not u_min < u_max:
            raise ValueError(f"u_min_nm must be < u_max_nm. Got {u_min} and {u_max}.")
        u_s = 0.5 * (u_min + u_max) if np.isnan(self.u_s_nm) else self.u_s_nm
        u_s = check_finite_scalar("u_s_nm", u_s)
        y_s = u_s if np.isnan(self.y_s_nm) else self.y_s_nm
        y_s = check_finite_scalar("y_s_nm", y_s)
        object.__setattr__(self, "coefficients", readonly(coef))
        object.__setattr__(self, "u_min_nm", u_min)
        object.__setattr__(self, "u_max_nm", u_max)
        object.__setattr__(self, "u_s_nm", u_s)
        object.__setattr__(self, "y_s_nm", y_s)
        slope, where = self._min_slope()
        if not slope > 0:
            raise ValueError(
                "the ascending branch f_a must be strictly increasing over "
                f"[u_min_nm, u_max_nm] = [{u_min}, {u_max}]. Got slope {slope:.3g} at "
                f"u = {self._u(where):.6g} nm."
            )

    # -- helpers -------------------------------------------------------------------------
    @property
    def half_range_nm(self) -> float:
        """``h = (u_max - u_min) / 2`` (nm), the normalisation of the command."""
        return 0.5 * (self.u_max_nm - self.u_min_nm)

    @property
    def degree(self) -> int:
        """Degree of the polynomial ``f_a``."""
        return int(self.coefficients.size - 1)

    def _s(self, u: Any) -> Any:
        return (u - self.u_s_nm) / self.half_range_nm

    def _u(self, s: Any) -> Any:
        return self.u_s_nm + self.half_range_nm * s

    def _min_slope(self) -> tuple[float, float]:
        # The slope of f_a about the normalised variable is P'(s) (h cancels).
        s_lo = self._s(self.u_min_nm)
        s_hi = self._s(self.u_max_nm)
        if np.isclose(s_lo, -1.0) and np.isclose(s_hi, 1.0):
            return _min_slope(np.asarray(self.coefficients))
        s = np.linspace(s_lo, s_hi, 4001)
        slope = npoly.polyval(s, npoly.polyder(self.coefficients))
        i = int(np.argmin(slope))
        return float(slope[i]), float(s[i])

    # -- the branches ----------------------------------------------------------------------
    def ascending(self, u_nm: ArrayLike) -> Any:
        """Ascending branch ``y = f_a(u)`` (nm), the forward trace's true position."""
        u = as_finite_array("u_nm", u_nm)
        return self.y_s_nm + self.half_range_nm * npoly.polyval(self._s(u), self.coefficients)

    def descending(self, u_nm: ArrayLike) -> Any:
        """Descending branch ``f_d(u) = 2 y_s - f_a(2 u_s - u)`` (nm), eq (22)."""
        u = as_finite_array("u_nm", u_nm)
        return 2.0 * self.y_s_nm - self.ascending(2.0 * self.u_s_nm - u)

    def ascending_slope(self, u_nm: ArrayLike) -> Any:
        """Slope ``d f_a / d u`` (dimensionless)."""
        u = as_finite_array("u_nm", u_nm)
        return npoly.polyval(self._s(u), npoly.polyder(self.coefficients))

    def descending_slope(self, u_nm: ArrayLike) -> Any:
        """Slope ``d f_d / d u = f_a'(2 u_s - u)`` (dimensionless), from eq (22)."""
        u = as_finite_array("u_nm", u_nm)
        return self.ascending_slope(2.0 * self.u_s_nm - u)

    def ascending_inverse(self, y_nm: ArrayLike, *, tol_nm: float = 1e-10) -> Any:
        """Command ``u`` with ``f_a(u) = y`` (nm), vectorised.

        Inside ``[f_a(u_min), f_a(u_max)]`` the inverse is exact (safeguarded Newton in a
        bracket, to ``tol_nm``); outside, it continues ``f_a`` as a straight line with the end
        slope, so the inverse stays monotone.
        """
        y = as_finite_array("y_nm", y_nm)
        y_lo = float(self.ascending(self.u_min_nm))
        y_hi = float(self.ascending(self.u_max_nm))
        lo = np.full(y.shape, self.u_min_nm)
        hi = np.full(y.shape, self.u_max_nm)
        grid = np.linspace(self.u_min_nm, self.u_max_nm, 513)
        u = np.interp(y, self.ascending(grid), grid)
        for _ in range(100):
            r = self.ascending(u) - y
            lo = np.where(r < 0, u, lo)
            hi = np.where(r > 0, u, hi)
            step = r / self.ascending_slope(u)
            new = u - step
            outside = (new <= lo) | (new >= hi)
            new = np.where(outside, 0.5 * (lo + hi), new)
            done = np.abs(new - u) <= tol_nm
            u = new
            if np.all(done | (y <= y_lo) | (y >= y_hi)):
                break
        below = y < y_lo
        above = y > y_hi
        u = np.where(
            below, self.u_min_nm + (y - y_lo) / float(self.ascending_slope(self.u_min_nm)), u
        )
        u = np.where(
            above, self.u_max_nm + (y - y_hi) / float(self.ascending_slope(self.u_max_nm)), u
        )
        return u

    def descending_inverse(self, y_nm: ArrayLike) -> Any:
        """Command ``u`` with ``f_d(u) = y`` (nm): ``2 u_s - f_a^{-1}(2 y_s - y)``, eq (22)."""
        y = as_finite_array("y_nm", y_nm)
        return 2.0 * self.u_s_nm - self.ascending_inverse(2.0 * self.y_s_nm - y)

    def pair_residuals_nm(self, u_ascending_nm: ArrayLike, u_descending_nm: ArrayLike) -> Any:
        """``f_a(u_a) - f_d(u_d)`` (nm): how far apart the loop puts each feature, eq (23)."""
        return self.ascending(u_ascending_nm) - self.descending(u_descending_nm)

    # -- fitting ---------------------------------------------------------------------------
    @classmethod
    def from_peaks(
        cls,
        u_ascending_nm: ArrayLike,
        u_descending_nm: ArrayLike,
        u_min_nm: float,
        u_max_nm: float,
        degree: int = 5,
        *,
        smoothing: float = 0.0,
        rcond: float = 1e-9,
    ) -> SymmetricLoop:
        """Fit ``f_a`` to features seen on both traces, eq (23), in least squares.

        Each pair ``(u_a, u_d)`` gives ``P(s_a) + P(-s_d) = 0`` (eq (23) about the centre,
        ``s = (u - u_s) / h``), solved in least squares together with the calibration
        condition ``f_a(u_max) - f_a(u_min) = u_max - u_min``, i.e. ``P(1) - P(-1) = 2``, as a
        hard (exactly met) constraint.

        Parameters
        ----------
        u_ascending_nm, u_descending_nm : array_like, shape (n,)
            Command at which each feature is seen on the forward and on the backward trace.
        u_min_nm, u_max_nm : float
            Extremes of the steady command cycle (nm).
        degree : int, optional
            Degree of ``f_a`` (the paper uses >= 5). Needs more than ``degree`` pairs.
        rcond : float, optional
            Relative singular-value cut-off of the least-squares problem; directions the pairs
            do not determine better than this are set to the least-curvature choice.

        Returns
        -------
        SymmetricLoop

        Raises
        ------
        ValueError
            Too few pairs, commands outside ``[u_min, u_max]``, or a fitted ``f_a`` that is not
            strictly increasing over ``[u_min, u_max]`` (the pairs cannot be a steady loop).
        """
        u_a = as_finite_1d("u_ascending_nm", u_ascending_nm)
        u_d = as_finite_1d("u_descending_nm", u_descending_nm)
        if u_a.size != u_d.size:
            raise ValueError(
                "u_ascending_nm and u_descending_nm must have the same length (one pair per "
                f"feature). Got {u_a.size} and {u_d.size}."
            )
        if isinstance(degree, bool) or not isinstance(degree, int | np.integer):
            raise TypeError(f"degree must be an integer. Got {degree!r}.")
        degree = int(degree)
        if degree < 1:
            raise ValueError(f"degree must be >= 1. Got {degree}.")
        u_min = check_finite_scalar("u_min_nm", u_min_nm)
        u_max = check_finite_scalar("u_max_nm", u_max_nm)
        if not u_min < u_max:
            raise ValueError(f"u_min_nm must be < u_max_nm. Got {u_min} and {u_max}.")
        smoothing = check_finite_scalar("smoothing", smoothing)
        if smoothing < 0:
            raise ValueError(f"smoothing must be >= 0. Got {smoothing}.")
        if u_a.size <= degree:
            raise ValueError(
                f"a loop of degree {degree} needs more than {degree} feature pairs "
                f"(eq. (23) gives one equation per pair). Got {u_a.size}."
            )
        span = u_max - u_min
        for name, u in (("u_ascending_nm", u_a), ("u_descending_nm", u_d)):
            bad = (u < u_min - 1e-9 * span) | (u > u_max + 1e-9 * span)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"{name} must lie in [u_min_nm, u_max_nm] = [{u_min}, {u_max}]. "
                    f"Got {u[i]} at index {i}."
                )
        h = 0.5 * span
        u_s = 0.5 * (u_min + u_max)
        s_a = (u_a - u_s) / h
        s_d = (u_d - u_s) / h
        coef = _calibrated_coefficients(s_a, s_d, degree, smoothing, rcond)
        slope, where = _min_slope(coef)
        if not slope > 0:
            raise ValueError(
                f"the {u_a.size} feature pairs do not describe a steady loop: the fitted "
                f"ascending branch f_a (degree {degree}) is not strictly increasing over "
                f"[{u_min}, {u_max}] nm (slope {slope:.3g} at u = {u_s + h * where:.6g} nm). "
                "Check the pairing, use a lower degree or more features."
            )
        return cls(coef, u_min, u_max)

    @classmethod
    def from_line_pairs(
        cls,
        pairs: Iterable[tuple[ArrayLike, ArrayLike]],
        u_min_nm: float,
        u_max_nm: float,
        degree: int = 5,
        *,
        smoothing: float = 0.0,
        rcond: float = 1e-9,
    ) -> SymmetricLoop:
        """Fit one loop to the pairs of many scan lines, eq (23) for every pair of every line.

        Parameters
        ----------
        pairs : iterable of (u_ascending_nm, u_descending_nm)
            For each line, the commands at which its features are seen on the forward and
            backward trace. All lines share the cycle ``[u_min_nm, u_max_nm]``.
        u_min_nm, u_max_nm, degree, rcond
            As in :meth:`from_peaks`.
        """
        u_a: list[NDArray[np.float64]] = []
        u_d: list[NDArray[np.float64]] = []
        for i, (a, d) in enumerate(pairs):
            a1 = as_finite_array(f"pairs[{i}][0]", a).ravel()
            d1 = as_finite_array(f"pairs[{i}][1]", d).ravel()
            if a1.size != d1.size:
                raise ValueError(
                    f"pairs[{i}] must hold two arrays of the same length. "
                    f"Got {a1.size} and {d1.size}."
                )
            u_a.append(a1)
            u_d.append(d1)
        cat = np.concatenate(u_a) if u_a else np.empty(0)
        cat_d = np.concatenate(u_d) if u_d else np.empty(0)
        return cls.from_peaks(
            cat, cat_d, u_min_nm, u_max_nm, degree, smoothing=smoothing, rcond=rcond
        )
