"""Sensorless identification of one scanner axis through the instrument interface.

The procedure of Section V (steps 1-3), with the AFM as its own position sensor:

1. an overview image of the working area; the line crossing the most particles
   (:func:`~piezocomp.identification.line_choice.choose_line`), and the tip brought back
   onto it (line finding on the instrument: :mod:`piezocomp.identification.acquisition`);
2. the identification waveform of Fig. 7a along that line
   (:func:`~piezocomp.identification.waveforms.identification_waveform`), run once, after
   settling on the line and followed by a check of the line
   (:mod:`piezocomp.identification.acquisition`: the acquisition helpers live there);
3. part A: the averaged steady forward and backward traces, their particle peaks (sub-sample)
   paired across the traces (:func:`~piezocomp.identification.peaks.guided_pairs`), the
   symmetric loop ``f_a`` (eqs 21-23) and ``h(y)``
   (:class:`~piezocomp.identification.profile.HeightProfile`): Section IV on the steady
   cycles, :mod:`piezocomp.identification.loop_fit`;
4. part B (and A): the recursive estimator of eqs (16)-(20)
   (:func:`~piezocomp.identification.rls.rls`) started from a model whose steady loop
   matches ``f_a`` (:func:`~piezocomp.identification.estimation.initial_from_loop`), then
   the batch refinement of the same prediction error
   (:func:`~piezocomp.identification.batch.refine` with ``output = h``);
5. model orders chosen by the height prediction error on a held-out part of the record
   (:func:`~piezocomp.identification.orders.select_orders`) unless fixed;
6. with calibration cycles (``calibration_span_nm``), the models mapped from the working
   loop's frame onto the calibration frame (:mod:`piezocomp.identification.frames`).

Only ``Instrument`` methods are used. The y axis uses the same procedure with the axes
swapped (columns of the overview, the waveform on the y command).

This module holds the configuration (:class:`SensorlessConfig`), the result
(:class:`AxisIdentification`) and the pipeline (:func:`identify_axis`,
:func:`identify_axes`). The names that lived here before the steps moved to their own
modules are still importable from it (``LoopEstimate``, ``estimate_loop``,
``aligned_pairs``, ``guided_pairs``, ``frame_map``, ``unmapped``, ``initial_from_loop``,
``thresholds_over_span``, ``score_on_truth`` and the private helpers).

:func:`~piezocomp.identification.scoring.score_on_truth` is separate: it runs a fresh
validation trajectory on a *virtual* AFM and compares the model's prediction with the true
extension from the simulator's ground truth door. Identification never calls it.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.acquisition import (
    LineStability,
    _command,
    _locate_line,
    _overview_and_line,
    cycle_pairs,
    line_stability,
    settle_on_line,
)
from piezocomp.identification.batch import RefineResult, Segment, refine
from piezocomp.identification.diagnostics import ExcitationWarning, check_excitation
from piezocomp.identification.estimation import (
    DEFAULT_CREEP_TAU_RANGE_S,
    BatchStage,
    Estimation,
    RLSStage,
    estimate,
    far_worse,
    heldout_rms,
    initial_from_loop,
    model_profile,
    predicted_forward_trace,
    record_state,
    thresholds_over_span,
)
from piezocomp.identification.frames import _ransac_map as _ransac_map
from piezocomp.identification.frames import frame_map, mapped, span_frame, unmapped
from piezocomp.identification.line_choice import LineChoice
from piezocomp.identification.loop_fit import (
    LoopEstimate,
    _fit_pi_loop,
    _fit_pi_loop_loo,
    estimate_loop,
)
from piezocomp.identification.loop_fit import _fit_loop as _fit_loop
from piezocomp.identification.loop_fit import _most_regularised as _most_regularised
from piezocomp.identification.orders import OrderSelection
from piezocomp.identification.peaks import aligned_pairs, guided_pairs
from piezocomp.identification.profile import HeightProfile
from piezocomp.identification.reference import (
    GratingRecord,
    ScaleFit,
    angle_findings,
    check_plausible,
    fit_scale,
)
from piezocomp.identification.rls import RLSResult, RLSSettings, rls
from piezocomp.identification.scoring import _speed_of as _speed_of
from piezocomp.identification.scoring import score_on_truth
from piezocomp.identification.waveforms import IdentificationWaveform, identification_waveform
from piezocomp.instrument import Instrument, ScanCalibration, ScanImage
from piezocomp.model import ModelState, ScannerModel, simulate

__all__ = [
    "AxisIdentification",
    "LoopEstimate",
    "SensorlessConfig",
    "aligned_pairs",
    "estimate_loop",
    "frame_map",
    "guided_pairs",
    "identify_axes",
    "identify_axis",
    "initial_from_loop",
    "score_on_truth",
    "thresholds_over_span",
    "unmapped",
]

_mapped = mapped
"""The former name of :func:`~piezocomp.identification.frames.mapped` (kept for callers)."""


_RLS_CANDIDATES = RLSSettings(
    alpha="unit",
    p0=0.1,
    passes=20,
    k0=3000,
    free=("c", "a", "w", "y0"),
    min_time_constant_s=DEFAULT_CREEP_TAU_RANGE_S[0],
)
"""The RLS every candidate order gets (:attr:`SensorlessConfig.rls_settings`)."""

_RLS_CONTINUE = replace(
    _RLS_CANDIDATES,
    passes=140,
    clip_nm=2.0,
    min_eigenvalue=0.0,
    creep_smoothing_nm=1000.0,
    weight_smoothing_nm=3000.0,
)
"""Its continuation (:attr:`SensorlessConfig.rls_continue`)."""

_RLS_START = replace(_RLS_CANDIDATES, clip_nm=2.0)
"""The RLS chain's own first run (:attr:`SensorlessConfig.rls_start`): the candidates'
settings with the robust update from the first pass."""


RLS_ASTRAY_RATIO = 5.0
"""Held-out height RMS of the RLS over the batch model's above which a finding says so."""

BATCH_ASTRAY_RATIO = 2.0
"""Held-out height RMS of the batch model over the RLS's above which a finding says so."""


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
    speed_factors : tuple of float
        Part B's ramps run at ``speed_nm_per_s`` times these factors in turn (capped at the
        instrument's speed limit; :func:`identification_waveform`). Default
        ``(0.5, 1.0, 2.0)`` (ninth session; ``(1.0,)`` is the paper's one speed). At one
        speed the lag of the fast creep modes is indistinguishable from a narrow play
        operator: on cpr5 the batch model crept 0.3-0.5 nm too far in every dwell of the
        validation. Three speeds tell them apart: batch 0.5 nm met on 42 of seeds 1-48
        instead of 34. The RLS lost its way on two seeds of 48 (2.12 and 17.6 nm, the
        second flagged by its held-out heights) and found it on one (3.62 -> 1.09 nm)
        (``docs/identification.md``, "Ramp speeds"), until ``rls_start`` (tenth session).
    rls_update_speed_factor : float, optional
        The RLS updates its estimate only on samples where the command moves at most this
        times ``speed_nm_per_s`` (:attr:`RLSSettings.max_update_speed_nm_per_s`, set on
        ``rls_settings``, ``rls_continue`` and ``rls_start`` by :meth:`for_speed`); faster
        ramps run its predictor only. ``None`` (default): every sample updates. The batch
        refinement uses every sample.
    orders : sequence of (n_play, n_creep)
        Candidate orders; a single pair fixes them. The ``n_creep`` creep time constants are
        placed log-uniformly over ``creep_tau_range_s``
        (:func:`~piezocomp.identification.estimation.creep_spectrum`). Default 16 or 32 play
        operators and 22 creep modes over 0.01-2000 s (a factor 1.8 apart; 19 over
        0.05-2000 s until the sixth session).
    holdout_fraction : float
        Fraction of the record (its end) held out to choose the orders.
    order_tolerance, prefer_orders : float, str
        The orders chosen: among the candidates whose batch refinement predicts the held-out
        heights within ``1 + order_tolerance`` times the best, the one with the fewest
        (``"smallest"``) or the most (``"largest"``) parameters
        (:func:`~piezocomp.identification.orders.select_orders`). Default: the most, within
        25 %. With the smoothness priors, 32 play operators refine the grid of thresholds
        over 16 rather than add freedom: fitted to the true extension the family is 0.25 nm
        off with 32 and 0.31 nm with 16, but the held-out heights put the two within 16 %
        of each other on 45 of seeds 1-48 and the smaller order won the near-ties. On cpr5
        the batch model met 0.5 nm on 44 of seeds 1-48 instead of 42 (15 better, 1 worse)
        and on 18 of fresh seeds 49-72 as before (9 better, 2 worse); the smaller order is
        still taken where the larger one's refinement failed (seed 39: held-out 20 times
        worse) or is clearly worse (seeds 33 and 42: 1.4 times) (``docs/identification.md``,
        "Which orders").
    rls_settings : RLSSettings
        Default ``alpha="unit", p0=0.1, passes=20, k0=3000`` (covariance reset every 3000
        samples; 20 passes predicted the held-out heights better than 6 on cpr5 seeds 1-3)
        with the creep poles held (a fixed spectrum, only the gains estimated) and the
        thresholds held where
        :func:`~piezocomp.identification.estimation.thresholds_over_span` puts them
        (``free`` without ``"r"``): on the cpr5 virtual AFM (seeds 1-3) this predicted the
        held-out heights and the true extension better than the paper's ``alpha(k)`` of
        eq (20) and than adapting the thresholds by eq (19) (both available:
        ``RLSSettings(alpha="paper", free=GROUPS)``); with few particles on the line,
        adapted thresholds overfit the flanks the heights inform.
    rls_continue : RLSSettings, optional
        A further RLS run of every candidate order from its estimate, after the order
        selection; the RLS orders are those whose continued estimate predicts the held-out
        heights best (:func:`~piezocomp.identification.estimation.estimate`; ``None``:
        none). The batch refinements start from the candidates' estimates of
        ``rls_settings``, which this leaves unchanged. Default: 140 more passes (160 in
        all) with Huber's robust update (``clip_nm = 2.0``: an error beyond 2 nm of height
        enters as 2 nm) and smoothness priors on the creep spectrum and the play weights
        (1000 and 3000 nm, processed after every covariance reset). The recursion converges
        slowly; where the predicted position is a few nm off, ``h'`` is read on the wrong
        flank of a particle; and the record cannot separate neighbouring modes. With the
        creep spectrum from 10 ms, the RLS on cpr5 went from 2.05-5.41 nm to 1.07-2.09 nm on
        seeds 1-6, and from 2.06-7.01 to 1.17-4.43 nm on seeds 7-12
        (docs/identification.md).
    rls_start : RLSSettings, optional
        The RLS chain's own first run of every candidate order, from the same start, before
        ``rls_continue`` (:func:`~piezocomp.identification.estimation.estimate`); ``None``:
        the chain goes on from the candidates' ``rls_settings`` estimates. The batch
        refinements start from those in either case, so this changes the RLS estimate only.
        Default: ``rls_settings`` with Huber's robust update from the first pass
        (``clip_nm = 2.0``). Three ramp speeds put the predicted position several nm off on
        the fast ramps of the first passes, where ``h'`` is read on the wrong flank of a
        particle; unclipped, those errors took the RLS into another valley on cpr5 seeds 24
        and 39 (2.12 and 17.6 nm). With it the RLS met 2 nm on all of seeds 1-48 (at most
        1.64 nm), and the batch models did not change (``docs/identification.md``, "The RLS
        chain's own start").
    rls_reindex_rounds, rls_reindex_passes : int
        Then ``h`` is re-indexed by the RLS estimate itself (as the batch refinement does with
        its model) and the RLS runs ``rls_reindex_passes`` passes on it (the continuation's
        settings), ``rls_reindex_rounds`` times; the estimate kept is that of the round
        (0: the loop's ``h``) that predicts the held-out heights best, each through its own
        ``h``. Default 3 rounds of 20 passes. The RLS estimate stays independent of the
        batch refinement. The loop's ``h`` (Section IV) fixes the odd part of the branch
        only weakly, and the RLS on it inherits that shape error; re-indexed, the RLS on
        cpr5 seeds 1-12 went from 1.07-4.43 nm to 0.47-2.87 nm, at most 1.63 nm but on seed 7
        (docs/identification.md).
    refine_max_nfev : int
        Evaluations allowed to the batch refinement (0: skip it).
    refine_free : tuple of str
        Parameter groups the batch refinement adjusts (eq 15 groups); thresholds and creep
        poles held by default, as for the RLS.
    creep_smoothing_nm : float
        Weight (nm) of the smoothness penalty on the creep spectrum in every batch
        refinement (:func:`~piezocomp.identification.batch.refine`): the residuals
        ``creep_smoothing_nm * (c_{i-1} - 2 c_i + c_{i+1})`` join the height residuals.
        The record cannot tell neighbouring modes of a 19-mode spectrum apart, and which
        of the equally good fits the optimiser reaches decided the validation (a change of
        rounding moved cpr5 seed 3 from 0.52 to 0.71 nm). 0: none. Default 300 nm: the
        lowest held-out height RMS over cpr5 seeds 1-6 among 30, 100, 300 and 1000 nm.
    weight_smoothing_nm : float
        The same penalty on the play operators' weights in the order of their thresholds (a
        smooth Preisach density gives smooth weights). 0: none. Default 1000 nm, chosen the
        same way among 100, 1000, 3000 and 10000 nm (docs/identification.md).
    reindex_rounds : int
        Rounds of re-indexing ``h(y)`` by the refined model's own prediction of part A and
        refining again (:func:`~piezocomp.identification.estimation.model_profile`; 0: the
        loop's ``h`` throughout, as in the paper). The batch model's frame map then uses the
        model's prediction of part A's forward trace, not ``f_a``. Default 8: on cpr5
        seeds 1-6 the error after scale fell from 0.79-1.45 nm (4 rounds) to 0.53-1.33 nm,
        and 12 rounds gave no more (docs/identification.md).
    selection_rounds : int, optional
        Rounds of re-indexing each candidate order gets before the orders are compared on
        the held-out heights; the chosen orders then continue to ``reindex_rounds``
        (``None``, or more than ``reindex_rounds``: every candidate gets all of them).
        Default 4 (1 until the eighth session): after one round the smaller order often
        looked better only because it converges sooner; compared after four, cpr5 seeds
        1-24 and 25, 28 chose 32 play operators on six more seeds, each better (batch
        0.40 → 0.26, 0.69 → 0.60, 0.59 → 0.48 nm, ...) and none worse.
    reindex_max_nfev : int, optional
        Evaluations of each refinement after a re-indexing (``None``: ``refine_max_nfev``).
        Default 15: each round starts from the previous round's model; with 40 the
        figures were the same within 0.07 nm and the computing time 1.3-1.6 times longer.
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
        calibration frame by the affine :func:`~piezocomp.identification.frames.frame_map`
        (which fixes the scale that the working span's calibration condition gets wrong when
        the small-signal sensitivity differs from the nominal one).
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
        (:class:`~piezocomp.identification.pi_loop.PILoop`, non-negative weights) fitted to
        the calibration cycles' pairs with its ridge chosen by the discrepancy principle
        (``"pi"``, default, :func:`~piezocomp.identification.loop_fit._fit_pi_loop`; biased
        towards a straighter loop: its central slope was 0.6-2 % too low on cpr5, see
        docs/identification.md) or by leave-one-pair-out error (``"pi-loo"``,
        :func:`~piezocomp.identification.loop_fit._fit_pi_loop_loo`: less biased on cpr5 but
        far more variable, and not less biased on an exact PI loop); or the
        degree-``calibration_degree`` polynomial of eq (23) (``"polynomial"``).
    overview_shifts : tuple of float
        Slow-axis shifts (in spans) of the overview images tried in turn until one holds a
        line with more than ``degree`` particles (the line need only span the working area
        along its own axis); if none does, the best line with ``min_line_particles`` is
        taken (the loop fit pools the pairs of the lines scanned near it).
    line_search_nm, line_search_step_nm : float
        Slow-axis neighbourhood searched, and its step, to get back onto a line with enough
        particles near the chosen one (see
        :func:`~piezocomp.identification.acquisition._locate_line`).
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
        0.9 nm (0.4 nm after 1200 s); see docs/identification-history.md.
    relocate_search_nm : float
        If the last settling cycle no longer pairs ``min_line_particles`` particles (the tip
        drifted off the line), the line is searched again over this neighbourhood of the
        slow command (:func:`~piezocomp.identification.acquisition._locate_line`).
    relocate_settle_s : float
        Time (s) spent scanning the line's steady cycle again after that search, before the
        record: the slow axis that carried the tip off the line is still creeping. Default
        300 s: on the cpr5 seeds 49-96 whose line was lost (24 of 48), the batch model met
        0.5 nm on 19 against 14 without it (docs/identification.md, "A line found again is
        settled again").
    check_cycles : int
        Steady cycles of the line scanned right after the record; their averaged forward
        trace is compared with part A's
        (:func:`~piezocomp.identification.acquisition.line_stability`), and a profile change
        beyond ``check_tolerance_nm`` (RMS, above the cycle-to-cycle repeatability) is
        reported as a finding. 0 skips the check.
    check_tolerance_nm : float
        Tolerance of that check.
    rerecord_unstable : int
        When the check finds the profile changed, the line is searched again over
        ``relocate_search_nm`` and recorded anew, at most this many times; the record whose
        profile changed least is kept, and a note says what was done. 0 only reports it.
    min_line_particles : int
        Particles the identification line itself must pair (its ``h(y)`` carries the
        information of eqs 17-18).
    loop_pairs_factor : int
        The loop fit (23) uses the pairs of every line scanned while locating the line; at
        least ``loop_pairs_factor * (degree + 1)`` of them are collected.
    seed : int
        Randomness of the waveform.
    extra_lines : int
        Further particle lines whose records refine the same batch model (each found by an
        overview ``extra_line_offset_nm`` further away on the slow axis, alternately above
        and below; searched, settled and recorded like the first, after the first line's
        record and calibration cycles). 0: the paper's single line.
    extra_line_offset_nm : float
        Slow-axis distance between the overviews' centres.
    joint_rounds : int
        Rounds of the joint refinement over all lines (each line's ``h`` re-indexed by the
        shared model); they replace as many of the first line's ``reindex_rounds``.
    rls_lines_passes, rls_lines_rounds : int
        With extra lines, the RLS also runs on every line (after ``rls_reindex_rounds``):
        ``rls_lines_rounds`` rounds of re-indexing each line's ``h`` by the RLS estimate and
        ``rls_lines_passes`` passes alternating the lines, each line weighted as in the joint
        rounds (``weight_lines``). That estimate replaces the first line's if it predicts
        the held-out heights of the lines better: the sum over the lines of each line's
        held-out RMS divided by its residual RMS under the first line's estimate. 0: the RLS
        on the first line only.
    weight_lines : bool
        In the joint rounds, weight each line's height residuals by the inverse of its own
        residual RMS over the fitted part (under the model of the round before; the first
        line's weight is 1): a line whose profile changed under the tip during its record
        (slow-axis creep) or reads noisier counts less. ``False``: every line alike.
    final_rounds : int
        After the held-out part has chosen the orders and the rounds: joint rounds of the
        batch model over the WHOLE record of every line (held-out part included), each
        line's ``h`` re-indexed by the model and weighted as in the joint rounds. The
        held-out scores reported are those before it. 0: none.
    rls_final_passes : int
        The same for the RLS: passes over the whole record of every line, alternating the
        lines (the first line last), each line's ``h`` re-indexed once by the estimate and
        weighted by its residual level. 0: none.
    batch_restart_ratio : float, optional
        When the batch model predicts the held-out heights more than this many times worse
        than the RLS estimate, and by more than 1 nm, its chain is run again from the RLS
        estimate and the better of the two is kept (:func:`estimate`'s
        ``batch_restart_ratio``; section "A batch model astray is refined again from the
        RLS" of ``docs/identification.md``). ``None``: never.
    workers : int, optional
        Threads of the estimation (:func:`estimate`: the candidate orders side by side,
        then the batch chain beside the RLS chain); the result does not depend on it.
        Default (``None``): the machine's processors, at most 4 (more have nothing to do).
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
    rls_update_speed_factor: float | None = None
    orders: tuple[tuple[int, int], ...] = ((16, 22), (32, 22))
    holdout_fraction: float = 0.25
    order_tolerance: float = 0.25
    prefer_orders: str = "largest"
    rls_settings: RLSSettings = field(default_factory=lambda: _RLS_CANDIDATES)
    rls_continue: RLSSettings | None = field(default_factory=lambda: _RLS_CONTINUE)
    rls_start: RLSSettings | None = field(default_factory=lambda: _RLS_START)
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
    rerecord_unstable: int = 1
    relocate_settle_s: float = 300.0
    min_line_particles: int = 4
    loop_pairs_factor: int = 3
    seed: int = 0
    extra_lines: int = 1
    extra_line_offset_nm: float = 1000.0
    joint_rounds: int = 3
    weight_lines: bool = True
    rls_lines_passes: int = 10
    rls_lines_rounds: int = 1
    final_rounds: int = 1
    rls_final_passes: int = 10
    batch_restart_ratio: float | None = BATCH_ASTRAY_RATIO
    workers: int | None = None

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

    def for_speed(self, speed_nm_per_s: float) -> SensorlessConfig:
        """This configuration with the RLS's update cap set for ramps of ``speed_nm_per_s``
        (``rls_update_speed_factor``; unchanged without one)."""
        f = self.rls_update_speed_factor
        if f is None:
            return self
        cap = float(f) * float(speed_nm_per_s) * (1.0 + 1e-9)
        names = ("rls_settings", "rls_continue", "rls_start")
        capped = {
            name: replace(v, max_update_speed_nm_per_s=cap)
            for name in names
            if (v := getattr(self, name)) is not None
        }
        return replace(self, **capped)

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
        if self.prefer_orders not in ("smallest", "largest"):
            raise ValueError(
                f"prefer_orders must be 'smallest' or 'largest'. Got {self.prefer_orders!r}."
            )
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
        f = self.rls_update_speed_factor
        if f is not None and (
            isinstance(f, bool) or check_finite_scalar("rls_update_speed_factor", f) <= 0
        ):
            raise ValueError(f"rls_update_speed_factor must be None or > 0. Got {f!r}.")
        if not isinstance(self.weight_lines, bool):
            raise TypeError(f"weight_lines must be True or False. Got {self.weight_lines!r}.")
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
        for name in ("settle_s", "line_settle_s", "relocate_settle_s"):
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
        for name in ("creep_smoothing_nm", "weight_smoothing_nm"):
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
        if self.calibration_loop not in ("pi", "pi-loo", "polynomial"):
            raise ValueError(
                "calibration_loop must be 'pi', 'pi-loo' or 'polynomial'. "
                f"Got {self.calibration_loop!r}."
            )
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
        if self.creep_start not in ("centre", "first-command"):
            raise ValueError(
                f"creep_start must be 'centre' or 'first-command'. Got {self.creep_start!r}."
            )


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
        ``(alpha, beta)`` of the RLS model (the loop's frame, or its own if its ``h`` was
        re-indexed by it); ``None`` means ``frame_map``.
    rls_profile : HeightProfile or None
        The ``h(y)`` of the RLS estimate (``profile`` re-indexed by the RLS estimate,
        ``config.rls_reindex_rounds``); ``None`` means ``profile``.
    rls_on_lines : bool
        Whether the RLS estimate is the one run on every line (``config.rls_lines_passes``).
    final_fit : bool
        Whether the models were fitted over the whole record at the end, held-out part
        included (``config.final_rounds``, ``config.rls_final_passes``): ``heldout_rms_nm``
        is then that of the models before it.
    reference : dict of str to ScaleFit, or None
        With a grating record (``identify_axis(..., reference=...)``): the scale each model
        (``"rls"``, ``"batch"``) was given by the grating (:func:`fit_scale`); the frame
        maps then take their ``alpha`` from it.
    unreferenced_models : dict of str to ScannerModel, or None
        The models as they were before the grating's scale (for comparison).
    reference_record : GratingRecord or None
        The grating record the scales came from.
    extra_lines : tuple of LineChoice
        The further lines whose records refined the batch model with the first
        (``config.extra_lines``), ``slow_nm`` where they were recorded.
    batch_restart : dict or None
        The batch chain's restart from the RLS estimate, if it ran
        (``config.batch_restart_ratio``; :attr:`Estimation.batch_restart`).
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
    reference: dict[str, ScaleFit] | None = None
    unreferenced_models: dict[str, ScannerModel] | None = None
    reference_record: GratingRecord | None = None
    extra_lines: tuple[LineChoice, ...] = ()
    rls_profile: HeightProfile | None = None
    rls_on_lines: bool = False
    final_fit: bool = False
    batch_restart: dict[str, Any] | None = None

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
        rls_prof = self.profile if self.rls_profile is None else self.rls_profile
        return {
            "rls": (unmapped(self.rls_model, *rls_map), rls_prof),
            "batch": (unmapped(self.batch_model, *self.frame_map), batch_prof),
        }


DEFAULT_CALIBRATION_SPEED_NM_PER_S = 1000.0
"""Speed of the calibration cycles when neither the configuration nor the instrument
states one."""


def rls_astray(heldout: dict[str, float]) -> list[str]:
    """A finding when the RLS estimate predicts the held-out heights far worse than the batch
    model (more than :data:`RLS_ASTRAY_RATIO` times and by more than 1 nm): it has settled in
    another basin and is likely nanometres off. On cpr5 seeds 1-48 the ratio was 0.8-3.5
    where the RLS met 2 nm and 12-15 where it did not (seeds 24 and 39, three ramp speeds,
    ninth session); with :attr:`SensorlessConfig.rls_start` it was 0.7-3.1 on seeds 5-48,
    all within 2 nm."""
    r, b = heldout.get("rls", float("nan")), heldout.get("batch", float("nan"))
    if not far_worse(r, b, RLS_ASTRAY_RATIO):
        return []
    return [
        f"the RLS estimate predicts the held-out heights to {r:.2f} nm RMS, {r / b:.0f} times "
        f"the batch model's {b:.2f} nm: it has probably settled in another basin and may be "
        "nanometres off; use the batch model"
    ]


def batch_astray(heldout: dict[str, float]) -> list[str]:
    """A finding when the batch model predicts the held-out heights far worse than the RLS
    estimate (more than :data:`BATCH_ASTRAY_RATIO` times and by more than 1 nm): the
    refinement has left for another basin. Over 218 cpr5 runs (seeds 1-120, eleventh session)
    the ratio was at most 1.42 (0.08 nm above the RLS), except seed 117: 4.69 (3.32 against
    0.71 nm), whose batch model was 25 nm off and its RLS 0.69 nm. With
    :attr:`SensorlessConfig.batch_restart_ratio` the batch chain is then run again from the
    RLS estimate (seed 117: 0.36 nm held-out, 0.63 nm off), and this fires only if the
    better of the two is still far worse."""
    r, b = heldout.get("rls", float("nan")), heldout.get("batch", float("nan"))
    if not far_worse(b, r, BATCH_ASTRAY_RATIO):
        return []
    return [
        f"the batch model predicts the held-out heights to {b:.2f} nm RMS, {b / r:.1f} times "
        f"the RLS estimate's {r:.2f} nm: the refinement has probably left for another basin "
        "and may be nanometres off; use the RLS model (model_rls.json)"
    ]


POOR_HELDOUT_NM = 2.0
"""Held-out height RMS of the batch model above which the result is flagged as poor: on a
settled line with 15 nm particles it is 0.2-0.5 nm; a line that moved under the tip during
the record, or a record not settled on it, gives several nm."""


def poor_fit(heldout: dict[str, float]) -> list[str]:
    """A finding when even the batch model predicts the held-out heights poorly (more than
    :data:`POOR_HELDOUT_NM` RMS): the record itself is suspect."""
    b = heldout.get("batch", float("nan"))
    if not b > POOR_HELDOUT_NM:
        return []
    return [
        f"the batch model predicts the held-out heights to {b:.2f} nm RMS only (more than "
        f"{POOR_HELDOUT_NM:g} nm): the model is probably nanometres off. Was the line settled "
        "before the record (scan it for several minutes first), and did the tip stay on it "
        "(no drift, no pushed particle)? Record again rather than use this model"
    ]


def batch_restart_notes(est: Estimation) -> list[str]:
    """A note on the batch chain's restart from the RLS estimate, if it was run
    (:attr:`Estimation.batch_restart`)."""
    r = est.batch_restart
    if r is None:
        return []
    kept = "kept" if r["kept"] == "restart" else "not kept: the first chain's model stays"
    return [
        f"the batch model predicted the held-out heights to {r['first']:.2f} nm RMS, far worse "
        f"than the RLS estimate's {est.heldout_rms_nm['rls']:.2f} nm; refined again from the "
        f"RLS estimate it predicts them to {r['restart']:.2f} nm ({kept})"
    ]


def scale_fits(
    models: dict[str, ScannerModel],
    reference: GratingRecord,
    heldout: dict[str, float],
    notes: list[str],
    prescale: Mapping[str, float] | None = None,
) -> dict[str, ScaleFit]:
    """The grating's scale of the ``"batch"`` and ``"rls"`` models (:func:`fit_scale`), with
    the grating's angle findings in ``notes``. A batch model whose scale cannot be found, or
    is implausible (:func:`~piezocomp.identification.reference.check_plausible`),
    raises; an RLS model's is left out with a note (its lengths are far off, which the
    held-out heights show; the batch model is scaled all the same). ``prescale`` holds each
    model's frame-map ``alpha``, about which the grating's period is searched."""
    pre = dict(prescale or {})
    fits = {"batch": fit_scale(models["batch"], reference, prescale=pre.get("batch", 1.0))}
    check_plausible(fits["batch"])
    try:
        rls_fit = fit_scale(models["rls"], reference, prescale=pre.get("rls", 1.0))
        check_plausible(rls_fit)
        fits = {"rls": rls_fit, **fits}
    except ValueError as exc:
        notes.append(
            f"the RLS model could not be scaled by the grating ({exc}); it is left unscaled "
            f"and is far off (held-out heights {heldout.get('rls', float('nan')):.2f} nm RMS "
            f"against the batch model's {heldout.get('batch', float('nan')):.2f}): use the "
            "batch model"
        )
    notes.extend(angle_findings(fits["batch"]))
    return fits


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


def _referenced_map(
    alpha_ref: float, frame: tuple[float, float], center_nm: float
) -> tuple[float, float]:
    """The frame map with the grating's scale: ``alpha_ref`` about the working line's centre,
    which stays where ``frame`` put it."""
    a, b = frame
    return alpha_ref, a * center_nm + b - alpha_ref * center_nm


@dataclass(frozen=True)
class ExtraLine:
    """A further particle line's record (``SensorlessConfig.extra_lines``), and the axis'
    commands from its settling on (for the command history)."""

    line: LineChoice
    u_nm: NDArray[np.float64]
    height_nm: NDArray[np.float64]
    history_u_nm: NDArray[np.float64]


def _extra_lines(
    instrument: Instrument,
    cfg: SensorlessConfig,
    axis: str,
    wf: IdentificationWaveform,
    speed: float,
    line_rate: float,
    notes: list[str],
) -> list[ExtraLine]:
    """Overview, line search, settling and the identification record on each extra line
    (instrument calls only). The areas tried are ``extra_line_offset_nm`` away on the slow
    axis, then twice as far, alternating sides (+1, -1, +2, -2, ... offsets), until
    ``extra_lines`` lines are found or twice as many areas plus two have been tried; an
    area without a usable line is reported and skipped."""
    out: list[ExtraLine] = []
    k_axis = 0 if axis == "x" else 1
    cx, cy = cfg.center_nm
    for j in range(2 * cfg.extra_lines + 2 if cfg.extra_lines else 0):
        if len(out) == cfg.extra_lines:
            break
        d = cfg.extra_line_offset_nm * (j // 2 + 1) * (1 if j % 2 == 0 else -1)
        sub = replace(cfg, center_nm=(cx, cy + d) if axis == "x" else (cx + d, cy))
        try:
            _, line_k = _overview_and_line(instrument, sub, axis, line_rate)
            slow_k, _, _ = _locate_line(instrument, sub, axis, line_k, wf, speed)
        except ValueError as exc:
            notes.append(
                f"no extra line at {d:+g} nm on the slow axis ({exc}); "
                + ("the next area is tried" if j + 1 < 2 * cfg.extra_lines + 2 else "none left")
            )
            continue
        cycle = wf.u_nm[: 2 * wf.half_cycle_samples + 1]
        settled = settle_on_line(instrument, axis, cycle, slow_k, cfg.line_settle_s)
        rec = instrument.run(_command(axis, wf.u_nm, slow_k))
        u_k = np.ascontiguousarray(rec.command_nm[:, k_axis], dtype=float)
        before = [] if settled is None else [settled.command_nm[:, k_axis]]
        out.append(
            ExtraLine(
                replace(line_k, slow_nm=slow_k),
                u_k,
                np.ascontiguousarray(rec.height_nm, dtype=float),
                np.concatenate([*before, u_k]),
            )
        )
    return out


def _lines_rms(
    model: ScannerModel,
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    profiles: list[HeightProfile],
    T: float,
    mask: NDArray[np.bool_],
    creep_start: float | None,
) -> list[float]:
    """Each line's height residual RMS over the samples of ``mask``, through its own ``h``."""
    return [
        heldout_rms(p_i, model, u_i, z_i, T, mask, creep_start)
        for (u_i, z_i), p_i in zip(lines, profiles, strict=True)
    ]


def _line_weights(
    model: ScannerModel,
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    profiles: list[HeightProfile],
    T: float,
    fitted: NDArray[np.bool_],
    creep_start: float | None,
) -> list[float]:
    """Each line's weight: the first line's residual RMS over its fitted samples divided by
    the line's own (so each line's residuals count in units of its own residual level)."""
    rms = _lines_rms(model, lines, profiles, T, fitted, creep_start)
    return [rms[0] / r if r > 0 else 1.0 for r in rms]


def _lam(penalty: float) -> float | None:
    """A smoothing penalty to pass on: ``None`` (choose by GCV) when it is not finite."""
    return float(penalty) if np.isfinite(penalty) else None


def _lines_profiles(
    model: ScannerModel,
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    T: float,
    wf: IdentificationWaveform,
    creep_start: float | None,
    penalties: Sequence[float],
) -> list[HeightProfile]:
    """Each line's ``h`` indexed by ``model`` (:func:`model_profile`), smoothed with its
    penalty (:func:`_line_penalties`). Raises ValueError if the model's forward trace does
    not advance."""
    forward = [wf.ascending(c) for c in range(1, wf.n_steady)]
    return [
        model_profile(model, u_i, z_i, T, forward, creep_start, lam=_lam(lam))
        for (u_i, z_i), lam in zip(lines, penalties, strict=True)
    ]


def _weights(
    cfg: SensorlessConfig,
    model: ScannerModel,
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    profiles: list[HeightProfile],
    T: float,
    fitted: NDArray[np.bool_],
    creep_start: float | None,
) -> list[float]:
    """:func:`_line_weights` with ``cfg.weight_lines``, else every line 1."""
    if not cfg.weight_lines:
        return [1.0] * len(lines)
    return _line_weights(model, lines, profiles, T, fitted, creep_start)


def _rls_passes(
    model: ScannerModel,
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    profiles: list[HeightProfile],
    weights: Sequence[float],
    T: float,
    cfg: SensorlessConfig,
    creep_start: float | None,
    passes: int,
    n_samples: int | None = None,
) -> RLSResult | None:
    """``passes`` single passes of the RLS (``cfg.rls_continue``, else ``rls_settings``)
    alternating the lines, each line's heights and ``h`` weighted, the first line last (so
    the last pass and its traces are the first line's); over the first ``n_samples`` of
    each record (``None``: all). Returns the last pass (``None`` if ``passes`` is 0)."""
    settings = replace(cfg.rls_continue or cfg.rls_settings, passes=1)
    n = slice(None) if n_samples is None else slice(0, n_samples)
    last = None
    for _ in range(passes):
        for i in [*range(1, len(lines)), 0]:
            u_i, z_i = lines[i]
            last = rls(
                u_i[n], weights[i] * z_i[n], profiles[i].scaled(weights[i]), model, T,
                settings=settings, state=record_state(model, float(u_i[0]), creep_start),
            )  # fmt: skip
            model = last.model
    return last


def _line_penalties(
    loop: LoopEstimate,
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    wf: IdentificationWaveform,
) -> list[float]:
    """Each line's smoothing penalty for ``h`` (:meth:`HeightProfile.from_samples`): chosen
    once by GCV on the line's steady forward traces indexed by the loop (the first line's
    is the loop's own ``h``), and kept when a model re-indexes the line (it moves the
    positions by a fraction of a per cent of the span)."""
    out = [loop.profile.penalty]
    for u_i, z_i in lines[1:]:
        heights = np.array([z_i[wf.ascending(c)] for c in range(1, wf.n_steady)])
        out.append(HeightProfile.from_loop(loop.loop, u_i[wf.ascending(1)], heights).penalty)
    return out


def _rls_on_lines(
    res: RLSResult,
    profile: HeightProfile,
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    T: float,
    cfg: SensorlessConfig,
    wf: IdentificationWaveform,
    fit_mask: NDArray[np.bool_],
    creep_start: float | None,
    penalties: Sequence[float],
) -> tuple[RLSResult, HeightProfile, bool]:
    """The RLS on every line (``SensorlessConfig.rls_lines_passes``), started from the first
    line's estimate ``res`` (whose ``h`` is ``profile``); returns the estimate kept, the
    first line's ``h`` for it and whether the lines' estimate was kept. Each line's ``h``
    is smoothed with its penalty in ``penalties`` (:func:`_line_penalties`)."""
    warmup = 2 * wf.half_cycle_samples
    n_fit = int(fit_mask.sum())
    fitted = fit_mask.copy()
    fitted[:warmup] = False
    heldout = ~fit_mask
    heldout[:warmup] = False

    def own_profiles(m: ScannerModel) -> list[HeightProfile]:
        return _lines_profiles(m, lines, T, wf, creep_start, penalties)

    try:
        profs = own_profiles(res.model)  # also the first round's
    except ValueError:
        return res, profile, False
    first = [profile, *profs[1:]]  # the first line as its estimate saw it
    level = _lines_rms(res.model, lines, first, T, fitted, creep_start)  # the yardstick
    if min(level) <= 0:
        return res, profile, False

    def score(m: ScannerModel, profs: list[HeightProfile]) -> float:
        rms = _lines_rms(m, lines, profs, T, heldout, creep_start)
        return float(sum(h / s for h, s in zip(rms, level, strict=True)))

    m, last = res.model, res
    for k in range(cfg.rls_lines_rounds):
        if k:
            try:
                profs = own_profiles(m)
            except ValueError:
                return res, profile, False
        w = _weights(cfg, m, lines, profs, T, fitted, creep_start)
        done = _rls_passes(m, lines, profs, w, T, cfg, creep_start, cfg.rls_lines_passes, n_fit)
        if done is not None:
            last, m = done, done.model
    try:
        profs = own_profiles(m)
    except ValueError:
        return res, profile, False
    if score(m, profs) < score(res.model, first):
        return last, profs[0], True
    return res, profile, False


def _whole_record_stages(
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    T: float,
    cfg: SensorlessConfig,
    wf: IdentificationWaveform,
    creep_start: float | None,
    penalties: Sequence[float],
) -> tuple[BatchStage | None, RLSStage | None]:
    """The final stages of :func:`estimate` (``batch_final``, ``rls_final``): the chosen
    models fitted over the whole record of every line, held-out part included
    (``SensorlessConfig.final_rounds``, ``rls_final_passes``); ``None`` where it is 0."""
    whole = np.ones(lines[0][0].size, dtype=bool)

    def batch_final(model: ScannerModel, prof: HeightProfile) -> tuple[ScannerModel, HeightProfile]:
        again = replace(cfg, joint_rounds=cfg.final_rounds)
        return _joint_rounds(model, lines, T, again, wf, whole, creep_start, prof, penalties)

    def rls_final(res: RLSResult, prof: HeightProfile) -> tuple[RLSResult, HeightProfile]:
        try:
            profs = _lines_profiles(res.model, lines, T, wf, creep_start, penalties)
        except ValueError:  # the estimate's forward trace does not advance: keep it
            return res, prof
        fitted = whole.copy()
        fitted[: 2 * wf.half_cycle_samples] = False
        w = _weights(cfg, res.model, lines, profs, T, fitted, creep_start)
        last = _rls_passes(res.model, lines, profs, w, T, cfg, creep_start, cfg.rls_final_passes)
        return (res, prof) if last is None else (last, profs[0])

    return (
        batch_final if cfg.final_rounds > 0 else None,
        rls_final if cfg.rls_final_passes > 0 else None,
    )


def _joint_rounds(
    model: ScannerModel,
    lines: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    T: float,
    cfg: SensorlessConfig,
    wf: IdentificationWaveform,
    fit_mask: NDArray[np.bool_],
    creep_start: float | None,
    first_profile: HeightProfile,
    penalties: Sequence[float],
) -> tuple[ScannerModel, HeightProfile]:
    """The batch model refined on every line at once, each line's ``h`` re-indexed by the
    shared model before each round (:func:`~piezocomp.identification.batch.refine` with
    ``extra``) and smoothed with its penalty in ``penalties`` (:func:`_line_penalties`);
    returns the model and the first line's ``h``."""
    warmup = 2 * wf.half_cycle_samples
    profs = [first_profile]
    fitted = fit_mask.copy()
    fitted[:warmup] = False
    for _ in range(cfg.joint_rounds):
        profs = _lines_profiles(model, lines, T, wf, creep_start, penalties)
        # each line's residuals in units of its own residual RMS (weight_lines)
        weights = _weights(cfg, model, lines, profs, T, fitted, creep_start)
        segments = [
            Segment(u_i, w_i * z_i, output=p_i.scaled(w_i),
                    state=record_state(model, float(u_i[0]), creep_start),
                    fit_mask=fit_mask, warmup_samples=warmup)
            for (u_i, z_i), p_i, w_i in zip(lines[1:], profs[1:], weights[1:], strict=True)
        ]  # fmt: skip
        u0, z0 = lines[0]
        model = refine(
            model, u0, z0, T, output=profs[0],
            state=record_state(model, float(u0[0]), creep_start), fit_mask=fit_mask,
            warmup_samples=warmup, max_nfev=cfg.reindex_max_nfev, free=cfg.refine_free,
            extra=segments, creep_smoothing_nm=cfg.creep_smoothing_nm,
            weight_smoothing_nm=cfg.weight_smoothing_nm,
        ).model  # fmt: skip
    return model, profs[0]


def identify_axis(
    instrument: Instrument,
    config: SensorlessConfig | None = None,
    axis: str = "x",
    *,
    reference: GratingRecord | None = None,
) -> AxisIdentification:
    """Identify the model of one axis with the AFM as its own sensor (Sections III.C-V).

    Steps: overview image(s) and line choice (Sec. V step 1); line search back onto a line
    with enough particles, collecting loop pairs
    (:func:`~piezocomp.identification.acquisition._locate_line`); optionally the
    calibration cycles (``config.calibration_span_nm``); the identification waveform of
    Fig. 7a; the loop (eqs 21-23) and ``h(y)`` from part A; for each candidate order, RLS
    (eqs 16-20) from a start fitted to the loop, then the batch refinement; the orders with
    the best held-out height prediction (:func:`select_orders`); finally the models mapped
    onto the calibration frame (if any), and, with a grating record, scaled to the
    grating's lengths (:mod:`~piezocomp.identification.reference`). Only ``instrument``'s
    public interface is used.

    Parameters
    ----------
    instrument : Instrument
        Any instrument (virtual or real); only its public interface is used.
    config : SensorlessConfig, optional
    axis : {"x", "y"}
    reference : GratingRecord, optional
        Steady cycles over a grating of known pitch, on this axis, over the working span at
        the identification speed (:func:`measure_grating`, before the particle sample is
        mounted): the length reference that fixes the scale particles cannot see.

    Returns
    -------
    AxisIdentification
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y'. Got {axis!r}.")
    if reference is not None and not isinstance(reference, GratingRecord):
        raise TypeError(f"reference must be a GratingRecord. Got {type(reference).__name__}.")
    if reference is not None and reference.axis != axis:
        raise ValueError(
            f"the grating record is of axis {reference.axis!r}; it cannot scale axis {axis!r}."
        )
    cfg = SensorlessConfig() if config is None else config
    check_fits(cfg, axis, float(instrument.range_nm))
    T = float(instrument.sample_period_s)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    cx, cy = cfg.center_nm
    speed = min(cfg.speed_nm_per_s, float(instrument.max_speed_nm_per_s))
    cfg = cfg.for_speed(speed)
    line_rate = speed / (2.0 * cfg.span_nm)
    center_line = cx if axis == "x" else cy  # the fast axis' centre; the overview sets the slow
    wf = identification_waveform(
        center_line,
        cfg.span_nm,
        speed,
        T,
        n_steady=cfg.n_steady,
        n_decaying=cfg.n_decaying,
        n_random=cfg.n_random,
        max_dwell_s=cfg.max_dwell_s,
        speed_factors=cfg.speed_factors,
        max_speed_nm_per_s=float(instrument.max_speed_nm_per_s),
        rng=cfg.seed,
    )
    acquisition_notes: list[str] = []
    overview, line = _overview_and_line(instrument, cfg, axis, line_rate)
    slow, _, search_pairs = _locate_line(instrument, cfg, axis, line, wf, speed)
    line = replace(line, slow_nm=slow)
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

    def relocate() -> tuple[float, list[Any]]:
        # The line searched again over relocate_search_nm (ValueError if not found).
        near = replace(cfg, line_search_nm=cfg.relocate_search_nm, loop_pairs_factor=0)
        found, _, pairs = _locate_line(instrument, near, axis, line, wf, speed, accept_best=True)
        return found, pairs

    if lost:
        # The line was lost while settling (thermal drift): find it again close by.
        try:
            slow, more = relocate()
        except ValueError as exc:
            acquisition_notes.append(
                f"the tip left the line while settling and the line was not found again "
                f"({exc}); the record runs at the settled slow command"
            )
            more = []
        search_pairs = [*search_pairs, *more]
        line = replace(line, slow_nm=slow)
        if cfg.relocate_settle_s > 0:
            settle_on_line(
                instrument, axis, wf.u_nm[: 2 * wf.half_cycle_samples + 1], slow,
                cfg.relocate_settle_s,
            )  # fmt: skip
    k = 0 if axis == "x" else 1
    timing["acquisition_setup"] = time.perf_counter() - t0

    def record_line(
        slow_nm: float,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[Any], LineStability | None]:
        # The record, then the line again at once (before the calibration cycles): has its
        # profile changed?
        rec = instrument.run(_command(axis, wf.u_nm, slow_nm))
        u_r = np.ascontiguousarray(rec.command_nm[:, k], dtype=float)
        z_r = np.ascontiguousarray(rec.height_nm, dtype=float)
        if cfg.check_cycles <= 0:
            return u_r, z_r, [u_r], None
        m2 = 2 * wf.half_cycle_samples
        chk = np.concatenate([wf.u_nm[:1], *([wf.u_nm[1 : m2 + 1]] * cfg.check_cycles)])
        crec_chk = instrument.run(_command(axis, chk, slow_nm))
        asc = [slice(m2 * c, m2 * c + wf.half_cycle_samples + 1) for c in range(cfg.check_cycles)]
        st = line_stability(
            u_r[wf.ascending(1)],
            np.array([z_r[wf.ascending(c)] for c in range(1, wf.n_steady)]),
            chk[asc[0]],
            np.array([crec_chk.height_nm[a] for a in asc[1:] or asc]),
            min_prominence_nm=cfg.min_prominence_nm,
        )
        return u_r, z_r, [u_r, crec_chk.command_nm[:, k]], st

    t1 = time.perf_counter()
    u, z, history, stability = record_line(line.slow_nm)
    for attempt in range(cfg.rerecord_unstable):
        if stability is None or stability.finding(cfg.check_tolerance_nm) is None:
            break
        # The slow axis crept across the line during the record: find the line again close
        # by (its creep has slowed since) and record again; keep the steadier record.
        try:
            slow2, more = relocate()
        except ValueError as exc:
            acquisition_notes.append(
                f"the line's profile changed during the record and the line was not found "
                f"again to record it anew ({exc})"
            )
            break
        again = record_line(slow2)
        assert again[3] is not None
        before = stability.height_change_rms_nm - stability.noise_rms_nm
        after = again[3].height_change_rms_nm - again[3].noise_rms_nm
        kept = after < before
        acquisition_notes.append(
            f"the line's profile changed during the record by {before:.2f} nm RMS beyond the "
            f"cycle-to-cycle repeatability; the line was found again and recorded anew "
            f"(attempt {attempt + 1}): {after:.2f} nm, "
            + ("the new record is used" if kept else "the first record is kept")
        )
        if kept:
            u, z, history, stability = again
            search_pairs = [*search_pairs, *more]
            line = replace(line, slow_nm=slow2)
        else:  # the scanner ran the new record all the same (its search's steady cycles
            # are left out, as for the extra lines: the record's part A wipes them out)
            history += again[2]
    timing["acquisition"] = time.perf_counter() - t1
    calibration = None
    if cfg.calibration_span_nm is not None:
        # After the identification record (which must follow the line search at once: the
        # slow axis creeps off a line a particle wide within seconds).
        cal_speed = min(
            _calibration_speed(cfg, instrument, acquisition_notes),
            float(instrument.max_speed_nm_per_s),
        )
        cwf = identification_waveform(
            center_line,
            cfg.calibration_span_nm,
            cal_speed,
            T,
            n_steady=cfg.n_steady,
            n_decaying=0,
            n_random=0,
        )
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

    # Extra lines last: a slow-axis move of a micrometre before the first line's record
    # would leave the slow axis creeping across it during the record.
    t_extra = time.perf_counter()
    extra = _extra_lines(instrument, cfg, axis, wf, speed, line_rate, acquisition_notes)
    if cfg.extra_lines:  # counted like the first line's set-up (its record's run included)
        timing["extra_lines"] = time.perf_counter() - t_extra
    for e in extra:
        history.append(e.history_u_nm)
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
    # with extra lines, the joint rounds replace as many of the first line's own rounds
    first_rounds = cfg.reindex_rounds
    if extra and cfg.reindex_rounds > 0:
        first_rounds = max(cfg.selection_rounds_used or 1, cfg.reindex_rounds - cfg.joint_rounds)
    lines = [(u, z)] + [(e.u_nm, e.height_nm) for e in extra]
    penalties = _line_penalties(loop, lines, wf)
    batch_final, rls_final = _whole_record_stages(lines, T, cfg, wf, creep_start, penalties)
    rls_lines = False

    def joint_rounds(
        model: ScannerModel, prof: HeightProfile
    ) -> tuple[ScannerModel, HeightProfile]:
        return _joint_rounds(model, lines, T, cfg, wf, fit_mask, creep_start, prof, penalties)

    def rls_on_lines(res: RLSResult, prof: HeightProfile) -> tuple[RLSResult, HeightProfile]:
        nonlocal rls_lines
        res, prof, rls_lines = _rls_on_lines(
            res, prof, lines, T, cfg, wf, fit_mask, creep_start, penalties
        )
        return res, prof

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
        reindex_rounds=first_rounds,
        selection_rounds=cfg.selection_rounds_used,
        reindex_max_nfev=cfg.reindex_max_nfev,
        rls_continue=cfg.rls_continue,
        rls_start=cfg.rls_start,
        order_tolerance=cfg.order_tolerance,
        prefer_orders=cfg.prefer_orders,
        rls_reindex_rounds=cfg.rls_reindex_rounds,
        rls_reindex_passes=cfg.rls_reindex_passes,
        creep_smoothing_nm=cfg.creep_smoothing_nm,
        weight_smoothing_nm=cfg.weight_smoothing_nm,
        batch_then=joint_rounds if extra else None,
        rls_then=rls_on_lines if extra and cfg.rls_lines_passes > 0 else None,
        batch_final=batch_final,
        rls_final=rls_final,
        batch_restart_ratio=cfg.batch_restart_ratio,
        workers=cfg.workers_used,
    )
    selection, rls_res, ref, batch_model = est.selection, est.rls, est.refine, est.batch_model
    batch_profile, rls_profile = est.batch_profile, est.rls_profile
    scores = dict(est.heldout_rms_nm)
    notes.extend([
        *batch_restart_notes(est), *rls_astray(scores), *batch_astray(scores), *poor_fit(scores)
    ])  # fmt: skip

    def own_frame(model: ScannerModel, prof: HeightProfile, name: str) -> tuple[float, float]:
        # A model whose h was re-indexed by it lives in its own frame: place the working
        # line's particles by its prediction of part A's forward trace, or without
        # calibration cycles put that trace on the loop's span (Section IV).
        if prof is profile:
            return alpha, beta
        y_fwd = predicted_forward_trace(model, u, T, forward, creep_start)
        u_fwd = u[forward[0]]
        try:
            if calibration is None:
                return span_frame(loop.loop, u_fwd, y_fwd)
            return mapped_frame(lambda x: np.interp(x, u_fwd, y_fwd))
        except ValueError as exc:
            notes.append(
                f"the {name} model's frame could not be mapped on its own ({exc}); it uses "
                "the loop's frame map"
            )
            return alpha, beta

    batch_map = own_frame(batch_model, batch_profile, "batch")
    rls_map = own_frame(rls_res.model, rls_profile, "RLS")
    timing["estimation"] = time.perf_counter() - t3
    fits = unreferenced = None
    if reference is not None:
        t4 = time.perf_counter()
        fits = scale_fits(
            {"rls": rls_res.model, "batch": batch_model},
            reference,
            scores,
            notes,
            prescale={"rls": rls_map[0], "batch": batch_map[0]},
        )
        unreferenced = {
            "rls": mapped(rls_res.model, *rls_map),
            "batch": mapped(batch_model, *batch_map),
        }
        if "rls" in fits:
            rls_map = _referenced_map(fits["rls"].alpha, rls_map, center_line)
        batch_map = _referenced_map(fits["batch"].alpha, batch_map, center_line)
        covered = max(float(np.ptp(reference.u_nm[a:b])) for a, b in reference.passes)
        span = wf.u_max_nm - wf.u_min_nm
        centre = float(np.mean([np.mean(reference.u_nm[a:b]) for a, b in reference.passes]))
        if covered < 0.95 * span or abs(centre - center_line) > 0.05 * span:
            notes.append(
                f"the grating passes cover {covered:.0f} nm of command about {centre:.0f} nm, "
                f"not the working span of {span:.0f} nm about {center_line:.0f} nm: the scale "
                "is carried over from elsewhere in the range"
            )
        timing["reference"] = time.perf_counter() - t4
    # Held-out scores in the working frame (where h lives); the models are then mapped onto
    # the calibration frame (identity without calibration cycles).
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
    timing["total_computing"] = (
        timing["acquisition_setup"]
        + timing["loop"]
        + timing["estimation"]
        + timing.get("extra_lines", 0.0)
        + timing.get("reference", 0.0)
    )
    # where the models hold: the waveform's commands, within the scanner's travel
    validity: dict[str, Any] = {"domain_nm": wf.domain_nm, "range_nm": float(instrument.range_nm)}
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
        rls_model=replace(mapped(rls_res.model, *rls_map), **validity),
        batch_model=replace(mapped(batch_model, *batch_map), **validity),
        refine=ref,
        fit_mask=fit_mask,
        heldout_rms_nm=scores,
        findings=tuple(findings),
        timing_s=timing,
        line_stability=stability,
        creep_start_nm=creep_start,
        batch_profile=batch_profile,
        rls_frame_map=rls_map,
        reference=fits,
        unreferenced_models=unreferenced,
        reference_record=reference,
        extra_lines=tuple(e.line for e in extra),
        rls_profile=rls_profile,
        rls_on_lines=rls_lines,
        final_fit=batch_final is not None or rls_final is not None,
        batch_restart=est.batch_restart,
    )


def check_fits(cfg: SensorlessConfig, axis: str, range_nm: float) -> None:
    """Refuse, before anything moves, a working line or calibration cycles that leave the
    scanner's range."""
    half = 0.5 * range_nm
    centre = cfg.center_nm[0 if axis == "x" else 1]
    if abs(centre) + 0.5 * cfg.span_nm > half:
        raise ValueError(
            f"the working line {centre:g} +- {0.5 * cfg.span_nm:g} nm leaves the scanner's range "
            f"+-{half:g} nm: lower span_nm (--span-nm) or move center_nm."
        )
    if cfg.calibration_span_nm is not None and cfg.calibration_span_nm > range_nm:
        raise ValueError(
            f"calibration_span_nm = {cfg.calibration_span_nm:g} nm exceeds the scanner's range "
            f"{range_nm:g} nm."
        )


def identify_axes(
    instrument: Instrument,
    config: SensorlessConfig | None = None,
    axes: Sequence[str] = ("x",),
    *,
    references: Mapping[str, GratingRecord] | None = None,
) -> dict[str, AxisIdentification]:
    """:func:`identify_axis` for each axis in turn (with its grating record, if given)."""
    refs = references or {}
    return {a: identify_axis(instrument, config, a, reference=refs.get(a)) for a in axes}
