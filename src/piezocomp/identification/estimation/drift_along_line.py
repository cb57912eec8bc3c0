"""The sample's drift along the line during an identification record, estimated with the model.

In air the sample drifts under the tip by 0.01-0.1 nm/s once the instrument has warmed up
(more while it warms up). Along the fast axis a record of a few minutes then sees
nanometres of drift, which a model of the command alone cannot tell from creep: the
estimation would take it for creep. Here the heights are predicted as

``z_m(k) = h(y_hat(k) + d(k))``

with ``d`` the sample's drift along the line since part A (where ``h`` was measured), in
``h``'s coordinates. ``d`` is a smooth path in time, piecewise linear between knots
``knot_spacing_s`` apart, of zero mean over part A's forward traces, and it is estimated
with the model (Gauss-Newton on the same height prediction error the estimation minimises,
the model held): drift is what the heights show that no function of the command explains.
A penalty on the path's second differences keeps it smooth, so a creep misfit, which
changes with the command from one second to the next, is not taken for drift; it also
carries the path on in a straight line past the last fitted sample (the held-out part of
the record is predicted, not fitted).

:func:`fit_line_drift` fits the path of one line with the model held, :func:`joint_line_drift`
every line's path together with the batch model; :func:`~piezocomp.identification.estimation.
drift_rounds.drift_rounds` alternates them with the estimation
(:class:`~piezocomp.identification.estimation.config.RoundsConfig`'s ``drift_rounds``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar, readonly
from piezocomp.identification.estimation.batch import RefineOptions, Segment, refine
from piezocomp.identification.estimation.prediction import creep_rest, heldout_rms, record_state
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.model import ScannerModel, simulate

__all__ = ["DriftBasis", "LineDrift", "fit_line_drift", "joint_line_drift", "straight"]


@dataclass(frozen=True)
class LineDrift:
    """The sample's drift along the line over one record.

    Attributes
    ----------
    knots_s : ndarray, shape (m,)
        Knot times from the record's first sample (s).
    drift_nm : ndarray, shape (m,)
        The drift at each knot (nm, in ``h``'s coordinates, zero mean over part A).
    sample_period_s : float
    n_samples : int
        Samples of the record.
    rms_before_nm, rms_after_nm : float
        Height residual RMS over the fitted samples without the drift and with it (nm).
    """

    knots_s: NDArray[np.float64]
    drift_nm: NDArray[np.float64]
    sample_period_s: float
    n_samples: int
    rms_before_nm: float
    rms_after_nm: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "knots_s", readonly(np.asarray(self.knots_s, dtype=float)))
        object.__setattr__(self, "drift_nm", readonly(np.asarray(self.drift_nm, dtype=float)))

    def path(self) -> NDArray[np.float64]:
        """The drift at every sample of the record (nm)."""
        t = np.arange(self.n_samples) * self.sample_period_s
        return np.interp(t, self.knots_s, self.drift_nm)

    @property
    def rate_nm_per_s(self) -> float:
        """Mean drift rate over the record: the slope of the straight line through the knots."""
        return float(np.polyfit(self.knots_s, self.drift_nm, 1)[0])

    @property
    def extent_nm(self) -> float:
        """How far the drift went over the record (largest minus smallest, nm)."""
        return float(np.ptp(self.drift_nm))


def _hat_basis(t: NDArray[np.float64], knots: NDArray[np.float64]) -> NDArray[np.float64]:
    """Piecewise-linear hat functions at ``knots`` (uniformly spaced) sampled at ``t``."""
    step = knots[1] - knots[0]
    return np.maximum(0.0, 1.0 - np.abs(t[:, None] - knots[None, :]) / step)


def straight(
    n: int, sample_period_s: float, reference: Sequence[slice], rate_nm_per_s: float
) -> LineDrift:
    """A drift at a constant rate over a record of ``n`` samples, zero mean over the
    reference samples."""
    T = float(sample_period_s)
    t = np.arange(n) * T
    ref = np.zeros(n, dtype=bool)
    for s in reference:
        ref[s] = True
    offset = float(np.mean(t[ref])) if ref.any() else 0.0
    knots = np.array([0.0, n * T])
    return LineDrift(knots, rate_nm_per_s * (knots - offset), T, n, float("nan"), float("nan"))


@dataclass(frozen=True)
class DriftBasis:
    """The drift paths of one record: piecewise linear in time, zero mean over the reference
    samples. ``matrix`` (n, m - 1) maps free coefficients to the drift at every sample; the
    first knot's coefficient is held at 0 (with the zero mean, a constant added to every
    knot changes nothing).
    """

    knots_s: NDArray[np.float64]
    matrix: NDArray[np.float64]
    mean_ref: NDArray[np.float64]
    sample_period_s: float

    @classmethod
    def of(
        cls, n: int, sample_period_s: float, reference: Sequence[slice], knot_spacing_s: float
    ) -> DriftBasis:
        """The basis for a record of ``n`` samples, knots about ``knot_spacing_s`` apart."""
        T = float(sample_period_s)
        duration = n * T
        m = max(3, math.ceil(duration / knot_spacing_s) + 1)
        knots = np.asarray(np.arange(m) * (duration / (m - 1)), dtype=np.float64)
        t = np.asarray(np.arange(n) * T, dtype=np.float64)
        ref = np.zeros(n, dtype=bool)
        for s in reference:
            ref[s] = True
        hats = _hat_basis(t, knots)
        mean_ref = hats[ref].mean(axis=0) if ref.any() else np.zeros(m)
        return cls(knots, (hats - mean_ref)[:, 1:], mean_ref, T)

    def drift(
        self, coefficients: NDArray[np.float64], start: LineDrift, line: dict[str, float]
    ) -> LineDrift:
        """The :class:`LineDrift` of ``start`` plus the path of free ``coefficients``
        (``line``: its residual RMS before and after, ``rms_before_nm`` and
        ``rms_after_nm``)."""
        c = np.concatenate([[0.0], coefficients])
        values = c - float(self.mean_ref @ c) + np.interp(self.knots_s, start.knots_s,
                                                          start.drift_nm)  # fmt: skip
        return LineDrift(self.knots_s, values, self.sample_period_s, self.matrix.shape[0],
                         float(line["rms_before_nm"]), float(line["rms_after_nm"]))  # fmt: skip


def joint_line_drift(
    model: ScannerModel,
    lines: Sequence[tuple[NDArray[np.float64], NDArray[np.float64], HeightProfile, LineDrift]],
    sample_period_s: float,
    *,
    reference: Sequence[slice],
    fit_mask: NDArray[np.bool_],
    warmup_samples: int,
    creep_start_nm: float | None = None,
    knot_spacing_s: float = 20.0,
    smoothing: float = 1.0,
    anchor: float = 0.0,
    free: Sequence[str] = ("c", "a", "w", "y0"),
    max_nfev: int = 15,
    creep_smoothing_nm: float = 0.0,
    weight_smoothing_nm: float = 0.0,
) -> tuple[ScannerModel, list[LineDrift]]:
    """The drift path of every line estimated together with the model (the batch refinement
    of :func:`~piezocomp.identification.estimation.batch.refine` with a drift basis per line).

    Estimated alone with the model held (:func:`fit_line_drift`), the drift path misses what the
    model, estimated before without it, already took for creep; estimated together, the two share
    the heights as the data decide. ``lines``: each line's command, heights, ``h`` and the drift
    path to start from (e.g. :func:`fit_line_drift`'s), the first line first; ``anchor``: how
    strongly the drift stays near that start
    (:func:`~piezocomp.identification.estimation.batch.refine`'s ``drift_anchor``). Returns the
    refined model and each line's drift."""
    T = float(sample_period_s)
    bases = [DriftBasis.of(u.size, T, reference, knot_spacing_s) for u, *_ in lines]
    starts = [d.path() for *_, d in lines]
    (u0, z0, p0, _), rest = lines[0], lines[1:]
    segments = [
        Segment(u, z, output=p, state=record_state(model, float(u[0]), creep_start_nm),
                creep_rest_nm=creep_rest(u[0], creep_start_nm), fit_mask=fit_mask,
                warmup_samples=warmup_samples, drift_basis=b.matrix, shift_nm=d0)
        for (u, z, p, _), b, d0 in zip(rest, bases[1:], starts[1:], strict=True)
    ]  # fmt: skip
    before = [heldout_rms(p, model, u, z, T, fit_mask, creep_start_nm) for u, z, p, _ in lines]
    res = refine(
        model, u0, z0, T, output=p0, state=record_state(model, float(u0[0]), creep_start_nm),
        shift_nm=starts[0], creep_rest_nm=creep_rest(u0[0], creep_start_nm),
        fit_mask=fit_mask, warmup_samples=warmup_samples, extra=segments,
        drift_basis=bases[0].matrix,
        options=RefineOptions(
            free=tuple(free), max_nfev=max_nfev, creep_smoothing_nm=creep_smoothing_nm,
            weight_smoothing_nm=weight_smoothing_nm, drift_smoothing=smoothing,
            drift_anchor=anchor,
        ),
    )  # fmt: skip
    out = []
    for (u, z, p, d0), b, c, start, rms0 in zip(
        lines, bases, res.drift_coefficients, starts, before, strict=True
    ):
        path = start + b.matrix @ c
        after = heldout_rms(p, res.model, u, z, T, fit_mask, creep_start_nm, path)
        out.append(b.drift(c, d0, {"rms_before_nm": rms0, "rms_after_nm": after}))
    return res.model, out


def fit_line_drift(
    model: ScannerModel,
    profile: HeightProfile,
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    sample_period_s: float,
    *,
    reference: Sequence[slice],
    fit_mask: NDArray[np.bool_],
    warmup_samples: int = 0,
    creep_start_nm: float | None = None,
    knot_spacing_s: float = 20.0,
    smoothing: float = 1.0,
    iterations: int = 8,
    rate_nm_per_s: float | None = None,
) -> LineDrift:
    """The drift path that, with ``model`` held, best explains the record's heights.

    Parameters
    ----------
    model : ScannerModel
        The model, in ``profile``'s frame (run over the record from
        :func:`~piezocomp.identification.estimation.prediction.record_state`).
    profile : HeightProfile
        The line's ``h``.
    u_nm, height_nm : ndarray, shape (n,)
        The record.
    sample_period_s : float
    reference : sequence of slice
        Samples where the drift is zero on average: the forward traces ``h`` was built from.
    fit_mask : ndarray of bool, shape (n,)
        Samples whose heights are fitted (the path runs on past them in a straight line).
    warmup_samples : int
        Leading samples left out (the model's state there is not known: a drift fitted to
        them would take the model's error for drift).
    creep_start_nm : float, optional
        As :func:`~piezocomp.identification.estimation.prediction.record_state`'s.
    knot_spacing_s : float
        Time between knots (s): the drift's rate may change this often.
    smoothing : float
        Weight of the second-difference penalty, relative to the heights' information about
        one knot: at 1 a bend of 1 nm costs as much as a 1 nm misfit of the heights over one
        knot interval.
    iterations : int
        Gauss-Newton steps at most.
    rate_nm_per_s : float, optional
        A drift rate measured before the record (e.g. on the settling cycles,
        :func:`~piezocomp.identification.acquisition.line_search.settling_drift_rate`): straight
        paths at this rate, either way, are tried as starts beside no drift, and the path that
        explains the heights best is kept (a drift of many nanometres is far from the start of none,
        where the heights' peaks no longer overlap).

    Returns
    -------
    LineDrift
    """
    T = check_finite_scalar("sample_period_s", sample_period_s)
    spacing = check_finite_scalar("knot_spacing_s", knot_spacing_s)
    lam = check_finite_scalar("smoothing", smoothing)
    if T <= 0 or spacing <= 0 or lam < 0:
        raise ValueError(f"sample_period_s and knot_spacing_s must be > 0 and smoothing >= 0. "
                         f"Got {T}, {spacing}, {lam}.")  # fmt: skip
    basis = DriftBasis.of(u_nm.size, T, reference, spacing)
    m = basis.matrix.shape[1]
    y, _ = simulate(model, u_nm, T, record_state(model, float(u_nm[0]), creep_start_nm))
    lo, hi = profile.y_range_nm
    # Only samples of the fitted part inside h's table inform the path.
    use = np.asarray(fit_mask, dtype=bool) & (y >= lo) & (y <= hi)
    use[: int(warmup_samples)] = False
    bu, yu, zu = basis.matrix[use], y[use], height_nm[use]
    if not yu.size:
        raise ValueError("no fitted sample of the record falls inside h's table.")
    second = np.diff(np.eye(m + 1), 2, axis=0)[:, 1:]  # of the knots, the first held at 0

    def rms_of(c: NDArray[np.float64]) -> float:
        return float(np.sqrt(np.mean((profile(yu + bu @ c) - zu) ** 2)))

    def solved(c: NDArray[np.float64]) -> NDArray[np.float64]:
        for _ in range(int(iterations)):
            s = yu + bu @ c
            r = zu - profile(s)
            jac = profile.derivative(s)[:, None] * bu
            info = jac.T @ jac
            per_knot = float(np.trace(info)) / m
            a = info + lam * per_knot * (second.T @ second) + 1e-9 * per_knot * np.eye(m)
            step = np.linalg.solve(a, jac.T @ r - lam * per_knot * (second.T @ (second @ c)))
            c = c + step
            if np.max(np.abs(step)) < 1e-3:
                break
        return c

    starts = [np.zeros(m)]
    if rate_nm_per_s is not None and math.isfinite(rate_nm_per_s) and rate_nm_per_s != 0:
        ramp = basis.knots_s[1:] - basis.knots_s[0]
        starts += [sign * rate_nm_per_s * ramp for sign in (1.0, -1.0)]
    c = min((solved(c0) for c0 in starts), key=rms_of)
    none = LineDrift(basis.knots_s, np.zeros(m + 1), T, u_nm.size, 0.0, 0.0)
    fit = {"rms_before_nm": rms_of(np.zeros(m)), "rms_after_nm": rms_of(c)}
    return basis.drift(c, none, fit)
