"""Sensorless recursive estimation of the scanner model, eqs (16)-(20).

The predictor is the model (14) run with the current estimates ``theta(k-1)``; the only
measurement is the height ``z_m(k) = h(y(k))`` (14) on the identification line, with ``h``
known from Section IV (:class:`~piezocomp.identification.loop.profile.HeightProfile`). Each sample:

* prediction error ``eps(k) = z_m(k) - h(y_hat(k))`` (17);
* regressor ``psi(k) = h'(y_hat(k)) dy_hat(k)/dtheta`` (18), with the sensitivity recursions
  of every parameter: creep gains and poles
  (``dx_i/dp_i = x_i(k-1) - u(k-1) + p_i dx_i(k-1)/dp_i``),
  gain, weights, thresholds (eq 19: while the command pushes a play operator, its output
  is ``z_j = u + r_j`` or ``u - r_j`` and ``dz_j/dr_j`` is ``+1`` or ``-1``; in between
  both keep their last values) and offset;
* the RLS update (20) with the data-dependent gain ``alpha(k) = psi' P psi / psi' psi``;
* projection onto the feasible set (``c >= 0``, ``0 < p < 1``, ``a > 0``, ``w > 0``, ordered
  positive thresholds: the model stays invertible, eq 10) after every update;
* covariance resetting ``P = p0 I`` every ``k0`` samples and/or when the smallest eigenvalue
  of ``P`` falls below a floor.

The recursion runs on ``phi = theta / scale`` (a fixed diagonal scaling that makes every
parameter of order one), so that ``P(0) = p0 I`` means the same thing for a pole near 1 and
for a threshold of hundreds of nm. With ``scale = 1`` it is eq (20) exactly.

A starting model with a creep coupling (eq 2') is estimated in its own family: ``theta``
takes ``beta`` last (``ThetaLayout(coupled=True)``), the predictor drives the creep by
``u + beta H`` with the current estimates, and each creep state carries its sensitivity to
``a``, ``w``, ``r`` and ``beta`` through the drive (the recursion of
:func:`~piezocomp.identification.estimation.parameters.simulate_with_gradient` with
``coupled=True``). ``beta`` is held unless ``"b"`` is among the groups set free (then from any
start, ``beta = 0`` included: its gradient there is the creep of the hysteresis output), and
is kept within :data:`~piezocomp.identification.estimation.reparametrisation.COUPLING_BOUNDS`.
Started at rest (no ``state`` given), each pass puts the creep states where they settle for
the current ``beta``.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar, readonly
from piezocomp.identification import _rls_kernel
from piezocomp.identification.estimation.candidates import DEFAULT_CREEP_TAU_RANGE_S
from piezocomp.identification.estimation.parameters import (
    COUPLING,
    GROUPS,
    REFINE_GROUPS,
    ThetaLayout,
    model_from_theta,
    smoothness_rows,
    theta_from_model,
)
from piezocomp.identification.estimation.reparametrisation import COUPLING_BOUNDS
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.model import ModelState, ScannerModel
from piezocomp.operators._kernels import sensitivity_size

__all__ = [
    "GROUPS",
    "RLS_CANDIDATES",
    "RLS_CONTINUE",
    "RLS_START",
    "RLSResult",
    "RLSSettings",
    "default_scale",
    "feasible_bounds",
    "rls",
]


@dataclass(frozen=True)
class RLSSettings:
    """Settings of the recursive estimator (20).

    Parameters
    ----------
    p0 : float
        Covariance after a reset, ``P = p0 I`` (of the scaled parameters), > 0.
    k0 : int
        Reset the covariance every ``k0`` samples (0: never on a schedule).
    min_eigenvalue : float
        Reset when the smallest eigenvalue of ``P`` falls below this (0: never).
    eig_check_every : int
        Samples between two eigenvalue checks (the check costs an eigen-decomposition).
    alpha : {"paper", "unit"}
        ``"paper"``: ``alpha(k) = psi' P psi / psi' psi`` (eq 20); ``"unit"``: ``alpha = 1``
        (textbook RLS).
    free : collection of str
        Groups of eq (15) that adapt (the others are held), among ``GROUPS``, and ``"b"``
        (the creep coupling of eq 2', for a starting model that has one).
    passes : int
        Passes over the record (the model state restarts, ``theta`` and ``P`` carry on).
    min_gain, min_weight : float
        Lower bounds of ``a`` and ``w_j`` (> 0).
    min_threshold_gap_nm : float
        Lower bound of ``r_1`` and of ``r_{j+1} - r_j`` (> 0).
    min_time_constant_s, max_time_constant_s : float
        Bounds of the creep time constants (the poles ``p = exp(-T / tau)`` are bounded
        accordingly, strictly inside (0, 1)).
    max_creep_gain : float
        Upper bound of each ``c_i``.
    creep_smoothing_nm, weight_smoothing_nm : float
        Smoothness priors (nm) on the creep spectrum and the play weights, as in the batch
        refinement (:func:`~piezocomp.identification.estimation.batch.refine`): the
        pseudo-measurements ``0 = mu * (x[i-1] - 2 x[i] + x[i+1])`` (creep gains in the order of
        their time constants, weights in the order of their thresholds) are processed at the start
        and after every covariance reset, so that each window between resets starts from the prior.
        0 (default): none.
    clip_nm : float, optional
        Huber's robust update: a prediction error beyond ``+-clip_nm`` enters the update (20)
        as ``+-clip_nm`` (``None``, default: eq (20) as printed). Where the predicted
        position is a few nm off, ``h'`` is read on the wrong flank of a particle and the
        full error pushes the estimate the wrong way; clipped, such samples cannot dominate
        a window between covariance resets.
    """

    p0: float = 1.0
    k0: int = 0
    min_eigenvalue: float = 1e-4
    eig_check_every: int = 200
    alpha: str = "paper"
    free: Collection[str] = GROUPS
    passes: int = 1
    min_gain: float = 1e-3
    min_weight: float = 1e-6
    min_threshold_gap_nm: float = 1.0
    min_time_constant_s: float = 0.05
    max_time_constant_s: float = 2000.0
    max_creep_gain: float = 1.0
    clip_nm: float | None = None
    creep_smoothing_nm: float = 0.0
    weight_smoothing_nm: float = 0.0
    _free: tuple[str, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("p0", "min_gain", "min_weight", "min_threshold_gap_nm", "max_creep_gain"):
            if check_finite_scalar(name, getattr(self, name)) <= 0:
                raise ValueError(f"{name} must be > 0. Got {getattr(self, name)}.")
        if self.clip_nm is not None and (
            isinstance(self.clip_nm, bool) or check_finite_scalar("clip_nm", self.clip_nm) <= 0
        ):
            raise ValueError(f"clip_nm must be None or > 0. Got {self.clip_nm!r}.")
        for name in ("creep_smoothing_nm", "weight_smoothing_nm"):
            if check_finite_scalar(name, getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0. Got {getattr(self, name)}.")
        if check_finite_scalar("min_eigenvalue", self.min_eigenvalue) < 0:
            raise ValueError(f"min_eigenvalue must be >= 0. Got {self.min_eigenvalue}.")
        for name in ("k0", "eig_check_every", "passes"):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v or v < 0:
                raise ValueError(f"{name} must be a non-negative integer. Got {v!r}.")
        if self.passes < 1:
            raise ValueError(f"passes must be >= 1. Got {self.passes}.")
        if self.alpha not in ("paper", "unit"):
            raise ValueError(f"alpha must be 'paper' or 'unit'. Got {self.alpha!r}.")
        lo = check_finite_scalar("min_time_constant_s", self.min_time_constant_s)
        hi = check_finite_scalar("max_time_constant_s", self.max_time_constant_s)
        if not 0 < lo < hi:
            raise ValueError(
                "need 0 < min_time_constant_s < max_time_constant_s. "
                f"Got {self.min_time_constant_s}, {self.max_time_constant_s}."
            )
        free = tuple(self.free)
        unknown = sorted(set(free) - set(REFINE_GROUPS))
        if unknown:
            raise ValueError(f"free must name groups among {list(REFINE_GROUPS)}. Got {unknown}.")
        object.__setattr__(self, "_free", free)


RLS_CANDIDATES = RLSSettings(
    alpha="unit",
    p0=0.1,
    passes=20,
    k0=3000,
    free=("c", "a", "w", "y0"),
    min_time_constant_s=DEFAULT_CREEP_TAU_RANGE_S[0],
)
"""The RLS every candidate order gets: unit gain, covariance reset every 3000 samples, creep
poles and thresholds held (only gains, weights and offset estimated)."""

RLS_CONTINUE = replace(
    RLS_CANDIDATES,
    passes=140,
    clip_nm=2.0,
    min_eigenvalue=0.0,
    creep_smoothing_nm=1000.0,
    weight_smoothing_nm=3000.0,
)
"""The RLS chain's continuation: 140 more passes, Huber's robust update (errors beyond 2 nm
of height enter as 2 nm) and smoothness priors on the creep spectrum and the play weights."""

RLS_START = replace(RLS_CANDIDATES, clip_nm=2.0)
"""The RLS chain's own first run: the candidates' settings with the robust update."""


@dataclass(frozen=True)
class RLSResult:
    """What the recursive estimator produced (Fig. 7b).

    Attributes
    ----------
    model : ScannerModel
        The final estimate.
    theta : ndarray, shape (n_theta,)
        Final eq (15) vector.
    theta_trace : ndarray, shape (n, n_theta)
        ``theta(k)`` after each sample of the last pass.
    error_nm : ndarray, shape (n,)
        Prediction error ``eps(k)`` of eq (17) in the last pass, nm.
    y_hat_nm : ndarray, shape (n,)
        Predicted extension of the last pass, nm.
    resets : ndarray of int
        Samples (of the last pass) after which ``P`` was reset.
    layout : ThetaLayout
    """

    model: ScannerModel
    theta: NDArray[np.float64]
    theta_trace: NDArray[np.float64]
    error_nm: NDArray[np.float64]
    y_hat_nm: NDArray[np.float64]
    resets: NDArray[np.intp]
    layout: ThetaLayout

    def __post_init__(self) -> None:
        for name in ("theta", "theta_trace", "error_nm", "y_hat_nm"):
            object.__setattr__(self, name, readonly(getattr(self, name)))


def feasible_bounds(
    layout: ThetaLayout, settings: RLSSettings, sample_period_s: float, max_threshold_nm: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Box bounds of eq (15) keeping a model feasible and invertible (:class:`RLSSettings`)."""
    lo = np.full(layout.size, -np.inf)
    hi = np.full(layout.size, np.inf)
    lo[layout.c] = 0.0
    hi[layout.c] = settings.max_creep_gain
    lo[layout.p] = np.exp(-sample_period_s / settings.min_time_constant_s)
    hi[layout.p] = np.exp(-sample_period_s / settings.max_time_constant_s)
    lo[layout.a] = settings.min_gain
    lo[layout.w] = settings.min_weight
    gap = settings.min_threshold_gap_nm
    if layout.n_play * gap >= max_threshold_nm:
        raise ValueError(
            f"{layout.n_play} thresholds at least {gap} nm apart do not fit below "
            f"max_threshold_nm = {max_threshold_nm}."
        )
    lo[layout.r] = gap * np.arange(1, layout.n_play + 1)
    hi[layout.r] = max_threshold_nm - gap * np.arange(layout.n_play - 1, -1, -1)
    if layout.coupled:
        lo[layout.b], hi[layout.b] = COUPLING_BOUNDS
    return lo, hi


def default_scale(
    model: ScannerModel, sample_period_s: float, span_nm: float, coupled: bool | None = None
) -> NDArray[np.float64]:
    """Scaling of eq (15) such that a unit change of each scaled parameter moves ``y`` by ~1 nm.

    With ``H = span / 2``: ``c``, ``a``, ``w``: ``1 / H``; ``r_j``: ``1 / max(w_j, 0.01)``;
    ``p_i``: ``(1 - p_i) / (max(c_i, 0.01) H / 2)`` (a pole change ``dp`` moves ``y`` by about
    ``c (x - u) dp / (1 - p)``); ``y0``: 1 nm; with a creep coupling, ``beta``:
    ``1 / (max(sum c_i, 0.01) H)`` (``dy/dbeta`` is the creep of the hysteresis output).
    ``P = p0 I`` is then a prior variance of each parameter's effect of ``p0`` nm^2.
    ``coupled``: the layout with ``beta`` (default: when the model has a coupling).
    """
    if coupled is None:
        coupled = model.creep_coupling != 0.0
    layout = ThetaLayout(model.n_creep, model.n_play, coupled)
    half = 0.5 * span_nm
    s = np.empty(layout.size)
    s[layout.c] = 1.0 / half
    one_minus_p = np.maximum(1.0 - model.creep_poles(sample_period_s), 1e-9)
    s[layout.p] = one_minus_p / (np.maximum(model.creep_gains, 0.01) * 0.5 * half)
    s[layout.a] = 1.0 / half
    s[layout.w] = 1.0 / half
    s[layout.r] = 1.0 / np.maximum(model.weights, 0.01)
    s[layout.y0] = 1.0
    if layout.coupled:
        s[layout.b] = 1.0 / (max(float(model.creep_gains.sum()), 0.01) * half)
    return s


def _passes(
    u: NDArray[np.float64],
    z: NDArray[np.float64],
    profile: HeightProfile,
    layout: ThetaLayout,
    theta: NDArray[np.float64],
    P: NDArray[np.float64],
    st0: ModelState,
    sc: NDArray[np.float64],
    free: NDArray[np.intp],
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    cfg: RLSSettings,
    prior: NDArray[np.float64],
    shift: NDArray[np.float64],
    T: float,
    creep_rest_nm: float | None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """``cfg.passes`` runs of the recursion over the record, each from ``st0``, updating
    ``theta`` and ``P`` in place; the last pass's prediction errors, predictions, parameter
    trace and covariance resets. With the coupled layout and ``creep_rest_nm``, each pass
    starts its creep states settled on that held command for the current ``theta`` (they
    move with ``beta``, eq 2') and their sensitivities at their values at rest
    (``dx/dbeta = (a + sum w) u_r``, ``dx/da = dx/dw_j = beta u_r``), as
    :func:`~piezocomp.identification.estimation.parameters.simulate_with_gradient` does."""
    hstart, hstep, hval, hslope = profile.table()
    n = u.size
    nc, nh = layout.n_creep, layout.n_play
    eps = np.empty(n)
    yhat = np.empty(n)
    trace = np.empty((n, layout.size))
    resets = np.zeros(n, dtype=np.bool_)
    for _ in range(cfg.passes):
        st = st0.packed()
        sens = np.zeros(sensitivity_size(nh, nc, layout.coupled))
        if layout.coupled and creep_rest_nm is not None:
            m = model_from_theta(theta, layout, T)
            st = st0.with_creep_at_rest(m, creep_rest_nm).packed()
            xc, beta = creep_rest_nm, m.creep_coupling
            sens[nc + nh : 2 * nc + nh] = beta * xc
            sens[2 * nc + nh : 3 * nc + nh] = (m.gain + float(m.weights.sum())) * xc
            sens[3 * nc + nh : 3 * nc + nh + nc * nh] = beta * xc
        resets[:] = False
        _rls_kernel.rls_run(
            u, z, layout.n_creep, layout.n_play, theta, P, st, sens, hstart, hstep, hval,
            hslope, sc, free, lower, upper, cfg.min_threshold_gap_nm, cfg.p0, int(cfg.k0),
            cfg.min_eigenvalue, int(cfg.eig_check_every), cfg.alpha == "paper",
            0.0 if cfg.clip_nm is None else float(cfg.clip_nm), prior, shift, eps, yhat, trace,
            resets,
        )  # fmt: skip
    return eps, yhat, trace, resets


def rls(
    u_nm: ArrayLike,
    height_nm: ArrayLike,
    profile: HeightProfile,
    initial: ScannerModel,
    sample_period_s: float,
    *,
    settings: RLSSettings | None = None,
    state: ModelState | None = None,
    shift_nm: ArrayLike | None = None,
) -> RLSResult:
    """Identify the model from a command and the measured heights, eqs (16)-(20).

    Parameters
    ----------
    u_nm : array_like, shape (n,)
        Command of the record (nominal nm).
    height_nm : array_like, shape (n,)
        Measured heights ``z_m`` (nm).
    profile : HeightProfile
        ``h(y)`` of the line (Section IV).
    initial : ScannerModel
        Starting estimate ``theta(0)`` (fixes the orders); moved onto the feasible set.
    sample_period_s : float
        ``T`` (s).
    settings : RLSSettings, optional
    state : ModelState, optional
        Model state before the first sample; default ``ModelState.at_rest(initial, u[0])``
        (with the coupled layout, at rest on ``u[0]`` for the current ``beta`` at each pass).
    shift_nm : array_like, shape (n,), optional
        The sample's drift along the line at each sample, in ``h``'s coordinates: the heights are
        ``h(y_hat + shift)`` (:mod:`~piezocomp.identification.estimation.drift_along_line`).
        Default none.

    Returns
    -------
    RLSResult
    """
    u = as_finite_1d("u_nm", u_nm)
    z = as_finite_1d("height_nm", height_nm)
    if z.shape != u.shape or u.size < 2:
        raise ValueError(
            f"height_nm must have one sample per command sample (>= 2). Got {z.size} and {u.size}."
        )
    if not isinstance(profile, HeightProfile):
        raise TypeError(f"profile must be a HeightProfile. Got {type(profile).__name__}.")
    if not isinstance(initial, ScannerModel):
        raise TypeError(f"initial must be a ScannerModel. Got {type(initial).__name__}.")
    initial.require_symmetric("the RLS estimator (eqs 16-20)")
    T = check_finite_scalar("sample_period_s", sample_period_s)
    if T <= 0:
        raise ValueError(f"sample_period_s must be > 0. Got {T}.")
    shift = np.zeros(u.size) if shift_nm is None else as_finite_1d("shift_nm", shift_nm)
    if shift.shape != u.shape:
        raise ValueError(f"shift_nm must have one entry per sample ({u.size}). Got {shift.size}.")
    cfg = RLSSettings() if settings is None else settings
    coupled = initial.creep_coupling != 0.0 or COUPLING in cfg._free
    layout = ThetaLayout(initial.n_creep, initial.n_play, coupled)
    span = float(np.ptp(u))
    if span <= 0:
        raise ValueError("u_nm must move (its peak-to-peak span is 0).")
    max_r = 0.5 * span  # a larger threshold never moves
    lower, upper = feasible_bounds(layout, cfg, T, max_r)
    sc = default_scale(initial, T, span, coupled)
    free = _free_indices(layout, cfg)
    theta = theta_from_model(initial, T, coupled=coupled)
    _rls_kernel.project(
        theta, layout.n_creep, layout.n_play, lower, upper, cfg.min_threshold_gap_nm
    )
    st0 = ModelState.at_rest(initial, u[0]) if state is None else state
    st0.check_for(initial)
    P = cfg.p0 * np.eye(free.size)  # covariance of the free parameters only
    adapted = tuple(g for g in ("c", "w") if g in cfg._free)
    prior = smoothness_rows(
        initial, cfg.creep_smoothing_nm, cfg.weight_smoothing_nm, adapted, coupled=coupled
    )
    if prior.shape[0]:
        _rls_kernel.apply_prior(
            theta, P, free, sc, prior, layout.n_creep, layout.n_play, lower, upper,
            cfg.min_threshold_gap_nm,
        )  # fmt: skip
    rest = u[0] if state is None else None  # at rest on u[0]: the creep follows beta
    eps, yhat, trace, resets = _passes(
        u, z, profile, layout, theta, P, st0, sc, free, lower, upper, cfg, prior, shift, T, rest
    )
    model = model_from_theta(theta, layout, T)
    return RLSResult(
        model=model,
        theta=theta,
        theta_trace=trace,
        error_nm=eps,
        y_hat_nm=yhat,
        resets=np.flatnonzero(resets),
        layout=layout,
    )


def _free_indices(layout: ThetaLayout, cfg: RLSSettings) -> NDArray[np.int64]:
    """Indices into ``theta`` of the parameter groups ``cfg`` adapts (eq 15 groups)."""
    free_mask = np.zeros(layout.size, dtype=bool)
    groups = {
        "c": layout.c,
        "p": layout.p,
        "a": slice(layout.a, layout.a + 1),
        "w": layout.w,
        "r": layout.r,
        "y0": slice(layout.y0, layout.y0 + 1),
    }
    if layout.coupled:
        groups[COUPLING] = slice(layout.b, layout.b + 1)
    for g in cfg._free:
        free_mask[groups[g]] = True
    return np.flatnonzero(free_mask).astype(np.int64)
