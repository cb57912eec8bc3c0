"""A steady hysteresis loop with Prandtl-Ishlinskii structure, fitted by eq (23).

:class:`~piezocomp.identification.loop.symmetric.SymmetricLoop` fits the ascending branch ``f_a`` as
a free polynomial; eq (23) cannot see an odd distortion of ``f_a`` about the loop's centre, and a
least-curvature regulariser chooses it. Here the branch has the shape of the steady loop of a
Prandtl-Ishlinskii operator with non-negative weights (eq 8): from the lower turning point ``u_min``
the ascending branch is

.. math:: f_a(u) = f_a(u_{min}) + \\sum_i w_i\\,(u - u_{min} - 2 r_i)_+,
          \\qquad w_i \\ge 0,\\ 0 = r_0 < r_1 < \\dots < h,

i.e. increasing and convex (the loading curve doubled). Any Preisach operator with a
non-negative density (plus a reversible linear part) has a convex ascending branch from
its minimum, so the structure holds beyond Prandtl-Ishlinskii; it forbids the odd
distortions that would bend the branch concave. The loop is closed and point-symmetric
(eqs 21-22), which fixes ``f_a(u_min) = y_s - h``; the calibration condition
``f_a(u_max) - f_a(u_min) = u_max - u_min`` fixes the scale, and each pair ``(u_a, u_d)``
gives ``f_a(u_a) + f_a(2 u_s - u_d) = 2 y_s`` (23). The weights are fitted by non-negative
least squares.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

from piezocomp._validation import as_finite_1d, as_finite_array, check_finite_scalar, readonly

__all__ = ["PILoop"]


def _ramps(x: NDArray[np.float64], knots: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(x - t_i)_+`` for every ``x`` (rows) and knot ``t_i`` (columns)."""
    return np.maximum(x[:, None] - knots[None, :], 0.0)


def _pair_rows(
    ua: NDArray[np.float64], ud: NDArray[np.float64], u_min: float, u_max: float,
    thresholds: NDArray[np.float64],
) -> NDArray[np.float64]:  # fmt: skip
    """Rows of eq (23), ``f_a(u_a) + f_a(2 u_s - u_d) - 2 y_s = 0``, linear in the weights."""
    knots = 2.0 * thresholds
    return (
        _ramps(ua - u_min, knots)
        + _ramps(u_max - ud, knots)
        - _ramps(np.array([u_max - u_min]), knots)
    )


def _stacked_pair_rows(
    pairs: Iterable[tuple[ArrayLike, ArrayLike]], u_min: float, u_max: float,
    thresholds: NDArray[np.float64],
) -> NDArray[np.float64]:  # fmt: skip
    """Rows of eq (23) for every pair of every line, ``(n_pairs, n_thresholds)``."""
    rows = [np.empty((0, thresholds.size))]
    for a, d in pairs:
        ua = as_finite_array("u_a", a).ravel()
        ud = as_finite_array("u_d", d).ravel()
        if ua.size != ud.size:
            raise ValueError("every line needs as many ascending as descending commands.")
        rows.append(_pair_rows(ua, ud, u_min, u_max, thresholds))
    return np.vstack(rows)


@dataclass(frozen=True)
class PILoop:
    """Steady point-symmetric loop whose ascending branch is a Prandtl-Ishlinskii branch.

    ``f_a(u) = y_s - A + sum_i w_i (u - u_min - 2 r_i)_+`` with the loop's half-height
    ``A = sum_i w_i (h - r_i)_+`` (closure), ``h = (u_max - u_min) / 2``, ``y_s = u_s``.

    Parameters
    ----------
    weights, thresholds_nm : array_like, shape (n,)
        Non-negative weights (dimensionless) and thresholds ``r_i >= 0`` (nm);
        ``thresholds_nm[0] = 0`` carries the linear part.
    u_min_nm, u_max_nm : float
        Extremes of the steady command cycle (nm); ``u_s = y_s`` is their mean.
    """

    weights: NDArray[np.float64]
    thresholds_nm: NDArray[np.float64]
    u_min_nm: float
    u_max_nm: float

    def __post_init__(self) -> None:
        w = as_finite_1d("weights", self.weights)
        r = as_finite_1d("thresholds_nm", self.thresholds_nm)
        if w.size != r.size or w.size == 0:
            raise ValueError(f"weights and thresholds must match. Got {w.size}, {r.size}.")
        if np.any(w < 0) or np.any(r < 0):
            raise ValueError("weights and thresholds_nm must be >= 0.")
        u_min = check_finite_scalar("u_min_nm", self.u_min_nm)
        u_max = check_finite_scalar("u_max_nm", self.u_max_nm)
        if not u_min < u_max:
            raise ValueError(f"u_min_nm must be < u_max_nm. Got {u_min} and {u_max}.")
        if not w[0] > 0 or r[0] != 0:
            raise ValueError("thresholds_nm[0] must be 0 with weights[0] > 0 (f_a increasing).")
        object.__setattr__(self, "weights", readonly(w))
        object.__setattr__(self, "thresholds_nm", readonly(r))
        object.__setattr__(self, "u_min_nm", u_min)
        object.__setattr__(self, "u_max_nm", u_max)

    @property
    def half_range_nm(self) -> float:
        return 0.5 * (self.u_max_nm - self.u_min_nm)

    @property
    def u_s_nm(self) -> float:
        return 0.5 * (self.u_min_nm + self.u_max_nm)

    @property
    def y_s_nm(self) -> float:
        return self.u_s_nm

    @property
    def half_height_nm(self) -> float:
        """``A = (f_a(u_max) - f_a(u_min)) / 2`` (nm)."""
        h = self.half_range_nm
        return float(np.sum(self.weights * np.maximum(h - self.thresholds_nm, 0.0)))

    def with_range(self, u_min_nm: float, u_max_nm: float) -> PILoop:
        """The steady loop of the same operator between other extremes (same loading curve)."""
        return PILoop(self.weights, self.thresholds_nm, u_min_nm, u_max_nm)

    def ascending(self, u_nm: ArrayLike) -> Any:
        """Ascending branch ``y = f_a(u)`` (nm); linear continuation below ``u_min``."""
        u = as_finite_array("u_nm", u_nm)
        d = np.atleast_1d(u).ravel() - self.u_min_nm
        p = _ramps(d, 2.0 * self.thresholds_nm) @ self.weights
        p = np.where(d < 0, self.weights[0] * d, p)
        out = self.y_s_nm - self.half_height_nm + p
        return out.reshape(np.shape(u)) if np.ndim(u) else float(out[0])

    def descending(self, u_nm: ArrayLike) -> Any:
        """Descending branch ``f_d(u) = 2 y_s - f_a(2 u_s - u)`` (nm), eq (22)."""
        u = as_finite_array("u_nm", u_nm)
        return 2.0 * self.y_s_nm - self.ascending(2.0 * self.u_s_nm - u)

    def ascending_slope(self, u_nm: ArrayLike) -> Any:
        """Slope ``d f_a / d u`` (dimensionless)."""
        u = as_finite_array("u_nm", u_nm)
        d = np.atleast_1d(u).ravel() - self.u_min_nm
        s = (d[:, None] > 2.0 * self.thresholds_nm[None, :]).astype(float) @ self.weights
        s = np.where(d <= 0, self.weights[0], s)
        return s.reshape(np.shape(u)) if np.ndim(u) else float(s[0])

    def pair_residuals_nm(self, u_ascending_nm: ArrayLike, u_descending_nm: ArrayLike) -> Any:
        """``f_a(u_a) - f_d(u_d)`` (nm), eq (23)."""
        return self.ascending(u_ascending_nm) - self.descending(u_descending_nm)

    @classmethod
    def from_loops_pairs(
        cls,
        loops: Sequence[tuple[Iterable[tuple[ArrayLike, ArrayLike]], float, float]],
        *,
        n_thresholds: int = 48,
        ridge: float = 0.0,
        calibration_weight: float = 1e5,
    ) -> PILoop:
        """One operator fitted to the steady loops of several ranges, eq (23), by NNLS.

        ``loops`` holds, per range, ``(pairs, u_min_nm, u_max_nm)`` (pairs as in
        :meth:`SymmetricLoop.from_line_pairs`). For a Prandtl-Ishlinskii operator every
        steady loop's ascending branch is ``f_a(u_min) + 2 phi((u - u_min) / 2)`` with the same
        loading curve ``phi``: the loops share the weights. The calibration condition holds
        on the first loop, ``f_a(u_max) - f_a(u_min) = u_max - u_min`` (a row weighted by
        ``calibration_weight``); the returned loop is the first one's
        (:meth:`with_range` gives the others). Thresholds: ``n_thresholds`` evenly spaced on
        ``[0, h)`` of the widest loop. ``ridge`` adds the rows ``ridge * h * w_i = 0`` for the
        hysteretic weights (``i >= 1``), in nm like the pair rows: eq (23) with the
        structure alone still leaves a family of loops (an odd distortion that keeps the
        branch convex), the ridge picks the one with the least hysteretic weight.
        """
        if not loops:
            raise ValueError("loops must hold at least one (pairs, u_min, u_max).")
        h_max = max(0.5 * (float(b) - float(a)) for _, a, b in loops)
        r = h_max * np.arange(n_thresholds) / n_thresholds
        rows = [_stacked_pair_rows(pairs, float(a), float(b), r) for pairs, a, b in loops]
        n = sum(m.shape[0] for m in rows)
        if n < 2:
            raise ValueError(f"a PI loop needs at least 2 feature pairs. Got {n}.")
        _, u_min0, u_max0 = loops[0]
        h0 = 0.5 * (float(u_max0) - float(u_min0))
        cal = calibration_weight * np.maximum(h0 - r, 0.0)[None, :] / h0
        ridge_rows = ridge * h_max * np.eye(r.size)[1:]
        a_mat = np.vstack([*rows, ridge_rows, cal])
        b = np.zeros(a_mat.shape[0])
        b[-1] = calibration_weight
        w, _ = nnls(a_mat, b, maxiter=50 * r.size)
        if not w[0] > 0:
            w[0] = 1e-9  # keep the branch strictly increasing
        return cls(w, r, float(u_min0), float(u_max0))

    @classmethod
    def from_line_pairs(
        cls,
        pairs: Iterable[tuple[ArrayLike, ArrayLike]],
        u_min_nm: float,
        u_max_nm: float,
        *,
        n_thresholds: int = 48,
        ridge: float = 0.0,
    ) -> PILoop:
        """:meth:`from_loops_pairs` for one loop."""
        return cls.from_loops_pairs(
            [(list(pairs), u_min_nm, u_max_nm)], n_thresholds=n_thresholds, ridge=ridge
        )
