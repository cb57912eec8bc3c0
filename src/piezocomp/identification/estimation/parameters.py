"""The parameter vector of eq (15) and the model's gradient with respect to it.

``theta = [c_1..c_Nc, p_1..p_Nc, a, w_1..w_NH, r_1..r_NH, y0]`` with discrete creep poles
``p_i = exp(-T / tau_i)``: ``2 N_c + 2 N_H + 2`` entries. For the extended family, whose creep
is driven by ``u + beta H`` (eq 2', :class:`~piezocomp.model.ScannerModel`'s
``creep_coupling``), the coupled layout appends ``beta``: ``2 N_c + 2 N_H + 3`` entries.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar
from piezocomp.model import ModelState, ScannerModel
from piezocomp.operators import _kernels

__all__ = [
    "COUPLING",
    "GROUPS",
    "REFINE_GROUPS",
    "ThetaLayout",
    "model_from_theta",
    "simulate_with_gradient",
    "smoothness_rows",
    "theta_from_model",
]

GROUPS = ("c", "p", "a", "w", "r", "y0")
"""Parameter groups of eq (15): creep gains and poles, gain, play weights and thresholds,
offset (the names the RLS's and the batch refinement's ``free`` take)."""

COUPLING = "b"
"""The group of the creep coupling ``beta`` of eq (2'), which the batch refinement and the
RLS of eq (20) also take in ``free``."""

REFINE_GROUPS = (*GROUPS, COUPLING)
"""Every group the batch refinement's and the RLS's ``free`` take."""


@dataclass(frozen=True)
class ThetaLayout:
    """Index slices of eq (15) for ``n_creep`` creep and ``n_play`` play operators, and of
    ``beta`` after them when ``coupled`` (eq 2')."""

    n_creep: int
    n_play: int
    coupled: bool = False

    @property
    def size(self) -> int:
        """``2 N_c + 2 N_H + 2`` (one more when coupled)."""
        return 2 * self.n_creep + 2 * self.n_play + 2 + int(self.coupled)

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
        return 2 * self.n_creep + 2 * self.n_play + 1

    @property
    def b(self) -> int:
        """Creep coupling ``beta`` (coupled layouts only)."""
        if not self.coupled:
            raise ValueError("this layout of eq (15) has no creep coupling (coupled=False).")
        return self.y0 + 1

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
            + (["beta"] if self.coupled else [])
        )


def theta_from_model(
    model: ScannerModel, sample_period_s: float, coupled: bool = False
) -> NDArray[np.float64]:
    """Eq (15) from a model (creep poles for sample period ``T``), with ``beta`` appended
    when ``coupled``.

    Eq (15) has no creep coupling: without ``coupled`` a model with ``creep_coupling != 0``
    is refused.
    """
    model.require_symmetric("theta of eq (15)")
    if not coupled:
        model.require_uncoupled("theta of eq (15)")
    return np.concatenate(
        (
            model.creep_gains,
            model.creep_poles(sample_period_s),
            [model.gain],
            model.weights,
            model.thresholds_nm,
            [model.offset_nm],
            [model.creep_coupling] if coupled else [],
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
        creep_coupling=th[layout.b] if layout.coupled else 0.0,
    )


def simulate_with_gradient(
    model: ScannerModel,
    u_nm: ArrayLike,
    sample_period_s: float,
    state: ModelState | None = None,
    *,
    coupled: bool = False,
    thresholds: bool = True,
    creep_rest_nm: float | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], ModelState]:
    """Eq (14) and ``dy/dtheta`` (eqs 18-19), with the sensitivity states started at zero.

    Parameters
    ----------
    model : ScannerModel
    u_nm : array_like, shape (n,)
    sample_period_s : float
    state : ModelState, optional
        Model state before the first sample (its sensitivity is taken as zero).
    coupled : bool
        The gradient of the extended family (eq 2'): one more column, ``dy/dbeta``, and the
        creep's sensitivity to ``a``, ``w`` and ``r`` through its drive ``u + beta H``
        (:func:`~piezocomp.operators._kernels.forward_sensitivity_coupled`); it holds at
        ``beta = 0`` too, where the other columns equal the paper's.
    thresholds : bool
        With ``coupled``: follow the creep's sensitivity to the thresholds (about half the
        kernel's work); ``False`` leaves the threshold columns NaN, for a refinement that
        holds them (the other columns are the same to the bit). Without ``coupled`` the
        threshold columns cost nothing more and are always given.
    creep_rest_nm : float, optional
        The creep states start settled on a command held at this value
        (:meth:`ModelState.at_rest`'s, replacing ``state``'s): with a creep coupling they
        are ``(1 + beta (a + sum_j w_j)) u_rest`` and so depend on the parameters, and their
        sensitivities start at ``dx/da = beta u_rest``, ``dx/dw_j = beta u_rest``,
        ``dx/dbeta = (a + sum_j w_j) u_rest`` instead of zero.

    Returns
    -------
    y : ndarray, shape (n,)
    jacobian : ndarray, shape (n, 2 N_c + 2 N_H + 2), one column more when coupled
        Columns in the order of eq (15) (:class:`ThetaLayout`). The threshold columns use
        the one-sided derivative of eq (19); the creep-pole columns the recursion
        ``dx_i(k)/dp_i = x_i(k-1) - s(k-1) + p_i dx_i(k-1)/dp_i`` (``s = u`` in eq 2).
    state : ModelState

    Raises
    ------
    ValueError
        For a model with dead zones (eq 8'), whose sensitivities are not followed; without
        ``coupled``, for a model with ``creep_coupling != 0``: the sensitivity
        recursion of eqs (18-19) is that of the paper's eq (2).
    """
    model.require_symmetric("simulate_with_gradient (eqs 18-19)")
    if not coupled:
        model.require_uncoupled("simulate_with_gradient (eqs 18-19)")
    u = as_finite_1d("u_nm", u_nm)
    st = model.initial_state() if state is None else state
    st.check_for(model)
    nh, nc = model.n_play, model.n_creep
    layout = ThetaLayout(nc, nh, coupled)
    sens = np.zeros(_kernels.sensitivity_size(nh, nc, coupled))
    if creep_rest_nm is not None:
        xc = check_finite_scalar("creep_rest_nm", creep_rest_nm)
        st = st.with_creep_at_rest(model, xc)
        if coupled:  # [dx/dp, dz/dr, dx/da, dx/dbeta, dx/dw, dx/dr], the kernel's layout
            beta = model.creep_coupling
            sens[nc + nh : 2 * nc + nh] = beta * xc
            sens[2 * nc + nh : 3 * nc + nh] = (model.gain + float(model.weights.sum())) * xc
            sens[3 * nc + nh : 3 * nc + nh + nc * nh] = beta * xc
    packed = st.packed()
    y = np.empty(u.size)
    jac = np.empty((u.size, layout.size))
    params = model.packed(sample_period_s)
    if coupled:
        _kernels.forward_sensitivity_coupled(u, nh, nc, params, packed, sens, y, jac, thresholds)
    else:
        _kernels.forward_sensitivity(u, nh, nc, params, packed, sens, y, jac)
    return y, jac, ModelState.from_packed(packed, nh, nc)


def smoothness_rows(
    model: ScannerModel,
    creep_smoothing_nm: float,
    weight_smoothing_nm: float,
    groups: tuple[str, ...] = ("c", "w"),
    coupled: bool = False,
) -> NDArray[np.float64]:
    """Rows of the smoothness priors over ``theta`` of eq (15), shape ``(k, n_theta)``.

    Each row is ``mu * (x[i-1] - 2 x[i] + x[i+1])``: second differences of the creep gains in
    the order of their time constants (weight ``creep_smoothing_nm``) and of the play weights
    in the order of their thresholds (``weight_smoothing_nm``). A group is left out when its
    weight is 0, when it is not in ``groups`` (the parameters that are adapted) or when it
    has fewer than 3 parameters. Used as extra residuals by the batch refinement and as
    pseudo-measurements by the RLS. ``coupled``: over the coupled layout (``beta`` last).
    """
    layout = ThetaLayout(model.n_creep, model.n_play, coupled)
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
