"""The estimation stage of the sensorless identification (Section III.C, eqs 16-20).

Given the identification record ``(u, z_m)``, the loop ``f_a`` and ``h(y)`` of Section IV,
for every candidate order: the recursive estimator of eqs (16)-(20)
(:func:`~piezocomp.identification.rls.rls`) from a start fitted to the loop
(:func:`initial_from_loop`, thresholds spread over the span by :func:`thresholds_over_span`),
then the batch refinement
of the same prediction error (:func:`~piezocomp.identification.batch.refine`, ``output = h``);
the orders are chosen by the height prediction error on a held-out part of the record
(:func:`~piezocomp.identification.orders.select_orders`), which needs no sensor.

Two choices here carry most of the accuracy (see ``docs/identification-history.md``, error budget):

* **Creep as a fixed spectrum.** A logarithmic creep (``~ log t`` over decades) is a dense
  spectrum of first-order modes. ``N_c`` creep operators with time constants placed
  log-uniformly over :data:`DEFAULT_CREEP_TAU_RANGE_S` (:func:`creep_spectrum`), only their
  gains ``c_i >= 0`` estimated (poles held), represent it far better than two to four free
  poles, and keep eq (14) linear in the estimated parameters but for the thresholds.
* **The creep state at the start of the record.** Before the record the scanner has been
  scanning the working area (overview image, line search) for longer than most creep time
  constants: its slow creep modes sit near the mean command there, the centre of the line,
  not at the record's first command. :func:`record_state` starts the model's creep states
  there (``creep_start_nm``) and the play operators at rest at the first command (the first
  steady cycle wipes them out). Starting the creep states at the first command instead,
  half a span away, leaves a spurious creep transient of several nm over the whole record,
  which the estimator then fits with wrong creep gains.
* **The profile in the model's own frame** (:func:`model_profile`). ``h(y)`` of Section IV
  indexes the steady forward traces of part A by the loop ``f_a``; eq (23) fixes ``f_a`` but
  for an odd distortion about the loop's centre, and the model fitted through that ``h``
  inherits the distortion. After the batch refinement the same traces are re-indexed by the
  refined model's own prediction of those cycles, and the refinement is repeated
  (``reindex_rounds`` times): ``h`` and the model then describe one frame, in which the
  minor loops of part B (which a distorted frame cannot fit with Prandtl-Ishlinskii
  structure) decide the shape of the loop. On the cpr5 virtual AFM it took the error after
  an affine map from 1.0-4.0 nm to 0.5-0.7 nm (seeds 1-3, ``docs/identification-history.md``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.batch import RefineResult, refine, single_threaded_blas
from piezocomp.identification.loop import SymmetricLoop
from piezocomp.identification.orders import OrderSelection, select_orders
from piezocomp.identification.profile import HeightProfile
from piezocomp.identification.rls import RLSResult, RLSSettings, rls
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.operators import _kernels

__all__ = [
    "DEFAULT_CREEP_TAU_RANGE_S",
    "Estimation",
    "creep_spectrum",
    "estimate",
    "heldout_rms",
    "initial_from_loop",
    "model_profile",
    "predicted_forward_trace",
    "record_state",
    "thresholds_over_span",
]

BatchStage = Callable[[ScannerModel, HeightProfile], tuple[ScannerModel, HeightProfile]]
"""A further stage of the batch chain: ``(model, h) -> (model, h)``."""
RLSStage = Callable[[RLSResult, HeightProfile], tuple[RLSResult, HeightProfile]]
"""A further stage of the RLS chain: ``(result, h) -> (result, h)``."""

DEFAULT_CREEP_TAU_RANGE_S = (0.01, 2000.0)
"""Shortest and longest creep time constant (s) of :func:`creep_spectrum`: from about the
sample period of 8 ms (faster modes act as part of the gain ``a``) to well beyond a record
of minutes (slower modes hold the memory of earlier commands). The modes between the
sample period and 50 ms make the lag after each reversal; a spectrum starting at 50 ms
(until the sixth session) left 0.45 nm of structural error on the cpr5 scanner's true
extension, 0.18 nm from 10 ms (``benchmarks/model_floor.py``)."""


def creep_spectrum(
    n_creep: int, tau_range_s: tuple[float, float] = DEFAULT_CREEP_TAU_RANGE_S
) -> NDArray[np.float64]:
    """``n_creep`` creep time constants log-uniform over ``tau_range_s`` (ends included).

    One operator sits at the geometric mean of the range; none gives an empty array.
    """
    if isinstance(n_creep, bool) or int(n_creep) != n_creep or n_creep < 0:
        raise ValueError(f"n_creep must be a non-negative integer. Got {n_creep!r}.")
    lo = check_finite_scalar("tau_range_s[0]", tau_range_s[0])
    hi = check_finite_scalar("tau_range_s[1]", tau_range_s[1])
    if not 0 < lo < hi:
        raise ValueError(f"tau_range_s must satisfy 0 < lo < hi. Got ({lo}, {hi}).")
    n = int(n_creep)
    if n == 0:
        return np.zeros(0)
    if n == 1:
        return np.array([np.sqrt(lo * hi)])
    return np.geomspace(lo, hi, n)


def thresholds_over_span(n_play: int, span_nm: float) -> NDArray[np.float64]:
    """Thresholds ``r_j = j span / (2 (N_H + 1))``: the kinks of the steady loop's branches
    (at ``u_min + 2 r_j``) spread evenly over the span actually used."""
    return span_nm / (2.0 * (n_play + 1)) * np.arange(1, n_play + 1, dtype=np.float64)


def initial_from_loop(
    loop: SymmetricLoop,
    n_play: int,
    n_creep: int,
    *,
    thresholds_nm: NDArray[np.float64] | None = None,
    time_constants_s: NDArray[np.float64] | None = None,
    n_samples: int = 400,
) -> ScannerModel:
    """A starting model whose steady loop matches the estimated loop ``f_a``, ``f_d``.

    The paper starts the RLS from zeros and lets a few large cycles settle it; here the
    Prandtl-Ishlinskii part (``a``, ``w``, ``y0``, thresholds fixed over the span) is fitted
    by non-negative least squares to the loop of eqs (21)-(22) on a steady cycle, and the
    creep gains start at 0 (time constants spread log-uniformly over 0.3-30 s). It puts the
    predictor within a fraction of a particle of the truth, where (17)-(18) are informative.
    """
    lo, hi = loop.u_min_nm, loop.u_max_nm
    r = thresholds_over_span(n_play, hi - lo) if thresholds_nm is None else thresholds_nm
    up = np.linspace(lo, hi, n_samples)
    down = up[::-1]
    u = np.concatenate([up, down, up, down])
    zs = np.empty((u.size, n_play))
    _kernels.play_bank(u, np.asarray(r, float), np.full(n_play, lo), zs)
    m = 2 * n_samples
    target = np.concatenate([loop.ascending(up), loop.descending(down)])
    ones = np.ones(m)
    design = np.column_stack([u[m:], zs[m:], ones, -ones])
    coef, _ = nnls(design, target)
    a = max(float(coef[0]), 1e-3)
    w = np.maximum(coef[1 : 1 + n_play], 1e-4)
    y0 = float(coef[-2] - coef[-1])
    tau = np.geomspace(0.3, 30.0, n_creep) if time_constants_s is None else time_constants_s
    return ScannerModel(
        offset_nm=y0,
        gain=a,
        thresholds_nm=r,
        weights=w,
        creep_time_constants_s=tau,
        creep_gains=np.zeros(n_creep),
    )


def record_state(
    model: ScannerModel, u0_nm: float, creep_start_nm: float | None = None
) -> ModelState:
    """Model state before the first sample of a record that starts at command ``u0_nm``.

    Play operators at rest at ``u0_nm``; creep states at ``creep_start_nm`` (nm of command;
    default ``u0_nm``, i.e. :meth:`ModelState.at_rest`): the mean command over the time
    before the record, e.g. the centre of the area scanned before it.
    """
    u0 = check_finite_scalar("u0_nm", u0_nm)
    xc = u0 if creep_start_nm is None else check_finite_scalar("creep_start_nm", creep_start_nm)
    return ModelState(np.full(model.n_play, u0), np.full(model.n_creep, xc), u0)


def heldout_rms(
    profile: HeightProfile,
    model: ScannerModel,
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    sample_period_s: float,
    mask: NDArray[np.bool_],
    creep_start_nm: float | None = None,
) -> float:
    """RMS of ``h(y_hat) - z_m`` over ``mask`` (nm), the model run over the whole record.

    Samples the model places outside ``profile``'s table are left out: ``h`` is not known
    there. Part A's steady cycles, which ``h`` comes from, do not reach every position of
    the record. When part B dwells at an end of the span, creep carries the tip up to
    ~50 nm further on cpr5. ``h`` continued by its end value then scored ~6 % of the
    samples against heights it never saw (cpr5 seed 5: 1.36 nm held-out RMS, 0.36 nm
    inside the table). NaN if no sample of ``mask`` falls inside.
    """
    y, _ = simulate(model, u_nm, sample_period_s, record_state(model, u_nm[0], creep_start_nm))
    lo, hi = profile.y_range_nm
    keep = np.asarray(mask, dtype=bool) & (y >= lo) & (y <= hi)
    if not keep.any():
        return float("nan")
    r = profile(y[keep]) - height_nm[keep]
    return float(np.sqrt(np.mean(r**2)))


def predicted_forward_trace(
    model: ScannerModel,
    u_nm: NDArray[np.float64],
    sample_period_s: float,
    forward_traces: Sequence[slice],
    creep_start_nm: float | None = None,
) -> NDArray[np.float64]:
    """The model's prediction of steady forward traces, averaged trace by trace (nm).

    The model runs over the whole record (from :func:`record_state`); ``forward_traces``
    are slices of the record, the forward traces of steady cycles with the same commands
    (e.g. part A's).

    Raises
    ------
    ValueError
        If there is no trace or the traces differ in length.
    """
    if not forward_traces:
        raise ValueError("forward_traces must hold at least one slice of the record.")
    y, _ = simulate(
        model, u_nm, sample_period_s, record_state(model, float(u_nm[0]), creep_start_nm)
    )
    ys = [y[s] for s in forward_traces]
    if len({a.size for a in ys}) != 1:
        raise ValueError("forward_traces must be slices of the same length.")
    return np.mean(ys, axis=0)


def model_profile(
    model: ScannerModel,
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    sample_period_s: float,
    forward_traces: Sequence[slice],
    creep_start_nm: float | None = None,
    lam: float | None = None,
) -> HeightProfile:
    """``h(y)`` from steady forward traces indexed by the model's own prediction.

    The traces' heights are tabulated (:meth:`HeightProfile.from_positions`) against
    :func:`predicted_forward_trace`, smoothed with penalty ``lam`` (default: by generalised
    cross-validation; a previous re-indexing's :attr:`HeightProfile.penalty` smooths the
    same heights alike at a fraction of the cost). Samples whose predicted position does not
    pass every earlier one are left out: just after the reversal, a creep mode faster than
    the ramp can carry the predicted position back for a few samples (the heights there are
    tabulated from the other samples at those positions).

    Raises
    ------
    ValueError
        As :func:`predicted_forward_trace`, or if fewer than half the samples of the
        predicted forward trace advance.
    """
    y = predicted_forward_trace(model, u_nm, sample_period_s, forward_traces, creep_start_nm)
    z = np.array([height_nm[s] for s in forward_traces])
    advances = y > np.maximum.accumulate(np.concatenate([[-np.inf], y[:-1]]))
    if advances.sum() < 0.5 * y.size:
        raise ValueError(
            f"the model's predicted forward trace advances on {int(advances.sum())} of "
            f"{y.size} samples; h(y) cannot be indexed by it."
        )
    return HeightProfile.from_positions(y[advances], z[:, advances], lam=lam)


@dataclass(frozen=True)
class Estimation:
    """Outcome of :func:`estimate`.

    Attributes
    ----------
    selection : OrderSelection
        Candidates and chosen orders (held-out height RMS, nm); ``fitted`` holds
        ``(RLSResult, RefineResult or None)`` of the chosen orders.
    rls : RLSResult
        RLS of the orders whose RLS estimate predicts the held-out heights best (with the
        batch refinement, the batch model's orders may differ; without it they are the same).
    refine : RefineResult or None
        Batch refinement of the chosen orders (``None`` if skipped).
    batch_model : ScannerModel
        The refined model (the RLS model if the refinement was skipped).
    heldout_rms_nm : dict
        Held-out height RMS (nm) of the starting model (``"initial"``), ``"rls"`` and
        ``"batch"`` for the chosen orders (each through its own profile), before the final
        stages (``batch_final``, ``rls_final``), if any.
    batch_profile : HeightProfile
        The ``h(y)`` the batch model was refined with: ``profile`` re-indexed by the model
        (:func:`model_profile`) if ``reindex_rounds > 0``, else ``profile``.
    rls_profile : HeightProfile
        The ``h(y)`` of the RLS estimate's last run: ``profile``, or ``profile`` re-indexed
        by the RLS estimate itself (``rls_reindex_rounds``).
    rls_round : int
        The re-indexing round the RLS estimate comes from (0: ``profile``).
    batch_restart : dict or None
        If the batch chain was run again from the RLS chain's estimate
        (``batch_restart_ratio``): the held-out height RMS (nm) of the ``"first"`` chain and
        of the ``"restart"``, and ``"kept"``, the one kept; ``None`` if it was not.
    """

    selection: OrderSelection
    rls: RLSResult
    refine: RefineResult | None
    batch_model: ScannerModel
    heldout_rms_nm: dict[str, float]
    batch_profile: HeightProfile
    rls_profile: HeightProfile
    rls_round: int = 0
    batch_restart: dict[str, Any] | None = None


def far_worse(worse: float, better: float, ratio: float) -> bool:
    """Whether held-out height RMS ``worse`` is more than ``ratio`` times ``better`` and more
    than 1 nm above it (both finite)."""
    return bool(
        np.isfinite(worse)
        and np.isfinite(better)
        and worse > ratio * better
        and worse - better > 1.0
    )


def estimate(
    u_nm: ArrayLike,
    height_nm: ArrayLike,
    sample_period_s: float,
    profile: HeightProfile,
    initial: Callable[[int, NDArray[np.float64]], ScannerModel],
    *,
    fit_mask: NDArray[np.bool_],
    warmup_samples: int,
    orders: Sequence[tuple[int, int]],
    rls_settings: RLSSettings,
    refine_max_nfev: int = 40,
    refine_free: Sequence[str] = ("c", "a", "w", "y0"),
    tau_range_s: tuple[float, float] = DEFAULT_CREEP_TAU_RANGE_S,
    creep_start_nm: float | None = None,
    forward_traces: Sequence[slice] = (),
    reindex_rounds: int = 0,
    selection_rounds: int | None = None,
    reindex_max_nfev: int | None = None,
    rls_continue: RLSSettings | None = None,
    rls_start: RLSSettings | None = None,
    order_tolerance: float = 0.02,
    prefer_orders: str = "smallest",
    creep_smoothing_nm: float = 0.0,
    weight_smoothing_nm: float = 0.0,
    rls_reindex_rounds: int = 0,
    rls_reindex_passes: int = 20,
    batch_then: BatchStage | None = None,
    rls_then: RLSStage | None = None,
    batch_final: BatchStage | None = None,
    rls_final: RLSStage | None = None,
    batch_restart_ratio: float | None = None,
    workers: int = 1,
) -> Estimation:
    """RLS (eqs 16-20), batch refinement and order selection on one record.

    Parameters
    ----------
    u_nm, height_nm : array_like, shape (n,)
        The identification record: command (nominal nm) and measured heights (nm).
    sample_period_s : float
    profile : HeightProfile
        ``h(y)`` (Section IV).
    initial : callable
        ``initial(n_play, time_constants_s) -> ScannerModel``: the starting model of a
        candidate (e.g. fitted to the loop, :func:`initial_from_loop`).
    fit_mask : ndarray of bool, shape (n,)
        Samples fitted; must be a prefix of the record (the RLS runs on it). The rest,
        after ``warmup_samples``, is held out to choose the orders.
    warmup_samples : int
        Leading samples left out of every cost (unknown initial play state).
    orders : sequence of (n_play, n_creep)
        Candidates; ``n_creep`` creep operators placed by :func:`creep_spectrum`.
    rls_settings : RLSSettings
    refine_max_nfev : int
        Evaluations of the batch refinement (0: skip it).
    refine_free : sequence of str
        Groups the batch refinement adjusts.
    tau_range_s : (float, float)
        Range of the creep spectrum (s).
    creep_start_nm : float, optional
        Creep states before the first sample (:func:`record_state`).
    forward_traces : sequence of slice
        Forward traces of the steady cycles ``profile`` was built from (part A), for
        :func:`model_profile`.
    reindex_rounds : int
        Rounds of re-indexing ``h`` by the refined model and refining again (0: ``profile``
        throughout); needs ``forward_traces``. Without the batch refinement
        (``refine_max_nfev = 0``) there is no refined model and ``profile`` is kept.
    selection_rounds : int, optional
        Rounds every candidate order gets before the held-out comparison; the chosen one
        then continues to ``reindex_rounds``. Default (``None``): all rounds for every
        candidate. Fewer rounds for the comparison spend the time on the chosen orders.
    reindex_max_nfev : int, optional
        Evaluations of each refinement after a re-indexing (it starts from the previous
        round's model); default ``refine_max_nfev``.
    creep_smoothing_nm : float
        Weight of the creep spectrum's smoothness penalty in every batch refinement
        (:func:`~piezocomp.identification.batch.refine`; 0: none).
    weight_smoothing_nm : float
        The same on the play operators' weights (0: none).
    rls_continue : RLSSettings, optional
        Settings of a further RLS run of every candidate, started from its estimate after
        the selection (``None``: none); the RLS orders are then those whose continued
        estimate predicts the held-out heights best. The candidates each got
        ``rls_settings`` first, and the batch refinements start from those; the
        continuation may differ (e.g. more passes, the robust update of ``clip_nm``, the
        smoothness priors).
    order_tolerance, prefer_orders
        ``tolerance`` and ``prefer`` of the order selection
        (:func:`~piezocomp.identification.orders.select_orders`) on the batch refinements'
        held-out heights.
    rls_start : RLSSettings, optional
        Settings of the RLS chain's own first run of every candidate, from the same start
        (``None``: the chain goes on from the candidates' ``rls_settings`` estimates). The
        batch refinements still start from those, so this changes the RLS estimate only:
        e.g. the robust update from the first pass, which keeps the RLS out of a wrong
        valley but moves the batch refinements' starts. Without the batch refinement
        (``refine_max_nfev = 0``) the batch model is then the candidates' run, no longer the
        RLS chain's.
    rls_reindex_rounds : int
        Rounds of re-indexing ``h`` by the RLS estimate itself (:func:`model_profile`) and
        running the RLS on it again (``rls_reindex_passes`` passes of ``rls_continue``, or of
        ``rls_settings`` without it), for the chosen RLS orders; needs ``forward_traces``.
        The estimate kept is the one of the round (0: ``profile``) whose estimate predicts
        the held-out heights best, each through its own ``h``. 0: ``profile`` throughout.
        The RLS estimate stays independent of the batch refinement.
    rls_reindex_passes : int
        Passes of each of those rounds.
    batch_then : callable, optional
        ``batch_then(model, h) -> (model, h)``: a last stage of the batch chain after the
        re-indexing rounds (e.g. the joint rounds on several lines); the held-out score is
        that of its result. :attr:`Estimation.refine` stays the refinement before it.
    rls_then : callable, optional
        ``rls_then(result, h) -> (result, h)``: the same for the RLS chain, after its
        re-indexing rounds.
    batch_final, rls_final : callable, optional
        Stages after the held-out scoring, one per chain, of the same form: e.g. a fit of
        the chosen model over the whole record, held-out part included, once the held-out
        part has done its work (choosing the orders and the rounds).
        :attr:`Estimation.heldout_rms_nm` is that of the models before them.
    batch_restart_ratio : float, optional
        When the batch chain predicts the held-out heights more than this many times worse
        than the RLS chain, and by more than 1 nm (:func:`far_worse`), the batch chain is run
        again from the RLS chain's estimate (its orders and its ``h``, before ``rls_final``:
        the issue's "started from the RLS estimate"), and the one of the two that predicts
        the held-out heights better is kept (:attr:`Estimation.batch_restart`). The batch
        chain otherwise starts from the candidates' first RLS runs, which on some records
        end in another basin that the robust RLS chain avoids. ``None``: never.
    workers : int
        Threads: the candidates are fitted side by side (each one's RLS continuation
        starting as soon as its first RLS is done), then the batch chain (re-indexing
        rounds, ``batch_then``, ``batch_final``) runs beside the RLS chain (re-indexing
        rounds, ``rls_then``, ``rls_final``), which are independent. The compiled kernels
        release the GIL. The result does not depend on it (1: everything in turn).

    Returns
    -------
    Estimation
    """
    u = np.ascontiguousarray(u_nm, dtype=float)
    z = np.ascontiguousarray(height_nm, dtype=float)
    T = float(sample_period_s)
    mask = np.asarray(fit_mask, dtype=bool)
    n_fit = int(mask.sum())
    if n_fit < 2 or not mask[:n_fit].all():
        raise ValueError("fit_mask must select a prefix of at least 2 samples of the record.")
    heldout = ~mask
    heldout[:warmup_samples] = False
    if not heldout.any():
        raise ValueError("no held-out samples left to choose the orders on.")
    rounds = int(reindex_rounds)
    if rounds < 0 or rounds != reindex_rounds:
        raise ValueError(f"reindex_rounds must be a non-negative integer. Got {reindex_rounds!r}.")
    sel_rounds = rounds if selection_rounds is None else int(selection_rounds)
    for label, given in (("rls_continue", rls_continue), ("rls_start", rls_start)):
        if given is not None and not isinstance(given, RLSSettings):
            raise TypeError(f"{label} must be RLSSettings or None. Got {type(given).__name__}.")
    if reindex_max_nfev is not None and not (
        not isinstance(reindex_max_nfev, bool) and int(reindex_max_nfev) == reindex_max_nfev >= 1
    ):
        raise ValueError(f"reindex_max_nfev must be an integer >= 1. Got {reindex_max_nfev!r}.")
    round_nfev = refine_max_nfev if reindex_max_nfev is None else int(reindex_max_nfev)
    if selection_rounds is not None and not 0 <= sel_rounds <= rounds:
        raise ValueError(
            f"selection_rounds must be between 0 and reindex_rounds ({rounds}). "
            f"Got {selection_rounds!r}."
        )
    for name, value, lo in (
        ("rls_reindex_rounds", rls_reindex_rounds, 0),
        ("rls_reindex_passes", rls_reindex_passes, 1),
    ):
        if isinstance(value, bool) or not (int(value) == value >= lo):
            raise ValueError(f"{name} must be an integer >= {lo}. Got {value!r}.")
    if batch_restart_ratio is not None and not (
        check_finite_scalar("batch_restart_ratio", batch_restart_ratio) >= 1.0
    ):
        raise ValueError(
            f"batch_restart_ratio must be >= 1 (or None). Got {batch_restart_ratio!r}."
        )
    if isinstance(workers, bool) or not (int(workers) == workers >= 1):
        raise ValueError(f"workers must be an integer >= 1. Got {workers!r}.")
    n_workers = int(workers)
    if (rounds or rls_reindex_rounds) and not forward_traces:
        raise ValueError(
            "reindex_rounds or rls_reindex_rounds > 0 needs forward_traces (the steady cycles "
            "of h)."
        )
    u_fit, z_fit = u[:n_fit], z[:n_fit]
    rls_scores: dict[tuple[int, int], float] = {}
    rls_results: dict[tuple[int, int], RLSResult] = {}  # the RLS chain's
    init_scores: dict[tuple[int, int], float] = {}

    def score(m: ScannerModel, prof: HeightProfile = profile) -> float:
        return heldout_rms(prof, m, u, z, T, heldout, creep_start_nm)

    def refined(m: ScannerModel, prof: HeightProfile, nfev: int = refine_max_nfev) -> RefineResult:
        return refine(
            m,
            u,
            z,
            T,
            output=prof,
            state=record_state(m, u[0], creep_start_nm),
            fit_mask=mask,
            warmup_samples=warmup_samples,
            max_nfev=nfev,
            free=tuple(refine_free),
            creep_smoothing_nm=creep_smoothing_nm,
            weight_smoothing_nm=weight_smoothing_nm,
        )

    def fit_fn(nh: int, nc: int) -> tuple[Any, float]:
        init = initial(nh, creep_spectrum(nc, tau_range_s))
        st = record_state(init, u[0], creep_start_nm)
        res = rls(u_fit, z_fit, profile, init, T, settings=rls_settings, state=st)
        if early is not None:  # the RLS chain's runs need nothing else: start them now
            continued[(nh, nc)] = early.submit(chain_start, (nh, nc), init, st, res)
        else:
            chain_start((nh, nc), init, st, res)
        init_scores[(nh, nc)] = score(init)
        if refine_max_nfev <= 0:
            rms = float(np.sqrt(np.mean(res.error_nm[warmup_samples:] ** 2)))
            return (res, None, profile), rms
        ref = refined(res.model, profile)
        ref, prof = more_rounds(ref, profile, sel_rounds)
        return (res, ref, prof), ref.rms

    def more_rounds(
        ref: RefineResult, prof: HeightProfile, k: int
    ) -> tuple[RefineResult, HeightProfile]:
        # Every re-indexing keeps the smoothing GCV chose for the loop's h: the positions
        # move by a fraction of a per cent of the span, which leaves that choice unchanged.
        for _ in range(k):
            lam = prof.penalty if np.isfinite(prof.penalty) else None
            prof = model_profile(ref.model, u, z, T, forward_traces, creep_start_nm, lam=lam)
            ref = refined(ref.model, prof, round_nfev)
        return ref, prof

    def score_fn(fitted: Any) -> float:
        res, ref, prof = fitted
        return score(ref.model if ref is not None else res.model, prof)

    def rls_chain() -> tuple[
        RLSResult, HeightProfile, int, float, tuple[ScannerModel, HeightProfile]
    ]:
        # The RLS estimate stands on its own: its orders are those of its best held-out
        # heights (the batch model's when the refinement is skipped: the selection then
        # scores the RLS). Returns the estimate and its h, the round kept, the held-out
        # score, and the estimate and its h before rls_final.
        keys = [(t.n_play, t.n_creep) for t in selection.trials]  # in the candidates' order
        for fut in continued.values():  # the RLS chain's runs started on the side threads
            fut.result()
        rls_key = min(keys, key=rls_scores.__getitem__)
        res, prof, best, kept = rls_results[rls_key], profile, rls_scores[rls_key], 0
        # The RLS on h re-indexed by its own estimate, round after round; the round whose
        # estimate predicts the held-out heights best (each through its own h) is kept.
        again = replace(rls_continue or rls_settings, passes=int(rls_reindex_passes))
        res_r, lam_r = res, (profile.penalty if np.isfinite(profile.penalty) else None)
        for r in range(1, int(rls_reindex_rounds) + 1):
            m_r = res_r.model
            try:
                prof_r = model_profile(m_r, u, z, T, forward_traces, creep_start_nm, lam=lam_r)
            except ValueError:  # the estimate's forward trace does not advance: keep the last
                break
            lam_r = prof_r.penalty
            res_r = rls(
                u_fit, z_fit, prof_r, m_r, T, settings=again,
                state=record_state(m_r, u[0], creep_start_nm),
            )  # fmt: skip
            s_r = score(res_r.model, prof_r)
            if s_r < best:
                res, prof, best, kept = res_r, prof_r, s_r, r
        if rls_then is not None:
            res, prof = rls_then(res, prof)
        held, before = score(res.model, prof), (res.model, prof)
        if rls_final is not None:
            res, prof = rls_final(res, prof)
        return res, prof, kept, held, before

    def chain_start(
        k: tuple[int, int], init: ScannerModel, st: ModelState, first: RLSResult
    ) -> None:
        # The RLS chain's estimate of candidate k: its own first run (rls_start) or the
        # candidates' one, then the continuation from it (P restarts at p0 I); the RLS
        # orders are those of the best of these estimates on the held-out heights.
        res = first
        if rls_start is not None:
            res = rls(u_fit, z_fit, profile, init, T, settings=rls_start, state=st)
        if rls_continue is not None:
            res = rls(u_fit, z_fit, profile, res.model, T, settings=rls_continue,
                      state=record_state(res.model, u[0], creep_start_nm))  # fmt: skip
        rls_results[k] = res
        rls_scores[k] = score(res.model)

    # With threads, each candidate's RLS continuation starts as soon as its first RLS is
    # done, beside the batch refinements (the operating system shares the processors).
    early = None
    if n_workers > 1 and (rls_continue is not None or rls_start is not None):
        early = ThreadPoolExecutor(max_workers=len(orders))
    continued: dict[tuple[int, int], Future[None]] = {}
    final_scores: dict[str, float] = {}  # held-out, before the final stages
    with single_threaded_blas(), early or contextlib.nullcontext():
        selection = select_orders(
            orders, fit_fn, score_fn, tolerance=order_tolerance, workers=n_workers,
            prefer=prefer_orders,
        )  # fmt: skip
        chosen_rls, ref, batch_profile = selection.fitted
        key = (selection.n_play, selection.n_creep)

        def batch_chain(
            ref_b: RefineResult | None, prof_b: HeightProfile, k: int
        ) -> tuple[RefineResult | None, ScannerModel, HeightProfile, float]:
            # k more re-indexing rounds, then batch_then; the held-out score (before
            # batch_final) is returned beside the final model.
            if ref_b is not None and k > 0:
                ref_b, prof_b = more_rounds(ref_b, prof_b, k)
            model_b = ref_b.model if ref_b is not None else chosen_rls.model
            if batch_then is not None:
                model_b, prof_b = batch_then(model_b, prof_b)
            held = score(model_b, prof_b)
            if batch_final is not None:
                model_b, prof_b = batch_final(model_b, prof_b)
            return ref_b, model_b, prof_b, held

        first = (ref, batch_profile, rounds - sel_rounds)
        if n_workers > 1:
            with ThreadPoolExecutor(max_workers=1) as side:
                rls_future = side.submit(rls_chain)
                chain = batch_chain(*first)
                rls_chained = rls_future.result()
        else:
            chain = batch_chain(*first)
            rls_chained = rls_chain()
        ref, batch_model, batch_profile, final_scores["batch"] = chain
        rls_res, rls_prof, rls_round, final_scores["rls"], rls_held = rls_chained
        restart: dict[str, Any] | None = None
        if (
            batch_restart_ratio is not None
            and ref is not None
            and far_worse(final_scores["batch"], final_scores["rls"], batch_restart_ratio)
        ):
            again = batch_chain(refined(*rls_held), rls_held[1], rounds)
            kept = "restart" if again[3] < final_scores["batch"] else "first"
            restart = {"first": final_scores["batch"], "restart": again[3], "kept": kept}
            if kept == "restart":
                ref, batch_model, batch_profile, final_scores["batch"] = again
    scores = {"initial": init_scores[key], "rls": final_scores["rls"],
              "batch": final_scores["batch"]}  # fmt: skip
    return Estimation(
        selection, rls_res, ref, batch_model, scores, batch_profile, rls_prof, rls_round,
        restart,
    )  # fmt: skip
