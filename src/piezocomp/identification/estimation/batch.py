"""Batch refinement of the scanner model by bounded nonlinear least squares.

The recursive estimator of eq (20) processes a record once, sample by sample. Given the
whole record, the same prediction error (17) can instead be minimised over all samples at
once:

``min_theta  sum_k  (h(y_hat(k; theta)) - z_m(k))^2``

with ``y_hat`` the model (14) run on the record with the parameters ``theta`` of eq (15), and ``h``
the output map: the identity when a position sensor measures ``y`` directly (sensor-based
identification), or the topography ``h(y)`` of eq (16) on the sensorless path. The Jacobian is the
regressor of eq (18), ``h'(y_hat) dy_hat/dtheta``, from the sensitivity recursions of
:func:`~piezocomp.identification.estimation.parameters.simulate_with_gradient` (eq 19 for the
thresholds), chained through the reparametrisation below.

Feasibility (the conditions that make eq (10) exist) is kept by bounds:

- ``c_i >= 0`` and ``1e-6 <= p_i <= 1 - 1e-9`` (poles ``p_i = exp(-T / tau_i)``), or a
  higher lower bound from a shortest time constant;
- ``a >= min_gain`` and ``w_j >= min_weight`` (small positive numbers);
- thresholds through positive increments ``r_1 = d_1``, ``r_j = r_{j-1} + d_j`` with
  ``d_j >= min_threshold_step_nm``, so ``0 < r_1 < ... < r_NH`` holds at every iterate;
  ``dy/dd_m = sum_{j >= m} dy/dr_j``.

The solver is :func:`scipy.optimize.least_squares` (``method="trf"``, ``x_scale="jac"``).

Several records (e.g. lines crossing different particles, each with its own ``h``) can
share one model: ``refine(..., extra=[Segment(...), ...])`` stacks their residuals; each
runs from its own state.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from piezocomp._validation import as_finite_1d, check_finite_scalar
from piezocomp.identification.estimation.batch_cost import (
    CostRecord,
    OutputMap,
    RefineCost,
    checked_basis,
)
from piezocomp.identification.estimation.parameters import (
    COUPLING,
    GROUPS,
    REFINE_GROUPS,
    smoothness_rows,
)
from piezocomp.identification.estimation.reparametrisation import Reparametrisation, lower_bounds
from piezocomp.identification.estimation.threads import single_threaded_blas
from piezocomp.model import ModelState, ScannerModel

__all__ = ["COUPLING", "GROUPS", "OutputMap", "RefineOptions", "RefineResult", "Segment", "refine"]


@dataclass(frozen=True)
class RefineResult:
    """Outcome of :func:`refine`.

    Attributes
    ----------
    model : ScannerModel
        The refined model (always feasible).
    initial_cost, cost : float
        ``0.5 * sum(residual**2)`` over the fitted samples, at the start and at the end.
    rms : float
        Root mean square residual over the fitted samples at the end (unit of ``measured``).
    cost_history : tuple of float
        The cost at every evaluation of the residuals, in order (trial steps that the
        trust region rejected included, so it need not decrease monotonically).
    n_residuals : int
        Number of samples in the cost.
    free : tuple of str
        The parameter groups that were refined.
    nfev, njev : int
        Residual and Jacobian evaluations.
    success : bool
        As reported by the solver (a convergence test was met).
    status : int
        Solver status code (see :func:`scipy.optimize.least_squares`).
    message : str
        Solver message.
    drift_coefficients : tuple of ndarray
        With drift bases: each record's estimated coefficients ``c`` (its drift is
        ``basis @ c``), this record first (empty for a record without a basis); an empty
        tuple without bases.
    """

    model: ScannerModel
    initial_cost: float
    cost: float
    rms: float
    cost_history: tuple[float, ...]
    n_residuals: int
    free: tuple[str, ...]
    nfev: int
    njev: int
    success: bool
    status: int
    message: str
    drift_coefficients: tuple[NDArray[np.float64], ...] = ()


@dataclass(frozen=True)
class RefineOptions:
    """How :func:`refine` fits: what it frees, its bounds, its penalties, the solver's stops.

    Attributes
    ----------
    free : tuple of str
        Groups refined, among ``("c", "p", "a", "w", "r", "y0")`` (eq 15) and ``"b"``, the
        creep coupling ``beta`` of the extended family (eq 2'), within
        :data:`~piezocomp.identification.estimation.reparametrisation.COUPLING_BOUNDS`; the
        others are held at their starting values (e.g. leave out ``"r"`` to hold the
        thresholds, or ``"p"`` to hold the creep poles). ``"b"`` may be freed from a model of
        the paper's family (``beta = 0``): the gradient ``dy/dbeta`` is not zero there.
    min_gain, min_weight : float
        Lower bounds (> 0) of ``a`` and ``w_j``.
    min_threshold_step_nm : float, optional
        Lower bound (> 0) of ``r_1`` and of ``r_j - r_{j-1}``; default ``1e-6`` times the
        peak-to-peak span of ``u`` (``1e-6`` nm if ``u`` is constant).
    min_time_constant_s : float, optional
        Lower bound of the creep time constants ``tau_i`` (through the poles,
        ``p_i >= exp(-T / min_time_constant_s)``); default: only the pole bounds
        ``[1e-6, 1 - 1e-9]``. Fast creep operators model the scanner's dynamics rather than
        creep, and the inverse (eq 13) of a large fast one overdrives the command.
    max_nfev, ftol, xtol, gtol
        Passed to :func:`scipy.optimize.least_squares`.
    creep_smoothing_nm : float
        Weight (nm) of a smoothness penalty on the creep spectrum: the residuals
        ``creep_smoothing_nm * (c_{i-1} - 2 c_i + c_{i+1})`` join the cost (creep gains in
        the order of their time constants, as :func:`creep_spectrum` places them). 0: none.
        Creep of a piezo is a smooth distribution of relaxation times; where the record
        cannot tell neighbouring modes apart, the penalty picks the smooth solution among
        the equally good ones. ``rms`` and ``n_residuals`` count the data residuals only.
    weight_smoothing_nm : float
        The same penalty on the play operators' weights ``w_j`` in the order of their
        thresholds (a smooth Preisach density gives smooth weights). 0: none.
    drift_smoothing : float
        Weight of a penalty on the second differences of each record's knots ``(0, c)``
        (a first knot held at 0, then ``c``), relative to the heights' information about one
        coefficient at the start.
    drift_anchor : float
        Weight, in the same units, of a penalty on ``c`` itself: the drift stays near the
        path given as ``shift_nm`` (e.g. a rate measured before the record) unless the
        heights say otherwise. 0: none.
    """

    free: tuple[str, ...] = GROUPS
    min_gain: float = 1e-9
    min_weight: float = 1e-9
    min_threshold_step_nm: float | None = None
    min_time_constant_s: float | None = None
    max_nfev: int | None = 200
    ftol: float = 1e-10
    xtol: float = 1e-10
    gtol: float = 1e-10
    creep_smoothing_nm: float = 0.0
    weight_smoothing_nm: float = 0.0
    drift_smoothing: float = 1.0
    drift_anchor: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "free", _check_free(self.free))
        for name in ("min_gain", "min_weight"):
            v = getattr(self, name)
            if check_finite_scalar(name, v) <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
            object.__setattr__(self, name, float(v))
        for name in ("drift_smoothing", "drift_anchor"):
            v = getattr(self, name)
            if check_finite_scalar(name, v) < 0:
                raise ValueError(f"{name} must be >= 0. Got {v}.")
            object.__setattr__(self, name, float(v))


@dataclass(frozen=True)
class Segment:
    """Another record fitted with the same model (:func:`refine`'s ``extra``).

    Attributes
    ----------
    u_nm, measured : array_like, shape (n,)
        Command and measurement, as :func:`refine`'s.
    output : OutputMap, optional
        Its own ``h`` (``None``: ``measured`` is ``y``).
    state : ModelState, optional
        Its model state before the first sample (``None``: at rest at ``u_nm[0]``). It may
        not depend on the parameters.
    fit_mask : array_like of bool, optional
    warmup_samples : int
    shift_nm : array_like, optional
        Its own known shift of the output map's argument, as :func:`refine`'s.
    drift_basis : array_like, shape (n, m), optional
        Its own drift basis, as :func:`refine`'s (its coefficients are its own).
    creep_rest_nm : float, optional
        Its creep states settled on a command held at this value, as :func:`refine`'s.
    """

    u_nm: ArrayLike
    measured: ArrayLike
    output: OutputMap | None = None
    state: ModelState | None = None
    fit_mask: ArrayLike | None = None
    warmup_samples: int = 0
    shift_nm: ArrayLike | None = None
    drift_basis: ArrayLike | None = None
    creep_rest_nm: float | None = None


def _prepared(
    u_nm: ArrayLike,
    measured: ArrayLike,
    output: OutputMap | None,
    fit_mask: ArrayLike | None,
    warmup_samples: int,
    where: str = "",
    shift_nm: ArrayLike | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]:
    """Checked command, target, residual mask and shift of one record, cut after its last
    fitted sample (later samples cannot change the cost)."""
    u = as_finite_1d(f"{where}u_nm", u_nm)
    shift = np.zeros(u.size) if shift_nm is None else as_finite_1d(f"{where}shift_nm", shift_nm)
    if shift.shape != u.shape:
        raise ValueError(
            f"{where}shift_nm must have one entry per command sample ({u.size}). Got {shift.size}."
        )
    z = as_finite_1d(f"{where}measured", measured)
    if z.shape != u.shape:
        raise ValueError(
            f"{where}measured must have one sample per command sample ({u.size}). Got {z.size}."
        )
    if output is not None and not (callable(output) and hasattr(output, "derivative")):
        raise TypeError(
            f"{where}output must be None or have __call__(y) and derivative(y). "
            f"Got {type(output).__name__}."
        )
    mask = _residual_mask(u.size, fit_mask, warmup_samples)
    if not mask.any():
        raise ValueError(
            f"{where}no samples left to fit (fit_mask and warmup_samples exclude all)."
        )
    n_sim = int(np.flatnonzero(mask)[-1]) + 1
    return u[:n_sim], z[:n_sim][mask[:n_sim]], mask[:n_sim], shift[:n_sim]


def _solve(cost: RefineCost, rep: Reparametrisation, o: RefineOptions) -> RefineResult:
    """Bounded least squares of ``cost`` from the starting model (drift coefficients 0)."""
    x0 = np.concatenate([rep.x0, np.zeros(cost.n_drift)])
    lower = np.concatenate([rep.lower, np.full(cost.n_drift, -np.inf)])
    upper = np.concatenate([rep.upper, np.full(cost.n_drift, np.inf)])
    res0 = cost.evaluate(x0)[0]
    if not np.all(np.isfinite(res0)):
        raise ValueError("the output map returned non-finite values at the starting model.")
    with single_threaded_blas():
        sol = least_squares(
            cost.fun,
            x0,
            jac=cost.jac,
            bounds=(lower, upper),
            method="trf",
            x_scale="jac",
            max_nfev=o.max_nfev,
            ftol=o.ftol,
            xtol=o.xtol,
            gtol=o.gtol,
        )
    final = rep.final_model(sol.x[: rep.x0.size])
    r = np.asarray(sol.fun)
    r = r[: r.size - cost.n_penalty_rows]  # the data residuals
    return RefineResult(
        model=final,
        initial_cost=cost.history[0],
        cost=float(sol.cost),
        rms=float(np.sqrt(np.mean(r**2))),
        cost_history=tuple(cost.history),
        n_residuals=int(r.size),
        free=o.free,
        nfev=int(sol.nfev),
        njev=int(sol.njev) if sol.njev is not None else 0,
        success=bool(sol.success),
        status=int(sol.status),
        message=str(sol.message),
        drift_coefficients=cost.drift_coefficients(sol.x),
    )


def _segment(model: ScannerModel, i: int, seg: Segment) -> tuple[CostRecord, Any]:
    """``extra[i]`` checked and prepared as :func:`refine`'s own record, with its basis."""
    if not isinstance(seg, Segment):
        raise TypeError(f"extra[{i}] must be a Segment. Got {type(seg).__name__}.")
    us, ts, ss, sh = _prepared(
        seg.u_nm, seg.measured, seg.output, seg.fit_mask, seg.warmup_samples, f"extra[{i}].",
        seg.shift_nm,
    )  # fmt: skip
    sst = ModelState.at_rest(model, float(us[0])) if seg.state is None else seg.state
    sst.check_for(model)
    rest = seg.creep_rest_nm
    if seg.state is None and rest is None:  # at rest at its first command: the creep's too
        rest = float(us[0])
    basis = checked_basis(seg.drift_basis, us.size, seg.output, f"extra[{i}].")
    return (us, ts, ss, sst, seg.output, sh, _rest(rest, f"extra[{i}].")), basis


def _rest(creep_rest_nm: float | None, where: str) -> float | None:
    """A record's held command of the creep's rest, checked."""
    if creep_rest_nm is None:
        return None
    return check_finite_scalar(f"{where}creep_rest_nm", creep_rest_nm)


def _check_free(free: Collection[str]) -> tuple[str, ...]:
    if isinstance(free, str):
        free = (free,)
    unknown = sorted(set(free) - set(REFINE_GROUPS))
    if unknown:
        raise ValueError(f"free must name groups among {REFINE_GROUPS}. Got unknown {unknown}.")
    out = tuple(g for g in REFINE_GROUPS if g in set(free))
    if not out:
        raise ValueError("free must name at least one parameter group to refine. Got none.")
    return out


def _residual_mask(n: int, fit_mask: ArrayLike | None, warmup_samples: int) -> NDArray[np.bool_]:
    if isinstance(warmup_samples, bool) or int(warmup_samples) != warmup_samples:
        raise TypeError(f"warmup_samples must be an integer. Got {warmup_samples!r}.")
    k = int(warmup_samples)
    if not 0 <= k < n:
        raise ValueError(f"warmup_samples must be in [0, {n}) for {n} samples. Got {k}.")
    if fit_mask is None:
        mask = np.ones(n, dtype=bool)
    else:
        mask = np.asarray(fit_mask)
        if mask.dtype != bool or mask.shape != (n,):
            raise ValueError(
                f"fit_mask must be a boolean array of shape ({n},). "
                f"Got dtype {mask.dtype}, shape {mask.shape}."
            )
        mask = mask.copy()
    mask[:k] = False
    return mask


def refine(
    model: ScannerModel,
    u_nm: ArrayLike,
    measured: ArrayLike,
    sample_period_s: float,
    *,
    output: OutputMap | None = None,
    state: ModelState | None = None,
    fit_mask: ArrayLike | None = None,
    warmup_samples: int = 0,
    extra: Collection[Segment] = (),
    shift_nm: ArrayLike | None = None,
    drift_basis: ArrayLike | None = None,
    creep_rest_nm: float | None = None,
    options: RefineOptions | None = None,
) -> RefineResult:
    """Refine a model over a whole record by bounded nonlinear least squares (eqs 14-19).

    Minimises ``0.5 * sum_k eps(k)^2`` over the fitted samples, with the prediction error
    of eq (17), ``eps(k) = z_m(k) - h(y_hat(k))``, and its gradient from eq (18).

    Parameters
    ----------
    model : ScannerModel
        Starting point (e.g. the RLS estimate of eq 20, or a non-negative least-squares
        fit); also fixes the orders ``N_H``, ``N_c``. Parameters outside the bounds below
        are moved onto them.
    u_nm : array_like, shape (n,)
        Command, nominal nm.
    measured : array_like, shape (n,)
        ``y`` measured by a sensor (``output=None``) or the measured height ``z_m``.
    sample_period_s : float
        Sample period ``T`` (> 0), s.
    output : OutputMap, optional
        ``h`` of eq (14) with ``h.derivative``; ``None`` means ``measured`` is ``y`` itself.
    state : ModelState, optional
        Model state before the first sample. ``None`` means :meth:`ModelState.zeros`:
        every play and creep state zero with ``u(-1) = 0``, i.e. a scanner freshly reset
        at zero command, whose first excursion follows the initial loading curve (8).
        For a record that starts held at ``u(0)`` pass ``ModelState.at_rest(model, u[0])``.
        The state must not depend on the parameters (its sensitivity is taken as zero), but
        for its creep part with ``creep_rest_nm``.
    fit_mask : array_like of bool, shape (n,), optional
        Samples whose residuals enter the cost (e.g. the fit part of a record, with the
        held-out part ``False``). The model always runs from sample 0.
    warmup_samples : int
        Residuals of the first ``warmup_samples`` samples are excluded: for a record that
        starts in an unknown part of its history, once the input has swept its whole
        range the play operators have forgotten their initial state (wiping-out), and
        creep states forget theirs after a few time constants.
    extra : collection of Segment
        Further records fitted with the same parameters; their residuals are appended to
        this record's (``n_residuals`` and ``rms`` count them all).
    shift_nm : array_like, shape (n,), optional
        A known shift added to the extension before the output map, sample by sample:
        ``eps(k) = z_m(k) - h(y_hat(k) + shift(k))``, the sample's drift along the line
        (:mod:`~piezocomp.identification.estimation.drift_along_line`). Default none.
    drift_basis : array_like, shape (n, m), optional
        Estimate a drift path with the model: the extension is ``y_hat + shift + B c`` with ``B``
        this basis and ``c`` free coefficients, one set per record (e.g.
        :class:`~piezocomp.identification.estimation.drift_along_line.DriftBasis`: hat functions in
        time, of zero mean where ``h`` was measured, the first knot's held at 0). Requires
        ``output``.
    creep_rest_nm : float, optional
        The creep states start settled on a command held at this value (replacing
        ``state``'s): those of the model at every iterate, with their sensitivity. With a
        creep coupling (eq 2') they are ``(1 + beta (a + sum_j w_j)) u_rest``, so a held
        starting state would pin ``beta`` near its start whenever ``u_rest != 0``.
    options : RefineOptions, optional
        What is refined, the bounds, the penalties and the solver's stops (default
        :class:`RefineOptions`).

    Returns
    -------
    RefineResult
    """
    if not isinstance(model, ScannerModel):
        raise TypeError(f"model must be a ScannerModel. Got {type(model).__name__}.")
    u_sim, target, sel, shift = _prepared(
        u_nm, measured, output, fit_mask, warmup_samples, shift_nm=shift_nm
    )
    o = RefineOptions() if options is None else options
    bases = [checked_basis(drift_basis, u_sim.size, output, "")]
    T = check_finite_scalar("sample_period_s", sample_period_s)
    if T <= 0:
        raise ValueError(f"sample_period_s must be > 0. Got {T}.")
    st = ModelState.zeros(model) if state is None else state
    st.check_for(model)
    min_step, pole_low = lower_bounds(u_nm, T, o.min_threshold_step_nm, o.min_time_constant_s)
    records: list[CostRecord] = [(u_sim, target, sel, st, output, shift, _rest(creep_rest_nm, ""))]
    for rec, basis in (_segment(model, i, seg) for i, seg in enumerate(extra)):
        records.append(rec)
        bases.append(basis)
    rep = Reparametrisation(model, T, o.free, o.min_gain, o.min_weight, min_step, pole_low)
    rows = smoothness_rows(
        model, o.creep_smoothing_nm, o.weight_smoothing_nm, o.free, rep.layout.coupled
    )
    smooth = rows if rows.shape[0] else None
    cost = RefineCost(rep, records, T, smooth, bases, o.drift_smoothing, o.drift_anchor)
    return _solve(cost, rep, o)
