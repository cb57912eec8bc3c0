"""The batch refinement's coordinates: the free parameters, their bounds, and the chain rule.

:func:`~piezocomp.identification.estimation.batch.refine` optimises a vector ``x`` of the free
parameters of eq (15), with the thresholds replaced by positive increments ``r_1 = d_1``,
``r_j = r_{j-1} + d_j`` (``d_j >= min_threshold_step_nm``, so ``0 < r_1 < ... < r_NH``
holds at every iterate; ``dy/dd_m = sum_{j >= m} dy/dr_j``), creep poles within
:data:`POLE_BOUNDS` (or above the pole of a shortest time constant), and positive gain and
weights, and for the extended family (eq 2') the creep coupling ``beta`` within
:data:`COUPLING_BOUNDS`. :class:`Reparametrisation` maps ``x`` to ``theta`` and chains
Jacobians back.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.estimation.parameters import (
    COUPLING,
    ThetaLayout,
    model_from_theta,
    theta_from_model,
)
from piezocomp.model import ScannerModel

__all__ = ["COUPLING_BOUNDS", "COUPLING_FLOOR", "POLE_BOUNDS", "Reparametrisation", "lower_bounds"]

POLE_BOUNDS = (1e-6, 1.0 - 1e-9)
"""Bounds kept on the discrete creep poles ``p_i``."""

COUPLING_BOUNDS = (0.0, 5.0)
"""Bounds kept on the creep coupling ``beta`` of eq (2') (dimensionless: the share of the
hysteresis output in the creep drive; fits to records come out below 1)."""

COUPLING_FLOOR = 1e-9
"""A fitted ``beta`` below this is the paper's model: it is set to exactly 0 (the solver
leaves a free parameter a hair off its bound, and ``beta != 0`` would make the model one of
the extended family that the paper's estimators refuse)."""


class Reparametrisation:
    """Map between the free vector ``x`` and ``theta`` of eq (15) (thresholds by increments).

    The layout is the coupled one (``beta`` last, eq 2') when ``beta`` is free
    (:data:`~piezocomp.identification.estimation.parameters.COUPLING` in ``free``) for a model
    with creep operators, or the model has a creep coupling; otherwise it is eq (15) exactly.
    """

    def __init__(
        self,
        model: ScannerModel,
        sample_period_s: float,
        free: tuple[str, ...],
        min_gain: float,
        min_weight: float,
        min_step: float,
        pole_low: float = POLE_BOUNDS[0],
    ) -> None:
        # without creep operators beta has nothing to drive: eq (15) as it is
        coupled = (COUPLING in free and model.n_creep > 0) or model.creep_coupling != 0.0
        self.layout = ThetaLayout(model.n_creep, model.n_play, coupled)
        self.T = sample_period_s
        lay = self.layout
        theta0 = theta_from_model(model, sample_period_s, coupled)
        # increments d_j of the thresholds
        r0 = theta0[lay.r]
        phi0 = theta0.copy()
        phi0[lay.r] = np.diff(r0, prepend=0.0)
        lo = np.full(lay.size, -np.inf)
        hi = np.full(lay.size, np.inf)
        lo[lay.c] = 0.0
        lo[lay.p], hi[lay.p] = pole_low, POLE_BOUNDS[1]
        lo[lay.a] = min_gain
        lo[lay.w] = min_weight
        lo[lay.r] = min_step
        if coupled:
            lo[lay.b], hi[lay.b] = COUPLING_BOUNDS
        index = {
            "c": np.arange(lay.size)[lay.c],
            "p": np.arange(lay.size)[lay.p],
            "a": np.array([lay.a]),
            "w": np.arange(lay.size)[lay.w],
            "r": np.arange(lay.size)[lay.r],
            "y0": np.array([lay.y0]),
            COUPLING: np.array([lay.b]) if coupled else np.zeros(0, dtype=int),
        }
        self.free_index = np.sort(np.concatenate([index[g] for g in free])).astype(int)
        self.coupling_free = coupled and COUPLING in free
        self.thresholds_free = "r" in free
        self.phi0 = phi0
        self.lower = lo[self.free_index]
        self.upper = hi[self.free_index]
        # start inside the bounds (an RLS estimate may sit on or just past one)
        self.x0 = np.clip(phi0[self.free_index], self.lower, self.upper)

    def theta(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """``theta`` of eq (15) for the free vector ``x``."""
        phi = self.phi0.copy()
        phi[self.free_index] = x
        phi[self.layout.r] = np.cumsum(phi[self.layout.r])
        return phi

    def model(self, x: NDArray[np.float64]) -> ScannerModel:
        return model_from_theta(self.theta(x), self.layout, self.T)

    def final_model(self, x: NDArray[np.float64]) -> ScannerModel:
        """:meth:`model` of the solution, a free ``beta`` below :data:`COUPLING_FLOOR` set to
        exactly 0."""
        m = self.model(x)
        if self.coupling_free and m.creep_coupling < COUPLING_FLOOR:
            m = replace(m, creep_coupling=0.0)
        return m

    def chain(
        self, jac_theta: NDArray[np.float64], rows: NDArray[np.bool_] | None = None
    ) -> NDArray[np.float64]:
        """``d/dx`` from ``d/dtheta`` (of ``rows`` only, if given): columns of the increments
        are reverse cumulative sums. With the thresholds held it is ``d/dtheta``'s free
        columns, taken without copying the others."""
        if not self.thresholds_free:
            if rows is None:
                return jac_theta[:, self.free_index]
            return jac_theta[np.ix_(rows, self.free_index)]
        j = jac_theta.copy() if rows is None else jac_theta[rows]
        rs = self.layout.r
        j[:, rs] = np.cumsum(j[:, rs][:, ::-1], axis=1)[:, ::-1]
        return j[:, self.free_index]


def lower_bounds(
    u_nm: ArrayLike,
    T: float,
    min_threshold_step_nm: float | None,
    min_time_constant_s: float | None,
) -> tuple[float, float]:
    """The smallest threshold step and the lowest creep pole the refinement allows (for a
    record ``u_nm`` sampled every ``T`` s), after checking the requested ones."""
    if min_threshold_step_nm is None:
        span = float(np.ptp(np.asarray(u_nm, dtype=float)))
        min_step = 1e-6 * span if span > 0 else 1e-6
    else:
        min_step = check_finite_scalar("min_threshold_step_nm", min_threshold_step_nm)
        if min_step <= 0:
            raise ValueError(f"min_threshold_step_nm must be > 0. Got {min_step}.")
    pole_low = POLE_BOUNDS[0]
    if min_time_constant_s is not None:
        tau_min = check_finite_scalar("min_time_constant_s", min_time_constant_s)
        if tau_min <= 0:
            raise ValueError(f"min_time_constant_s must be > 0. Got {tau_min}.")
        pole_low = max(pole_low, float(np.exp(-T / tau_min)))
        if pole_low >= POLE_BOUNDS[1]:
            raise ValueError(
                f"min_time_constant_s ({tau_min} s) is too long for sample period {T} s."
            )
    return min_step, pole_low
