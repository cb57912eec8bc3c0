"""Sensorless identification of one scanner axis through the instrument interface.

The procedure of Section V (steps 1-3), with the AFM as its own position sensor:

1. an overview image of the working area; the line crossing the most particles
   (:func:`~piezocomp.identification.line_choice.choose_line`);
2. the identification waveform of Fig. 7a along that line
   (:func:`~piezocomp.identification.waveforms.identification_waveform`), run once, after
   settling on the line and followed by a check of the line
   (:mod:`piezocomp.identification.acquisition`: the acquisition helpers live there);
3. part A: the averaged steady forward and backward traces, their particle peaks (sub-sample)
   paired across the traces, the symmetric loop ``f_a`` (eqs 21-23) and ``h(y)``
   (:class:`~piezocomp.identification.profile.HeightProfile`);
4. part B (and A): the recursive estimator of eqs (16)-(20)
   (:func:`~piezocomp.identification.rls.rls`) started from a model whose steady loop
   matches ``f_a``, then the batch refinement of the same prediction error
   (:func:`~piezocomp.identification.batch.refine` with ``output = h``);
5. model orders chosen by the height prediction error on a held-out part of the record
   (:func:`~piezocomp.identification.orders.select_orders`) unless fixed.

Only ``Instrument`` methods are used. The y axis uses the same procedure with the axes
swapped (columns of the overview, the waveform on the y command).

:func:`score_on_truth` is separate: it runs a fresh validation trajectory on a *virtual* AFM
and compares the model's prediction with the true extension from the simulator's ground
truth door. Identification never calls it.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.acquisition import (
    LineStability,
    cycle_pairs,
    line_stability,
    settle_on_line,
)
from piezocomp.identification.batch import RefineResult
from piezocomp.identification.diagnostics import ExcitationWarning, check_excitation
from piezocomp.identification.estimation import (
    DEFAULT_CREEP_TAU_RANGE_S,
    estimate,
    heldout_rms,
    predicted_forward_trace,
    record_state,
)
from piezocomp.identification.line_choice import LineChoice, choose_line
from piezocomp.identification.loop import SymmetricLoop
from piezocomp.identification.orders import OrderSelection
from piezocomp.identification.peaks import Peaks, find_peaks, pair_peaks
from piezocomp.identification.pi_loop import PILoop
from piezocomp.identification.profile import HeightProfile
from piezocomp.identification.rls import RLSResult, RLSSettings
from piezocomp.identification.waveforms import (
    IdentificationWaveform,
    identification_waveform,
    validation_waveform,
)
from piezocomp.instrument import Instrument, ScanCalibration, ScanImage
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.operators import _kernels

__all__ = [
    "AxisIdentification",
    "LoopEstimate",
    "SensorlessConfig",
    "aligned_pairs",
    "estimate_loop",
    "frame_map",
    "guided_pairs",
    "identify_axis",
    "initial_from_loop",
    "score_on_truth",
    "thresholds_over_span",
    "unmapped",
]


@dataclass(frozen=True)
class SensorlessConfig:
    """Settings of the sensorless procedure (all lengths nm of command, times s).

    Parameters
    ----------
    center_nm : tuple of float
        Centre of the working area (x, y).
    span_nm : float
        Side of the working area; the identification line spans it.
    speed_nm_per_s : float
        Ramp speed of the identification waveform (and the overview's fast-axis speed).
    overview_pixels : int
        Pixels per side of the overview image.
    degree : int
        Degree of ``f_a`` (>= 5 in the paper).
    min_prominence_nm : float
        Smallest particle prominence.
    n_steady, n_decaying, n_random, max_dwell_s
        Shape of the waveform (:func:`identification_waveform`).
    orders : sequence of (n_play, n_creep)
        Candidate orders; a single pair fixes them. The ``n_creep`` creep time constants are
        placed log-uniformly over ``creep_tau_range_s``
        (:func:`~piezocomp.identification.estimation.creep_spectrum`).
    holdout_fraction : float
        Fraction of the record (its end) held out to choose the orders.
    rls_settings : RLSSettings
        Default ``alpha="unit", p0=0.1, passes=20, k0=3000`` (covariance reset every 3000
        samples; 20 passes predicted the held-out heights better than 6 on cpr5 seeds 1-3)
        with the creep poles held (a fixed spectrum, only the gains estimated) and the
        thresholds held where
        :func:`thresholds_over_span` puts them (``free`` without ``"r"``): on the cpr5
        virtual AFM (seeds 1-3) this predicted the held-out heights and the true extension
        better than the paper's ``alpha(k)`` of eq (20) and than adapting the thresholds by
        eq (19) (both available: ``RLSSettings(alpha="paper", free=GROUPS)``); with few
        particles on the line, adapted thresholds overfit the flanks the heights inform.
    refine_max_nfev : int
        Evaluations allowed to the batch refinement (0: skip it).
    refine_free : tuple of str
        Parameter groups the batch refinement adjusts (eq 15 groups); thresholds and creep
        poles held by default, as for the RLS.
    reindex_rounds : int
        Rounds of re-indexing ``h(y)`` by the refined model's own prediction of part A and
        refining again (:func:`~piezocomp.identification.estimation.model_profile`; 0: the
        loop's ``h`` throughout, as in the paper). The batch model's frame map then uses the
        model's prediction of part A's forward trace, not ``f_a``.
    creep_tau_range_s : (float, float)
        Shortest and longest creep time constant (s) of the creep spectrum.
    creep_start : {"centre", "first-command"}
        Creep states of the model before the record's first sample: at the centre of the
        line (the area has been scanned about it, overview and line search, for longer than
        most creep time constants) or at the first command (:meth:`ModelState.at_rest`).
        The state is kept in :attr:`AxisIdentification.creep_start_nm`.
    calibration_span_nm : float, optional
        ``None`` (the paper): the scale of ``y`` is fixed by the calibration condition of
        Section IV on the working span. Otherwise, steady cycles over this span (centred on
        the line's centre; e.g. the full range, where the nominal sensitivity was
        calibrated) give a second loop whose calibration condition holds; the estimation runs
        in the working loop's frame as in the paper and the models are then mapped onto the
        calibration frame by the affine :func:`frame_map` (which fixes the scale that the
        working span's calibration condition gets wrong when the small-signal sensitivity
        differs from the nominal one).
    calibration_speed_nm_per_s : float, optional
        Ramp speed of the calibration cycles. ``None`` (default): the speed of the
        instrument's calibration record (its ``calibration_scan``,
        :class:`~piezocomp.instrument.ScanCalibration`), where the calibration condition
        holds (creep makes a steady cycle's width depend on its speed); if the instrument
        states none, 1000 nm/s and a finding that the scale holds only if the scanner was
        calibrated at that speed.
    calibration_degree : int
        Degree of the calibration loop polynomial.
    calibration_loop : {"pi", "pi-loo", "polynomial"}
        Which calibration loop :func:`frame_map` uses: a Prandtl-Ishlinskii branch
        (:class:`PILoop`, non-negative weights) fitted to the calibration cycles' pairs with
        its ridge chosen by the discrepancy principle (``"pi"``, default,
        :func:`_fit_pi_loop`; biased towards a straighter loop: its central slope was
        0.6-2 % too low on cpr5, see docs/identification.md) or by leave-one-pair-out error
        (``"pi-loo"``, :func:`_fit_pi_loop_loo`: less biased on cpr5 but far more variable,
        and not less biased on an exact PI loop); or the degree-``calibration_degree``
        polynomial of eq (23) (``"polynomial"``).
    overview_shifts : tuple of float
        Slow-axis shifts (in spans) of the overview images tried in turn until one holds a
        line with more than ``degree`` particles (the line need only span the working area
        along its own axis); if none does, the best line with ``min_line_particles`` is
        taken (the loop fit pools the pairs of the lines scanned near it).
    line_search_nm, line_search_step_nm : float
        Slow-axis neighbourhood searched, and its step, to get back onto a line with enough
        particles near the chosen one (see :func:`_locate_line`).
    settle_s : float
        Wait (s) after the large slow-axis move to the start of the line search, so that the
        slow axis' creep (logarithmic: fastest just after a step) has slowed before the tip
        has to stay on a line one particle wide.
    line_settle_s : float
        Time (s) spent scanning the located line's steady cycle before the identification
        record (:func:`~piezocomp.identification.acquisition.settle_on_line`): the slow axis'
        creep after the line search slows down (rate ~ 1/t) while the fast axis stays in its
        steady cycle, so the tip moves less across the line during the record. Default 600 s:
        on cpr5 (seed 1) the true slow-axis excursion during the record falls from 4.0 nm to
        0.9 nm (0.4 nm after 1200 s); see docs/identification.md.
    relocate_search_nm : float
        If the last settling cycle no longer pairs ``min_line_particles`` particles (the tip
        drifted off the line), the line is searched again over this neighbourhood of the
        slow command (:func:`_locate_line`).
    check_cycles : int
        Steady cycles of the line scanned right after the record; their averaged forward
        trace is compared with part A's
        (:func:`~piezocomp.identification.acquisition.line_stability`), and a profile change
        beyond ``check_tolerance_nm`` (RMS, above the cycle-to-cycle repeatability) is
        reported as a finding. 0 skips the check.
    check_tolerance_nm : float
        Tolerance of that check.
    min_line_particles : int
        Particles the identification line itself must pair (its ``h(y)`` carries the
        information of eqs 17-18).
    loop_pairs_factor : int
        The loop fit (23) uses the pairs of every line scanned while locating the line; at
        least ``loop_pairs_factor * (degree + 1)`` of them are collected.
    seed : int
        Randomness of the waveform.
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
    orders: tuple[tuple[int, int], ...] = ((16, 19), (32, 19))
    holdout_fraction: float = 0.25
    rls_settings: RLSSettings = field(
        default_factory=lambda: RLSSettings(
            alpha="unit", p0=0.1, passes=20, k0=3000, free=("c", "a", "w", "y0")
        )
    )
    refine_max_nfev: int = 40
    refine_free: tuple[str, ...] = ("c", "a", "w", "y0")
    reindex_rounds: int = 4
    creep_tau_range_s: tuple[float, float] = DEFAULT_CREEP_TAU_RANGE_S
    creep_start: str = "centre"
    calibration_span_nm: float | None = None
    calibration_speed_nm_per_s: float | None = None
    calibration_degree: int = 9
    calibration_loop: str = "pi"
    line_search_nm: float = 200.0
    overview_shifts: tuple[float, ...] = (0.0, 1.0, -1.0, 2.0, -2.0)
    line_search_step_nm: float = 4.0
    settle_s: float = 0.0
    line_settle_s: float = 600.0
    relocate_search_nm: float = 40.0
    check_cycles: int = 4
    check_tolerance_nm: float = 1.0
    min_line_particles: int = 4
    loop_pairs_factor: int = 3
    seed: int = 0

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
        if isinstance(self.reindex_rounds, bool) or self.reindex_rounds not in range(0, 101):
            raise ValueError(
                f"reindex_rounds must be an integer in [0, 100]. Got {self.reindex_rounds!r}."
            )
        if self.span_nm <= 0 or self.speed_nm_per_s <= 0:
            raise ValueError("span_nm and speed_nm_per_s must be > 0.")
        speed = self.calibration_speed_nm_per_s
        if speed is not None and (
            isinstance(speed, bool) or check_finite_scalar("calibration_speed_nm_per_s", speed) <= 0
        ):
            raise ValueError(f"calibration_speed_nm_per_s must be None or > 0. Got {speed!r}.")
        if self.calibration_loop not in ("pi", "pi-loo", "polynomial"):
            raise ValueError(
                "calibration_loop must be 'pi', 'pi-loo' or 'polynomial'. "
                f"Got {self.calibration_loop!r}."
            )
        if self.creep_start not in ("centre", "first-command"):
            raise ValueError(
                f"creep_start must be 'centre' or 'first-command'. Got {self.creep_start!r}."
            )


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


@dataclass(frozen=True)
class LoopEstimate:
    """Section IV on part A: the averaged traces, the paired peaks, ``f_a`` and ``h``."""

    u_forward_nm: NDArray[np.float64]
    forward_nm: NDArray[np.float64]
    u_backward_nm: NDArray[np.float64]
    backward_nm: NDArray[np.float64]
    u_ascending_peaks_nm: NDArray[np.float64]
    u_descending_peaks_nm: NDArray[np.float64]
    loop: SymmetricLoop
    profile: HeightProfile
    all_pairs: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...] = ()


def estimate_loop(
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    waveform: IdentificationWaveform,
    *,
    degree: int = 5,
    min_prominence_nm: float = 3.0,
    max_shift_nm: float | None = None,
    extra_peaks: Sequence[tuple[Peaks, Peaks]] = (),
) -> LoopEstimate:
    """Loop and ``h(y)`` from the steady cycles of part A (Section IV, eqs 21-23).

    Cycles 1.. of part A (the first settles the history) are averaged trace by trace; peaks
    are found with sub-sample precision on both averaged traces, paired (unpaired peaks are
    rejected) and fitted by :meth:`SymmetricLoop.from_line_pairs`, together with
    ``extra_pairs`` from other lines scanned with the same steady cycle, if any.

    Raises
    ------
    ValueError
        If fewer than ``degree + 1`` pairs are available in all (too few particles for the
        degree).
    """
    cycles = range(1, waveform.n_steady)
    u_f = u_nm[waveform.ascending(1)]
    u_b = u_nm[waveform.descending(1)]
    z_f = np.array([height_nm[waveform.ascending(c)] for c in cycles])
    z_b = np.array([height_nm[waveform.descending(c)] for c in cycles])
    f_mean, b_mean = z_f.mean(axis=0), z_b.mean(axis=0)
    step = abs(float(u_f[1] - u_f[0]))
    sep = max(2.0 * step, 5.0)
    pf = find_peaks(u_f, f_mean, min_prominence_nm=min_prominence_nm, min_separation_nm=sep)
    pb = find_peaks(u_b, b_mean, min_prominence_nm=min_prominence_nm, min_separation_nm=sep)
    span = waveform.u_max_nm - waveform.u_min_nm
    shift = 0.15 * span if max_shift_nm is None else max_shift_nm
    lines = [(pf, pb), *extra_peaks]
    paired = guided_pairs(lines, max_shift_nm=shift)
    n_line = paired[0][0].size
    n_total = sum(a.size for a, _ in paired)
    if n_line <= degree and n_total <= degree:
        raise ValueError(
            f"the line crosses too few particles for a loop of degree {degree}: "
            f"{len(pf)} peaks on the forward trace, {len(pb)} on the backward trace, "
            f"{n_line} pair up (and {n_total - n_line} pairs from other lines); eq (23) needs "
            f"more than {degree} pairs. Choose another line or lower the degree."
        )
    u_a = paired[0][0]
    u_d = paired[0][1]
    loop = _fit_loop(paired, waveform.u_min_nm, waveform.u_max_nm, degree)
    profile = HeightProfile.from_loop(loop, u_f, z_f)
    return LoopEstimate(u_f, f_mean, u_b, b_mean, u_a, u_d, loop, profile, tuple(paired))


def _most_regularised(
    fits: Sequence[Callable[[], Any]],
    paired: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    noise_nm: float,
) -> Any:
    """The discrepancy principle shared by the loop fits.

    ``fits`` build the same loop with increasing regularisation. Eq (23) determines the
    loop's width well but the odd part of ``f_a`` about the centre only weakly: with little
    regularisation the fit bends ``f_a`` to follow the noise of the peak positions (a
    residual far below that noise, a branch distorted by tens of nm). The loop kept is the
    most regularised one before the pair residual RMS first exceeds
    ``max(noise_nm, 2 * smallest residual)``; fits that fail (``ValueError``: e.g. an
    ``f_a`` that is not increasing) are skipped.
    """
    ua = np.concatenate([np.asarray(a, float) for a, _ in paired])
    ud = np.concatenate([np.asarray(d, float) for _, d in paired])
    results: list[tuple[float, Any]] = []
    errors = []
    for fit in fits:
        try:
            loop = fit()
        except ValueError as exc:
            errors.append(str(exc))
            continue
        results.append((float(np.sqrt(np.mean(loop.pair_residuals_nm(ua, ud) ** 2))), loop))
    if not results:
        raise ValueError(errors[-1])
    bound = max(noise_nm, 2.0 * min(r for r, _ in results))
    best = results[0][1]
    for res, loop in results:
        if res > bound:
            break
        best = loop
    return best


def _fit_loop(
    paired: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    u_min: float,
    u_max: float,
    degree: int,
    *,
    noise_nm: float = 0.5,
    rconds: Sequence[float] = (1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3),
) -> SymmetricLoop:
    """:meth:`SymmetricLoop.from_line_pairs` regularised as much as the pairs allow.

    The fit picks the least-curved solution among those the pairs do not tell apart,
    ``rcond`` deciding which; the largest ``rcond`` allowed by :func:`_most_regularised`.
    """
    fits = [
        partial(SymmetricLoop.from_line_pairs, paired, u_min, u_max, degree, rcond=rc)
        for rc in sorted(rconds)
    ]
    loop: SymmetricLoop = _most_regularised(fits, paired, noise_nm)
    return loop


def _fit_pi_loop(
    paired: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    u_min: float,
    u_max: float,
    *,
    noise_nm: float = 0.5,
    ridges: Sequence[float] = tuple(np.geomspace(0.01, 3.0, 11)),
) -> PILoop:
    """:meth:`PILoop.from_line_pairs` regularised as much as the pairs allow.

    The Prandtl-Ishlinskii structure (a convex ascending branch) narrows, but does not close,
    eq (23)'s blindness to odd distortions; the ridge on the hysteretic weights picks the
    loop: the largest ``ridge`` allowed by :func:`_most_regularised` (unregularised first).
    """
    fits = [
        partial(PILoop.from_line_pairs, paired, u_min, u_max, ridge=ridge)
        for ridge in (0.0, *sorted(ridges))
    ]
    loop: PILoop = _most_regularised(fits, paired, noise_nm)
    return loop


def _fit_pi_loop_loo(
    paired: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    u_min: float,
    u_max: float,
    *,
    ridges: Sequence[float] = (0.0, 0.003, 0.01, 0.02, 0.03, 0.055, 0.1, 0.2, 0.3),
) -> PILoop:
    """:meth:`PILoop.from_line_pairs` with the ridge of least leave-one-pair-out error.

    Each pair of eq (23) is predicted by the loop fitted to the others; the ridge whose
    prediction error (RMS of ``f_a(u_a) - f_d(u_d)`` over the left-out pairs) is smallest
    is refitted to all pairs. Unlike the discrepancy principle of :func:`_fit_pi_loop`,
    which takes the most regularised loop that still fits, this does not favour a
    straighter loop (whose central slope is too low).
    """
    ua = np.concatenate([np.asarray(a, float).ravel() for a, _ in paired])
    ud = np.concatenate([np.asarray(d, float).ravel() for _, d in paired])
    n = ua.size
    if n < 3:
        raise ValueError(f"a PI loop by leave-one-out needs at least 3 feature pairs. Got {n}.")
    best, best_err = 0.0, np.inf
    for ridge in ridges:
        err = np.empty(n)
        for i in range(n):
            keep = np.arange(n) != i
            fit = PILoop.from_line_pairs([(ua[keep], ud[keep])], u_min, u_max, ridge=ridge)
            err[i] = fit.pair_residuals_nm(ua[i : i + 1], ud[i : i + 1])[0]
        rms = float(np.sqrt(np.mean(err**2)))
        if rms < best_err:
            best, best_err = float(ridge), rms
    return PILoop.from_line_pairs([(ua, ud)], u_min, u_max, ridge=best)


def aligned_pairs(
    pf: Peaks,
    pb: Peaks,
    *,
    max_shift_nm: float,
    height_tolerance_nm: float = 1.5,
    min_shift_nm: float | None = None,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Order-preserving alignment of forward and backward peaks by their heights.

    The particles of a line appear in the same order on both traces, each with the same
    height, the forward one shifted by ``0 <= u_a - u_d <= max_shift_nm`` (the loop's width
    there). A dynamic programme (sequence alignment) finds the order-preserving matching with
    the most pairs (ties: closest heights) among height-consistent candidates; it does not
    assume one typical shift, so it works when the shift exceeds the particle spacing
    (large spans). ``min_shift_nm`` (default ``-0.02 max_shift_nm``) is the smallest shift.
    """
    f, b = pf.position_nm, pb.position_nm
    nf, nb = f.size, b.size
    shift = f[:, None] - b[None, :]
    dh = np.abs(pf.height_nm[:, None] - pb.height_nm[None, :])
    lo = -0.02 * max_shift_nm if min_shift_nm is None else min_shift_nm
    ok = (shift >= lo) & (shift <= max_shift_nm) & (dh <= height_tolerance_nm)
    gain = np.where(ok, 1.0 - 0.5 * dh / height_tolerance_nm, -np.inf)
    score = np.zeros((nf + 1, nb + 1))
    move = np.zeros((nf + 1, nb + 1), dtype=np.int8)  # 0 diag, 1 skip forward, 2 skip back
    for i in range(1, nf + 1):
        for j in range(1, nb + 1):
            best, mv = score[i - 1, j - 1] + gain[i - 1, j - 1], 0
            if score[i - 1, j] > best:
                best, mv = score[i - 1, j], 1
            if score[i, j - 1] > best:
                best, mv = score[i, j - 1], 2
            score[i, j] = best
            move[i, j] = mv
        move[i, 0] = 1
    move[0, 1:] = 2
    i, j = nf, nb
    rows, cols = [], []
    while i > 0 and j > 0:
        mv = move[i, j]
        if mv == 0:
            rows.append(i - 1)
            cols.append(j - 1)
            i, j = i - 1, j - 1
        elif mv == 1:
            i -= 1
        else:
            j -= 1
    return np.array(rows[::-1], dtype=np.intp), np.array(cols[::-1], dtype=np.intp)


def guided_pairs(
    lines: Sequence[tuple[Peaks, Peaks]],
    *,
    max_shift_nm: float,
    tolerance_nm: float = 3.0,
    height_tolerance_nm: float = 1.5,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Pair forward and backward peaks of several lines of one steady cycle (eq 23 pairs).

    The forward-backward shift of a particle is the loop's width where it sits: it varies
    along the line (from 0 at the ends to its largest in the middle), so one typical shift
    (:func:`pair_peaks`) mis-pairs neighbours, and on large spans the shift exceeds the
    particle spacing. Each line is aligned by :func:`aligned_pairs` (order and height);
    then a smooth shift model ``s(u_a)`` (robust polynomial of degree up to 4, pooled over
    the lines) rejects the pairs whose shift departs from it by more than
    ``max(tolerance_nm, 4 MAD)`` (mis-pairs).

    Returns
    -------
    list of (u_ascending, u_descending)
        One entry per line (possibly empty arrays).
    """
    per_line = []
    for pf, pb in lines:
        i, j = aligned_pairs(
            pf, pb, max_shift_nm=max_shift_nm, height_tolerance_nm=height_tolerance_nm
        )
        per_line.append((pf.position_nm[i], pb.position_nm[j]))
    ua = np.concatenate([a for a, _ in per_line]) if per_line else np.empty(0)
    sh = np.concatenate([a - d for a, d in per_line]) if per_line else np.empty(0)
    deg = min(4, np.unique(np.round(ua)).size - 2)
    if deg < 1:
        return per_line
    scale = max(float(np.max(np.abs(ua))), 1.0)
    keep = np.ones(ua.size, dtype=bool)
    for _ in range(4):  # fit, reject gross mis-pairs, refit
        coef = np.polyfit(ua[keep] / scale, sh[keep], deg)
        res = sh - np.polyval(coef, ua / scale)
        mad = 1.4826 * np.median(np.abs(res[keep] - np.median(res[keep])))
        new = np.abs(res) <= max(tolerance_nm, 4.0 * mad)
        if np.array_equal(new, keep) or np.unique(np.round(ua[new])).size <= deg:
            break
        keep = new
    out = []
    start = 0
    for a, d in per_line:
        k = keep[start : start + a.size]
        out.append((a[k], d[k]))
        start += a.size
    return out


def frame_map(
    working: LoopEstimate,
    calibration: LoopEstimate,
    *,
    window_nm: float,
    min_prominence_nm: float = 3.0,
    height_tolerance_nm: float = 4.0,
    inlier_nm: float = 3.0,
    max_inlier_nm: float = 9.0,
    alpha_range: tuple[float, float] = (0.5, 1.5),
    calibration_loop: SymmetricLoop | PILoop | None = None,
    working_positions: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
) -> tuple[float, float]:
    """Affine map ``Y = alpha y + beta`` from the working loop's frame to the calibration's.

    The same particles are seen on the forward traces of both (steady) cycles, at
    ``y = f_a(u)`` of the working loop and at ``Y = F_a(U)`` of the calibration loop, with
    about the same heights (within ``height_tolerance_nm``: the slow axis creeps across the
    line between the two records, which changes how high each particle appears). Every two
    height-compatible correspondences give a candidate map (``alpha`` in ``alpha_range``,
    ``|beta| <= window_nm``); the one most particles agree with
    (within ``inlier_nm``) is refitted by least squares on its inliers. If fewer than 3
    particles agree, the tolerance is widened step by step (``2 inlier_nm``, ``3 inlier_nm``,
    ... up to ``max_inlier_nm``): the working loop's ``f_a`` can be off by several nm in the
    middle of the span (eq 23 determines its odd part weakly), and on a line with only three
    or four particles one such particle left the map undetermined (cpr5 seed 2). A widened
    match must be unambiguous (no other map, ``alpha`` differing by more than 2 %, with as
    many inliers) and its particles' heights must agree within
    ``min(height_tolerance_nm, 2)``: three particles and a wide tolerance otherwise match
    a wrong map by chance among the many calibration particles. ``calibration_loop``
    (default ``calibration.loop``) is the loop that places the calibration particles, e.g.
    the :class:`PILoop` of :func:`_fit_pi_loop`. ``working_positions`` (default
    ``working.loop.ascending``) places the working line's particles from their commands on
    the forward trace, e.g. a model's prediction of that trace (the model's own frame).

    Raises
    ------
    ValueError
        If fewer than 3 particles match.
    """

    def peaks(le: LoopEstimate, place: Callable[[Any], Any]) -> Peaks:
        p = find_peaks(le.u_forward_nm, le.forward_nm, min_prominence_nm=min_prominence_nm)
        y = np.asarray(place(p.position_nm), dtype=float)
        return Peaks(y, p.height_nm, p.prominence_nm)

    cal_loop = calibration.loop if calibration_loop is None else calibration_loop
    place = working.loop.ascending if working_positions is None else working_positions
    pw, pc = peaks(working, place), peaks(calibration, cal_loop.ascending)
    y, hy = pw.position_nm, pw.height_nm
    Y, hY = pc.position_nm, pc.height_nm
    if y.size < 3 or Y.size < 3:
        raise ValueError(
            f"too few particles to map the frames: {y.size} on the working line, {Y.size} on "
            "the calibration cycles (need 3 each)."
        )
    close = np.abs(hy[:, None] - hY[None, :]) <= height_tolerance_nm  # same particle?
    tols = inlier_nm * np.arange(1, max(1, int(max_inlier_nm / inlier_nm + 1e-9)) + 1)
    strict = np.abs(hy[:, None] - hY[None, :]) <= min(height_tolerance_nm, 2.0)
    for k, tol in enumerate(tols):
        ok = close if k == 0 else strict
        n, alpha, beta, rival = _ransac_map(y, Y, ok, tol, alpha_range, window_nm)
        if k > 0 and n >= 3 and rival:
            n = 0  # ambiguous at a widened tolerance: refuse
            break
        if n >= 3:
            close = ok
            break
    if n < 3:
        raise ValueError(
            f"only {n} particles of the working line were found on the calibration cycles "
            f"within {tols[-1]:.1f} nm (need 3 to map the frames)."
        )
    d = np.abs(alpha * y[:, None] + beta - Y[None, :])
    d = np.where(close, d, np.inf)
    j = d.argmin(axis=1)
    inl = d[np.arange(y.size), j] <= tol
    coef = np.polyfit(y[inl], Y[j[inl]], 1)
    return float(coef[0]), float(coef[1])


def _ransac_map(
    y: NDArray[np.float64],
    Y: NDArray[np.float64],
    close: NDArray[np.bool_],
    inlier_nm: float,
    alpha_range: tuple[float, float],
    window_nm: float,
) -> tuple[int, float, float, bool]:
    """Best affine map of :func:`frame_map` at one inlier tolerance: (inliers, alpha, beta,
    whether another map with ``alpha`` more than 2 % away has as many inliers)."""
    best: tuple[int, float, float, float] = (0, np.inf, 1.0, 0.0)
    tops: list[tuple[int, float]] = []
    # Every two height-compatible correspondences define a candidate map; keep the one
    # that the most particles agree with (RANSAC over all pairs, exhaustive: few peaks).
    for i1 in range(y.size):
        for i2 in range(i1 + 1, y.size):
            for j1 in np.flatnonzero(close[i1]):
                for j2 in np.flatnonzero(close[i2]):
                    if j2 <= j1:
                        continue
                    alpha = (Y[j2] - Y[j1]) / (y[i2] - y[i1])
                    if not alpha_range[0] <= alpha <= alpha_range[1]:
                        continue
                    beta = Y[j1] - alpha * y[i1]
                    if abs(beta) > window_nm:
                        continue
                    d = np.abs(alpha * y[:, None] + beta - Y[None, :])
                    d = np.where(close, d, np.inf).min(axis=1)
                    inl = d <= inlier_nm
                    n = int(inl.sum())
                    r = float(np.sum(d[inl] ** 2))
                    tops.append((n, alpha))
                    if n > best[0] or (n == best[0] and r < best[1]):
                        best = (n, r, alpha, beta)
    rival = any(n == best[0] and abs(a / best[2] - 1.0) > 0.02 for n, a in tops)
    return best[0], best[2], best[3], rival


@dataclass(frozen=True)
class AxisIdentification:
    """Everything the sensorless identification of one axis produced.

    Attributes
    ----------
    axis : str
    line : LineChoice
    waveform : IdentificationWaveform
    u_nm, height_nm : ndarray
        The identification record (command of the axis, measured heights).
    history_u_nm : ndarray
        Every command of the axis from the start of the identification record on (the
        record, then the calibration cycles and moves if any), for continuing a model.
    loop : LoopEstimate
        Section IV on the working span (part A).
    calibration : LoopEstimate or None
        Section IV on the calibration cycles (``calibration_span_nm``), if any.
    frame_map : (float, float)
        ``(alpha, beta)`` of :func:`frame_map` for the batch model (``(1, 0)`` without
        calibration cycles); with ``reindex_rounds > 0`` it places the working line's
        particles by the batch model's own prediction of part A.
    profile : HeightProfile
        The loop's ``h(y)`` (``y = f_a(u)``, Section IV) used by the RLS (working frame).
    orders : OrderSelection
        Candidates tried and the chosen orders (held-out height RMS, nm).
    rls : RLSResult
        RLS of the chosen orders (Fig. 7b traces).
    rls_model, batch_model : ScannerModel
        The estimates, mapped by ``frame_map`` onto the calibration frame if there is one
        (``rls.model`` stays in the working frame).
    refine : RefineResult or None
    fit_mask : ndarray of bool
        Samples used for fitting (the rest is held out).
    heldout_rms_nm : dict
        Held-out height RMS (nm) of the starting model (``"initial"``), ``"rls"`` and
        ``"batch"``.
    findings : tuple of str
        Excitation diagnostics, and a note if the calibration cycles could not be used
        (also issued as :class:`ExcitationWarning`).
    timing_s : dict
        Computing time of each stage.
    line_stability : LineStability or None
        The line's profile change over the record (``config.check_cycles``), if checked.
    creep_start_nm : float or None
        Creep states assumed before the record (:meth:`initial_state`).
    batch_profile : HeightProfile or None
        The ``h(y)`` the batch model was refined with (``profile`` re-indexed by the model,
        ``config.reindex_rounds``); ``None`` means ``profile``.
    rls_frame_map : (float, float) or None
        ``(alpha, beta)`` of the RLS model (the loop's frame); ``None`` means ``frame_map``.
    """

    axis: str
    line: LineChoice
    waveform: IdentificationWaveform
    overview: ScanImage
    u_nm: NDArray[np.float64]
    height_nm: NDArray[np.float64]
    sample_period_s: float
    history_u_nm: NDArray[np.float64]
    loop: LoopEstimate
    calibration: LoopEstimate | None
    frame_map: tuple[float, float]
    profile: HeightProfile
    orders: OrderSelection
    rls: RLSResult
    rls_model: ScannerModel
    batch_model: ScannerModel
    refine: RefineResult | None
    fit_mask: NDArray[np.bool_]
    heldout_rms_nm: dict[str, float]
    findings: tuple[str, ...]
    timing_s: dict[str, float]
    line_stability: LineStability | None = None
    creep_start_nm: float | None = None
    batch_profile: HeightProfile | None = None
    rls_frame_map: tuple[float, float] | None = None

    def initial_state(self, model: ScannerModel) -> ModelState:
        """The state the estimation assumed before the record's first sample (any frame:
        states are in nm of command): play operators at rest at the first command, creep
        states at ``creep_start_nm``
        (:func:`~piezocomp.identification.estimation.record_state`)."""
        return record_state(model, float(self.u_nm[0]), self.creep_start_nm)

    def predict_heights(
        self, model: ScannerModel, profile: HeightProfile | None = None
    ) -> NDArray[np.float64]:
        """``h(y_hat)`` of a working-frame model over the identification record (eqs 14, 16),
        through ``profile`` (default the loop's :attr:`profile`)."""
        y, _ = simulate(model, self.u_nm, self.sample_period_s, self.initial_state(model))
        return np.asarray((self.profile if profile is None else profile)(y))

    def working_models(self) -> dict[str, tuple[ScannerModel, HeightProfile]]:
        """The RLS and batch models in their working frames, each with the ``h(y)`` it was
        estimated with (``{"rls": (model, profile), "batch": (model, profile)}``)."""
        rls_map = self.frame_map if self.rls_frame_map is None else self.rls_frame_map
        batch_prof = self.profile if self.batch_profile is None else self.batch_profile
        return {
            "rls": (unmapped(self.rls_model, *rls_map), self.profile),
            "batch": (unmapped(self.batch_model, *self.frame_map), batch_prof),
        }


def _mapped(model: ScannerModel, alpha: float, beta: float) -> ScannerModel:
    """The model whose output is ``alpha y + beta`` (gains scaled, thresholds unchanged)."""
    if alpha == 1.0 and beta == 0.0:
        return model
    return ScannerModel(
        offset_nm=alpha * model.offset_nm + beta,
        gain=alpha * model.gain,
        thresholds_nm=model.thresholds_nm,
        weights=alpha * model.weights,
        creep_time_constants_s=model.creep_time_constants_s,
        creep_gains=alpha * model.creep_gains,
    )


def unmapped(model: ScannerModel, alpha: float, beta: float) -> ScannerModel:
    """Inverse of the frame map: the model in the working loop's frame."""
    return _mapped(model, 1.0 / alpha, -beta / alpha)


def _command(axis: str, u: NDArray[np.float64], slow: float) -> NDArray[np.float64]:
    cmd = np.empty((u.size, 2))
    cmd[:, 0 if axis == "x" else 1] = u
    cmd[:, 1 if axis == "x" else 0] = slow
    return cmd


def _heldout_rms(profile: HeightProfile, model: ScannerModel, u, z, T, mask) -> float:
    return heldout_rms(profile, model, u, z, T, mask)


DEFAULT_CALIBRATION_SPEED_NM_PER_S = 1000.0
"""Speed of the calibration cycles when neither the configuration nor the instrument
states one."""


def _calibration_speed(cfg: SensorlessConfig, instrument: Any, notes: list[str]) -> float:
    """The calibration cycles' speed: the configuration's, else the instrument's calibration
    record (``calibration_scan``), else the default with a note."""
    if cfg.calibration_speed_nm_per_s is not None:
        return float(cfg.calibration_speed_nm_per_s)
    scan = getattr(instrument, "calibration_scan", None)
    if isinstance(scan, ScanCalibration):
        return scan.speed_nm_per_s
    notes.append(
        "the instrument states no calibration scan: the calibration cycles ran at "
        f"{DEFAULT_CALIBRATION_SPEED_NM_PER_S:g} nm/s, and the model's scale holds only if "
        "the scanner was calibrated at that speed (set calibration_speed_nm_per_s)"
    )
    return DEFAULT_CALIBRATION_SPEED_NM_PER_S


def _creep_start(cfg: SensorlessConfig, wf: IdentificationWaveform) -> float | None:
    """Creep states before the record: the line's centre (``"centre"``: the area was scanned
    about it for longer than most creep time constants) or the first command."""
    return 0.5 * (wf.u_min_nm + wf.u_max_nm) if cfg.creep_start == "centre" else None


def _overview_and_line(
    instrument: Instrument, cfg: SensorlessConfig, axis: str, line_rate: float
) -> tuple[ScanImage, LineChoice]:
    """Overview images of the working span, shifted along the slow axis by
    ``cfg.overview_shifts`` spans in turn, until one holds a line with enough particles."""
    cx, cy = cfg.center_nm
    errors = []
    images = []
    for shift in cfg.overview_shifts:
        d = shift * cfg.span_nm
        centre = (cx, cy + d) if axis == "x" else (cx + d, cy)
        lo = (centre[1] if axis == "x" else centre[0]) - cfg.span_nm / 2
        if abs(lo) > instrument.range_nm / 2 or abs(lo + cfg.span_nm) > instrument.range_nm / 2:
            continue
        image = instrument.scan_image(centre, cfg.span_nm, cfg.overview_pixels, line_rate)
        images.append(image)
        try:
            return image, choose_line(
                image,
                degree=cfg.degree,
                axis=axis,
                min_prominence_nm=cfg.min_prominence_nm,
                max_shift_nm=0.15 * cfg.span_nm,
            )
        except ValueError as exc:
            errors.append(f"overview at {centre}: {exc}")
    # No line crosses more than `degree` particles: the loop fit pools the pairs of many
    # lines (see _locate_line), so a line with `min_line_particles` particles will do.
    for image in images:
        try:
            return image, choose_line(
                image,
                degree=cfg.min_line_particles - 1,
                axis=axis,
                min_prominence_nm=cfg.min_prominence_nm,
                max_shift_nm=0.15 * cfg.span_nm,
            )
        except ValueError as exc:
            errors.append(str(exc))
    raise ValueError("; ".join(errors) if errors else "no overview fits inside the range.")


def _locate_line(
    instrument: Instrument,
    cfg: SensorlessConfig,
    axis: str,
    line: LineChoice,
    wf: IdentificationWaveform,
    speed: float,
    *,
    accept_best: bool = False,
) -> tuple[float, int, list[tuple[Peaks, Peaks]]]:
    """Get the tip back onto a line crossing enough particles, collecting loop pairs.

    With ``accept_best`` (re-locating a line lost while settling), a search that meets no
    line satisfying every requirement returns to the line that paired the most particles if
    it paired ``min_line_particles`` (approached from below again, as in the search).

    The slow axis has its own hysteresis and creep (tens of nm after the overview), so
    returning to the overview row's command does not return to the same true row, and
    particles are ~15 nm wide. From ``line_search_nm`` below the row's command, single full
    cycles of the line are scanned at increasing slow commands (steps of
    ``line_search_step_nm``; the slow axis only ascends, as in the raster) until one pairs
    at least ``min_line_particles`` particles over half the span and the lines scanned so far
    have given more than ``loop_pairs_factor * (degree + 1)`` pairs; the tip stays there.
    Every scanned line runs the same fast-axis cycle as part A (continuous cycling, so the
    same steady loop), so its paired peaks are equations (23) of that loop too
    (:meth:`SymmetricLoop.from_line_pairs`). Instrument calls only.

    Returns
    -------
    slow_nm : float
        The slow-axis command of the line found.
    n_pairs : int
        Particles paired on it.
    peaks : list of (Peaks, Peaks)
        Forward and backward peaks of every line scanned.
    """
    m = wf.half_cycle_samples
    cycle = wf.u_nm[: 2 * m + 1]
    k = 0 if axis == "x" else 1
    lo = line.slow_nm - cfg.line_search_nm
    hi = line.slow_nm + cfg.line_search_nm
    limit = instrument.range_nm / 2
    lo, hi = max(lo, -limit), min(hi, limit)

    def go(slow: float) -> None:
        xy = (wf.u_nm[0], slow) if axis == "x" else (slow, wf.u_nm[0])
        instrument.move_to(xy[0], xy[1], speed)

    go(lo)
    if cfg.settle_s > 0:
        instrument.wait(cfg.settle_s)
    best = (-1, lo)
    pairs: list[tuple[Peaks, Peaks]] = []
    n_total = 0
    need = cfg.loop_pairs_factor * (cfg.degree + 1)
    for slow in np.arange(lo, hi + 1e-9, cfg.line_search_step_nm):
        go(float(slow))
        rec = instrument.run(_command(axis, cycle, float(slow)))
        u = rec.command_nm[:, k]
        z = rec.height_nm
        pf = find_peaks(u[: m + 1], z[: m + 1], min_prominence_nm=cfg.min_prominence_nm)
        pb = find_peaks(u[m:], z[m:], min_prominence_nm=cfg.min_prominence_nm)
        i_f, _ = pair_peaks(pf.position_nm, pb.position_nm, max_shift_nm=0.15 * cfg.span_nm)
        n = int(i_f.size)
        pairs.append((pf, pb))
        n_total += n
        spread = float(np.ptp(pf.position_nm[i_f])) if n > 1 else 0.0
        if n > best[0]:
            best = (n, float(slow))
        if n >= cfg.min_line_particles and spread >= 0.5 * cfg.span_nm and n_total > need:
            return float(slow), n, pairs
    if accept_best and best[0] >= cfg.min_line_particles:
        go(lo)
        go(best[1])
        return best[1], best[0], pairs
    raise ValueError(
        f"no line between slow commands {lo:.1f} and {hi:.1f} nm near the chosen overview line "
        f"pairs at least min_line_particles = {cfg.min_line_particles} particles over half the "
        f"span with more than {need} pairs collected (best line: {best[0]} at "
        f"{best[1]:.1f} nm; {n_total} pairs). Choose another area or lower the requirements."
    )


def identify_axis(
    instrument: Instrument,
    config: SensorlessConfig | None = None,
    axis: str = "x",
) -> AxisIdentification:
    """Identify the model of one axis with the AFM as its own sensor (Sections III.C-V).

    Steps: overview image(s) and line choice (Sec. V step 1); line search back onto a line
    with enough particles, collecting loop pairs (:func:`_locate_line`); optionally the
    calibration cycles (``config.calibration_span_nm``); the identification waveform of
    Fig. 7a; the loop (eqs 21-23) and ``h(y)`` from part A; for each candidate order, RLS
    (eqs 16-20) from a start fitted to the loop, then the batch refinement; the orders with
    the best held-out height prediction (:func:`select_orders`); finally the models mapped
    onto the calibration frame (if any). Only ``instrument``'s public interface is used.

    Parameters
    ----------
    instrument : Instrument
        Any instrument (virtual or real); only its public interface is used.
    config : SensorlessConfig, optional
    axis : {"x", "y"}

    Returns
    -------
    AxisIdentification
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y'. Got {axis!r}.")
    cfg = SensorlessConfig() if config is None else config
    T = float(instrument.sample_period_s)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    cx, cy = cfg.center_nm
    speed = min(cfg.speed_nm_per_s, float(instrument.max_speed_nm_per_s))
    line_rate = speed / (2.0 * cfg.span_nm)
    overview, line = _overview_and_line(instrument, cfg, axis, line_rate)
    cx, cy = (cx, overview.y_nm.mean()) if axis == "x" else (overview.x_nm.mean(), cy)
    center_line = cx if axis == "x" else cy
    wf = identification_waveform(
        center_line,
        cfg.span_nm,
        speed,
        T,
        n_steady=cfg.n_steady,
        n_decaying=cfg.n_decaying,
        n_random=cfg.n_random,
        max_dwell_s=cfg.max_dwell_s,
        rng=cfg.seed,
    )
    slow, _, search_pairs = _locate_line(instrument, cfg, axis, line, wf, speed)
    line = replace(line, slow_nm=slow)
    acquisition_notes: list[str] = []
    srec = settle_on_line(
        instrument, axis, wf.u_nm[: 2 * wf.half_cycle_samples + 1], slow, cfg.line_settle_s
    )
    lost = srec is not None and (
        cycle_pairs(
            srec.command_nm[:, 0 if axis == "x" else 1],
            srec.height_nm,
            wf.half_cycle_samples,
            min_prominence_nm=cfg.min_prominence_nm,
            max_shift_nm=0.15 * cfg.span_nm,
        )
        < cfg.min_line_particles
    )
    if lost:
        # The line was lost while settling (thermal drift): find it again close by.
        near = replace(cfg, line_search_nm=cfg.relocate_search_nm, loop_pairs_factor=0)
        try:
            slow, _, more = _locate_line(instrument, near, axis, line, wf, speed, accept_best=True)
        except ValueError as exc:
            acquisition_notes.append(
                f"the tip left the line while settling and the line was not found again "
                f"({exc}); the record runs at the settled slow command"
            )
            more = []
        search_pairs = [*search_pairs, *more]
        line = replace(line, slow_nm=slow)
    k = 0 if axis == "x" else 1
    timing["acquisition_setup"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    record = instrument.run(_command(axis, wf.u_nm, line.slow_nm))
    timing["acquisition"] = time.perf_counter() - t1
    u = np.ascontiguousarray(record.command_nm[:, k], dtype=float)
    z = np.ascontiguousarray(record.height_nm, dtype=float)
    history = [u]
    stability = None
    if cfg.check_cycles > 0:
        # The line again, at once (before the calibration cycles): has its profile changed?
        m2 = 2 * wf.half_cycle_samples
        chk = np.concatenate([wf.u_nm[:1], *([wf.u_nm[1 : m2 + 1]] * cfg.check_cycles)])
        crec_chk = instrument.run(_command(axis, chk, line.slow_nm))
        history.append(crec_chk.command_nm[:, k])
        asc = [slice(m2 * c, m2 * c + wf.half_cycle_samples + 1) for c in range(cfg.check_cycles)]
        stability = line_stability(
            u[wf.ascending(1)],
            np.array([z[wf.ascending(c)] for c in range(1, wf.n_steady)]),
            chk[asc[0]],
            np.array([crec_chk.height_nm[a] for a in asc[1:] or asc]),
            min_prominence_nm=cfg.min_prominence_nm,
        )
    calibration = None
    if cfg.calibration_span_nm is not None:
        # After the identification record (which must follow the line search at once: the
        # slow axis creeps off a line a particle wide within seconds).
        cal_speed = min(
            _calibration_speed(cfg, instrument, acquisition_notes),
            float(instrument.max_speed_nm_per_s),
        )
        cwf = identification_waveform(
            center_line, cfg.calibration_span_nm, cal_speed, T, n_steady=cfg.n_steady,
            n_decaying=0, n_random=0,
        )  # fmt: skip
        go = (cwf.u_nm[0], slow) if axis == "x" else (slow, cwf.u_nm[0])
        history.append(instrument.move_to(go[0], go[1], cal_speed).command_nm[:, k])
        crec = instrument.run(_command(axis, cwf.u_nm, slow))
        history.append(crec.command_nm[:, k])
        calibration = estimate_loop(
            np.ascontiguousarray(crec.command_nm[:, k]),
            np.ascontiguousarray(crec.height_nm),
            cwf,
            degree=cfg.calibration_degree,
            min_prominence_nm=cfg.min_prominence_nm,
        )

    t2 = time.perf_counter()
    loop = estimate_loop(
        u,
        z,
        wf,
        degree=cfg.degree,
        min_prominence_nm=cfg.min_prominence_nm,
        extra_peaks=search_pairs,
    )
    profile = loop.profile
    alpha, beta = 1.0, 0.0
    notes: list[str] = list(acquisition_notes)
    if stability is not None and (text := stability.finding(cfg.check_tolerance_nm)):
        notes.append(text)
    calibration_pi = None
    if calibration is not None and cfg.calibration_loop in ("pi", "pi-loo"):
        fit_pi = _fit_pi_loop if cfg.calibration_loop == "pi" else _fit_pi_loop_loo
        calibration_pi = fit_pi(
            calibration.all_pairs, calibration.loop.u_min_nm, calibration.loop.u_max_nm
        )

    def mapped_frame(positions: Any = None) -> tuple[float, float]:
        assert calibration is not None
        return frame_map(
            loop,
            calibration,
            window_nm=0.3 * cfg.span_nm,
            min_prominence_nm=cfg.min_prominence_nm,
            calibration_loop=calibration_pi,
            working_positions=positions,
        )

    if calibration is not None:
        try:
            alpha, beta = mapped_frame()
        except ValueError as exc:
            calibration = None
            notes.append(
                f"the calibration cycles could not be used ({exc}); the model keeps the "
                "working span's calibration condition (Section IV), whose scale may be off"
            )
    timing["loop"] = time.perf_counter() - t2

    n = u.size
    n_fit = n - round(cfg.holdout_fraction * (n - wf.part_b.start))
    fit_mask = np.zeros(n, dtype=bool)
    fit_mask[:n_fit] = True
    warmup = 2 * wf.half_cycle_samples
    u_fit = u[:n_fit]

    t3 = time.perf_counter()
    creep_start = _creep_start(cfg, wf)
    forward = [wf.ascending(c) for c in range(1, wf.n_steady)]
    est = estimate(
        u,
        z,
        T,
        profile,
        lambda nh, taus: initial_from_loop(loop.loop, nh, taus.size, time_constants_s=taus),
        fit_mask=fit_mask,
        warmup_samples=warmup,
        orders=cfg.orders,
        rls_settings=cfg.rls_settings,
        refine_max_nfev=cfg.refine_max_nfev,
        refine_free=cfg.refine_free,
        tau_range_s=cfg.creep_tau_range_s,
        creep_start_nm=creep_start,
        forward_traces=forward,
        reindex_rounds=cfg.reindex_rounds,
    )
    selection, rls_res, ref, batch_model = est.selection, est.rls, est.refine, est.batch_model
    batch_map = (alpha, beta)
    if calibration is not None and est.batch_profile is not profile:
        # The batch model lives in its own frame (h re-indexed by it): place the working
        # line's particles by its prediction of part A's forward trace.
        y_fwd = predicted_forward_trace(batch_model, u, T, forward, creep_start)
        u_fwd = u[forward[0]]
        try:
            batch_map = mapped_frame(lambda x: np.interp(x, u_fwd, y_fwd))
        except ValueError as exc:
            notes.append(
                f"the batch model's frame could not be mapped on its own ({exc}); it uses "
                "the loop's frame map"
            )
    timing["estimation"] = time.perf_counter() - t3
    # Held-out scores in the working frame (where h lives); the models are then mapped onto
    # the calibration frame (identity without calibration cycles).
    scores = est.heldout_rms_nm
    findings = notes + list(
        check_excitation(
            u_fit,
            T,
            batch_model.thresholds_nm,
            batch_model.creep_time_constants_s,
        )
    )
    for text in findings:
        warnings.warn(text, ExcitationWarning, stacklevel=2)
    timing["total_computing"] = timing["acquisition_setup"] + timing["loop"] + timing["estimation"]
    return AxisIdentification(
        axis=axis,
        line=line,
        waveform=wf,
        overview=overview,
        u_nm=u,
        height_nm=z,
        sample_period_s=T,
        history_u_nm=np.concatenate(history),
        loop=loop,
        calibration=calibration,
        frame_map=batch_map,
        profile=profile,
        orders=selection,
        rls=rls_res,
        rls_model=_mapped(rls_res.model, alpha, beta),
        batch_model=_mapped(batch_model, *batch_map),
        refine=ref,
        fit_mask=fit_mask,
        heldout_rms_nm=scores,
        findings=tuple(findings),
        timing_s=timing,
        line_stability=stability,
        creep_start_nm=creep_start,
        batch_profile=est.batch_profile,
        rls_frame_map=(alpha, beta),
    )


def score_on_truth(
    afm: Any,
    ident: AxisIdentification,
    models: dict[str, ScannerModel],
    *,
    span_nm: float = 1000.0,
    center_nm: float = 0.0,
    speed_nm_per_s: float | None = None,
    n_turns: int = 24,
    rng: int | np.random.Generator | None = 12345,
) -> dict[str, Any]:
    """Score models against the TRUE extension of a virtual AFM (for benchmarks only).

    Runs a fresh validation trajectory with minor loops (:func:`validation_waveform`) over
    ``center +- span/2`` on the identification line, right after the identification (and
    calibration) records, and compares each model's prediction, run continuously from the
    start of the identification record over ``ident.history_u_nm``, the move and the
    validation trajectory (so model and scanner carry the same history), with the true
    extension from
    ``afm.truth.last_record_positions_nm``. The first sweep of the validation trajectory is
    not scored, and the constant offset between the model's frame (loop centre at the
    command centre, Section IV) and the sample's frame, which no sensorless measurement can
    see, is removed (mean difference).

    The scale of the position frame is fixed, sensorlessly, by the calibration condition of
    Section IV (the steady loop over the span spans the command span). A scanner whose
    small-signal sensitivity differs from its nominal one breaks that condition; the slope of
    the truth against the prediction (``scale``) measures it, and the errors after removing
    that slope too (``*_after_scale_nm``) measure what remains.

    Parameters
    ----------
    afm : VirtualAFM
        The simulator the identification ran on (its ``truth`` door is read here only).
    ident : AxisIdentification
    models : dict of str to ScannerModel
        Models to score, by name.
    span_nm, center_nm, speed_nm_per_s, n_turns, rng
        The validation trajectory (speed default: that of the identification waveform).

    Returns
    -------
    dict
        Per model: ``validation_max_error_nm``, ``validation_rms_error_nm`` (offset removed),
        ``offset_nm``, ``scale``, ``validation_max_error_after_scale_nm`` and
        ``validation_rms_error_after_scale_nm`` (offset and scale removed).
    """
    axis = ident.axis
    k = 0 if axis == "x" else 1
    T = ident.sample_period_s
    speed = _speed_of(ident.waveform) if speed_nm_per_s is None else float(speed_nm_per_s)
    v = validation_waveform(center_nm, span_nm, speed, T, n_turns=n_turns, rng=rng, start_nm=None)
    slow = ident.line.slow_nm
    cur = afm.command_nm
    pieces = []
    dist = abs(cur[k] - v[0])
    if dist > 0:
        mv = afm.move_to(*((v[0], slow) if axis == "x" else (slow, v[0])), speed)
        pieces.append(np.asarray(mv.command_nm[:, k]))
    rec = afm.run(_command(axis, v, slow))
    truth = np.asarray(afm.truth.last_record_positions_nm)[:, k]
    history = np.concatenate([ident.history_u_nm, *pieces, rec.command_nm[:, k]])
    n_v = v.size
    lo_i = int(np.argmax(v >= v.max() - 1e-9))  # after the first full sweep
    out: dict[str, Any] = {"n_samples": int(n_v - lo_i), "speed_nm_per_s": float(speed)}
    for name, model in models.items():
        y, _ = simulate(model, history, T, ident.initial_state(model))
        pred = y[-n_v:][lo_i:]
        tr = truth[lo_i:]
        d = tr - pred
        off = float(np.mean(d))
        err = d - off
        coef = np.polyfit(pred, tr, 1)
        err_aff = tr - np.polyval(coef, pred)
        out[name] = {
            "validation_max_error_nm": float(np.max(np.abs(err))),
            "validation_rms_error_nm": float(np.sqrt(np.mean(err**2))),
            "offset_nm": off,
            "scale": float(coef[0]),
            "validation_max_error_after_scale_nm": float(np.max(np.abs(err_aff))),
            "validation_rms_error_after_scale_nm": float(np.sqrt(np.mean(err_aff**2))),
        }
    return out


def _speed_of(wf: IdentificationWaveform) -> float:
    return (wf.u_max_nm - wf.u_min_nm) / (wf.half_cycle_samples * wf.sample_period_s)


def identify_axes(
    instrument: Instrument, config: SensorlessConfig | None = None, axes: Sequence[str] = ("x",)
) -> dict[str, AxisIdentification]:
    """:func:`identify_axis` for each axis in turn."""
    return {a: identify_axis(instrument, config, a) for a in axes}
