"""The parameter vector of eq (15) and the model's gradient with respect to it.

``theta = [c_1..c_Nc, p_1..p_Nc, a, w_1..w_NH, r_1..r_NH, y0]`` with discrete creep poles
``p_i = exp(-T / tau_i)``: ``2 N_c + 2 N_H + 2`` entries.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar
from piezocomp.model import ModelState, ScannerModel
from piezocomp.operators import _kernels

__all__ = [
    "GROUPS",
    "ThetaLayout",
    "model_from_theta",
    "simulate_with_gradient",
    "smoothness_rows",
    "theta_from_model",
]

GROUPS = ("c", "p", "a", "w", "r", "y0")
"""Parameter groups of eq (15): creep gains and poles, gain, play weights and thresholds,
offset (the names the RLS's and the batch refinement's ``free`` take)."""


@dataclass(frozen=True)
class ThetaLayout:
    """Index slices of eq (15) for ``n_creep`` creep and ``n_play`` play operators."""

    n_creep: int
    n_play: int

    @property
    def size(self) -> int:
        """``2 N_c + 2 N_H + 2``."""
        return 2 * self.n_creep + 2 * self.n_play + 2

    @property
    def c(self) -> slice:
        """Creep gains ``c_i``."""
        return slice(0, self.n_creep)

    @property
    def p(self) -> slice:
        """Creep poles ``p_i``."""
        return slice(self.n_creep, 2 * self.n_creep)

    @property
    def a(self) -> int:
        """Gain ``a``."""
        return 2 * self.n_creep

    @property
    def w(self) -> slice:
        """Play weights ``w_j``."""
        return slice(2 * self.n_creep + 1, 2 * self.n_creep + 1 + self.n_play)

    @property
    def r(self) -> slice:
        """Play thresholds ``r_j``."""
        start = 2 * self.n_creep + 1 + self.n_play
        return slice(start, start + self.n_play)

    @property
    def y0(self) -> int:
        """Offset ``y0``."""
        return self.size - 1

    def names(self) -> list[str]:
        """Readable names of the entries, in order."""
        nc, nh = self.n_creep, self.n_play
        return (
            [f"c{i + 1}" for i in range(nc)]
            + [f"p{i + 1}" for i in range(nc)]
            + ["a"]
            + [f"w{j + 1}" for j in range(nh)]
            + [f"r{j + 1}" for j in range(nh)]
            + ["y0"]
        )


def theta_from_model(model: ScannerModel, sample_period_s: float) -> NDArray[np.float64]:
    """Eq (15) from a model (creep poles for sample period ``T``).

    Eq (15) has no creep coupling: a model with ``creep_coupling != 0`` is refused.
    """
    model.require_uncoupled("theta of eq (15)")
    return np.concatenate(
        (
            model.creep_gains,
            model.creep_poles(sample_period_s),
            [model.gain],
            model.weights,
            model.thresholds_nm,
            [model.offset_nm],
        )
    )


def model_from_theta(theta: ArrayLike, layout: ThetaLayout, sample_period_s: float) -> ScannerModel:
    """A (validated) model from eq (15); poles must lie in (0, 1)."""
    th = as_finite_1d("theta", theta)
    if th.size != layout.size:
        raise ValueError(f"theta must have {layout.size} entries. Got {th.size}.")
    T = check_finite_scalar("sample_period_s", sample_period_s)
    p = th[layout.p]
    if np.any((p <= 0) | (p >= 1)):
        i = int(np.flatnonzero((p <= 0) | (p >= 1))[0])
        raise ValueError(f"creep pole p{i + 1} must lie in (0, 1). Got {p[i]}.")
    return ScannerModel(
        offset_nm=th[layout.y0],
        gain=th[layout.a],
        thresholds_nm=th[layout.r],
        weights=th[layout.w],
        creep_time_constants_s=-T / np.log(p),
        creep_gains=th[layout.c],
    )


def simulate_with_gradient(
    model: ScannerModel,
    u_nm: ArrayLike,
    sample_period_s: float,
    state: ModelState | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], ModelState]:
    """Eq (14) and ``dy/dtheta`` (eqs 18-19), with the sensitivity states started at zero.

    Returns
    -------
    y : ndarray, shape (n,)
    jacobian : ndarray, shape (n, 2 N_c + 2 N_H + 2)
        Columns in the order of eq (15) (:class:`ThetaLayout`). The threshold columns use
        the one-sided derivative of eq (19); the creep-pole columns the recursion
        ``dx_i(k)/dp_i = x_i(k-1) - u(k-1) + p_i dx_i(k-1)/dp_i``.
    state : ModelState

    Raises
    ------
    ValueError
        For a model with ``creep_coupling != 0``: the sensitivity recursion is that of the
        paper's eq (2) only.
    """
    model.require_uncoupled("simulate_with_gradient (eqs 18-19)")
    u = as_finite_1d("u_nm", u_nm)
    st = model.initial_state() if state is None else state
    st.check_for(model)
    layout = ThetaLayout(model.n_creep, model.n_play)
    packed = st.packed()
    sens = np.zeros(model.n_creep + model.n_play)
    y = np.empty(u.size)
    jac = np.empty((u.size, layout.size))
    _kernels.forward_sensitivity(
        u, model.n_play, model.n_creep, model.packed(sample_period_s), packed, sens, y, jac
    )
    return y, jac, ModelState.from_packed(packed, model.n_play, model.n_creep)


def smoothness_rows(
    model: ScannerModel,
    creep_smoothing_nm: float,
    weight_smoothing_nm: float,
    groups: tuple[str, ...] = ("c", "w"),
) -> NDArray[np.float64]:
    """Rows of the smoothness priors over ``theta`` of eq (15), shape ``(k, n_theta)``.

    Each row is ``mu * (x[i-1] - 2 x[i] + x[i+1])``: second differences of the creep gains in
    the order of their time constants (weight ``creep_smoothing_nm``) and of the play weights
    in the order of their thresholds (``weight_smoothing_nm``). A group is left out when its
    weight is 0, when it is not in ``groups`` (the parameters that are adapted) or when it
    has fewer than 3 parameters. Used as extra residuals by the batch refinement and as
    pseudo-measurements by the RLS.
    """
    layout = ThetaLayout(model.n_creep, model.n_play)
    rows = []
    for name, mu, group, idx, key in (
        ("creep_smoothing_nm", creep_smoothing_nm, "c", layout.c, model.creep_time_constants_s),
        ("weight_smoothing_nm", weight_smoothing_nm, "w", layout.w, model.thresholds_nm),
    ):
        if check_finite_scalar(name, mu) < 0:
            raise ValueError(f"{name} must be >= 0. Got {mu}.")
        cols = np.arange(layout.size)[idx][np.argsort(key)]
        if mu > 0 and group in groups and cols.size >= 3:
            d2 = np.zeros((cols.size - 2, layout.size))
            for i in range(cols.size - 2):
                d2[i, cols[i : i + 3]] = mu * np.array([1.0, -2.0, 1.0])
            rows.append(d2)
    return np.vstack(rows) if rows else np.zeros((0, layout.size))
