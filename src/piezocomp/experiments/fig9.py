"""Fig. 9 of the paper: back to the start after a path of straight moves.

A 253 x 253 nm image is taken at (0.3, 0.3) um; the tip then visits (-0.5, -0.3),
(0.45, 0.45), (-0.4, -0.4) and comes back to (0.3, 0.3) um along straight lines, and the
same image is taken again. The error is the translation between the two images, by
cross-correlation as the paper measured it (14.3 nm uncompensated, 1.0 nm compensated) and,
on a simulator, from the ground truth. Coordinates are relative to the experiment's origin
(the centre of the working area).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from piezocomp._validation import check_finite_scalar
from piezocomp.experiments.contract import (
    DRIFT_METHOD,
    Outcome,
    Plan,
    Trial,
    finite_or_none,
    shown_methods,
    succeeded,
)
from piezocomp.experiments.methods import MethodModels, trial_instrument
from piezocomp.experiments.results import Fig9, Fig9Method, Fig9Speed
from piezocomp.experiments.truth import Truth, true_displacement
from piezocomp.imaging.registration import image_displacement
from piezocomp.instrument import Instrument, ScanImage
from piezocomp.virtual_afm import AFMConfig, VirtualAFM

__all__ = [
    "NAME",
    "PAPER",
    "PATH_NM",
    "Fig9Result",
    "Fig9Settings",
    "plan",
    "run",
    "run_trial",
    "summarise",
]

NAME = "fig9"

PATH_NM = ((300.0, 300.0), (-500.0, -300.0), (450.0, 450.0), (-400.0, -400.0), (300.0, 300.0))
"""The path of Fig. 9, nm from the origin."""

PAPER = {"uncompensated": 14.3, "compensated": 1.0}
"""Displacement between the two images in the paper, nm."""


@dataclass(frozen=True)
class Fig9Settings:
    """The experiment of Fig. 9.

    Parameters
    ----------
    speed_nm_per_s : float
        Speed of the moves (the paper manipulates at about 1 um/s).
    size_nm, pixels, line_rate_hz
        The images (the paper's 253 nm; 128 pixels at 2 lines/s here).
    keep_images : bool
        Keep both images in the result.
    """

    speed_nm_per_s: float = 1000.0
    size_nm: float = 253.0
    pixels: int = 128
    line_rate_hz: float = 2.0
    keep_images: bool = False

    def __post_init__(self) -> None:
        for name in ("speed_nm_per_s", "size_nm", "line_rate_hz"):
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        if isinstance(self.pixels, bool) or not isinstance(self.pixels, int) or self.pixels < 8:
            raise ValueError(f"pixels must be an integer >= 8. Got {self.pixels!r}.")


@dataclass(frozen=True)
class Fig9Result:
    """Displacement between the images before and after the path.

    Attributes
    ----------
    settings : Fig9Settings
    error_nm : float
        By cross-correlation (NaN if an image held nothing to register).
    true_error_nm : float or None
        From the ground truth (``None`` without one).
    images : (ScanImage, ScanImage) or None
        Before and after (with ``keep_images``).
    """

    settings: Fig9Settings
    error_nm: float
    true_error_nm: float | None = None
    images: tuple[ScanImage, ScanImage] | None = field(default=None, repr=False)


def run(
    instrument: Instrument,
    settings: Fig9Settings,
    *,
    origin_nm: tuple[float, float] = (0.0, 0.0),
    truth: Truth | None = None,
) -> Fig9Result:
    """Run Fig. 9's experiment on ``instrument`` (raw or compensated), coordinates relative
    to ``origin_nm``."""
    s = settings
    o = np.asarray(origin_nm, dtype=float)
    start = o + PATH_NM[0]
    center = (float(start[0]), float(start[1]))
    instrument.move_to(center[0], center[1], s.speed_nm_per_s)
    before = instrument.scan_image(center, s.size_nm, s.pixels, s.line_rate_hz)
    for p in PATH_NM[1:]:
        q = o + p
        instrument.move_to(float(q[0]), float(q[1]), s.speed_nm_per_s)
    after = instrument.scan_image(center, s.size_nm, s.pixels, s.line_rate_hz)
    try:
        error = image_displacement(before, after).magnitude_nm
    except ValueError:
        error = float("nan")
    true = None if truth is None else true_displacement(truth, before, after)
    return Fig9Result(s, error, true, (before, after) if s.keep_images else None)


# ---------------------------------------------------------------- in piezocomp reproduce
def plan(p: Plan) -> list[Trial]:
    """Every method at every speed (the paper's keeps its images), and on a drifting scanner
    the paper's speed inside the drift compensator."""
    trials = []
    for m in p.methods:
        for v in p.speeds_nm_per_s:
            keep = v == p.paper_speed_nm_per_s
            trials.append(Trial(NAME, m, Fig9Settings(speed_nm_per_s=v, keep_images=keep), keep))
    if p.drift_compensated:
        st = Fig9Settings(speed_nm_per_s=p.paper_speed_nm_per_s, keep_images=True)
        trials.append(Trial(NAME, DRIFT_METHOD, st, True))
    return trials


def run_trial(trial: Trial, config: AFMConfig, seed: int, models: MethodModels) -> Fig9Result:
    """The path on a fresh virtual AFM, scored against its truth."""
    afm = VirtualAFM(config, seed=seed)
    st = trial.settings
    size = 2.0 * float(np.max(np.abs(PATH_NM))) + st.size_nm  # the drift compensator's area
    inst, origin = trial_instrument(trial.method, afm, models, size)
    return run(inst, st, origin_nm=origin, truth=afm.truth)


def summarise(p: Plan, outcomes: list[Outcome]) -> dict[str, Any]:
    """``fig9``: each method's displacement (measured and true) at each speed, the paper's
    speed's also as ``methods``."""
    ok = succeeded(outcomes, NAME)
    shown = shown_methods(p, outcomes)
    speeds: list[Fig9Speed] = []
    for v in p.speeds_nm_per_s:
        methods: dict[str, Fig9Method] = {}
        for m in shown:
            rs = [r for t, r in ok if t.method == m and r.settings.speed_nm_per_s == v]
            if rs:
                methods[m] = {
                    "error_nm": finite_or_none(rs[0].error_nm),
                    "true_error_nm": finite_or_none(rs[0].true_error_nm),
                }
        speeds.append({"speed_nm_per_s": v, "methods": methods})
    section: Fig9 = {
        "speed_nm_per_s": p.paper_speed_nm_per_s,
        "methods": speeds[0]["methods"],
        "speeds": speeds,
    }
    return {"fig9": section}
