"""The acquisition stage's settings: :class:`AcquisitionConfig`, with the identification
waveform's, :class:`WaveformConfig` (``acquisition`` in
:class:`~piezocomp.identification.config.IdentifyConfig`). Lengths nm of command, times s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from piezocomp._validation import check_finite_scalar, check_int_at_least
from piezocomp.identification.acquisition.drift_across_line import DITHER_NM

__all__ = ["AcquisitionConfig", "WaveformConfig"]


@dataclass(frozen=True)
class WaveformConfig:
    """The identification waveform of Fig. 7a
    (:func:`~piezocomp.identification.acquisition.waveforms.identification_waveform`).

    Parameters
    ----------
    n_steady, n_decaying, n_random : int
        Steady cycles of part A; decaying and random ramps of part B.
    max_dwell_s : float
        Longest dwell of part B's random ramps.
    speed_factors : tuple of float
        Part B's ramps run at the acquisition's ``speed_nm_per_s`` times these factors in
        turn (capped at the instrument's speed limit): 0.5 to 8 are 125 nm/s to 2 um/s at the
        default speed, the speeds the compensator is then used at; several speeds tell the
        fast creep modes from narrow play operators; ``(1.0,)`` is the paper's single speed.
    seed : int
        Randomness of the waveform.
    """

    n_steady: int = 4
    n_decaying: int = 12
    n_random: int = 30
    max_dwell_s: float = 4.0
    speed_factors: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0, 8.0)
    seed: int = 0

    def __post_init__(self) -> None:
        factors = tuple(
            check_finite_scalar("speed_factors", v) for v in np.atleast_1d(self.speed_factors)
        )
        if not factors or min(factors) <= 0:
            raise ValueError(
                f"speed_factors must hold at least one factor, all > 0. Got {self.speed_factors}."
            )
        object.__setattr__(self, "speed_factors", factors)

    @property
    def reduced(self) -> bool:
        """Whether the waveform holds fewer cycles or shorter dwells than the default's (as
        ``--quick``'s): a shorter record tells drift from creep less well."""
        default = WaveformConfig()
        return any(getattr(self, k) < getattr(default, k)
                   for k in ("n_steady", "n_decaying", "n_random", "max_dwell_s"))  # fmt: skip


@dataclass(frozen=True)
class AcquisitionConfig:
    """What the instrument is asked to do for one axis (Section V, steps 1-2), and how its
    records are read (the peak finding).

    Parameters
    ----------
    center_nm, span_nm, speed_nm_per_s
        Centre (x, y) and side of the working area; base ramp speed of the waveform. The
        default span, 2000 nm, reaches about +-800 true nm on the virtual ``cpr5``.
    waveform : WaveformConfig
        The identification waveform of Fig. 7a.
    min_prominence_nm : float
        Smallest particle prominence counted as a peak, wherever peaks are found.
    calibrate : "full-range", "span" or float
        Steady cycles over a wider span, where the nominal sensitivity was calibrated, give a
        second loop onto whose frame the models are mapped
        (:func:`~piezocomp.identification.reference.frames.frame_map`): ``"full-range"``, the
        scanner's whole range; a number, that span (nm); ``"span"``: none, the paper's calibration
        condition on the working span.
    calibration_speed_nm_per_s : float, optional
        The calibration cycles' speed (``None``: the instrument's ``calibration_scan``).
    overview_pixels, overview_speed_nm_per_s
        Pixels per side of the overview image, and the speed of its fast axis (capped at
        the instrument's speed limit; ``None``: ``speed_nm_per_s``). The overview only
        chooses the line: at the waveform's 250 nm/s a 2 um, 128-line overview takes 34
        minutes, at an imaging speed a few, but the slow axis then creeps over the line for
        longer and the models came out worse on ``cpr5`` (``docs/identification.md``,
        *Instrument time*).
    line_settle_s, relocate_settle_s
        Time scanning the line's steady cycle before the record, so that the slow axis'
        creep has slowed; settling time when the tip left the line while settling.
    cross_dither_nm
        Step of the slow command on every other settling cycle, by which the line's slide across its
        particles is measured and then followed during the record
        (:mod:`~piezocomp.identification.acquisition.drift_across_line`); 0: the slow command is
        held.
    check_cycles, rerecord_unstable
        Steady cycles scanned right after the record to check the line's profile (0: no
        check); times the line is found again and recorded anew when it changed (0: report
        only).
    extra_lines, extra_line_offset_nm
        Further particle lines (overviews this far apart on the slow axis) whose records
        refine the same models with the first (0: the paper's single line).
    """

    center_nm: tuple[float, float] = (0.0, 0.0)
    span_nm: float = 2000.0
    speed_nm_per_s: float = 250.0
    waveform: WaveformConfig = field(default_factory=WaveformConfig)
    min_prominence_nm: float = 3.0
    calibrate: str | float = "full-range"
    calibration_speed_nm_per_s: float | None = None
    overview_pixels: int = 128
    overview_speed_nm_per_s: float | None = None
    line_settle_s: float = 600.0
    relocate_settle_s: float = 300.0
    cross_dither_nm: float = DITHER_NM
    check_cycles: int = 4
    rerecord_unstable: int = 1
    extra_lines: int = 1
    extra_line_offset_nm: float = 1000.0

    def __post_init__(self) -> None:
        if not isinstance(self.waveform, WaveformConfig):
            raise TypeError(f"waveform must be a WaveformConfig. Got {type(self.waveform)}.")
        centre = tuple(check_finite_scalar("center_nm", v) for v in self.center_nm)
        if len(centre) != 2:
            raise ValueError(f"center_nm must be (x, y). Got {self.center_nm!r}.")
        object.__setattr__(self, "center_nm", centre)
        for name in ("span_nm", "speed_nm_per_s", "extra_line_offset_nm", "min_prominence_nm"):
            if check_finite_scalar(name, getattr(self, name)) <= 0:
                raise ValueError(f"{name} must be > 0. Got {getattr(self, name)}.")
        for name in ("overview_speed_nm_per_s", "calibration_speed_nm_per_s"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not check_finite_scalar(name, v) > 0):
                raise ValueError(f"{name} must be None or > 0. Got {v!r}.")
        cal = self.calibrate
        if cal not in ("full-range", "span") and (
            isinstance(cal, (bool, str)) or not check_finite_scalar("calibrate", cal) > 0
        ):
            raise ValueError(
                f"calibrate must be 'full-range', 'span' or a span in nm > 0. Got {cal!r}."
            )
        for name, lo in (("extra_lines", 0), ("rerecord_unstable", 0), ("check_cycles", 0),
                         ("overview_pixels", 2)):  # fmt: skip
            check_int_at_least(name, getattr(self, name), lo)
        for name in ("line_settle_s", "relocate_settle_s", "cross_dither_nm"):
            if check_finite_scalar(name, getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0. Got {getattr(self, name)}.")

    def calibration_span_nm(self, range_nm: float | None) -> float | None:
        """The calibration cycles' span for a scanner of ``range_nm`` (``None``: none)."""
        if self.calibrate == "span":
            return None
        if self.calibrate == "full-range":
            if range_nm is None or not float(range_nm) > 0:
                raise ValueError(
                    f"calibrate='full-range' needs the scanner's range_nm > 0. Got {range_nm}."
                )
            return float(range_nm)
        return float(self.calibrate)
