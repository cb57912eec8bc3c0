"""Frames of the position ``y``: the working loop's and the calibration cycles' (Section IV).

The calibration condition of Section IV fixes the scale of ``y`` on the span the loop was
fitted on: ``f_a(u_max) - f_a(u_min) = u_max - u_min``. On the working span that scale is off
when the scanner's small-signal sensitivity differs from its nominal one; steady cycles over
the span where the nominal sensitivity was calibrated (e.g. the full range) give a second
loop whose condition holds
(:attr:`~piezocomp.identification.config.AcquisitionConfig.calibrate`). The
same particles, seen on both, relate the two frames by an affine map ``Y = alpha y + beta``:

* :func:`frame_map` finds it (RANSAC over height-compatible particle correspondences,
  :func:`_ransac_map`);
* :func:`mapped` gives the model whose output is ``alpha y + beta`` (the model on the
  calibration frame), :func:`unmapped` the inverse (back to the working frame).

A model refined against ``h(y)`` re-indexed by its own prediction lives in its own frame,
whose scale nothing in the topography fixes: the re-indexing rounds can carry it far from the
loop's (a noise-free cpr5 seed 2 went to twice the loop's lengths). Without calibration
cycles, :func:`span_frame` puts such a model back on the condition of Section IV, applied to
the model's own prediction of the steady cycles.

:class:`CalibrationFrame` is the pipeline's use of them: the calibration cycles' loop, and
each estimated model's map onto it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.peaks import Peaks, find_peaks
from piezocomp.identification.acquisition.recording import AxisRecords
from piezocomp.identification.estimation.prediction import predicted_forward_trace
from piezocomp.identification.loop.fit import LoopEstimate, estimate_loop, fit_pi_loop
from piezocomp.identification.loop.pi_branch import PILoop
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.loop.symmetric import SymmetricLoop
from piezocomp.model import ScannerModel

__all__ = [
    "CALIBRATION_DEGREE",
    "CalibrationFrame",
    "FrameMap",
    "frame_map",
    "mapped",
    "span_frame",
    "unmapped",
]

FrameMap = tuple[float, float]
"""``(alpha, beta)``: a model's output ``y`` becomes ``alpha y + beta``."""

CALIBRATION_DEGREE = 9
"""Degree of the eq (23) polynomial that pairs the calibration cycles' particles (the
calibration loop itself is a Prandtl-Ishlinskii branch,
:func:`~piezocomp.identification.loop.fit.fit_pi_loop`)."""


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
    match's particles' heights must agree within ``min(height_tolerance_nm, 2)``, and every
    match must be unambiguous (no other map, ``alpha`` differing by more than 2 %, with as
    many inliers): three particles otherwise match a wrong map by chance among the many
    calibration particles (harsh seed 1, y axis: the tip had drifted onto another line
    before the calibration cycles, and a 3-particle map with ``alpha`` 1.25 instead of
    ~0.8 made the model 230 nm wrong). ``calibration_loop``
    (default ``calibration.loop``) is the loop that places the calibration particles, e.g.
    the :class:`PILoop` of :func:`~piezocomp.identification.loop.fit.fit_pi_loop`.
    ``working_positions`` (default ``working.loop.ascending``) places the working line's
    particles from their commands on the forward trace, e.g. a model's prediction of that
    trace (the model's own frame).

    Raises
    ------
    ValueError
        If fewer than 3 particles match, or the match is ambiguous.
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
    ambiguous = False
    for k, tol in enumerate(tols):
        ok = close if k == 0 else strict
        n, alpha, beta, rival = _ransac_map(y, Y, ok, tol, alpha_range, window_nm)
        if n >= 3 and rival:
            ambiguous = True  # another map agrees with as many particles: refuse
            break
        if n >= 3:
            close = ok
            break
    if ambiguous:
        raise ValueError(
            f"the particles do not decide the frame map: {n} of the working line's particles "
            f"agree with alpha = {alpha:.3f}, beta = {beta:.1f} nm, and as many with another "
            "alpha more than 2 % away: the line's particles are too few or too evenly "
            "spaced to tell the two apart, or the calibration cycles ran on another line "
            "(the sample drifted or a particle moved)"
        )
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


def mapped(model: ScannerModel, alpha: float, beta: float) -> ScannerModel:
    """The model whose output is ``alpha y + beta`` (gains scaled, thresholds unchanged).

    A creep coupling (eq 2') is divided by ``alpha``: the hysteresis output ``H`` scales by
    ``alpha``, and the creep drive ``u + beta_c H`` must not change. Dead zones (eq 8') move
    with ``H``: thresholds times ``alpha``, gains unchanged.
    """
    if alpha == 1.0 and beta == 0.0:
        return model
    return ScannerModel(
        offset_nm=alpha * model.offset_nm + beta,
        gain=alpha * model.gain,
        thresholds_nm=model.thresholds_nm,
        weights=alpha * model.weights,
        creep_time_constants_s=model.creep_time_constants_s,
        creep_gains=alpha * model.creep_gains,
        creep_coupling=model.creep_coupling / alpha,
        dead_zones_nm=alpha * model.dead_zones_nm,
        dead_zone_gains=model.dead_zone_gains,
    )


def unmapped(model: ScannerModel, alpha: float, beta: float) -> ScannerModel:
    """Inverse of the frame map: the model in the working loop's frame."""
    return mapped(model, 1.0 / alpha, -beta / alpha)


def span_frame(
    loop: SymmetricLoop, u_forward_nm: NDArray[np.float64], y_forward_nm: NDArray[np.float64]
) -> tuple[float, float]:
    """The map ``Y = alpha y + beta`` that puts a model on the loop's frame (Section IV).

    ``y_forward_nm`` is the model's prediction of the steady forward trace commanded by
    ``u_forward_nm`` (e.g.
    :func:`~piezocomp.identification.estimation.prediction.predicted_forward_trace` over part A).
    The map makes that trace span what the loop's ascending branch spans over the same commands
    (``f_a(u_max) - f_a(u_min) = u_max - u_min``, eq 23's calibration condition) about the same
    middle, so the model and the loop share scale and centre.

    Raises
    ------
    ValueError
        If the trace does not advance from its first sample to its last, or the arrays
        differ in length.
    """
    u = np.asarray(u_forward_nm, dtype=float)
    y = np.asarray(y_forward_nm, dtype=float)
    if u.shape != y.shape or u.ndim != 1 or u.size < 2:
        raise ValueError(
            f"u_forward_nm and y_forward_nm must be 1-D of the same length >= 2. Got shapes "
            f"{u.shape} and {y.shape}."
        )
    ext = float(y[-1] - y[0])
    if not (np.isfinite(ext) and ext > 0):
        raise ValueError(
            f"the model's forward trace must advance over the span; it moves {ext:.3g} nm "
            "from its first sample to its last."
        )
    lo, hi = (float(v) for v in loop.ascending(np.array([u[0], u[-1]])))
    alpha = (hi - lo) / ext
    return alpha, 0.5 * (lo + hi) - alpha * 0.5 * float(y[0] + y[-1])


@dataclass(frozen=True)
class CalibrationFrame:
    """The frame the models are put on (Section IV): the calibration cycles' own, or the
    working span's calibration condition without them.

    Attributes
    ----------
    working : LoopEstimate
        The working line's loop (the loop stage's).
    calibration : LoopEstimate or None
        The calibration cycles' loop; ``None`` without calibration cycles or when they could
        not be used (the working span's condition holds then).
    window_nm, min_prominence_nm : float
        :func:`frame_map`'s window on ``beta`` and the peaks' prominence.
    calibration_loop : PILoop or None
        The calibration loop as a Prandtl-Ishlinskii branch (:func:`fit_pi_loop`).
    loop_map : FrameMap
        The working loop's map onto this frame (``(1, 0)`` without calibration cycles).
    """

    working: LoopEstimate
    calibration: LoopEstimate | None
    window_nm: float
    min_prominence_nm: float
    calibration_loop: PILoop | None = None
    loop_map: FrameMap = (1.0, 0.0)

    @classmethod
    def from_records(
        cls,
        records: AxisRecords,
        working: LoopEstimate,
        *,
        span_nm: float,
        min_prominence_nm: float,
        notes: list[str],
    ) -> CalibrationFrame:
        """The calibration loop of ``records``' calibration cycles (Section IV on them, with
        :data:`CALIBRATION_DEGREE`) and the working loop's map onto it; a note in ``notes``
        when the cycles cannot be used."""
        window = 0.3 * span_nm
        cal = records.calibration
        if cal is None:
            return cls(working, None, window, min_prominence_nm)
        calibration = estimate_loop(
            cal.u_nm, cal.height_nm, cal.waveform, degree=CALIBRATION_DEGREE,
            min_prominence_nm=min_prominence_nm,
        )  # fmt: skip
        lo, hi = calibration.loop.u_min_nm, calibration.loop.u_max_nm
        frame = cls(working, calibration, window, min_prominence_nm,
                    fit_pi_loop(calibration.all_pairs, lo, hi))  # fmt: skip
        try:
            loop_map = frame.onto_calibration(None)
        except ValueError as exc:
            notes.append(
                f"the calibration cycles could not be used ({exc}); the model keeps the "
                "working span's calibration condition (Section IV), whose scale may be off"
            )
            return cls(working, None, window, min_prominence_nm)
        return replace(frame, loop_map=loop_map)

    def onto_calibration(
        self, trace: tuple[NDArray[np.float64], NDArray[np.float64]] | None
    ) -> FrameMap:
        """:func:`frame_map` onto the calibration loop, of the loop's frame (``trace``
        ``None``) or of a model in its own frame, given its prediction ``(u, y_hat)`` of the
        working line's forward trace."""
        assert self.calibration is not None
        positions = None if trace is None else (lambda x: np.interp(x, trace[0], trace[1]))
        return frame_map(
            self.working, self.calibration, window_nm=self.window_nm,
            min_prominence_nm=self.min_prominence_nm, calibration_loop=self.calibration_loop,
            working_positions=positions,
        )  # fmt: skip

    def map_of(self, trace: tuple[NDArray[np.float64], NDArray[np.float64]] | None) -> FrameMap:
        """The map onto this frame of the loop's frame (``trace`` ``None``) or of a model in
        its own frame, given its prediction ``(u, y_hat)`` of the working line's forward
        trace (without calibration cycles: :func:`span_frame`, the loop's span)."""
        if trace is None:
            return self.loop_map
        if self.calibration is None:
            return span_frame(self.working.loop, *trace)
        return self.onto_calibration(trace)

    def model_maps(
        self,
        records: AxisRecords,
        working: dict[str, tuple[ScannerModel, HeightProfile]],
        creep_start_nm: float,
        shift_nm: NDArray[np.float64] | None,
        notes: list[str],
    ) -> dict[str, FrameMap]:
        """Each model's map onto this frame: the loop's for a model estimated on the loop's
        ``h``; for one whose ``h`` was re-indexed by it, its own, from its prediction of part
        A's forward trace (``shift_nm``: the drift along the first line taken out; the loop's
        map, with a note, when that cannot be mapped)."""
        forward = records.waveform.forward_traces
        maps: dict[str, FrameMap] = {}
        for name in ("batch", "rls"):
            model, prof = working[name]
            if prof is self.working.profile:  # in the loop's frame
                maps[name] = self.map_of(None)
                continue
            y_fwd = predicted_forward_trace(model, records.u_nm, records.sample_period_s,
                                            forward, creep_start_nm, shift_nm)  # fmt: skip
            try:
                maps[name] = self.map_of((records.u_nm[forward[0]], y_fwd))
            except ValueError as exc:
                label = "RLS" if name == "rls" else name
                notes.append(
                    f"the {label} model's frame could not be mapped on its own ({exc}); it "
                    "uses the loop's frame map"
                )
                maps[name] = self.map_of(None)
        return maps
