"""When a drift-compensated instrument measures its landmarks.

Before a motion (a move, a push, a path, a wait or an image), the drift is measured when it
is *due*: by the motion's end the predicted uncertainty would pass ``tolerance_nm``, or
``max_interval_s`` would have passed since the last measurement (:func:`due`). A long image
or wait is also interrupted between its lines or pieces when that is *worth* it
(:func:`worth_measuring`): due with ``image_tolerance_nm``, and the last measurement did
bring the uncertainty below it, or the landmarks would be lost otherwise (:func:`at_risk`:
the prediction too uncertain for their windows).
"""

from __future__ import annotations

import numpy as np

from piezocomp.drift.filter import DriftFilter, DriftSettings
from piezocomp.drift.landmark_set import safe_sigma_nm

__all__ = ["WAIT_STEP_S", "at_risk", "due", "worth_measuring"]

WAIT_STEP_S = 2.0
"""Longest piece of a wait held without asking whether the drift must be measured, s (an
image's line at 0.5 Hz)."""


def due(
    f: DriftFilter, settings: DriftSettings, end_s: float, last_s: float,
    tolerance_nm: float | None = None,
) -> bool:  # fmt: skip
    """Whether the drift must be measured before a motion that ends at ``end_s``: the
    uncertainty would pass ``tolerance_nm`` (default ``settings.tolerance_nm``) by then, or
    ``max_interval_s`` would have passed since the last measurement at ``last_s``."""
    if end_s - last_s > settings.max_interval_s:
        return True
    tol = settings.tolerance_nm if tolerance_nm is None else tolerance_nm
    return bool(np.max(f.at(end_s).std_nm) > tol)


def at_risk(f: DriftFilter, settings: DriftSettings, end_s: float) -> bool:
    """Whether by ``end_s`` the prediction would be too uncertain for the landmarks'
    windows (:func:`~piezocomp.drift.landmark_set.safe_sigma_nm`)."""
    return bool(np.max(f.at(end_s).std_nm) > safe_sigma_nm(settings.landmarks))


def worth_measuring(f: DriftFilter, settings: DriftSettings, end_s: float, last_s: float) -> bool:
    """Whether to interrupt an image or a wait to measure before a piece that ends at
    ``end_s``: the drift will be due with ``image_tolerance_nm`` (or ``max_interval_s``), and
    the last measurement did bring the uncertainty below that tolerance (with noisy
    measurements another one would not, and every line would be interrupted), or the
    landmarks would be lost otherwise (:func:`at_risk`)."""
    s = settings
    if not due(f, s, end_s, last_s, s.image_tolerance_nm):
        return False
    return (
        end_s - last_s > s.max_interval_s
        or at_risk(f, s, end_s)
        or bool(np.max(f.estimate.std_nm) < s.image_tolerance_nm)
    )
