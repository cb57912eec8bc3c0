"""The estimation stage's settings (Section III.C): how the candidate orders are estimated
(RLS, eqs 16-20, and batch refinement of the same prediction error), re-indexed and compared
on the held-out heights: the estimation stage's configuration, ``estimation`` in
:class:`~piezocomp.identification.config.IdentifyConfig`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from piezocomp._validation import check_finite_scalar, check_int_at_least
from piezocomp.identification.estimation.candidates import DEFAULT_CREEP_TAU_RANGE_S
from piezocomp.identification.estimation.parameters import REFINE_GROUPS
from piezocomp.identification.estimation.rls import (
    RLS_CANDIDATES,
    RLS_CONTINUE,
    RLS_START,
    RLSSettings,
)

__all__ = ["BATCH_ASTRAY_RATIO", "EstimationConfig", "RoundsConfig"]

BATCH_ASTRAY_RATIO = 2.0
"""Held-out height RMS of the batch model over the RLS's above which a finding says so (and
the batch chain is run again from the RLS estimate, ``EstimationConfig.batch_restart_ratio``)."""


@dataclass(frozen=True)
class EstimationConfig:
    """How :func:`~piezocomp.identification.estimation.chain.estimate` estimates and compares the
    candidate orders (the estimation stage's configuration, ``estimation`` in
    :class:`~piezocomp.identification.config.IdentifyConfig`).

    Parameters
    ----------
    orders : sequence of (n_play, n_creep)
        Candidates (a single pair fixes them); ``n_creep`` creep operators placed
        log-uniformly over ``creep_tau_range_s``
        (:func:`~piezocomp.identification.estimation.candidates.creep_spectrum`).
    rls_settings : RLSSettings
        The RLS every candidate gets (eqs 16-20); the batch refinements start from it.
    refine_max_nfev : int
        Evaluations of the batch refinement (0: skip it; the batch model is then the RLS's).
    refine_free : sequence of str
        Groups the batch refinement adjusts (eq 15 groups; thresholds and poles held), and
        ``"b"``: the creep coupling ``beta`` of the extended family (eq 2'), freed from the
        RLS estimate's ``beta = 0``, so that the batch model's creep follows the hysteresis
        output as well as the command (leave it out for the paper's family; the RLS chain
        always estimates the paper's).
    creep_tau_range_s : (float, float)
        Shortest and longest creep time constant of the spectrum, s.
    reindex_rounds, selection_rounds, reindex_max_nfev
        Rounds of re-indexing ``h`` by the refined model and refining again (0: the given
        ``h`` throughout, as in the paper; needs ``forward_traces``); rounds every candidate
        gets before the held-out comparison (``None``: all; capped at ``reindex_rounds``);
        evaluations of each round's refinement (``None``: ``refine_max_nfev``).
    rls_start, rls_continue : RLSSettings, optional
        The RLS chain's own first run of every candidate (with Huber's robust update), and a
        further run from its estimate (more passes, smoothness priors); the RLS orders are
        those whose chain predicts the held-out heights best (``None``: skipped). The batch
        refinements start from the candidates' ``rls_settings`` runs in any case.
    order_tolerance : float
        ``tolerance`` of :func:`~piezocomp.identification.estimation.orders.select_orders` on the
        held-out heights; the candidate with the most parameters within it is chosen (the
        held-out heights cannot tell 16 play operators from 32 while the truth prefers 32).
    creep_smoothing_nm, weight_smoothing_nm : float
        Smoothness penalties on the creep spectrum and on the play weights in every batch
        refinement (0: none).
    rls_reindex_rounds, rls_reindex_passes : int
        Rounds of re-indexing ``h`` by the RLS estimate itself, each followed by this many
        passes (of ``rls_continue``, else ``rls_settings``); the round whose estimate
        predicts the held-out heights best is kept.
    batch_restart_ratio : float, optional
        When the batch chain predicts the held-out heights this many times worse than the
        RLS chain and by more than 1 nm
        (:func:`~piezocomp.identification.estimation.chain.far_worse`), it is run again from the
        RLS chain's estimate and the better of the two is kept (``None``: never).
    workers : int, optional
        Threads; the result does not depend on it (``None``: the processors this process
        may use, at most 4).
    """

    orders: tuple[tuple[int, int], ...] = ((16, 22), (32, 22))
    rls_settings: RLSSettings = field(default_factory=lambda: RLS_CANDIDATES)
    refine_max_nfev: int = 40
    refine_free: tuple[str, ...] = ("c", "a", "w", "y0", "b")
    creep_tau_range_s: tuple[float, float] = DEFAULT_CREEP_TAU_RANGE_S
    reindex_rounds: int = 8
    selection_rounds: int | None = 4
    reindex_max_nfev: int | None = 15
    rls_continue: RLSSettings | None = field(default_factory=lambda: RLS_CONTINUE)
    rls_start: RLSSettings | None = field(default_factory=lambda: RLS_START)
    order_tolerance: float = 0.25
    creep_smoothing_nm: float = 300.0
    weight_smoothing_nm: float = 1000.0
    rls_reindex_rounds: int = 3
    rls_reindex_passes: int = 20
    batch_restart_ratio: float | None = BATCH_ASTRAY_RATIO
    workers: int | None = None

    def __post_init__(self) -> None:
        if not self.orders:
            raise ValueError("orders must hold at least one (n_play, n_creep) pair.")
        orders = tuple((int(a), int(b)) for a, b in self.orders)
        for nh, nc in orders:
            if nh < 1 or nc < 0:
                raise ValueError(f"orders need n_play >= 1 and n_creep >= 0. Got ({nh}, {nc}).")
        object.__setattr__(self, "orders", orders)
        free = (self.refine_free,) if isinstance(self.refine_free, str) else self.refine_free
        free = tuple(free)
        if not free or set(free) - set(REFINE_GROUPS):
            raise ValueError(
                f"refine_free must name groups among {REFINE_GROUPS}. Got {list(free)!r}."
            )
        object.__setattr__(self, "refine_free", free)
        tol = self.order_tolerance
        if isinstance(tol, bool) or check_finite_scalar("order_tolerance", tol) < 0:
            raise ValueError(f"order_tolerance must be a finite number >= 0. Got {tol!r}.")
        rounds = self.reindex_rounds
        if isinstance(rounds, bool) or rounds not in range(0, 101):
            raise ValueError(f"reindex_rounds must be an integer in [0, 100]. Got {rounds!r}.")
        for name, lo, none in (("selection_rounds", 0, True), ("reindex_max_nfev", 1, True),
                               ("workers", 1, True), ("rls_reindex_rounds", 0, False),
                               ("rls_reindex_passes", 1, False)):  # fmt: skip
            v = getattr(self, name)
            if not (none and v is None) and (
                isinstance(v, bool) or not isinstance(v, int) or v < lo
            ):
                allowed = "None or an integer" if none else "an integer"
                raise ValueError(f"{name} must be {allowed} >= {lo}. Got {v!r}.")
        r = self.batch_restart_ratio
        if r is not None and (
            isinstance(r, bool) or check_finite_scalar("batch_restart_ratio", r) < 1
        ):
            raise ValueError(f"batch_restart_ratio must be None or >= 1. Got {r!r}.")
        for name in ("creep_smoothing_nm", "weight_smoothing_nm"):
            if check_finite_scalar(name, getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0. Got {getattr(self, name)}.")
        self._check_rls()

    def _check_rls(self) -> None:
        """The RLS settings are RLSSettings (``rls_continue`` and ``rls_start`` may be
        ``None``) whose bounds leave the creep spectrum's poles where they are."""
        tau_lo = float(self.creep_tau_range_s[0])
        for name in ("rls_settings", "rls_continue", "rls_start"):
            v = getattr(self, name)
            if v is None and name != "rls_settings":
                continue
            if not isinstance(v, RLSSettings):
                raise TypeError(f"{name} must be RLSSettings. Got {type(v).__name__}.")
            if v.min_time_constant_s > tau_lo:
                raise ValueError(
                    f"{name}.min_time_constant_s ({v.min_time_constant_s} s) is above the "
                    f"creep spectrum's shortest time constant ({tau_lo} s): the RLS's bounds "
                    "would move the creep poles it holds. Lower it to at most the spectrum's."
                )

    @property
    def workers_used(self) -> int:
        """``workers``, or the processors this process may run on (at most 4) when it is
        ``None``."""
        if self.workers is not None:
            return int(self.workers)
        try:
            n = len(os.sched_getaffinity(0))  # a container's share, where the OS tells it
        except AttributeError:  # pragma: no cover - not on Linux
            n = os.cpu_count() or 1
        return max(1, min(4, n))

    @property
    def selection_rounds_used(self) -> int:
        """``selection_rounds`` capped at ``reindex_rounds``; all of them when ``None``."""
        sel = self.selection_rounds
        return int(self.reindex_rounds) if sel is None else min(int(sel), int(self.reindex_rounds))

    @property
    def round_nfev(self) -> int:
        """Evaluations of each re-indexing round's refinement."""
        nf = self.reindex_max_nfev
        return self.refine_max_nfev if nf is None else int(nf)


@dataclass(frozen=True)
class RoundsConfig:
    """The rounds after each candidate's estimation
    (:mod:`~piezocomp.identification.estimation.several_lines`,
    :mod:`~piezocomp.identification.estimation.drift_rounds`).

    Parameters
    ----------
    joint_rounds, rls_lines_passes : int
        With extra lines: rounds of the joint batch refinement over all lines, each line
        weighted by the inverse of its residual level; passes of the RLS on every line, kept
        if it predicts the lines' held-out heights better.
    drift_rounds : int
        Rounds of estimating the sample's drift along the line during each record with the
        batch model, then the models again with it taken out
        (:mod:`~piezocomp.identification.estimation.drift_along_line`); kept when it predicts the
        held-out heights better than the estimate without (0: no drift).
    final_rounds, rls_final_passes : int
        After the held-out part has chosen orders and rounds: batch rounds and RLS passes
        over the whole record of every line (0: none).
    """

    joint_rounds: int = 3
    rls_lines_passes: int = 10
    drift_rounds: int = 1
    final_rounds: int = 1
    rls_final_passes: int = 10

    def __post_init__(self) -> None:
        for name, lo in (("joint_rounds", 1), ("rls_lines_passes", 0), ("final_rounds", 0),
                         ("rls_final_passes", 0), ("drift_rounds", 0)):  # fmt: skip
            check_int_at_least(name, getattr(self, name), lo)
        if self.drift_rounds > 10:
            raise ValueError(
                f"drift_rounds must be an integer in [0, 10]. Got {self.drift_rounds}."
            )

    @property
    def final_fit(self) -> bool:
        """Whether the models are fitted again over the whole record, held-out part
        included."""
        return self.final_rounds > 0 or self.rls_final_passes > 0
