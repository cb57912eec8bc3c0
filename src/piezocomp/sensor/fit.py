"""Sensor-based identification of the scanner model (14) from a record of ``(u, y)``.

When a position sensor measures the extension ``y`` itself (closed-loop scanners, test
rigs), the model (14) is identified without the topography map of Sec. III.C:

1. place the play thresholds over the span the input actually used and the creep time
   constants log-spaced between a few sample periods and a third of the record;
2. with thresholds and poles fixed, eq (14) is linear in ``a``, ``w_j``, ``c_i`` and ``y0``:
   solve for them by non-negative least squares (:func:`scipy.optimize.nnls`), which keeps
   ``a, w_j, c_i >= 0`` (``y0`` is free in sign: the data are centred);
3. refine every parameter, thresholds and poles included, by bounded nonlinear least
   squares (:func:`piezocomp.identification.estimation.batch.refine`).

The record is split in time: the first part is fitted, the rest held out. Fit and
validation errors are reported for the linear stage and for the refined model.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import lsq_linear, minimize_scalar, nnls

from piezocomp._validation import as_finite_1d, check_finite_scalar, readonly
from piezocomp.identification.acquisition.diagnostics import check_excitation, warn_excitation
from piezocomp.identification.estimation import batch
from piezocomp.identification.estimation.parameters import (
    ThetaLayout,
    simulate_with_gradient,
    smoothness_rows,
)
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.operators.creep import creep_bank
from piezocomp.operators.dead_zone import dead_zone_columns
from piezocomp.sensor.record import ErrorFigures, error_figures, split_record

__all__ = [
    "ASYMMETRY_TOLERANCE",
    "DEAD_ZONES",
    "DEFAULT_MAX_COUPLING",
    "MIN_ASYMMETRY_SLOPE",
    "REFERENCE_LONGEST",
    "REFERENCE_ORDERS",
    "REST_GRID",
    "STATE_TOLERANCE",
    "AsymmetryFit",
    "CouplingChoice",
    "ReferenceFit",
    "SensorFit",
    "choose_creep_coupling",
    "estimate_rest_command",
    "fit_asymmetry",
    "fit_plain_pi",
    "fit_sensor",
    "initial_state",
    "nnls_stage",
    "place_dead_zones",
    "place_thresholds",
    "place_time_constants",
    "start_of_record",
]

InitialState = Literal["rest", "zero", "estimate", "auto"]
"""How the state before a record's first sample is taken: held at the first command
(``"rest"``), reset at zero command (``"zero"``), held at a command found from the record
itself (``"estimate"``, :func:`estimate_rest_command`), or the one of these three that
the held-out part prefers (``"auto"``, :func:`fit_sensor` only). Functions that take
a state also take a number: the command, nm, the scanner was held at before the record."""

StateKind = str | float | ModelState

STATE_TOLERANCE = 0.02
"""``initial_state="auto"`` takes the estimated rest command only if it predicts the
held-out part more than this fraction better than the better of ``"rest"`` and ``"zero"``
(which have no parameter to fit; the order selection's rule of parsimony)."""

REFERENCE_ORDERS = (16, 19)
"""``(N_H, N_c)`` of the reference fit :func:`fit_sensor` reports beside its own: the same
family by plain non-negative least squares with many placed operators (thresholds uniform
over the span, time constants log-spaced from the shortest allowed to the fitted part's
length, :data:`REFERENCE_LONGEST`), nothing refined: a dense creep spectrum, as
``benchmarks/model_floor.py`` fits the family."""

REFERENCE_LONGEST = 1.0
"""The reference's longest creep time constant, as a fraction of the fitted part's length
(modes slower than the record still carry its slow creep; the fit's own placement stops at
a third)."""

DEAD_ZONES = 4
"""Dead zones of eq (8') the asymmetric candidate of :func:`fit_sensor` places
(:func:`place_dead_zones`): half above the centre of the hysteresis output's fitted span, half
below. On the micromanipulator's record (``benchmarks/piezo_record.py``) 2, 4 and 6 took the
held-out error from 0.70 % of range to 0.48, 0.39 and 0.38 %."""

MIN_ASYMMETRY_SLOPE = 0.1
"""The least slope of ``S`` (eq 8') a fitted asymmetric candidate may have, where the slope
between the innermost thresholds is 1: a flatter map is invertible, but its inverse would
multiply the command's steps there by more than ten (:func:`fit_asymmetry` bounds it)."""

ASYMMETRY_TOLERANCE = 0.02
"""The asymmetric candidate is kept only if it predicts the held-out part more than this
fraction better than the symmetric model it was built on (asymmetry only on evidence)."""

MIN_TAU_PERIODS = 5.0
"""The shortest placed creep time constant, in sample periods."""

DEFAULT_MIN_TIME_CONSTANT_S = 0.1
"""Default shortest creep time constant, s. Creep is slow (Sec. II: 10 s to 100 s); faster
operators end up modelling the scanner's dynamics (lag), and the inverse of eq (13) then
overdrives the command to cancel them."""


@dataclass(frozen=True)
class SensorFit:
    """Outcome of :func:`fit_sensor`.

    Samples ``[warmup_samples, split_index)`` were fitted; ``[split_index, n)`` held out.

    Attributes
    ----------
    model : ScannerModel
        The identified model: of the linear stage's and the refined one, the one with the
        lower rms error on the held-out samples (see ``chosen``).
    nnls_model : ScannerModel
        The linear stage's model (thresholds and poles as placed).
    fit_errors, validation_errors : ErrorFigures
        Errors of ``model`` on the fitted and the held-out samples (``validation_errors``
        is ``None`` when nothing was held out).
    nnls_fit_errors, nnls_validation_errors : ErrorFigures
        The same for ``nnls_model``.
    refinement : RefineResult or None
        The nonlinear least-squares outcome (``None`` without refinement).
    refined_fit_errors, refined_validation_errors : ErrorFigures or None
        The refined model's errors (``None`` without refinement or without held-out part).
    chosen : {"linear", "refined", "reference", "asymmetric"}
        Which model ``model`` is: of the linear stage, the refined model and the reference
        fit, the one that predicts the held-out samples best (a refinement that fits the
        fitted part more closely can generalise worse); ties go to the refined model, then
        to the linear stage. With nothing held out, the refined one. The held-out part
        thus chooses among three models: its figure is the choice's, and a record the fit
        never saw is the test of the model kept. ``"asymmetric"``: the one of these three
        with the dead zones of eq (8') added (``asymmetry``), kept because it predicts the
        held-out part more than :data:`ASYMMETRY_TOLERANCE` better.
    split_index, warmup_samples : int
    initial_state : {"rest", "zero", "estimate", "command"}
        How the state before the first sample was taken (:func:`initial_state`;
        ``"command"``: a rest command given as a number); with ``"auto"`` asked, the
        hypothesis chosen.
    rest_command_nm : float or None
        The command the scanner was taken to rest at before the record (``u[0]`` for
        ``"rest"``, ``0`` for ``"zero"``, the one found for ``"estimate"``; the reference's
        own when ``chosen == "reference"``).
    reference : ReferenceFit or None
        The family fitted by plain non-negative least squares at :data:`REFERENCE_ORDERS`.
    state_scores : dict or None
        With ``initial_state="auto"``: each hypothesis' (``rest``, ``zero``, ``estimate``)
        rms error of the linear stage on the held-out part (on the fitted part when nothing
        is held out), nm; ``initial_state`` is the one chosen.
    output_range_nm : float
        Peak-to-peak of the measured output after the warm-up.
    floored_weights : tuple of str
        Linear-stage parameters (``"a"``, ``"w3"``...) that non-negative least squares set
        to zero and that were raised to ``min_weight`` to keep the model invertible.
    diagnostics : tuple of str
        Excitation findings (also issued as :class:`ExcitationWarning`).
    predicted_nm : ndarray, shape (n,)
        ``model``'s prediction over the whole record (read-only).
    coupling : CouplingChoice or None
        The creep-coupling search (``creep_coupling="fit"``), else ``None``. With it,
        ``nnls_model`` is the linear stage of the family chosen (its ``creep_coupling``).
    asymmetry : AsymmetryFit or None
        The asymmetric candidate (Kuhnen's modified PI, eq 8'), ``None`` when none was
        fitted (``n_dead_zones=0``, nothing held out, or a fit refused by
        :func:`fit_asymmetry`).
    asymmetry_note : str or None
        Why no asymmetric candidate was fitted or kept as fitted (:func:`fit_asymmetry`'s
        note, or nothing held out); ``None`` otherwise.
    """

    model: ScannerModel
    nnls_model: ScannerModel
    fit_errors: ErrorFigures
    validation_errors: ErrorFigures | None
    nnls_fit_errors: ErrorFigures
    nnls_validation_errors: ErrorFigures | None
    refinement: batch.RefineResult | None
    split_index: int
    warmup_samples: int
    initial_state: str
    output_range_nm: float
    floored_weights: tuple[str, ...]
    diagnostics: tuple[str, ...]
    predicted_nm: NDArray[np.float64] = field(repr=False)
    refined_fit_errors: ErrorFigures | None = None
    refined_validation_errors: ErrorFigures | None = None
    chosen: str = "linear"
    coupling: CouplingChoice | None = None
    rest_command_nm: float | None = None
    reference: ReferenceFit | None = None
    state_scores: dict[str, float] | None = None
    asymmetry: AsymmetryFit | None = None
    asymmetry_note: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "predicted_nm", readonly(self.predicted_nm))

    def summary(self) -> dict[str, Any]:
        """The figures as plain JSON-ready values."""

        def figs(e: ErrorFigures | None) -> dict[str, float | int] | None:
            return None if e is None else e.as_dict()

        out: dict[str, Any] = {
            "n_play": self.model.n_play,
            "n_creep": self.model.n_creep,
            "split_index": self.split_index,
            "warmup_samples": self.warmup_samples,
            "initial_state": self.initial_state,
            "output_range_nm": self.output_range_nm,
            "nnls": {
                "n_play": self.nnls_model.n_play,
                "n_creep": self.nnls_model.n_creep,
                "fit": figs(self.nnls_fit_errors),
                "validation": figs(self.nnls_validation_errors),
            },
            "refined": None,
            "chosen": self.chosen,
            "rest_command_nm": self.rest_command_nm,
            "state_scores": self.state_scores,
            "reference": None if self.reference is None else self.reference.as_dict(),
            "creep_coupling": self.model.creep_coupling,
            "coupling_search": None if self.coupling is None else self.coupling.as_dict(),
            "n_dead_zones": self.model.n_dead_zones,
            "asymmetry": None if self.asymmetry is None else self.asymmetry.as_dict(),
            "asymmetry_note": self.asymmetry_note,
            "floored_weights": list(self.floored_weights),
            "diagnostics": list(self.diagnostics),
        }
        if self.refinement is not None:
            out["refined"] = {
                "fit": figs(self.refined_fit_errors),
                "validation": figs(self.refined_validation_errors),
                "nfev": self.refinement.nfev,
                "success": self.refinement.success,
                "message": self.refinement.message,
            }
        return out


@dataclass(frozen=True)
class ReferenceFit:
    """The model family fitted by plain non-negative least squares (:func:`fit_sensor`).

    Attributes
    ----------
    model : ScannerModel
        Many placed operators (:data:`REFERENCE_ORDERS`), only their weights estimated.
    fit_errors, validation_errors : ErrorFigures
        On the fitted and the held-out samples (``None`` with nothing held out).
    rest_command_nm : float or None
        The rest command its starting state used (found at its own orders with
        ``initial_state="estimate"``).
    """

    model: ScannerModel
    fit_errors: ErrorFigures
    validation_errors: ErrorFigures | None
    rest_command_nm: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready figures."""
        return {
            "n_play": self.model.n_play,
            "n_creep": self.model.n_creep,
            "creep_coupling": self.model.creep_coupling,
            "rest_command_nm": self.rest_command_nm,
            "fit": self.fit_errors.as_dict(),
            "validation": (
                None if self.validation_errors is None else self.validation_errors.as_dict()
            ),
        }


@dataclass(frozen=True)
class AsymmetryFit:
    """The asymmetric candidate of :func:`fit_sensor` (:func:`fit_asymmetry`).

    Attributes
    ----------
    model : ScannerModel
        The symmetric model it was built on (``base``), its thresholds, time constants and
        creep coupling held, with the dead zones of eq (8') added and every weight refitted.
    base : str
        Which candidate it was built on (``"linear"``, ``"refined"`` or ``"reference"``).
    fit_errors, validation_errors : ErrorFigures
        On the fitted and the held-out samples.
    base_validation_rms_nm : float
        The base model's held-out rms, nm: the asymmetric one is kept if it is more than
        :data:`ASYMMETRY_TOLERANCE` below it.
    kept : bool
        Whether it became :attr:`SensorFit.model`.
    """

    model: ScannerModel
    base: str
    fit_errors: ErrorFigures
    validation_errors: ErrorFigures
    base_validation_rms_nm: float
    kept: bool

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready figures."""
        return {
            "base": self.base,
            "kept": self.kept,
            "dead_zones_nm": self.model.dead_zones_nm.tolist(),
            "dead_zone_gains": self.model.dead_zone_gains.tolist(),
            "fit": self.fit_errors.as_dict(),
            "validation": self.validation_errors.as_dict(),
            "base_validation_rms_nm": self.base_validation_rms_nm,
        }


# ---------------------------------------------------------------------------- placement
def place_thresholds(u_nm: ArrayLike, n_play: int) -> NDArray[np.float64]:
    """Uniform thresholds over the span used: ``r_j = j h / (N_H + 1)``, ``j = 1..N_H``.

    ``h`` is half the peak-to-peak span of ``u``: a play operator with ``r >= h`` never
    leaves its initial band (eq 4), so every placed threshold stays below ``h``.
    """
    n = _check_order("n_play", n_play)
    u = as_finite_1d("u_nm", u_nm)
    half = 0.5 * float(np.ptp(u)) if u.size else 0.0
    if n and half <= 0:
        raise ValueError("cannot place thresholds: the input is constant (zero span).")
    return half * np.arange(1, n + 1) / (n + 1)


def place_time_constants(
    n_samples: int,
    sample_period_s: float,
    n_creep: int,
    min_time_constant_s: float | None = None,
    longest_fraction: float = 1.0 / 3.0,
) -> NDArray[np.float64]:
    """Creep time constants log-spaced over ``[lo, f n T]`` (one: their geometric mean).

    ``lo = max(5 T, min_time_constant_s)``; ``f = longest_fraction`` of the record's
    length (a third by default).
    """
    n = _check_order("n_creep", n_creep)
    T = check_finite_scalar("sample_period_s", sample_period_s)
    if n == 0:
        return np.zeros(0)
    frac = check_finite_scalar("longest_fraction", longest_fraction)
    if frac <= 0:
        raise ValueError(f"longest_fraction must be > 0. Got {frac}.")
    lo, hi = MIN_TAU_PERIODS * T, n_samples * T * frac
    if min_time_constant_s is not None:
        lo = max(lo, check_finite_scalar("min_time_constant_s", min_time_constant_s))
    if hi <= lo:
        raise ValueError(
            f"the record ({n_samples} samples, {n_samples * T:.4g} s) is too short to place "
            f"creep time constants between {lo:.4g} s and {frac:.3g} of its length."
        )
    if n == 1:
        return np.array([np.sqrt(lo * hi)])
    return np.geomspace(lo, hi, n)


def initial_state(model: ScannerModel, u_nm: NDArray[np.float64], kind: StateKind) -> ModelState:
    """State before the first sample: ``"rest"`` (held at ``u[0]``), ``"zero"``, a number
    (held at that command, nm), or a given :class:`ModelState` (checked against ``model``'s
    orders).

    ``"rest"`` (:meth:`ModelState.at_rest`) suits a record that starts with the scanner
    held still at the first command; ``"zero"`` a scanner freshly reset at zero command
    (the first excursion follows the initial loading curve, eq 8), which is the same as
    held at ``0``; a number, a scanner held at another command and stepped to ``u[0]`` when
    the record starts (:func:`estimate_rest_command` finds it). ``"estimate"`` is resolved
    to such a number by :func:`fit_sensor` before any state is built.
    """
    if isinstance(kind, ModelState):
        kind.check_for(model)
        return kind
    if isinstance(kind, int | float | np.floating) and not isinstance(kind, bool):
        return ModelState.at_rest(model, check_finite_scalar("the rest command", float(kind)))
    if kind == "rest":
        return ModelState.at_rest(model, float(u_nm[0]))
    if kind == "zero":
        return ModelState.zeros(model)
    raise ValueError(f"initial_state must be 'rest', 'zero' or a command in nm. Got {kind!r}.")


def _rest_command(kind: StateKind, u: NDArray[np.float64]) -> float | None:
    """The command the creep rests on before the record (``None`` for a given state)."""
    if isinstance(kind, ModelState):
        return None
    if kind == "rest":
        return float(u[0])
    if kind == "zero":
        return 0.0
    return float(kind)  # type: ignore[arg-type]


def _check_order(name: str, value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise ValueError(f"{name} must be a non-negative integer. Got {value!r}.")
    return int(value)


# ---------------------------------------------------------------------------- linear stage
def _regressor(
    u: NDArray[np.float64],
    T: float,
    thresholds: NDArray[np.float64],
    taus: NDArray[np.float64],
    kind: StateKind,
) -> tuple[NDArray[np.float64], list[str]]:
    """Columns ``[u, z_1..z_NH, x_1..x_Nc]`` of eq (14) (``y`` is linear in their weights)."""
    unit = ScannerModel(
        gain=1.0,
        thresholds_nm=thresholds,
        weights=np.ones(thresholds.size),
        creep_time_constants_s=taus,
        creep_gains=np.ones(taus.size),
    )
    _, jac, _ = simulate_with_gradient(unit, u, T, initial_state(unit, u, kind))
    lay = ThetaLayout(unit.n_creep, unit.n_play)
    cols = np.column_stack((jac[:, lay.a], jac[:, lay.w], jac[:, lay.c]))
    names = ["a"] + [f"w{j + 1}" for j in range(unit.n_play)]
    names += [f"c{i + 1}" for i in range(unit.n_creep)]
    return cols, names


def nnls_stage(
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    thresholds_nm: ArrayLike,
    time_constants_s: ArrayLike,
    *,
    rows: ArrayLike | None = None,
    initial_state: StateKind = "rest",
    min_weight: float = 1e-9,
    creep_smoothing_nm: float = 0.0,
    weight_smoothing_nm: float = 0.0,
    creep_coupling: float = 0.0,
    max_iterations: int = 50,
    start: ScannerModel | None = None,
) -> tuple[ScannerModel, tuple[str, ...], NDArray[np.float64], list[str]]:
    """``a, w_j, c_i >= 0`` and ``y0`` of eq (14) by non-negative least squares.

    With thresholds and creep poles fixed, ``y(k) = y0 + [u, z_j, x_i](k) . [a, w, c]``.
    The rows and ``y`` are centred on the fitted samples (that removes ``y0``, free in
    sign), the columns scaled to unit norm, and :func:`scipy.optimize.nnls` solves for the
    rest; ``y0`` follows from the means. ``a`` or ``w_j`` that come out below
    ``min_weight`` are raised to it (the model must have ``a, w_j > 0`` to be invertible,
    eq 10); their names are returned. ``creep_smoothing_nm`` and ``weight_smoothing_nm``
    add the smoothness priors of the batch refinement
    (:func:`~piezocomp.identification.estimation.parameters.smoothness_rows`: second differences of
    the creep gains and of the play weights as extra residuals): a record shorter than the
    slowest creep modes cannot tell them apart, and without them the fit piles the gains
    onto the slowest.

    ``initial_state`` is ``"rest"``, ``"zero"`` (:func:`initial_state`) or a
    :class:`ModelState` of the orders fitted (its creep states in the units of the creep
    drive).

    ``creep_coupling`` (``beta``, held): the creep of eq (2'), driven by
    ``u + beta (a u + sum_j w_j z_j)``. The model is then bilinear in ``(a, w)`` and ``c``;
    it is solved by alternating NNLS from the ``beta = 0`` solution (at most
    ``max_iterations`` rounds), or from ``start``'s ``(a, w)`` (a model of the same orders,
    e.g. the fit of a nearby ``beta``). ``0`` (default): the paper's model, computed exactly
    as before the coupling existed.

    Returns
    -------
    model : ScannerModel
    floored : tuple of str
    regressor : ndarray, shape (n, 1 + N_H + N_c)
        The columns ``[u, z_j, x_i]`` over the whole record (``x_i`` driven by the fitted
        model's ``s`` with a coupling).
    names : list of str
        Their parameter names.
    """
    u = as_finite_1d("u_nm", u_nm)
    y = as_finite_1d("y_nm", y_nm)
    if y.shape != u.shape:
        raise ValueError(f"y_nm must have one sample per command sample ({u.size}). Got {y.size}.")
    T = check_finite_scalar("sample_period_s", sample_period_s)
    r = as_finite_1d("thresholds_nm", thresholds_nm)
    tau = as_finite_1d("time_constants_s", time_constants_s)
    sel = np.ones(u.size, bool) if rows is None else np.asarray(rows, dtype=bool)
    if sel.shape != u.shape or not sel.any():
        raise ValueError(f"rows must be a non-empty boolean mask of shape {u.shape}.")
    beta = check_finite_scalar("creep_coupling", creep_coupling)
    if beta < 0:
        raise ValueError(f"creep_coupling must be >= 0. Got {beta}.")
    if isinstance(max_iterations, bool) or int(max_iterations) < 1:
        raise ValueError(f"max_iterations must be >= 1. Got {max_iterations!r}.")
    reg, names = _regressor(u, T, r, tau, initial_state)
    nh, nc = r.size, tau.size
    if beta != 0.0 and start is not None:
        if (start.n_play, start.n_creep) != (nh, nc):
            raise ValueError(
                f"start must have {nh} play and {nc} creep operators. "
                f"Got {start.n_play} and {start.n_creep}."
            )
        coef = np.concatenate(([start.gain], start.weights, start.creep_gains))
    else:
        coef, floored, y0 = _solve(reg, y, sel, r, tau, names, min_weight, creep_smoothing_nm,
                                   weight_smoothing_nm, beta != 0.0)  # fmt: skip
    if beta != 0.0:
        coef, floored, y0, reg = _coupled_solve(
            u, y, sel, T, r, tau, names, beta, reg, coef, initial_state, min_weight,
            creep_smoothing_nm, weight_smoothing_nm, max_iterations,
        )  # fmt: skip
    a_hat, w_hat, c_hat = coef[0], coef[1 : 1 + nh], coef[1 + nh : 1 + nh + nc]
    model = ScannerModel(
        offset_nm=y0,
        gain=a_hat,
        thresholds_nm=r,
        weights=w_hat,
        creep_time_constants_s=tau,
        creep_gains=c_hat,
        creep_coupling=beta,
    )
    return model, tuple(floored), reg, names


def _solve(
    reg: NDArray[np.float64],
    y: NDArray[np.float64],
    sel: NDArray[np.bool_],
    r: NDArray[np.float64],
    tau: NDArray[np.float64],
    names: list[str],
    min_weight: float,
    creep_smoothing_nm: float,
    weight_smoothing_nm: float,
    reduce: bool = False,
) -> tuple[NDArray[np.float64], list[str], float]:
    """Coefficients ``[a, w, c]`` (floored), the floored names and ``y0`` of one NNLS.

    ``reduce``: solve the same problem on its QR factor (``min |R x - Q^T b|`` has the
    minimiser of ``min |A x - b|``), several times faster on a long record; off for the
    paper's model, whose results stay those computed before the coupling existed.
    """
    a_mat = reg[sel]
    b = y[sel]
    col_mean = a_mat.mean(axis=0)
    b_mean = float(b.mean())
    centred = a_mat - col_mean
    scale = np.linalg.norm(centred, axis=0)
    scale[scale <= 0] = 1.0
    nh, nc = r.size, tau.size
    unit = ScannerModel(thresholds_nm=r, weights=np.ones(nh), creep_time_constants_s=tau,
                        creep_gains=np.zeros(nc))  # fmt: skip
    prior = smoothness_rows(unit, creep_smoothing_nm, weight_smoothing_nm)
    layout = ThetaLayout(nc, nh)
    order = np.concatenate([[layout.a], np.arange(layout.size)[layout.w],
                            np.arange(layout.size)[layout.c]])  # fmt: skip
    prior = prior[:, order] / scale  # onto [a, w, c], in the scaled unknowns
    data, rhs = centred / scale, b - b_mean
    if reduce and data.shape[0] > data.shape[1] + 1:  # R of [A | b]: R_A and Q^T b
        rb = np.asarray(np.linalg.qr(np.column_stack((data, rhs)), mode="r"), dtype=float)
        data, rhs = rb[: data.shape[1], : data.shape[1]], rb[: data.shape[1], -1]
    lhs = np.vstack([data, prior])
    rhs = np.concatenate([rhs, np.zeros(prior.shape[0])])
    coef_s, _ = nnls(lhs, rhs)
    coef = coef_s / scale
    floored = []
    for j, name in enumerate(names):
        if not name.startswith("c") and coef[j] < min_weight:
            coef[j] = min_weight
            floored.append(name)
    y0 = b_mean - float(col_mean @ coef)
    return coef, floored, y0


def _coupled_solve(
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    sel: NDArray[np.bool_],
    T: float,
    r: NDArray[np.float64],
    tau: NDArray[np.float64],
    names: list[str],
    beta: float,
    reg: NDArray[np.float64],
    coef: NDArray[np.float64],
    kind: StateKind,
    min_weight: float,
    creep_smoothing_nm: float,
    weight_smoothing_nm: float,
    max_iterations: int,
) -> tuple[NDArray[np.float64], list[str], float, NDArray[np.float64]]:
    """The NNLS of eq (14) with the creep of eq (2'), by alternation.

    The creep columns ``x_i[s]`` depend on ``(a, w)`` through ``s = u + beta H``,
    ``H = a u + sum_j w_j z_j``, so the model is bilinear, not linear, in ``(a, w, c)``. From
    ``(a, w)`` of the paper's fit (``coef``), ``H`` and the creep columns are rebuilt with the
    current ``(a, w)`` and the NNLS solved again until ``H`` moves by less than ``1e-9`` of
    its span (or ``max_iterations``): a fixed point is a model whose own creep drive was
    used. The play columns ``[u, z_j]`` do not depend on ``beta``.
    """
    nh = r.size
    hyst = reg[:, : 1 + nh]  # [u, z_j]
    floored: list[str] = []
    y0 = 0.0
    for _ in range(max_iterations):
        h = hyst @ coef[: 1 + nh]
        creep = _coupled_creep(u, h, beta, coef[: 1 + nh], kind, tau, T)
        reg = np.column_stack((hyst, creep))
        coef, floored, y0 = _solve(reg, y, sel, r, tau, names, min_weight,
                                   creep_smoothing_nm, weight_smoothing_nm, True)  # fmt: skip
        moved = float(np.max(np.abs(hyst @ coef[: 1 + nh] - h)))
        if moved <= 1e-9 * max(float(np.ptp(h)), 1.0):
            break
    return coef, floored, y0, reg


def _coupled_creep(
    u: NDArray[np.float64],
    h: NDArray[np.float64],
    beta: float,
    coef: NDArray[np.float64],
    kind: StateKind,
    tau: NDArray[np.float64],
    T: float,
) -> NDArray[np.float64]:
    """Creep columns ``x_i[s]`` of eq (2') for the drive ``s = u + beta H`` (``H = h``, of the
    coefficients ``coef = [a, w_1..w_NH]``), started as ``kind`` says."""
    nh, nc = coef.size - 1, tau.size
    s_drive = u + beta * h
    if isinstance(kind, ModelState):  # s(-1) = u(-1) + beta H(-1) of the fitted a, w
        h_prev = coef[0] * kind.u_prev_nm + float(coef[1 : 1 + nh] @ kind.play_nm)
        x0, s_prev = kind.creep_nm.copy(), kind.u_prev_nm + beta * h_prev
    elif kind == "rest":  # held at u[0] for ever: the creep settled on s(0)
        x0, s_prev = np.full(nc, s_drive[0]), float(s_drive[0])
    elif kind == "zero":
        x0, s_prev = np.zeros(nc), 0.0
    else:  # held at a command u_r: plays centred on it, H(-1) = (a + sum w) u_r
        u_r = float(kind)  # type: ignore[arg-type]
        s_prev = u_r + beta * (coef[0] + float(coef[1 : 1 + nh].sum())) * u_r
        x0 = np.full(nc, s_prev)
    creep, _ = creep_bank(s_drive, tau, T, x0, s_prev)
    return np.asarray(creep)


# ---------------------------------------------------------------------------- asymmetry
def place_dead_zones(h_nm: ArrayLike, n_dead_zones: int) -> NDArray[np.float64]:
    """Thresholds of eq (8') over the span of a hysteresis output ``h``: ``n / 2`` of them
    above its centre and ``n / 2`` below, evenly out to 40 % of the span either side
    (``centre +- 0.4 span (1..n/2) / (n/2)``); a threshold that would fall on ``h = 0``, where
    a dead zone has no side, is left out."""
    n = _check_order("n_dead_zones", n_dead_zones)
    if n % 2:
        raise ValueError(f"n_dead_zones must be even (pairs about the centre). Got {n}.")
    h = as_finite_1d("h_nm", h_nm)
    lo, hi = float(h.min()), float(h.max())
    centre, span = 0.5 * (lo + hi), hi - lo
    if n == 0 or span <= 0:
        return np.zeros(0)
    steps = 0.4 * np.arange(1, n // 2 + 1) / (n // 2)
    d = np.sort(np.concatenate((centre - span * steps, centre + span * steps)))
    return d[np.abs(d) > 1e-9 * span]


def fit_asymmetry(
    base: ScannerModel,
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    *,
    rows: ArrayLike,
    initial_state: StateKind = "rest",
    n_dead_zones: int = DEAD_ZONES,
    min_weight: float = 1e-9,
    max_iterations: int = 50,
) -> tuple[ScannerModel | None, str | None]:
    """Kuhnen's modified PI (eq 8') on ``base``'s operators: ``y = y0 + S(H) + sum c_i x_i``.

    ``base``'s thresholds, creep time constants and creep coupling are held; the dead zones
    are placed over the span of its hysteresis output on ``rows`` (:func:`place_dead_zones`).
    With ``H`` known, ``y`` is linear in ``[a, w, c, g]``: the columns
    ``[u, z_j, x_i, q_{d_l}(H)]`` are solved by bounded least squares
    (:func:`scipy.optimize.lsq_linear`), centred and scaled as :func:`nnls_stage` does, with
    ``a, w_j, c_i >= 0`` as in the linear stage and the dead zones' gains written as the
    slopes ``s_l`` of ``S`` going outwards from zero (``g_l = s_l - s_{l-1}``, ``s_0 = 1``),
    each at least :data:`MIN_ASYMMETRY_SLOPE`: the map is invertible by construction and its
    inverse never multiplies the command's steps by more than ten. The
    dead-zone columns (and, with a coupling, the creep columns) depend on ``H`` and so on
    ``(a, w)``: they are rebuilt from the new ``(a, w)`` and the problem solved again until
    ``H`` moves by less than ``1e-9`` of its span (or ``max_iterations``), so that the model
    is the one whose own ``S(H)`` was fitted. ``a`` and ``w_j`` are floored at ``min_weight``.

    Returns
    -------
    model : ScannerModel or None
        ``None`` when no dead zone could be placed.
    note : str or None
        Why ``model`` is ``None``, or that the iterations stopped before ``H`` settled (the
        model is then returned, its dead zones fitted to the last iterate's ``H`` but
        scored as a model like any other); ``None`` otherwise.
    """
    u, y, T = _record(u_nm, y_nm, sample_period_s)
    sel = np.asarray(rows, dtype=bool)
    if sel.shape != u.shape or not sel.any():
        raise ValueError(f"rows must be a non-empty boolean mask of shape {u.shape}.")
    base.require_symmetric("fit_asymmetry's base")
    r, tau, beta = base.thresholds_nm, base.creep_time_constants_s, base.creep_coupling
    nh, nc = r.size, tau.size
    reg, _ = _regressor(u, T, r, tau, initial_state)
    hyst = reg[:, : 1 + nh]
    coef_h = np.concatenate(([base.gain], base.weights))
    h = hyst @ coef_h
    d = place_dead_zones(h[sel], n_dead_zones)
    if d.size == 0:
        return None, "no dead zone could be placed (the hysteresis output does not move)"
    sides = [np.flatnonzero(d > 0), np.flatnonzero(d < 0)[::-1]]  # outwards from zero
    n_s = d.size
    settled = False
    coef = np.zeros(1 + nh + nc + n_s)
    y0 = 0.0
    for _ in range(max_iterations):
        creep = reg[:, 1 + nh :]
        if beta != 0.0:
            creep = _coupled_creep(u, h, beta, coef_h, initial_state, tau, T)
        q = dead_zone_columns(h, d)
        # S's part beyond the identity, in the slopes s_l outwards from zero (s_0 = 1):
        # sum_l g_l q_l = -q_first + sum_l s_l (q_l - q_next), with g_l = s_l - s_{l-1}
        known = np.zeros(u.size)
        slope_cols = []
        for idx in sides:
            if idx.size:
                known -= q[:, idx[0]]
                nxt = np.column_stack((q[:, idx[1:]], np.zeros(u.size)))
                slope_cols.append(q[:, idx] - nxt)
        a_mat = np.column_stack((hyst, creep, *slope_cols))[sel]
        b = (y - known)[sel]
        mu, b_mu = a_mat.mean(axis=0), float(b.mean())
        sc = np.linalg.norm(a_mat - mu, axis=0)
        sc[sc <= 0] = 1.0
        data, rhs = (a_mat - mu) / sc, b - b_mu
        if data.shape[0] > data.shape[1] + 1:  # the same problem on its R factor
            rb = np.asarray(np.linalg.qr(np.column_stack((data, rhs)), mode="r"), dtype=float)
            data, rhs = rb[: data.shape[1], : data.shape[1]], rb[: data.shape[1], -1]
        lower = np.concatenate((np.zeros(1 + nh + nc), np.full(n_s, MIN_ASYMMETRY_SLOPE)))
        coef = lsq_linear(data, rhs, bounds=(lower * sc, np.inf), method="bvls").x / sc
        coef = np.maximum(coef, lower)  # the bounds again, after the rescaling's rounding
        coef[: 1 + nh] = np.maximum(coef[: 1 + nh], min_weight)
        y0 = b_mu - float(mu @ coef)
        coef_h = coef[: 1 + nh]
        h_new = hyst @ coef_h
        moved = float(np.max(np.abs(h_new - h)))
        h = h_new
        if moved <= 1e-9 * max(float(np.ptp(h)), 1.0):
            settled = True
            break
    slopes = coef[1 + nh + nc :]
    g = np.empty(n_s)
    k = 0
    for idx in sides:
        s_prev = 1.0
        for i in idx:
            g[i], s_prev = slopes[k] - s_prev, slopes[k]
            k += 1
    model = ScannerModel(
        offset_nm=y0,
        gain=coef[0],
        thresholds_nm=r,
        weights=coef[1 : 1 + nh],
        creep_time_constants_s=tau,
        creep_gains=coef[1 + nh : 1 + nh + nc],
        creep_coupling=beta,
        dead_zones_nm=d,
        dead_zone_gains=g,
    )
    note = (
        None
        if settled
        else (
            f"the dead zones' fit stopped after {max_iterations} rounds before its hysteresis "
            "output settled"
        )
    )
    return model, note


# ---------------------------------------------------------------------------- coupling
@dataclass(frozen=True)
class CouplingChoice:
    """Outcome of :func:`choose_creep_coupling`: the creep coupling of eq (2') and the family.

    Attributes
    ----------
    coupling : float
        The chosen ``beta``: ``best_coupling`` if that model predicts the held-out samples
        better than the paper's (``beta = 0``), else ``0``.
    best_coupling : float
        The ``beta`` of the bounded search on the fitting residual.
    family : {"paper", "coupled"}
        Which family won on the held-out samples.
    fit_rms_nm, validation_rms_nm : tuple of float
        ``(paper, best_coupling)`` rms errors on the fitted and the held-out samples, nm.
    evaluations : int
        Fits run by the search.
    """

    coupling: float
    best_coupling: float
    family: str
    fit_rms_nm: tuple[float, float]
    validation_rms_nm: tuple[float, float]
    evaluations: int

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready figures."""
        return {
            "coupling": self.coupling,
            "best_coupling": self.best_coupling,
            "family": self.family,
            "fit_rms_nm": {"paper": self.fit_rms_nm[0], "coupled": self.fit_rms_nm[1]},
            "validation_rms_nm": {
                "paper": self.validation_rms_nm[0],
                "coupled": self.validation_rms_nm[1],
            },
            "evaluations": self.evaluations,
        }


DEFAULT_MAX_COUPLING = 2.0
"""Upper bound of the creep coupling searched (dimensionless; cpr5 wants about 0.5-0.7)."""


def choose_creep_coupling(
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    thresholds_nm: ArrayLike,
    time_constants_s: ArrayLike,
    *,
    fit_rows: ArrayLike,
    validation_rows: ArrayLike,
    initial_state: StateKind = "rest",
    max_coupling: float = DEFAULT_MAX_COUPLING,
    tolerance: float = 5e-3,
    min_weight: float = 1e-9,
    creep_smoothing_nm: float = 0.0,
    weight_smoothing_nm: float = 0.0,
) -> tuple[ScannerModel, ScannerModel, CouplingChoice]:
    """The creep coupling ``beta`` of eq (2') and the family, from a record of ``(u, y)``.

    For each ``beta`` the linear stage (:func:`nnls_stage`, thresholds and time constants
    held) is fitted on ``fit_rows``; ``beta`` minimises the rms error of the fitted model
    (simulated over the whole record) on those rows, by a bounded 1-D search over
    ``[0, max_coupling]`` (:func:`scipy.optimize.minimize_scalar`, ``xatol = tolerance``;
    ``beta = 0`` itself is evaluated too). The coupled model is kept only if it predicts
    ``validation_rows`` better than the paper's model (``beta = 0``), so the choice is never
    worse on them.

    Returns
    -------
    model : ScannerModel
        The chosen model (the paper's when ``choice.family == "paper"``).
    paper : ScannerModel
        The ``beta = 0`` model (exactly :func:`nnls_stage`'s).
    choice : CouplingChoice
    """
    u, y, T = _record(u_nm, y_nm, sample_period_s)
    fit = np.asarray(fit_rows, dtype=bool)
    val = np.asarray(validation_rows, dtype=bool)
    for name, mask in (("fit_rows", fit), ("validation_rows", val)):
        if mask.shape != u.shape or not mask.any():
            raise ValueError(f"{name} must be a non-empty boolean mask of shape {u.shape}.")
    top = check_finite_scalar("max_coupling", max_coupling)
    if top <= 0:
        raise ValueError(f"max_coupling must be > 0. Got {top}.")
    r = as_finite_1d("thresholds_nm", thresholds_nm)
    tau = as_finite_1d("time_constants_s", time_constants_s)
    models: dict[float, tuple[ScannerModel, float]] = {}

    def fitted(beta: float) -> tuple[ScannerModel, float]:
        if beta not in models:
            near = min(models, key=lambda b: abs(b - beta)) if models else None
            m, *_ = nnls_stage(
                u, y, T, r, tau, rows=fit, initial_state=initial_state, min_weight=min_weight,
                creep_smoothing_nm=creep_smoothing_nm, weight_smoothing_nm=weight_smoothing_nm,
                creep_coupling=beta, start=None if near is None else models[near][0],
            )  # fmt: skip
            pred, _ = simulate(m, u, T, _state(m, u, initial_state))
            models[beta] = (m, float(np.sqrt(np.mean((pred[fit] - y[fit]) ** 2))))
        return models[beta]

    paper, paper_fit = fitted(0.0)
    minimize_scalar(
        lambda b: fitted(float(b))[1], bounds=(0.0, top), method="bounded",
        options={"xatol": float(tolerance)},
    )  # fmt: skip
    best = min(models, key=lambda b: models[b][1])  # beta = 0 included
    coupled, coupled_fit = fitted(best)

    def val_rms(m: ScannerModel) -> float:
        pred, _ = simulate(m, u, T, _state(m, u, initial_state))
        return float(np.sqrt(np.mean((pred[val] - y[val]) ** 2)))

    paper_val, coupled_val = val_rms(paper), val_rms(coupled)
    better = best > 0.0 and coupled_val < paper_val
    choice = CouplingChoice(
        coupling=best if better else 0.0,
        best_coupling=best,
        family="coupled" if better else "paper",
        fit_rms_nm=(paper_fit, coupled_fit),
        validation_rms_nm=(paper_val, coupled_val),
        evaluations=len(models),
    )
    return (coupled if better else paper), paper, choice


# ---------------------------------------------------------------------------- start
def estimate_rest_command(
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    thresholds_nm: ArrayLike,
    time_constants_s: ArrayLike,
    *,
    rows: ArrayLike,
    creep_coupling: float = 0.0,
    min_weight: float = 1e-9,
    tolerance: float | None = None,
) -> float:
    """The command the scanner was held at before a record, from the record itself.

    A real record seldom starts from a known state: the actuator rested at some command,
    then the drive began (often with a step to ``u[0]``). The state ``at_rest(u_r)`` (play
    operators centred on ``u_r``, creep settled on it, :meth:`ModelState.at_rest`) covers
    ``"rest"`` (``u_r = u[0]``) and ``"zero"`` (``u_r = 0``) and everything between. For each
    ``u_r`` the linear stage (:func:`nnls_stage`) is fitted on ``rows``; ``u_r`` minimises its
    rms error there: a grid of :data:`REST_GRID` points over the span of the fitted commands
    and ``0``, widened by that span on either side, with ``u[0]`` and ``0``, then a bounded
    Brent search (:func:`scipy.optimize.minimize_scalar`) between the best point's
    neighbours. The play operators forget ``u_r`` once the drive has swept their width
    (wiping-out); the creep does not, which is what the search is for.

    Parameters
    ----------
    u_nm, y_nm, sample_period_s, thresholds_nm, time_constants_s
        As :func:`nnls_stage`.
    rows : array_like of bool
        The samples fitted (a warm-up and a held-out part left out).
    creep_coupling : float
        ``beta`` of eq (2'), held.
    tolerance : float, optional
        ``xatol`` of the search, nm (default ``1e-3`` of the span).

    Returns
    -------
    float
        ``u_r``, nm.
    """
    u, y, T = _record(u_nm, y_nm, sample_period_s)
    sel = np.asarray(rows, dtype=bool)
    if sel.shape != u.shape or not sel.any():
        raise ValueError(f"rows must be a non-empty boolean mask of shape {u.shape}.")
    r = as_finite_1d("thresholds_nm", thresholds_nm)
    tau = as_finite_1d("time_constants_s", time_constants_s)
    lo, hi = _rest_span(u[sel])
    tol = 1e-3 * (hi - lo) if tolerance is None else check_finite_scalar("tolerance", tolerance)
    if not tol > 0 and hi > lo:
        raise ValueError(f"tolerance must be > 0. Got {tol}.")
    scores: dict[float, float] = {}

    def rms(u_r: float) -> float:
        if u_r not in scores:
            m, *_ = nnls_stage(u, y, T, r, tau, rows=sel, initial_state=u_r,
                               creep_coupling=creep_coupling, min_weight=min_weight)  # fmt: skip
            pred, _ = simulate(m, u, T, ModelState.at_rest(m, u_r))
            scores[u_r] = float(np.sqrt(np.mean((pred[sel] - y[sel]) ** 2)))
        return scores[u_r]

    return _search_rest(rms, float(u[0]), lo, hi, tol)


def start_of_record(
    model: ScannerModel,
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    *,
    rows: ArrayLike,
) -> tuple[float, float]:
    """The rest command and the sensor offset that start ``model`` on another record.

    To predict a record the model was not fitted on (another day, another drive), its state
    before the first sample and the sensor's zero are unknown. Both are found from
    ``rows`` (say, the record's first seconds) with the model held: the offset as the mean
    error, the rest command ``u_r`` (state :meth:`ModelState.at_rest`) minimising the rms
    error left, searched as :func:`estimate_rest_command` searches it, over the span of this
    record's commands (and ``0``) widened by that span on either side. Score the
    prediction on the other samples.

    Returns
    -------
    rest_command_nm, offset_nm : float
        Simulate from ``ModelState.at_rest(model, rest_command_nm)`` and subtract
        ``offset_nm`` from the prediction.
    """
    u, y, T = _record(u_nm, y_nm, sample_period_s)
    sel = np.asarray(rows, dtype=bool)
    if sel.shape != u.shape or not sel.any():
        raise ValueError(f"rows must be a non-empty boolean mask of shape {u.shape}.")
    lo, hi = _rest_span(u)
    scores: dict[float, tuple[float, float]] = {}

    def rms(u_r: float) -> float:
        if u_r not in scores:
            pred, _ = simulate(model, u, T, ModelState.at_rest(model, u_r))
            err = pred[sel] - y[sel]
            off = float(err.mean())
            scores[u_r] = (float(np.sqrt(np.mean((err - off) ** 2))), off)
        return scores[u_r][0]

    best = _search_rest(rms, float(u[0]), lo, hi, 1e-3 * (hi - lo))
    return best, scores[best][1]


REST_GRID = 13
"""Points of the coarse grid of the rest-command search, before Brent's method."""


def _rest_span(u: NDArray[np.float64]) -> tuple[float, float]:
    """Where a rest command is looked for: the commands' span and ``0``, widened by that
    span on either side (an actuator may rest outside the drive's span)."""
    lo, hi = min(float(u.min()), 0.0), max(float(u.max()), 0.0)
    width = hi - lo
    return lo - width, hi + width


def _search_rest(
    rms: Callable[[float], float], first: float, lo: float, hi: float, tol: float
) -> float:
    """The rest command of least ``rms``: a coarse grid over ``[lo, hi]`` with ``first``
    (``u[0]``) and ``0``, then a bounded Brent search between the best point's neighbours
    (the error need not be unimodal over the whole span)."""
    grid = np.linspace(lo, hi, REST_GRID) if hi > lo else np.array([lo])
    points = sorted({*map(float, grid), first, 0.0})
    values = [rms(v) for v in points]
    k = int(np.argmin(values))
    a, b = points[max(k - 1, 0)], points[min(k + 1, len(points) - 1)]
    if b > a:
        found = minimize_scalar(lambda v: rms(float(v)), bounds=(a, b), method="bounded",
                                options={"xatol": tol})  # fmt: skip
        if rms(float(found.x)) < values[k]:
            return float(found.x)
    return points[k]


# ---------------------------------------------------------------------------- pipeline
def fit_sensor(
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    *,
    n_play: int = 8,
    n_creep: int = 2,
    thresholds_nm: ArrayLike | None = None,
    time_constants_s: ArrayLike | None = None,
    validation_fraction: float = 0.25,
    split_index: int | None = None,
    warmup_samples: int = 0,
    initial_state: InitialState | float = "auto",
    refine: bool = True,
    refine_free: Collection[str] = batch.GROUPS,
    min_weight: float = 1e-9,
    min_time_constant_s: float | None = DEFAULT_MIN_TIME_CONSTANT_S,
    max_nfev: int | None = 200,
    creep_coupling: float | Literal["fit"] = 0.0,
    max_coupling: float = DEFAULT_MAX_COUPLING,
    reference_orders: tuple[int, int] | None = REFERENCE_ORDERS,
    n_dead_zones: int = DEAD_ZONES,
) -> SensorFit:
    """Identify the model (14) from a command ``u`` and a measured extension ``y``.

    Parameters
    ----------
    u_nm, y_nm : array_like, shape (n,)
        Command (nominal nm) and measured extension (nm), sampled every ``T``.
    sample_period_s : float
        ``T`` (> 0), s.
    n_play, n_creep : int
        ``N_H`` and ``N_c`` (ignored where ``thresholds_nm`` / ``time_constants_s`` given).
    thresholds_nm : array_like, optional
        Starting thresholds; default :func:`place_thresholds` over the fitted part of ``u``.
    time_constants_s : array_like, optional
        Starting creep time constants; default :func:`place_time_constants` for the fitted
        part's length.
    validation_fraction : float
        Fraction of the record, at its end, held out for validation (0: none).
    split_index : int, optional
        Explicit first held-out sample (overrides ``validation_fraction``).
    warmup_samples : int
        First samples excluded from the fit and the figures (unknown initial state; see
        :func:`piezocomp.identification.estimation.batch.refine`).
    initial_state : {"rest", "zero", "estimate", "auto"} or float
        State before the first sample (:func:`initial_state`): ``"estimate"`` finds the
        command the scanner rested at from the fitted part (:func:`estimate_rest_command`,
        with the linear stage's orders and ``beta = 0``); the command found is
        ``SensorFit.rest_command_nm``. ``"auto"``: of ``"rest"`` and ``"zero"``, the one
        whose linear stage predicts the held-out part better, or ``"estimate"`` if it
        predicts it more than :data:`STATE_TOLERANCE` better still
        (``SensorFit.state_scores``; on the fitted part when nothing is held out). The
        linear stage that judges has the reference's orders and placement (many operators
        tell a wrong start from a model too small), or the fit's own without a reference.
        When it chooses ``"estimate"``, the fit's own models and the reference each use the
        rest command estimated at their own orders (``SensorFit.rest_command_nm`` is the
        kept model's). :func:`~piezocomp.sensor.orders.select_sensor_orders` makes this
        choice again for every candidate order.
    refine : bool
        Run the nonlinear refinement (all parameters, or the groups in ``refine_free``); the
        refined model is kept unless it predicts the held-out samples worse than the linear
        stage's (``SensorFit.chosen``).
    min_weight : float
        Floor of ``a`` and ``w_j`` (> 0).
    min_time_constant_s : float or None
        Shortest creep time constant, placed and kept by the refinement
        (:data:`DEFAULT_MIN_TIME_CONSTANT_S`); ``None``: 5 sample periods when placing,
        no bound but the poles' ``(0, 1)`` when refining.
    max_nfev : int, optional
        Budget of the refinement.
    creep_coupling : float or "fit"
        The creep coupling ``beta`` of eq (2'): ``0`` (default) the paper's model, exactly
        as before the coupling existed; a number ``> 0``: held by both stages; ``"fit"``:
        :func:`choose_creep_coupling` over ``[0, max_coupling]``, the coupled family kept
        only if it predicts the held-out part better (a held-out part is needed). The
        refinement, if asked for, refines the family chosen (``beta`` free with it when it
        is the coupled one), and the model kept is the one better on the held-out part
        (``chosen``).
    max_coupling : float
        Upper bound of the coupling searched with ``creep_coupling="fit"``.
    reference_orders : (int, int) or None
        ``(N_H, N_c)`` of the reference fit (:data:`REFERENCE_ORDERS`): the same family
        by plain non-negative least squares with that many placed operators, same split,
        warm-up and starting state (with ``"estimate"``, its own rest command; with
        ``creep_coupling="fit"``, its own ``beta`` search). It is a third candidate
        of ``chosen``, so the model kept never predicts the held-out part worse than it.
        ``None``: no reference.
    n_dead_zones : int
        Dead zones of the asymmetric candidate (Kuhnen's modified PI, eq 8',
        :func:`fit_asymmetry`), built on the best of the other candidates and kept only if
        it predicts the held-out part more than :data:`ASYMMETRY_TOLERANCE` better
        (``SensorFit.asymmetry``); even, :data:`DEAD_ZONES` by default. ``0``, or nothing
        held out: symmetric models only.

    Returns
    -------
    SensorFit

    Warns
    -----
    ExcitationWarning
        When the fitted part does not excite the model (see
        :mod:`piezocomp.identification.acquisition.diagnostics`).
    """
    u, y, T = _record(u_nm, y_nm, sample_period_s)
    n = u.size
    fixed_beta = 0.0
    if creep_coupling != "fit":
        fixed_beta = check_finite_scalar("creep_coupling", creep_coupling)
        if fixed_beta < 0:
            raise ValueError(f"creep_coupling must be >= 0 or 'fit'. Got {fixed_beta}.")
    split = split_record(n, validation_fraction, split_index, warmup_samples)
    if creep_coupling == "fit" and split >= n:
        raise ValueError("creep_coupling='fit' needs a held-out part (validation_fraction > 0).")
    n_zones = _check_order("n_dead_zones", n_dead_zones)
    if n_zones % 2:
        raise ValueError(f"n_dead_zones must be even (pairs about the centre). Got {n_zones}.")
    warm = int(warmup_samples)
    fit_rows, val_rows = np.arange(n) >= warm, np.arange(n) >= split
    fit_rows &= ~val_rows
    u_fit = u[warm:split]
    r = place_thresholds(u_fit, n_play) if thresholds_nm is None else thresholds_nm
    tau = (
        place_time_constants(split - warm, T, n_creep, min_time_constant_s)
        if time_constants_s is None
        else time_constants_s
    )
    r, tau = as_finite_1d("thresholds_nm", r), as_finite_1d("time_constants_s", tau)
    if not (
        initial_state in ("rest", "zero", "estimate", "auto")
        or (isinstance(initial_state, int | float) and not isinstance(initial_state, bool)
            and np.isfinite(initial_state))
    ):  # fmt: skip
        raise ValueError(
            "initial_state must be 'rest', 'zero', 'estimate', 'auto' or a finite command in "
            f"nm. Got {initial_state!r}."
        )
    ref_orders = None
    if reference_orders is not None:
        if len(reference_orders) != 2:
            raise ValueError(
                f"reference_orders must be (N_H, N_c) of the reference. Got {reference_orders!r}."
            )
        ref_orders = tuple(
            _check_order(f"reference_orders[{i}]", v) for i, v in enumerate(reference_orders)
        )
        r_ref = place_thresholds(u_fit, ref_orders[0])
        tau_ref = place_time_constants(split - warm, T, ref_orders[1], min_time_constant_s,
                                       REFERENCE_LONGEST)  # fmt: skip
    kind: StateKind = initial_state
    state_scores: dict[str, float] | None = None
    if initial_state == "estimate":
        kind = estimate_rest_command(u, y, T, r, tau, rows=fit_rows, min_weight=min_weight)
    judged: StateKind | None = None
    if initial_state == "auto":  # judged with the reference's many operators, if any
        r_j, tau_j = (r, tau) if ref_orders is None else (r_ref, tau_ref)
        state_name, judged, state_scores = _choose_state(
            u, y, T, r_j, tau_j, fit_rows, val_rows if split < n else fit_rows, min_weight
        )
        kind = judged
        if state_name == "estimate" and ref_orders is not None:  # at the fit's own orders
            kind = estimate_rest_command(u, y, T, r, tau, rows=fit_rows, min_weight=min_weight)
    else:
        state_name = initial_state if isinstance(initial_state, str) else "command"
    nnls_model, floored, reg, names = nnls_stage(
        u, y, T, r, tau, rows=fit_rows, initial_state=kind, min_weight=min_weight
    )
    findings = check_excitation(u_fit, T, r, tau, reg[fit_rows], names)
    warn_excitation(findings, stacklevel=2)
    paper_model, coupling = nnls_model, None
    if creep_coupling == "fit":
        nnls_model, _, coupling = choose_creep_coupling(
            u, y, T, r, tau, fit_rows=fit_rows, validation_rows=val_rows,
            initial_state=kind, max_coupling=max_coupling, min_weight=min_weight,
        )  # fmt: skip
    elif fixed_beta > 0:
        nnls_model, floored, _, _ = nnls_stage(
            u, y, T, r, tau, rows=fit_rows, initial_state=kind,
            min_weight=min_weight, creep_coupling=fixed_beta,
        )  # fmt: skip

    out_range = float(np.ptp(y[warm:]))
    rows = (fit_rows, val_rows if split < n else None)
    pred, nnls_fit, nnls_val = _figures(nnls_model, u, y, T, kind, rows, out_range)
    model, fit_e, val_e, chosen = nnls_model, nnls_fit, nnls_val, "linear"
    result, ref_fit, ref_val = None, None, None
    if refine:
        options = batch.RefineOptions(
            free=tuple(refine_free), min_gain=min_weight, min_weight=min_weight,
            min_time_constant_s=min_time_constant_s, max_nfev=max_nfev,
        )  # fmt: skip
        # the family the linear stage chose is refined: beta free after the search, held
        # when given
        start = nnls_model if nnls_model.creep_coupling > 0 else paper_model
        if creep_coupling == "fit" and start.creep_coupling > 0:
            options = replace(options, free=(*options.free, batch.COUPLING))
        state = _state(start, u, kind)
        rest = None if kind == "zero" else _rest_command(kind, u)  # the creep follows beta
        result = batch.refine(start, u, y, T, state=state, fit_mask=fit_rows, options=options,
                              creep_rest_nm=rest)  # fmt: skip
        ref_pred, ref_fit, ref_val = _figures(result.model, u, y, T, kind, rows, out_range)
        if ref_val is None or nnls_val is None or ref_val.rms_nm <= nnls_val.rms_nm:
            model, pred, fit_e, val_e, chosen = result.model, ref_pred, ref_fit, ref_val, "refined"
    reference, kept_kind = None, kind
    if ref_orders is not None:
        ref_kind = kind if judged is None else judged
        if initial_state == "estimate":
            ref_kind = estimate_rest_command(u, y, T, r_ref, tau_ref, rows=fit_rows,
                                             min_weight=min_weight)  # fmt: skip
        if creep_coupling == "fit":
            ref_model, _, _ = choose_creep_coupling(
                u, y, T, r_ref, tau_ref, fit_rows=fit_rows, validation_rows=val_rows,
                initial_state=ref_kind, max_coupling=max_coupling, min_weight=min_weight,
            )  # fmt: skip
        else:
            ref_model, *_ = nnls_stage(u, y, T, r_ref, tau_ref, rows=fit_rows,
                                       initial_state=ref_kind, min_weight=min_weight,
                                       creep_coupling=fixed_beta)  # fmt: skip
        ref_pred, r_fit, r_val = _figures(ref_model, u, y, T, ref_kind, rows, out_range)
        reference = ReferenceFit(ref_model, r_fit, r_val, _rest_command(ref_kind, u))
        if r_val is not None and val_e is not None and r_val.rms_nm < val_e.rms_nm:
            model, pred, fit_e, val_e, chosen = ref_model, ref_pred, r_fit, r_val, "reference"
            kept_kind = ref_kind
    asymmetry, asymmetry_note = None, None
    if n_zones and val_e is None:
        asymmetry_note = "not fitted: nothing is held out to judge it on"
    elif n_zones and val_e is not None:  # judged on the held-out part
        asym, asymmetry_note = fit_asymmetry(
            model, u, y, T, rows=fit_rows, initial_state=kept_kind, n_dead_zones=n_zones,
            min_weight=min_weight,
        )  # fmt: skip
        if asym is not None:
            a_pred, a_fit, a_val = _figures(asym, u, y, T, kept_kind, rows, out_range)
            assert a_val is not None  # a held-out part exists
            keep = a_val.rms_nm < (1.0 - ASYMMETRY_TOLERANCE) * val_e.rms_nm
            asymmetry = AsymmetryFit(asym, chosen, a_fit, a_val, val_e.rms_nm, keep)
            if keep:
                model, pred, fit_e, val_e, chosen = asym, a_pred, a_fit, a_val, "asymmetric"
    return SensorFit(
        model=model,
        nnls_model=nnls_model,
        fit_errors=fit_e,
        validation_errors=val_e,
        nnls_fit_errors=nnls_fit,
        nnls_validation_errors=nnls_val,
        refinement=result,
        split_index=split,
        warmup_samples=warm,
        initial_state=state_name,
        output_range_nm=out_range,
        floored_weights=floored,
        diagnostics=findings,
        predicted_nm=pred,
        refined_fit_errors=ref_fit,
        refined_validation_errors=ref_val,
        chosen=chosen,
        coupling=coupling,
        rest_command_nm=_rest_command(kept_kind, u),
        reference=reference,
        state_scores=state_scores,
        asymmetry=asymmetry,
        asymmetry_note=asymmetry_note,
    )


def _choose_state(
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    T: float,
    r: NDArray[np.float64],
    tau: NDArray[np.float64],
    fit_rows: NDArray[np.bool_],
    judge_rows: NDArray[np.bool_],
    min_weight: float,
) -> tuple[str, StateKind, dict[str, float]]:
    """``initial_state="auto"``: ``"rest"``, ``"zero"`` and the estimated rest command, each
    with the linear stage at ``(r, tau)`` fitted on ``fit_rows`` and scored (rms, nm) on
    ``judge_rows``; the estimate only if :data:`STATE_TOLERANCE` better than the better of
    the other two. Returns the name chosen, its state and the scores."""
    estimate = estimate_rest_command(u, y, T, r, tau, rows=fit_rows, min_weight=min_weight)
    hypotheses: dict[str, StateKind] = {"rest": "rest", "zero": "zero", "estimate": estimate}
    scores = {}
    for name, k in hypotheses.items():
        m, *_ = nnls_stage(u, y, T, r, tau, rows=fit_rows, initial_state=k,
                           min_weight=min_weight)  # fmt: skip
        pred, _ = simulate(m, u, T, _state(m, u, k))
        scores[name] = float(np.sqrt(np.mean((pred[judge_rows] - y[judge_rows]) ** 2)))
    name = min(("rest", "zero"), key=lambda k: scores[k])  # ties: rest
    if scores["estimate"] < (1.0 - STATE_TOLERANCE) * scores[name]:
        name = "estimate"
    return name, hypotheses[name], scores


def _record(
    u_nm: ArrayLike, y_nm: ArrayLike, sample_period_s: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The record checked: finite ``u`` and ``y`` of one length, a period > 0."""
    u = as_finite_1d("u_nm", u_nm)
    y = as_finite_1d("y_nm", y_nm)
    if y.shape != u.shape:
        raise ValueError(f"y_nm must have one sample per command sample ({u.size}). Got {y.size}.")
    T = check_finite_scalar("sample_period_s", sample_period_s)
    if T <= 0:
        raise ValueError(f"sample_period_s must be > 0. Got {T}.")
    return u, y, T


def _state(model: ScannerModel, u: NDArray[np.float64], kind: StateKind) -> ModelState:
    return initial_state(model, u, kind)


def _figures(
    model: ScannerModel,
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    sample_period_s: float,
    kind: StateKind,
    rows: tuple[NDArray[np.bool_], NDArray[np.bool_] | None],
    out_range_nm: float,
) -> tuple[NDArray[np.float64], ErrorFigures, ErrorFigures | None]:
    """The model's prediction of the whole record, and its errors on the fitted and the
    held-out rows (``None`` with no held-out part)."""
    pred, _ = simulate(model, u, sample_period_s, _state(model, u, kind))
    fit_rows, val_rows = rows
    fit = error_figures(pred[fit_rows], y[fit_rows], out_range_nm)
    val = None if val_rows is None else error_figures(pred[val_rows], y[val_rows], out_range_nm)
    return pred, fit, val


def fit_plain_pi(
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    n_play: int = 10,
    **kwargs: Any,
) -> SensorFit:
    """The plain PI baseline: ``N_H`` uniformly spaced play operators, no creep, no refinement.

    Non-negative least squares on ``[u, z_j, 1]`` with the thresholds of
    :func:`place_thresholds` (the classical "10-operator PI fit" for ``n_play=10``).
    ``kwargs`` go to :func:`fit_sensor` (split, warm-up, initial state).
    """
    for key in ("n_creep", "refine", "time_constants_s", "reference_orders", "n_dead_zones"):
        if key in kwargs:
            raise TypeError(
                f"fit_plain_pi has no creep, no refinement and no asymmetry; do not pass {key!r}."
            )
    return fit_sensor(u_nm, y_nm, sample_period_s, n_play=n_play, n_creep=0, refine=False,
                      reference_orders=None, n_dead_zones=0, **kwargs)  # fmt: skip
