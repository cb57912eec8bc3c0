"""The research-level configuration of the sensorless identification: every setting of
every stage.

:class:`SensorlessConfig` holds them all (all of which go into ``summary.json``), with the
defaults the accuracy table of ``docs/identification.md`` was measured with: the estimation
stage's own settings (:class:`~piezocomp.identification.estimation_options.EstimationOptions`, whose
fields it inherits, with the RLS settings of :mod:`~piezocomp.identification.rls`:
``RLS_CANDIDATES``, ``RLS_START``, ``RLS_CONTINUE``) and those of the acquisition, the loop
and the lines; the fields only a driven acquisition uses (:data:`ACQUISITION_FIELDS`).
A user sets the few of :class:`~piezocomp.identification.settings.IdentifySettings`, which
builds this one. Lengths are nm of command, times s.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.cross_drift import DITHER_NM
from piezocomp.identification.estimation_options import EstimationOptions
from piezocomp.identification.rls import RLS_CANDIDATES, RLS_CONTINUE, RLS_START

__all__ = [
    "ACQUISITION_FIELDS",
    "RLS_CANDIDATES",
    "RLS_CONTINUE",
    "RLS_START",
    "SensorlessConfig",
]

ACQUISITION_FIELDS = frozenset({
    "center_nm", "span_nm", "speed_nm_per_s", "overview_pixels", "overview_speed_nm_per_s",
    "n_steady", "n_decaying",
    "n_random", "max_dwell_s", "speed_factors", "calibration_span_nm",
    "calibration_speed_nm_per_s", "calibration_degree", "overview_shifts",
    "line_search_nm", "line_search_step_nm", "settle_s", "line_settle_s", "relocate_search_nm",
    "relocate_settle_s", "cross_dither_nm", "check_cycles", "check_tolerance_nm",
    "rerecord_unstable",
    "min_line_particles", "loop_pairs_factor", "seed", "extra_lines", "extra_line_offset_nm",
    "joint_rounds", "rls_lines_passes",
})  # fmt: skip
"""The :class:`SensorlessConfig` fields only the driven acquisition uses (a recorded run's
waveform file fixes the waveform; it has one line and no calibration cycles)."""


@dataclass(frozen=True)
class SensorlessConfig(EstimationOptions):
    """Every setting of the sensorless procedure (lengths nm of command, times s).

    The research-level object:
    :class:`~piezocomp.identification.settings.IdentifySettings` holds the dozen a user sets
    and builds this one (its ``config``); everything else has the default the
    accuracy table of ``docs/identification.md`` was measured with, and the reasons for
    the defaults are in ``docs/identification-design.md``.

    Parameters
    ----------
    center_nm, span_nm, speed_nm_per_s
        Centre (x, y) and side of the working area; ramp speed of the waveform.
    overview_pixels, overview_speed_nm_per_s
        Pixels per side of the overview image, and the speed of its fast axis (capped at
        the instrument's speed limit; ``None``: ``speed_nm_per_s``). The overview only
        chooses the line (the line search then finds it by its own cycles): at the
        waveform's 250 nm/s a 2 um, 128-line overview takes 34 minutes, at an imaging
        speed a few, but the slow axis then creeps over the line for longer and the models
        came out worse on ``cpr5`` (``docs/identification.md``, *Instrument time*).
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
    holdout_fraction : float
        Fraction of part B (its end) held out to choose the orders and rounds.
    orders, rls_settings, rls_start, rls_continue, rls_reindex_rounds, rls_reindex_passes
        The estimation stage's settings
        (:class:`~piezocomp.identification.estimation_options.EstimationOptions`), as are
        ``refine_max_nfev``, ``refine_free``, ``creep_tau_range_s``, ``creep_smoothing_nm``,
        ``weight_smoothing_nm``, ``reindex_rounds``, ``selection_rounds``,
        ``reindex_max_nfev``, ``order_tolerance``, ``batch_restart_ratio`` and ``workers``.
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
    joint_rounds, rls_lines_passes
        With extra lines: rounds of the joint batch refinement over all lines, each line
        weighted by the inverse of its residual level; the RLS on every
        line, kept if it predicts the lines' held-out heights better.
    final_rounds, rls_final_passes : int
        After the held-out part has chosen orders and rounds: batch rounds and RLS passes
        over the whole record of every line (0: none).
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
    overview_speed_nm_per_s: float | None = None
    degree: int = 5
    min_prominence_nm: float = 3.0
    n_steady: int = 4
    n_decaying: int = 12
    n_random: int = 30
    max_dwell_s: float = 4.0
    speed_factors: tuple[float, ...] = (0.5, 1.0, 2.0)
    holdout_fraction: float = 0.25
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
    final_rounds: int = 1
    rls_final_passes: int = 10
    drift_rounds: int = 1
    drift_knot_spacing_s: float = 20.0
    drift_smoothing: float = 1.0
    drift_anchor: float = 1.0

    def estimation_options(self, reindex_rounds: int | None = None) -> EstimationOptions:
        """The estimation stage's options (``reindex_rounds``: the first line's own rounds,
        default :attr:`reindex_rounds`)."""
        own = {f.name: getattr(self, f.name) for f in fields(EstimationOptions)}
        if reindex_rounds is not None:
            own["reindex_rounds"] = int(reindex_rounds)
        return EstimationOptions(**own)

    @property
    def reduced_record(self) -> bool:
        """Whether the waveform holds fewer cycles or shorter dwells than the default's (as
        ``--quick``'s): a shorter record tells drift from creep less well."""
        return any(getattr(self, k) < getattr(SensorlessConfig, k)
                   for k in ("n_steady", "n_decaying", "n_random", "max_dwell_s"))  # fmt: skip

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.0 < float(self.holdout_fraction) < 0.9:
            raise ValueError(f"holdout_fraction must be in (0, 0.9). Got {self.holdout_fraction}.")
        if self.span_nm <= 0 or self.speed_nm_per_s <= 0:
            raise ValueError("span_nm and speed_nm_per_s must be > 0.")
        ov = self.overview_speed_nm_per_s
        if ov is not None and not check_finite_scalar("overview_speed_nm_per_s", ov) > 0:
            raise ValueError(f"overview_speed_nm_per_s must be > 0 or None. Got {ov}.")
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
            ("rls_lines_passes", 0),
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
        dr = self.drift_rounds
        if isinstance(dr, bool) or not isinstance(dr, int) or not 0 <= dr <= 10:
            raise ValueError(f"drift_rounds must be an integer in [0, 10]. Got {dr!r}.")
        if check_finite_scalar("drift_knot_spacing_s", self.drift_knot_spacing_s) <= 0:
            raise ValueError(f"drift_knot_spacing_s must be > 0. Got {self.drift_knot_spacing_s}.")
        for name in ("drift_smoothing", "drift_anchor"):
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
