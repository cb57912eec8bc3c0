"""The estimation stage's chain of estimators, RLS then batch (Section III.C, eqs 16-20).

Given the identification record ``(u, z_m)`` and ``h(y)`` of Section IV, for every candidate order:
the recursive estimator of eqs (16)-(20) (:func:`~piezocomp.identification.estimation.rls.rls`) from
a start fitted to the loop
(:func:`~piezocomp.identification.estimation.candidates.initial_from_loop`), then the batch
refinement of the same prediction error (:func:`~piezocomp.identification.estimation.batch.refine`,
``output = h``), with ``h`` re-indexed by the refined model between rounds
(:func:`~piezocomp.identification.estimation.prediction.model_profile`); the orders are chosen by
the height prediction error on a held-out part of the record
(:func:`~piezocomp.identification.estimation.orders.select_orders`), which needs no sensor. The RLS
estimate is carried on in a chain of its own, independent of the batch refinement. With
further lines (:class:`~piezocomp.identification.estimation.several_lines.SeveralLines`) each
chain ends with its stages over every line."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp.identification.estimation.batch import RefineOptions, RefineResult, refine
from piezocomp.identification.estimation.candidates import creep_spectrum
from piezocomp.identification.estimation.config import EstimationConfig
from piezocomp.identification.estimation.orders import OrderSelection, select_orders
from piezocomp.identification.estimation.prediction import (
    creep_rest,
    heldout_rms,
    model_profile,
    record_state,
)
from piezocomp.identification.estimation.rls import RLSResult, rls
from piezocomp.identification.estimation.several_lines import SeveralLines
from piezocomp.identification.estimation.threads import single_threaded_blas
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.model import ModelState, ScannerModel

__all__ = [
    "Estimation",
    "estimate",
    "far_worse",
]


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
        Held-out height RMS (nm) of the starting model (``"initial"``), ``"rls"`` and ``"batch"``
        for the chosen orders (each through its own profile), before the fits over the whole record
        (:meth:`~piezocomp.identification.estimation.several_lines.SeveralLines.whole_batch`,
        :meth:`~piezocomp.identification.estimation.several_lines.SeveralLines.whole_rls`), if any.
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
    rls_on_lines : bool
        Whether the RLS estimate kept is the one run on every line
        (:meth:`~piezocomp.identification.estimation.several_lines.SeveralLines.rls`).
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
    rls_on_lines: bool = False


def far_worse(worse: float, better: float, ratio: float) -> bool:
    """Whether held-out height RMS ``worse`` is more than ``ratio`` times ``better`` and more
    than 1 nm above it (both finite)."""
    finite = bool(np.isfinite(worse) and np.isfinite(better))
    return finite and worse > ratio * better and worse - better > 1.0


@dataclass(frozen=True)
class _RLSChainEnd:
    """Where the RLS chain of :func:`estimate` ended: the estimate and its ``h``, the
    re-indexing round kept, its held-out score, the model and ``h`` before the fit over the
    whole record, and whether the estimate is the one run on every line."""

    result: RLSResult
    profile: HeightProfile
    round: int
    heldout_nm: float
    before: tuple[ScannerModel, HeightProfile]
    on_lines: bool


@dataclass(frozen=True)
class _BatchChainEnd:
    """Where the batch chain of :func:`estimate` ended: the last refinement (``None`` if
    skipped), the model and its ``h``, and the held-out score before the fit over the whole
    record."""

    refine: RefineResult | None
    model: ScannerModel
    profile: HeightProfile
    heldout_nm: float


Key = tuple[int, int]


class _Chains:
    """The candidates' fits and the two chains of one :func:`estimate` call (its state: the
    record, the options, and the RLS chain's estimates as they complete)."""

    def __init__(
        self,
        u: NDArray[np.float64],
        z: NDArray[np.float64],
        T: float,
        profile: HeightProfile,
        initial: Callable[[int, NDArray[np.float64]], ScannerModel],
        mask: NDArray[np.bool_],
        warmup: int,
        creep_start: float | None,
        forward: Sequence[slice],
        options: EstimationConfig,
        lines: SeveralLines | None,
        early: ThreadPoolExecutor | None,
        shift: NDArray[np.float64] | None = None,
    ) -> None:
        self.u, self.z, self.T, self.profile, self.initial = u, z, T, profile, initial
        self.mask, self.warmup, self.creep_start, self.forward = mask, warmup, creep_start, forward
        self.o, self.lines = options, lines
        n_fit = int(mask.sum())
        self.u_fit, self.z_fit = u[:n_fit], z[:n_fit]
        self.shift = shift  # the sample's drift along the line (None: none)
        self.shift_fit = None if shift is None else shift[:n_fit]
        self.heldout = ~mask
        self.heldout[:warmup] = False
        self.rls_scores: dict[Key, float] = {}
        self.rls_results: dict[Key, RLSResult] = {}  # the RLS chain's
        self.init_scores: dict[Key, float] = {}
        self.early = early  # threads for the RLS chain's runs, started as candidates finish
        self.continued: dict[Key, Future[None]] = {}

    def score(self, m: ScannerModel, prof: HeightProfile | None = None) -> float:
        prof = self.profile if prof is None else prof
        return heldout_rms(prof, m, self.u, self.z, self.T, self.heldout, self.creep_start,
                           self.shift)  # fmt: skip

    def state(self, m: ScannerModel) -> ModelState:
        return record_state(m, self.u[0], self.creep_start)

    def refined(
        self, m: ScannerModel, prof: HeightProfile, nfev: int | None = None
    ) -> RefineResult:
        o = self.o
        return refine(
            m, self.u, self.z, self.T, output=prof, state=self.state(m), fit_mask=self.mask,
            warmup_samples=self.warmup, shift_nm=self.shift,
            creep_rest_nm=creep_rest(self.u[0], self.creep_start),
            options=RefineOptions(
                free=o.refine_free, max_nfev=o.refine_max_nfev if nfev is None else nfev,
                creep_smoothing_nm=o.creep_smoothing_nm,
                weight_smoothing_nm=o.weight_smoothing_nm,
            ),
        )  # fmt: skip

    def fit(self, nh: int, nc: int) -> tuple[Any, float]:
        """One candidate: its RLS from the start, then the batch refinement and the
        selection rounds (the RLS chain's runs start beside it)."""
        init = self.initial(nh, creep_spectrum(nc, self.o.creep_tau_range_s))
        st = record_state(init, self.u[0], self.creep_start)
        res = rls(self.u_fit, self.z_fit, self.profile, init, self.T, settings=self.o.rls_settings,
                  state=st, shift_nm=self.shift_fit)  # fmt: skip
        if self.early is not None:  # the RLS chain's runs need nothing else: start them now
            self.continued[(nh, nc)] = self.early.submit(self.chain_start, (nh, nc), init, st, res)
        else:
            self.chain_start((nh, nc), init, st, res)
        self.init_scores[(nh, nc)] = self.score(init)
        if self.o.refine_max_nfev <= 0:
            rms = float(np.sqrt(np.mean(res.error_nm[self.warmup :] ** 2)))
            return (res, None, self.profile), rms
        ref = self.refined(res.model, self.profile)
        ref, prof = self.more_rounds(ref, self.profile, self.o.selection_rounds_used)
        return (res, ref, prof), ref.rms

    def more_rounds(
        self, ref: RefineResult, prof: HeightProfile, k: int
    ) -> tuple[RefineResult, HeightProfile]:
        # Every re-indexing keeps the smoothing GCV chose for the loop's h: the positions
        # move by a fraction of a per cent of the span, which leaves that choice unchanged.
        for _ in range(k):
            lam = prof.penalty if np.isfinite(prof.penalty) else None
            prof = model_profile(ref.model, self.u, self.z, self.T, self.forward,
                                 self.creep_start, lam=lam, shift_nm=self.shift)  # fmt: skip
            ref = self.refined(ref.model, prof, self.o.round_nfev)
        return ref, prof

    def fitted_score(self, fitted: Any) -> float:
        res, ref, prof = fitted
        return self.score(ref.model if ref is not None else res.model, prof)

    def chain_start(self, k: Key, init: ScannerModel, st: ModelState, first: RLSResult) -> None:
        # The RLS chain's estimate of candidate k: its own first run (rls_start) or the
        # candidates' one, then the continuation from it (P restarts at p0 I).
        o, res = self.o, first
        if o.rls_start is not None:
            res = rls(self.u_fit, self.z_fit, self.profile, init, self.T, settings=o.rls_start,
                      state=st, shift_nm=self.shift_fit)  # fmt: skip
        if o.rls_continue is not None:
            res = rls(self.u_fit, self.z_fit, self.profile, res.model, self.T,
                      settings=o.rls_continue, state=self.state(res.model),
                      shift_nm=self.shift_fit)  # fmt: skip
        self.rls_results[k] = res
        self.rls_scores[k] = self.score(res.model)

    def rls_chain(self, keys: list[Key]) -> _RLSChainEnd:
        """The RLS estimate on its own: the orders of its best held-out heights, then the
        re-indexing rounds by its own estimate (the best round kept), then, with
        :class:`~piezocomp.identification.estimation.several_lines.SeveralLines`, the RLS on every
        line and over the whole record."""
        o = self.o
        for fut in self.continued.values():  # the RLS chain's runs started on the side threads
            fut.result()
        rls_key = min(keys, key=self.rls_scores.__getitem__)
        res, prof, best = self.rls_results[rls_key], self.profile, self.rls_scores[rls_key]
        kept = 0
        again = replace(o.rls_continue or o.rls_settings, passes=int(o.rls_reindex_passes))
        res_r = res
        lam_r = self.profile.penalty if np.isfinite(self.profile.penalty) else None
        for r in range(1, int(o.rls_reindex_rounds) + 1):
            m_r = res_r.model
            try:
                prof_r = model_profile(m_r, self.u, self.z, self.T, self.forward,
                                       self.creep_start, lam=lam_r,
                                       shift_nm=self.shift)  # fmt: skip
            except ValueError:  # the estimate's forward trace does not advance: keep the last
                break
            lam_r = prof_r.penalty
            res_r = rls(self.u_fit, self.z_fit, prof_r, m_r, self.T, settings=again,
                        state=self.state(m_r), shift_nm=self.shift_fit)  # fmt: skip
            s_r = self.score(res_r.model, prof_r)
            if s_r < best:
                res, prof, best, kept = res_r, prof_r, s_r, r
        on_lines = False
        if self.lines is not None:
            res, prof, on_lines = self.lines.rls(res, prof)
        held, before = self.score(res.model, prof), (res.model, prof)
        if self.lines is not None:
            res, prof = self.lines.whole_rls(res, prof)
        return _RLSChainEnd(res, prof, kept, held, before, on_lines)

    def batch_chain(
        self, ref_b: RefineResult | None, prof_b: HeightProfile, k: int, rls_model: ScannerModel
    ) -> _BatchChainEnd:
        """``k`` more re-indexing rounds, then, with
        :class:`~piezocomp.identification.estimation.several_lines.SeveralLines`, the joint rounds
        on every line; the held-out score (before the fit over the whole record) beside the final
        model."""
        if ref_b is not None and k > 0:
            ref_b, prof_b = self.more_rounds(ref_b, prof_b, k)
        model_b = ref_b.model if ref_b is not None else rls_model
        if self.lines is not None:
            model_b, prof_b = self.lines.joint(model_b, prof_b)
        held = self.score(model_b, prof_b)
        if self.lines is not None:
            model_b, prof_b = self.lines.whole_batch(model_b, prof_b)
        return _BatchChainEnd(ref_b, model_b, prof_b, held)


def _checked_mask(
    fit_mask: ArrayLike, warmup_samples: int, o: EstimationConfig, has_traces: bool
) -> NDArray[np.bool_]:
    """:func:`estimate`'s fit mask, checked (with what the rounds need)."""
    mask = np.asarray(fit_mask, dtype=bool)
    n_fit = int(mask.sum())
    if n_fit < 2 or not mask[:n_fit].all():
        raise ValueError("fit_mask must select a prefix of at least 2 samples of the record.")
    if mask[warmup_samples:].all():
        raise ValueError("no held-out samples left to choose the orders on.")
    if (o.reindex_rounds or o.rls_reindex_rounds) and not has_traces:
        raise ValueError("reindex_rounds or rls_reindex_rounds > 0 needs forward_traces.")
    return mask


def estimate(
    u_nm: ArrayLike,
    height_nm: ArrayLike,
    sample_period_s: float,
    profile: HeightProfile,
    initial: Callable[[int, NDArray[np.float64]], ScannerModel],
    *,
    fit_mask: NDArray[np.bool_],
    warmup_samples: int,
    options: EstimationConfig,
    creep_start_nm: float | None = None,
    forward_traces: Sequence[slice] = (),
    lines: SeveralLines | None = None,
    shift_nm: NDArray[np.float64] | None = None,
) -> Estimation:
    """RLS (eqs 16-20), batch refinement and order selection on one record.

    Every candidate order gets the RLS from ``initial`` and the batch refinement of the same
    prediction error (with ``options.selection_rounds`` re-indexing rounds); the orders are
    chosen on the held-out heights. Then two independent chains: the batch chain (the rest
    of the re-indexing rounds, then ``lines.joint`` and ``lines.whole_batch``) and the RLS
    chain (the candidates' own robust runs and continuations, its best orders, re-indexing
    by its own estimate, then ``lines.rls`` and ``lines.whole_rls``), side by side with
    more than one worker (``options.workers_used``; the compiled kernels release the GIL;
    the result does not depend on it). A batch chain far worse than the RLS chain is run
    again from the RLS estimate (``options.batch_restart_ratio``).

    Parameters
    ----------
    u_nm, height_nm : array_like, shape (n,)
        The identification record: command (nominal nm) and measured heights (nm).
    sample_period_s : float
    profile : HeightProfile
        ``h(y)`` (Section IV).
    initial : callable
        ``initial(n_play, time_constants_s) -> ScannerModel``: a candidate's starting model
        (e.g. :func:`initial_from_loop`).
    fit_mask : ndarray of bool, shape (n,)
        Samples fitted: a prefix of the record; the rest, after ``warmup_samples``, is held
        out to choose the orders.
    warmup_samples : int
        Leading samples left out of every cost (unknown initial play state).
    options : EstimationConfig
    creep_start_nm : float, optional
        Creep states before the first sample (:func:`record_state`).
    forward_traces : sequence of slice
        Forward traces of the steady cycles ``profile`` was built from (part A), for the
        re-indexing rounds (:func:`model_profile`).
    lines : SeveralLines, optional
        Every line of the axis, the first being ``(u_nm, height_nm, shift_nm)``: the chains end with
        their stages over all of them
        (:class:`~piezocomp.identification.estimation.several_lines.SeveralLines`). Default: none.
    shift_nm : ndarray, shape (n,), optional
        The sample's drift along the line at each sample (the heights are
        ``h(y_hat + shift)``, :mod:`~piezocomp.identification.estimation.drift_along_line`).
        Default none.
    """
    o = options
    u = np.ascontiguousarray(u_nm, dtype=float)
    z = np.ascontiguousarray(height_nm, dtype=float)
    mask = _checked_mask(fit_mask, int(warmup_samples), o, bool(forward_traces))
    # With threads, each candidate's RLS continuation starts as soon as its first RLS is
    # done, beside the batch refinements (the operating system shares the processors).
    early = None
    workers = o.workers_used
    if workers > 1 and (o.rls_continue is not None or o.rls_start is not None):
        early = ThreadPoolExecutor(max_workers=len(o.orders))
    run = _Chains(u, z, float(sample_period_s), profile, initial, mask, int(warmup_samples),
                  creep_start_nm, forward_traces, o, lines, early,
                  None if shift_nm is None else np.asarray(shift_nm, dtype=float))  # fmt: skip
    with single_threaded_blas(), early or contextlib.nullcontext():
        selection = select_orders(o.orders, run.fit, run.fitted_score, tolerance=o.order_tolerance,
                                  workers=workers, prefer="largest")  # fmt: skip
        chosen_rls, ref, batch_profile = selection.fitted
        keys = [(t.n_play, t.n_creep) for t in selection.trials]  # in the candidates' order
        first = (ref, batch_profile, o.reindex_rounds - o.selection_rounds_used, chosen_rls.model)
        if workers > 1:
            with ThreadPoolExecutor(max_workers=1) as side:
                rls_future = side.submit(run.rls_chain, keys)
                chain = run.batch_chain(*first)
                end = rls_future.result()
        else:
            chain = run.batch_chain(*first)
            end = run.rls_chain(keys)
        restart: dict[str, Any] | None = None
        ratio = o.batch_restart_ratio
        if (
            ratio is not None
            and chain.refine is not None
            and far_worse(chain.heldout_nm, end.heldout_nm, ratio)
        ):
            again = run.batch_chain(run.refined(*end.before), end.before[1], o.reindex_rounds,
                                    chosen_rls.model)  # fmt: skip
            kept = "restart" if again.heldout_nm < chain.heldout_nm else "first"
            restart = {"first": chain.heldout_nm, "restart": again.heldout_nm, "kept": kept}
            if kept == "restart":
                chain = again
    key = (selection.n_play, selection.n_creep)
    scores = {"initial": run.init_scores[key], "rls": end.heldout_nm, "batch": chain.heldout_nm}
    return Estimation(
        selection, end.result, chain.refine, chain.model, scores, chain.profile, end.profile,
        end.round, restart, end.on_lines,
    )  # fmt: skip
