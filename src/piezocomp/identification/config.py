"""The research-level configuration of the sensorless identification: every setting of
every stage.

:class:`SensorlessConfig` holds them all (all of which go into ``summary.json``), with the
defaults the accuracy table of ``docs/identification.md`` was measured with; the RLS
settings of the candidates and of the RLS chain (:data:`RLS_CANDIDATES`, :data:`RLS_START`,
:data:`RLS_CONTINUE`); the fields only a driven acquisition uses (:data:`ACQUISITION_FIELDS`).
A user sets the few of :class:`~piezocomp.identification.settings.IdentifySettings`, which
builds this one. Lengths are nm of command, times s.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import numpy as np

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.candidates import DEFAULT_CREEP_TAU_RANGE_S
from piezocomp.identification.cross_drift import DITHER_NM
from piezocomp.identification.estimation import EstimationOptions
from piezocomp.identification.findings import BATCH_ASTRAY_RATIO
from piezocomp.identification.rls import RLSSettings

__all__ = [
    "ACQUISITION_FIELDS",
    "RLS_CANDIDATES",
    "RLS_CONTINUE",
    "RLS_START",
    "SensorlessConfig",
]

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

ACQUISITION_FIELDS = frozenset({
    "center_nm", "span_nm", "speed_nm_per_s", "overview_pixels", "n_steady", "n_decaying",
    "n_random", "max_dwell_s", "speed_factors", "calibration_span_nm",
    "calibration_speed_nm_per_s", "calibration_degree", "overview_shifts",
    "line_search_nm", "line_search_step_nm", "settle_s", "line_settle_s", "relocate_search_nm",
    "relocate_settle_s", "cross_dither_nm", "check_cycles", "check_tolerance_nm",
    "rerecord_unstable",
    "min_line_particles", "loop_pairs_factor", "seed", "extra_lines", "extra_line_offset_nm",
    "joint_rounds", "rls_lines_passes", "rls_lines_rounds",
})  # fmt: skip
"""The :class:`SensorlessConfig` fields only the driven acquisition uses (a recorded run's
waveform file fixes the waveform; it has one line and no calibration cycles)."""


@dataclass(frozen=True)
class SensorlessConfig:
    """Every setting of the sensorless procedure (lengths nm of command, times s).

    The research-level object:
    :class:`~piezocomp.identification.settings.IdentifySettings` holds the dozen a user sets
    and builds this one (its ``config``); everything else has the default the
    accuracy table of ``docs/identification.md`` was measured with, and the reasons for
    the defaults are in ``docs/identification-design.md``.

    Parameters
    ----------
    center_nm, span_nm, speed_nm_per_s
        Centre (x, y) and side of the working area; ramp speed of the waveform and of the
        overview's fast axis.
    overview_pixels : int
        Pixels per side of the overview image.
    degree : int
        Degree of the loop polynomial ``f_a`` of eq (23) (>= 5 in the paper).
    min_prominence_nm : float
        Smallest particle prominence counted as a peak.
    n_steady, n_decaying, n_random, max_dwell_s
        Shape of the waveform of Fig. 7a (:func:`identification_waveform`).
    speed_factors : tuple of float
        Part B's ramps run at ``speed_nm_per_s`` times these factors in turn (capped at the
        instrument's speed limit). Several speeds tell the fast creep modes from narrow
        play operators; ``(1.0,)`` is the paper's single speed.
    orders : sequence of (n_play, n_creep)
        Candidate orders (a single pair fixes them); the creep time constants are placed
        log-uniformly over ``creep_tau_range_s``.
    holdout_fraction : float
        Fraction of part B (its end) held out to choose the orders and rounds.
    order_tolerance : float
        Among the candidates within ``1 + order_tolerance`` times the best held-out height
        RMS, the one with the most parameters
        (:func:`~piezocomp.identification.orders.select_orders`).
    rls_settings, rls_start, rls_continue : RLSSettings
        The RLS of eqs (16)-(20) for every candidate order; the RLS chain's first run (with
        Huber's robust update) and its continuation (more passes, smoothness priors) after
        the orders are chosen (``None``: skipped).
    rls_reindex_rounds, rls_reindex_passes : int
        Rounds of re-indexing ``h`` by the RLS estimate itself, each followed by this many
        passes; the round that predicts the held-out heights best is kept.
    refine_max_nfev, refine_free
        Evaluations of the batch refinement (0: none) and the parameter groups it adjusts
        (eq 15 groups; thresholds and creep poles held).
    creep_smoothing_nm, weight_smoothing_nm : float
        Weights of the smoothness penalties on the creep spectrum and on the play weights in
        every batch refinement (0: none).
    reindex_rounds, selection_rounds, reindex_max_nfev
        Rounds of re-indexing ``h(y)`` by the refined model's own prediction and refining
        again (0: the loop's ``h`` throughout, as in the paper); rounds every candidate
        order gets before the orders are compared; evaluations per round.
    creep_tau_range_s : (float, float)
        Shortest and longest creep time constant of the spectrum.
    calibration_span_nm, calibration_speed_nm_per_s, calibration_degree
        Steady cycles over this span (e.g. the whole range, where the nominal sensitivity
        was calibrated) give a second loop onto whose frame the models are mapped
        (:func:`~piezocomp.identification.frames.frame_map`); ``None``: the paper's
        calibration condition on the working span. Their speed (``None``: the instrument's
        ``calibration_scan``), and the degree of the eq (23) polynomial that pairs their
        particles (the calibration loop itself is a Prandtl-Ishlinskii branch,
        :func:`~piezocomp.identification.loop_fit.fit_pi_loop`).
    overview_shifts, line_search_nm, line_search_step_nm
        Slow-axis shifts (in spans) of the overviews tried in turn; neighbourhood and step of
        the search back onto a line (:func:`~piezocomp.identification.acquisition.locate_line`).
    settle_s, line_settle_s, relocate_search_nm, relocate_settle_s
        Wait after the move to the line search; time scanning the line's steady cycle before
        the record, so that the slow axis' creep has slowed; neighbourhood searched and
        settling time when the tip left the line while settling.
    cross_dither_nm
        Step of the slow command on every other settling cycle, by which the line's slide
        across its particles is measured and then followed during the record
        (:mod:`~piezocomp.identification.cross_drift`); 0: the slow command is held.
    check_cycles, check_tolerance_nm, rerecord_unstable
        Steady cycles scanned right after the record to check the line's profile (0: no
        check); the change beyond repeatability (RMS) reported as a finding; times the line
        is found again and recorded anew when it changed (0: report only).
    min_line_particles, loop_pairs_factor
        Particles the identification line must pair; the loop fit gathers at least
        ``loop_pairs_factor * (degree + 1)`` pairs from the lines scanned while searching.
    seed : int
        Randomness of the waveform.
    extra_lines, extra_line_offset_nm
        Further particle lines (overviews this far apart on the slow axis) whose records
        refine the same models with the first (0: the paper's single line).
    joint_rounds, rls_lines_passes, rls_lines_rounds
        With extra lines: rounds of the joint batch refinement over all lines, each line
        weighted by the inverse of its residual level; the RLS on every
        line, kept if it predicts the lines' held-out heights better.
    final_rounds, rls_final_passes : int
        After the held-out part has chosen orders and rounds: batch rounds and RLS passes
        over the whole record of every line (0: none).
    batch_restart_ratio : float, optional
        When the batch model predicts the held-out heights this many times worse than the
        RLS estimate (and by more than 1 nm), its chain is run again from the RLS estimate
        and the better is kept (``None``: never).
    workers : int, optional
        Threads of the estimation; the result does not depend on it (``None``: the
        processors this process may use, at most 4).
    drift_rounds : int
        Rounds of estimating the sample's drift along the line during each record with the
        batch model, then the models again with it taken out
        (:mod:`~piezocomp.identification.line_drift`); the estimate with the drift is kept
        when it predicts the held-out heights better than the one without (0: no drift).
    drift_knot_spacing_s, drift_smoothing : float
        The drift path's knot spacing and smoothing
        (:func:`~piezocomp.identification.line_drift.fit_line_drift`).
    drift_anchor : float
        How strongly the drift path stays near the rate measured while the tip settled on the
        line (:func:`~piezocomp.identification.line_drift.joint_line_drift`'s ``anchor``):
        with many slow creep modes the heights alone leave part of a steady drift to creep.
    """

    center_nm: tuple[float, float] = (0.0, 0.0)
    span_nm: float = 1000.0
    speed_nm_per_s: float = 250.0
    overview_pixels: int = 128
    degree: int = 5
    min_prominence_nm: float = 3.0
    n_steady: int = 4
    n_decaying: int = 12
    n_random: int = 30
    max_dwell_s: float = 4.0
    speed_factors: tuple[float, ...] = (0.5, 1.0, 2.0)
    orders: tuple[tuple[int, int], ...] = ((16, 22), (32, 22))
    holdout_fraction: float = 0.25
    order_tolerance: float = 0.25
    rls_settings: RLSSettings = field(default_factory=lambda: RLS_CANDIDATES)
    rls_continue: RLSSettings | None = field(default_factory=lambda: RLS_CONTINUE)
    rls_start: RLSSettings | None = field(default_factory=lambda: RLS_START)
    rls_reindex_rounds: int = 3
    rls_reindex_passes: int = 20
    refine_max_nfev: int = 40
    refine_free: tuple[str, ...] = ("c", "a", "w", "y0")
    creep_smoothing_nm: float = 300.0
    weight_smoothing_nm: float = 1000.0
    reindex_rounds: int = 8
    selection_rounds: int | None = 4
    reindex_max_nfev: int | None = 15
    creep_tau_range_s: tuple[float, float] = DEFAULT_CREEP_TAU_RANGE_S
    calibration_span_nm: float | None = None
    calibration_speed_nm_per_s: float | None = None
    calibration_degree: int = 9
    line_search_nm: float = 200.0
    overview_shifts: tuple[float, ...] = (0.0, 1.0, -1.0, 2.0, -2.0)
    line_search_step_nm: float = 4.0
    settle_s: float = 0.0
    line_settle_s: float = 600.0
    relocate_search_nm: float = 40.0
    check_cycles: int = 4
    check_tolerance_nm: float = 1.0
    rerecord_unstable: int = 1
    relocate_settle_s: float = 300.0
    cross_dither_nm: float = DITHER_NM
    min_line_particles: int = 4
    loop_pairs_factor: int = 3
    seed: int = 0
    extra_lines: int = 1
    extra_line_offset_nm: float = 1000.0
    joint_rounds: int = 3
    rls_lines_passes: int = 10
    rls_lines_rounds: int = 1
    final_rounds: int = 1
    rls_final_passes: int = 10
    batch_restart_ratio: float | None = BATCH_ASTRAY_RATIO
    workers: int | None = None
    drift_rounds: int = 1
    drift_knot_spacing_s: float = 20.0
    drift_smoothing: float = 1.0
    drift_anchor: float = 1.0

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
    def selection_rounds_used(self) -> int | None:
        """``selection_rounds`` capped at ``reindex_rounds`` (``None`` stays ``None``)."""
        sel = self.selection_rounds
        return None if sel is None else min(sel, self.reindex_rounds)

    def estimation_options(self, reindex_rounds: int | None = None) -> EstimationOptions:
        """The estimation stage's options (``reindex_rounds``: the first line's own rounds,
        default :attr:`reindex_rounds`)."""
        rounds = self.reindex_rounds if reindex_rounds is None else int(reindex_rounds)
        return EstimationOptions(
            orders=self.orders, rls_settings=self.rls_settings,
            refine_max_nfev=self.refine_max_nfev, refine_free=self.refine_free,
            tau_range_s=self.creep_tau_range_s, reindex_rounds=rounds,
            selection_rounds=self.selection_rounds_used, reindex_max_nfev=self.reindex_max_nfev,
            rls_continue=self.rls_continue, rls_start=self.rls_start,
            order_tolerance=self.order_tolerance,
            creep_smoothing_nm=self.creep_smoothing_nm,
            weight_smoothing_nm=self.weight_smoothing_nm,
            rls_reindex_rounds=self.rls_reindex_rounds,
            rls_reindex_passes=self.rls_reindex_passes,
            batch_restart_ratio=self.batch_restart_ratio, workers=self.workers_used,
        )  # fmt: skip

    def __post_init__(self) -> None:
        if not self.orders:
            raise ValueError("orders must hold at least one (n_play, n_creep) pair.")
        orders = tuple((int(a), int(b)) for a, b in self.orders)
        for nh, nc in orders:
            if nh < 1 or nc < 0:
                raise ValueError(f"orders need n_play >= 1 and n_creep >= 0. Got ({nh}, {nc}).")
        object.__setattr__(self, "orders", orders)
        if not 0.0 < float(self.holdout_fraction) < 0.9:
            raise ValueError(f"holdout_fraction must be in (0, 0.9). Got {self.holdout_fraction}.")
        tol = self.order_tolerance
        if isinstance(tol, bool) or check_finite_scalar("order_tolerance", tol) < 0:
            raise ValueError(f"order_tolerance must be a finite number >= 0. Got {tol!r}.")
        if isinstance(self.reindex_rounds, bool) or self.reindex_rounds not in range(0, 101):
            raise ValueError(
                f"reindex_rounds must be an integer in [0, 100]. Got {self.reindex_rounds!r}."
            )
        sel = self.selection_rounds
        if sel is not None and (isinstance(sel, bool) or not isinstance(sel, int) or sel < 0):
            raise ValueError(f"selection_rounds must be None or an integer >= 0. Got {sel!r}.")
        nf = self.reindex_max_nfev
        if nf is not None and (isinstance(nf, bool) or not isinstance(nf, int) or nf < 1):
            raise ValueError(f"reindex_max_nfev must be None or an integer >= 1. Got {nf!r}.")
        if self.span_nm <= 0 or self.speed_nm_per_s <= 0:
            raise ValueError("span_nm and speed_nm_per_s must be > 0.")
        factors = tuple(
            check_finite_scalar("speed_factors", v) for v in np.atleast_1d(self.speed_factors)
        )
        if not factors or min(factors) <= 0:
            raise ValueError(
                f"speed_factors must hold at least one factor, all > 0. Got {self.speed_factors}."
            )
        object.__setattr__(self, "speed_factors", factors)
        for name, lo in (
            ("extra_lines", 0),
            ("joint_rounds", 1),
            ("rls_reindex_rounds", 0),
            ("rls_reindex_passes", 1),
            ("rls_lines_passes", 0),
            ("rls_lines_rounds", 1),
            ("final_rounds", 0),
            ("rls_final_passes", 0),
            ("rerecord_unstable", 0),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}. Got {v!r}.")
        for name in ("settle_s", "line_settle_s", "relocate_settle_s", "cross_dither_nm"):
            if check_finite_scalar(name, getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0. Got {getattr(self, name)}.")
        r = self.batch_restart_ratio
        if r is not None and (
            isinstance(r, bool) or check_finite_scalar("batch_restart_ratio", r) < 1
        ):
            raise ValueError(f"batch_restart_ratio must be None or >= 1. Got {r!r}.")
        w = self.workers
        if w is not None and (isinstance(w, bool) or not isinstance(w, int) or w < 1):
            raise ValueError(f"workers must be None or an integer >= 1. Got {w!r}.")
        dr = self.drift_rounds
        if isinstance(dr, bool) or not isinstance(dr, int) or not 0 <= dr <= 10:
            raise ValueError(f"drift_rounds must be an integer in [0, 10]. Got {dr!r}.")
        if check_finite_scalar("drift_knot_spacing_s", self.drift_knot_spacing_s) <= 0:
            raise ValueError(f"drift_knot_spacing_s must be > 0. Got {self.drift_knot_spacing_s}.")
        for name in ("creep_smoothing_nm", "weight_smoothing_nm", "drift_smoothing",
                     "drift_anchor"):  # fmt: skip
            if check_finite_scalar(name, getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0. Got {getattr(self, name)}.")
        off = check_finite_scalar("extra_line_offset_nm", self.extra_line_offset_nm)
        if off <= 0:
            raise ValueError(f"extra_line_offset_nm must be > 0. Got {off}.")
        speed = self.calibration_speed_nm_per_s
        if speed is not None and (
            isinstance(speed, bool) or check_finite_scalar("calibration_speed_nm_per_s", speed) <= 0
        ):
            raise ValueError(f"calibration_speed_nm_per_s must be None or > 0. Got {speed!r}.")
        self._check_rls()

    def _check_rls(self) -> None:
        """The RLS settings are RLSSettings (``rls_continue`` and ``rls_start`` may be
        ``None``) whose bounds leave the creep spectrum's poles where they are."""
        for name in ("rls_settings", "rls_continue", "rls_start"):
            v = getattr(self, name)
            if not isinstance(v, RLSSettings) and not (name != "rls_settings" and v is None):
                raise TypeError(f"{name} must be RLSSettings. Got {type(v).__name__}.")
        tau_lo = float(self.creep_tau_range_s[0])
        for name in ("rls_settings", "rls_continue", "rls_start"):
            v = getattr(self, name)
            if v is not None and v.min_time_constant_s > tau_lo:
                raise ValueError(
                    f"{name}.min_time_constant_s ({v.min_time_constant_s} s) is above the "
                    f"creep spectrum's shortest time constant ({tau_lo} s): the RLS's bounds "
                    "would move the creep poles it holds. Lower it to at most the spectrum's."
                )
