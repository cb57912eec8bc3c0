"""Findings on the estimated models: the held-out heights tell whether one went astray.

The held-out part of the record is predicted by each model through its own ``h(y)``; no
sensor is needed. :func:`rls_astray`, :func:`batch_astray`, :func:`poor_fit` and
:func:`batch_restart_notes` return the sentences a user should read, and
:func:`drift_during_record` one on a drift the estimation could not take out;
:func:`line_drift_text` says what the drift taken out was.
"""

from __future__ import annotations

import math
from typing import Any

from piezocomp.identification.estimation.chain import Estimation, far_worse
from piezocomp.identification.estimation.config import BATCH_ASTRAY_RATIO

__all__ = [
    "BATCH_ASTRAY_RATIO",
    "DRIFT_FINDING_NM",
    "POOR_HELDOUT_NM",
    "RLS_ASTRAY_RATIO",
    "batch_astray",
    "batch_restart_notes",
    "drift_during_record",
    "line_drift_text",
    "poor_fit",
    "rls_astray",
]

RLS_ASTRAY_RATIO = 5.0
"""Held-out height RMS of the RLS over the batch model's above which a finding says so."""


def rls_astray(heldout: dict[str, float]) -> list[str]:
    """A finding when the RLS estimate predicts the held-out heights far worse than the batch
    model (more than :data:`RLS_ASTRAY_RATIO` times and by more than 1 nm): it has settled in
    another basin and is likely nanometres off. Over cpr5 seeds the ratio stays below about
    3.5 where the RLS is within 2 nm of the truth and exceeds 10 where it is not."""
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
    refinement has left for another basin. With
    :attr:`~piezocomp.identification.estimation.config.EstimationConfig.batch_restart_ratio`
    the batch chain is first run again from the RLS estimate; this fires only if the better of
    the two is still far worse."""
    r, b = heldout.get("rls", float("nan")), heldout.get("batch", float("nan"))
    if not far_worse(b, r, BATCH_ASTRAY_RATIO):
        return []
    return [
        f"the batch model predicts the held-out heights to {b:.2f} nm RMS, {b / r:.1f} times "
        f"the RLS estimate's {r:.2f} nm: the refinement has probably left for another basin "
        "and may be nanometres off; use the RLS model (model_rls.json)"
    ]


POOR_HELDOUT_NM = 1.5
"""Held-out height RMS of the batch model above which the result is flagged as poor: on a
settled line with 15 nm particles it is 0.1-0.5 nm without drift, 0.5-1.2 nm on the drifting
virtual cpr5 (0.05 nm/s; the drift taken out, with models truly 1.8-2.8 nm off at most, as
on the drift-free scanner); a line that moved under the tip during the record, or a record
not settled on it, gives 1.7 nm and more (a record started right after a 600 nm move onto
the line: 1.7 nm; one of 20 drifting samples: 2.6 nm)."""


SMALL_ORDERS = (16, 10)
"""Fewer play (or creep) operators than these: a model too small for a scanner like ``cpr5``
(the default candidates are 16 and 32 play, 22 creep operators; ``--quick`` runs 8 and 2)."""


def poor_fit(heldout: dict[str, float], orders: tuple[int, int] | None = None) -> list[str]:
    """A finding when even the batch model predicts the held-out heights poorly (more than
    :data:`POOR_HELDOUT_NM` RMS): the record itself is suspect, or, with ``orders`` (the
    model's ``(n_play, n_creep)``) below :data:`SMALL_ORDERS`, the model too small (with no
    creep operators at all, it cannot follow creep: expected of a comparison without it)."""
    b = heldout.get("batch", float("nan"))
    if not b > POOR_HELDOUT_NM:
        return []
    record = (
        "Was the line settled before the record (identify scans it for line_settle_s first; "
        "a record made elsewhere needs several minutes of it), and did the tip stay on it "
        "(no drift, no pushed particle)? Record again rather than use this model"
    )
    text = (f"the batch model predicts the held-out heights to {b:.2f} nm RMS only (more than "
            f"{POOR_HELDOUT_NM:g} nm): the model may be nanometres off, or far more. ")  # fmt: skip
    if orders is not None and orders[1] == 0:
        return [
            text + "It has no creep operators: the heights of a scanner that creeps cannot be "
            "predicted without them. Expected of a model meant to leave creep out (a "
            "comparison); otherwise identify with creep operators (the default orders)."
        ]
    if orders is not None and (orders[0] < SMALL_ORDERS[0] or orders[1] < SMALL_ORDERS[1]):
        return [
            text + f"It has {orders[0]} play and {orders[1]} creep operators only, too few for "
            "a scanner like cpr5 (the published method's orders and --quick's are this small): "
            "for a model to use, identify with the default orders. If the fit stays poor with "
            "them, the record itself is suspect. " + record
        ]
    return [text + record]


def batch_restart_notes(est: Estimation) -> list[str]:
    """A note on the batch chain's restart from the RLS estimate, if it was run
    (:attr:`~piezocomp.identification.estimation.chain.Estimation.batch_restart`)."""
    r = est.batch_restart
    if r is None:
        return []
    kept = "kept" if r["kept"] == "restart" else "not kept: the first chain's model stays"
    return [
        f"the batch model predicted the held-out heights to {r['first']:.2f} nm RMS, far worse "
        f"than the RLS estimate's {est.heldout_rms_nm['rls']:.2f} nm; refined again from the "
        f"RLS estimate it predicts them to {r['restart']:.2f} nm ({kept})"
    ]


DRIFT_FINDING_NM = 1.0
"""Drift along the line over the record (nm) above which a finding says so."""


def line_drift_text(line_drift: dict[str, Any], settling_nm_per_s: float | None = None) -> str:
    """The drift along the line estimated with the model (``line_drift``,
    :class:`~piezocomp.identification.result.AxisIdentification`'s), as the particles' slide
    in the command, the sign the settling rate ``settling_nm_per_s`` has (the path ``d`` of
    ``h(y + d)`` moves the particles by ``-d``), with the held-out heights without and with
    it taken out."""
    settling = ""
    if settling_nm_per_s is not None and math.isfinite(settling_nm_per_s):
        settling = f"; {settling_nm_per_s:+.3f} nm/s while the tip settled"
    without, with_ = line_drift["heldout_rms_without_nm"], line_drift["heldout_rms_with_nm"]
    return (
        f"the particles slid {-line_drift['rate_nm_per_s']:+.3f} nm/s along the line during "
        f"the first record, estimated with the model (the least-squares slope of its path, "
        f"which spans {line_drift['extent_nm']:.1f} nm{settling}), held-out "
        f"heights {without:.2f} nm without it taken out, {with_:.2f} nm with"
        + ("" if line_drift["kept"] else " (not kept: it did not help)")
    )


def drift_during_record(
    rate_nm_per_s: float | None,
    record_s: float,
    line_drift: dict[str, Any] | None = None,
    *,
    n_creep: int | None = None,
    reduced: bool = False,
) -> list[str]:
    """A finding when the sample drifted along the line and the drift could not be taken
    out: the drift estimated with the model (``line_drift``) did not predict the held-out
    heights better, and the rate measured while the tip settled (``rate_nm_per_s``, the
    particles' slide) amounts to more than :data:`DRIFT_FINDING_NM` over the record. A
    drift that was taken out is no finding (:func:`line_drift_text` reports it). The advice
    depends on the model's creep operators (``n_creep``) and on whether the record was a
    ``reduced`` one (``--quick``)."""
    if line_drift is not None and line_drift["kept"]:
        return []
    # Not kept: the held-out heights do not support that path (on a scanner that does not
    # drift it is model error), so only the rate measured while settling speaks.
    if rate_nm_per_s is None or not abs(rate_nm_per_s) * record_s > DRIFT_FINDING_NM:
        return []
    moved = abs(rate_nm_per_s) * record_s
    why = (
        "it was not estimated with the model (drift_rounds = 0, or the heights could not "
        "place its path)"
        if line_drift is None
        else "estimated from the heights, it did not predict the held-out part better"
    )
    carried = (
        "the model, which has no creep operators, carries it in its error"
        if n_creep == 0
        else "the models may carry it as creep, that far off"
    )
    longer = "A record of the default length tells drift from creep better. " if reduced else ""
    return [
        f"the particles slid {rate_nm_per_s:+.3f} nm/s along the line while the tip settled "
        f"on it: about {moved:.1f} nm over the {record_s:.0f} s record at that rate; the "
        f"drift was not taken out of the estimation ({why}), so {carried}. {longer}An "
        "instrument still warming up drifts faster (piezocomp drift measures it)"
    ]
