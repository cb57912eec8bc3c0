"""Acquisition helpers of the sensorless identification: finding the line, settling, checking.

Section V, step 1, on the instrument: a line crossing enough particles, and the tip on it.

* ``overview_and_line``: overview images of the working area, shifted along the slow axis
  in turn, until one holds a line crossing enough particles
  (:func:`~piezocomp.identification.acquisition.line_choice.choose_line`);
* ``locate_line``: get the tip back onto such a line (the slow axis' own hysteresis and
  creep move it off the overview row) by single cycles of the line at ascending slow
  commands; the paired peaks of every line scanned are equations (23) of the same steady
  loop, which the loop fit pools
  (:func:`~piezocomp.identification.loop.fit.estimate_loop`).

The identification record of Fig. 7a lasts minutes along a line a particle wide
(:mod:`piezocomp.identification.sensorless`). The slow axis has its own creep (logarithmic:
its rate falls like ``1 / t`` after a move), so a record started right after the large
slow-axis moves of the overview and the line search sees the tip creep *across* the line:
the height profile ``h`` along the line changes during the record, which eqs (16)-(18) read
as a fast-axis error. What an operator can do about it, with the instrument alone:

* :func:`settle_on_line`: keep scanning the chosen line (the same steady fast-axis cycle as
  part A, so the fast axis stays in the same periodic state) for a while before recording,
  so that the slow axis' creep has slowed down;
* :func:`line_stability`: scan the line again after the record and compare the averaged
  steady traces with those of part A; a profile that changed (heights or peak positions) is
  reported as a finding.

Only :class:`~piezocomp.instrument.Instrument` methods are used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.drift_across_line import dither_offsets
from piezocomp.identification.acquisition.line_choice import LineChoice, choose_line
from piezocomp.identification.acquisition.peaks import Peaks, find_peaks, pair_peaks
from piezocomp.identification.acquisition.waveforms import IdentificationWaveform
from piezocomp.instrument import Instrument, Record, ScanImage

if TYPE_CHECKING:
    from piezocomp.identification.acquisition.config import AcquisitionConfig

__all__ = [
    "LINE_SEARCH_NM",
    "LOOP_PAIRS_FACTOR",
    "LineStability",
    "axis_command",
    "cycle_pairs",
    "line_stability",
    "locate_line",
    "overview_and_line",
    "settle_on_line",
    "settling_drift_rate",
]

OVERVIEW_SHIFTS = (0.0, 1.0, -1.0, 2.0, -2.0)
"""Slow-axis shifts, in spans, of the overviews tried in turn."""

LINE_SEARCH_NM = 200.0
"""Neighbourhood of the overview's line searched for it (:func:`locate_line`)."""

LINE_SEARCH_STEP_NM = 4.0
"""Step of the slow command in the line search."""

MIN_LINE_PARTICLES = 4
"""Particles the identification line must pair."""

LOOP_PAIRS_FACTOR = 3
"""The loop fit gathers at least this many times ``degree + 1`` pairs from the lines scanned
while searching."""


def axis_command(
    axis: str, u: NDArray[np.float64], slow: float | NDArray[np.float64]
) -> NDArray[np.float64]:
    """Command (n, 2) with ``u`` on the fast ``axis`` and the other axis held at ``slow`` (or
    following it, sample by sample:
    :func:`~piezocomp.identification.acquisition.following.run_following`)."""
    cmd = np.empty((u.size, 2))
    cmd[:, 0 if axis == "x" else 1] = u
    cmd[:, 1 if axis == "x" else 0] = slow
    return cmd


def settle_on_line(
    instrument: Instrument,
    axis: str,
    cycle_nm: NDArray[np.float64],
    slow_nm: float,
    duration_s: float,
    dither_nm: float = 0.0,
) -> Record | None:
    """Scan the line's steady cycle ``cycle_nm`` (which starts and ends at the same command)
    at slow command ``slow_nm`` for whole cycles lasting at least ``duration_s``; with
    ``dither_nm``, every other cycle ``dither_nm`` lower
    (:func:`~piezocomp.identification.acquisition.drift_across_line.dither_offsets`), by which the
    line's slide across its particles is measured
    (:func:`~piezocomp.identification.acquisition.drift_across_line.cross_line_drift`).

    Returns the record (``None`` if ``duration_s <= 0``).
    """
    if duration_s <= 0:
        return None
    c = np.asarray(cycle_nm, float)
    per = (c.size - 1) * float(instrument.sample_period_s)
    n = max(1, math.ceil(duration_s / per - 1e-9))
    u = np.concatenate([c[:1], *([c[1:]] * n)])
    slow = np.full(u.size, float(slow_nm))
    if dither_nm > 0:  # each step spread over the first hundredth of its cycle (slew)
        k = c.size - 1
        steps = dither_offsets(n, dither_nm)
        ramp = max(1, k // 100)
        knots = np.ravel([[i * k, i * k + ramp] for i in range(n)])
        before = np.concatenate([[0.0], steps[:-1]])
        values = np.ravel(np.column_stack([before, steps]))
        slow += np.interp(np.arange(u.size, dtype=float), knots, values)
    return instrument.run(axis_command(axis, u, slow))


def cycle_pairs(
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    half_cycle_samples: int,
    *,
    min_prominence_nm: float = 3.0,
    max_shift_nm: float,
) -> int:
    """Particles paired between the forward and backward traces of the LAST full cycle
    (``2 half_cycle_samples + 1`` samples) of a record of the line's steady cycle."""
    m = int(half_cycle_samples)
    u = np.asarray(u_nm, float)[-(2 * m + 1) :]
    z = np.asarray(height_nm, float)[-(2 * m + 1) :]
    pf = find_peaks(u[: m + 1], z[: m + 1], min_prominence_nm=min_prominence_nm)
    pb = find_peaks(u[m:], z[m:], min_prominence_nm=min_prominence_nm)
    i, _ = pair_peaks(pf.position_nm, pb.position_nm, max_shift_nm=max_shift_nm)
    return int(i.size)


MATCH_NM = 10.0
"""A peak of a settling cycle is the same particle as one of the cycle before's within this
(a drift of 10 nm per cycle, 1 nm/s at the default 8 s cycle, is beyond any AFM's)."""


def settling_drift_rate(
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    t_s: NDArray[np.float64],
    cycle_samples: int,
    *,
    min_prominence_nm: float = 3.0,
) -> float | None:
    """The rate (command nm/s) at which the line's particles move along the fast axis while
    the tip scans its steady cycle, from a settling record (:func:`settle_on_line`).

    Once the fast axis is in its periodic state, a particle's peak stays at one command from
    cycle to cycle; a steady slide of every peak is the sample drifting along the line (or,
    early on, the last of the fast axis' creep from the moves before). Each forward trace's
    peaks are matched to the cycle before's and the median shifts added up; the slide is
    fitted by a line over the second half of the record (the creep has died down by then).
    ``None`` with fewer than 6 cycles or when the particles cannot be followed.
    """
    per = int(cycle_samples)
    m = per // 2
    n_cycles = (np.asarray(u_nm).size - 1) // per
    if n_cycles < 6:
        return None
    prev: NDArray[np.float64] | None = None
    total = 0.0
    times, shifts = [], []
    for c in range(n_cycles):
        sl = slice(c * per, c * per + m + 1)
        p = find_peaks(u_nm[sl], height_nm[sl], min_prominence_nm=min_prominence_nm).position_nm
        if prev is not None and prev.size and p.size:
            d = [q - prev[np.argmin(np.abs(prev - q))] for q in p]
            d = [v for v in d if abs(v) < MATCH_NM]
            if not d:  # the particles were lost from one cycle to the next
                return None
            total += float(np.median(d))
            times.append(float(np.mean(t_s[sl])))
            shifts.append(total)
        prev = p
    t, s = np.asarray(times), np.asarray(shifts)
    if t.size < 6:
        return None
    late = t >= t[0] + 0.5 * (t[-1] - t[0])
    return float(np.polyfit(t[late], s[late], 1)[0])


@dataclass(frozen=True)
class LineStability:
    """How much the line's steady traces changed between part A and the check cycles.

    Attributes
    ----------
    height_change_rms_nm : float
        RMS of the difference of the averaged forward traces (end minus start), nm.
    height_change_max_nm : float
        Largest absolute difference of the averaged forward traces, nm.
    peak_height_change_nm : ndarray
        Height change (end minus start) of each particle peak found on both, nm.
    peak_shift_nm : ndarray
        Position change (end minus start, command nm) of the same peaks (the fast axis'
        state, removed by a straight-line fit before comparing heights).
    noise_rms_nm : float
        RMS difference between two single cycles of part A (the repeatability), nm.
    """

    height_change_rms_nm: float
    height_change_max_nm: float
    peak_height_change_nm: NDArray[np.float64]
    peak_shift_nm: NDArray[np.float64]
    noise_rms_nm: float

    def finding(self, tolerance_nm: float = 1.0) -> str | None:
        """A sentence if the profile changed by more than ``tolerance_nm`` (RMS) beyond the
        cycle-to-cycle repeatability, else ``None``."""
        excess = self.height_change_rms_nm - self.noise_rms_nm
        if excess <= tolerance_nm:
            return None
        big = (
            float(np.max(np.abs(self.peak_height_change_nm)))
            if self.peak_height_change_nm.size
            else 0.0
        )
        return (
            f"the line's height profile changed during the identification record: the steady "
            f"forward traces after it differ from part A's by {self.height_change_rms_nm:.2f} nm "
            f"RMS ({self.height_change_max_nm:.1f} nm at most; particle peaks by up to "
            f"{big:.1f} nm) against {self.noise_rms_nm:.2f} nm between cycles: the slow axis "
            "probably crept across the line; h(y) is then only an average, and the estimates "
            "carry its change as errors (settle longer on the line before recording)"
        )


def line_stability(
    u_start: NDArray[np.float64],
    z_start: NDArray[np.float64],
    u_end: NDArray[np.float64],
    z_end: NDArray[np.float64],
    *,
    min_prominence_nm: float = 3.0,
    max_shift_nm: float = 20.0,
) -> LineStability:
    """Compare steady forward traces at the start (rows of ``z_start``, one per cycle, at
    commands ``u_start``) and at the end (``z_end`` at ``u_end``) of a record.

    Both are averaged cycle by cycle; the end average is interpolated onto ``u_start``.
    Peaks of both averages are paired (within ``max_shift_nm``) to report per-particle
    height changes and shifts. The fast axis itself need not return to the same steady state
    (its creep remembers part B), which shifts the whole trace along the line: the end trace
    is re-aligned by the straight-line fit of the peak shifts before the heights are
    compared, so that the height change measures the profile (the slow axis), not the shift.
    """
    us = np.asarray(u_start, float)
    zs = np.atleast_2d(np.asarray(z_start, float))
    ze = np.atleast_2d(np.asarray(z_end, float))
    a = zs.mean(axis=0)
    order = np.argsort(u_end)
    ue, be = np.asarray(u_end, float)[order], ze.mean(axis=0)[order]
    b = np.interp(us, ue, be)
    pa = find_peaks(us, a, min_prominence_nm=min_prominence_nm)
    pb = find_peaks(us, b, min_prominence_nm=min_prominence_nm)
    i, j = pair_peaks(pa.position_nm, pb.position_nm, max_shift_nm=max_shift_nm)
    shift = pb.position_nm[j] - pa.position_nm[i]
    if shift.size:
        coef = np.polyfit(pa.position_nm[i], shift, min(1, shift.size - 1))
        b = np.interp(us + np.polyval(coef, us), ue, be)
    d = b - a
    d = d - np.median(d)  # a constant height offset (Z drift) is not a profile change
    noise = float(np.sqrt(np.mean((zs[-1] - zs[0]) ** 2))) if zs.shape[0] > 1 else 0.0
    return LineStability(
        height_change_rms_nm=float(np.sqrt(np.mean(d**2))),
        height_change_max_nm=float(np.max(np.abs(d))),
        peak_height_change_nm=np.asarray(pb.height_nm[j] - pa.height_nm[i], float),
        peak_shift_nm=np.asarray(shift, float),
        noise_rms_nm=noise,
    )


def overview_and_line(
    instrument: Instrument, cfg: AcquisitionConfig, axis: str, line_rate: float, degree: int
) -> tuple[ScanImage, LineChoice]:
    """Overview images of the working span, shifted along the slow axis by
    :data:`OVERVIEW_SHIFTS` spans in turn, until one holds a line with enough particles for
    a loop of ``degree`` (eq 23)."""
    cx, cy = cfg.center_nm
    errors = []
    images = []
    for shift in OVERVIEW_SHIFTS:
        d = shift * cfg.span_nm
        centre = (cx, cy + d) if axis == "x" else (cx + d, cy)
        lo = (centre[1] if axis == "x" else centre[0]) - cfg.span_nm / 2
        if abs(lo) > instrument.range_nm / 2 or abs(lo + cfg.span_nm) > instrument.range_nm / 2:
            continue
        image = instrument.scan_image(
            centre, cfg.span_nm, cfg.overview_pixels, line_rate, fast_axis=axis
        )
        images.append(image)
        try:
            return image, choose_line(
                image,
                degree=degree,
                axis=axis,
                min_prominence_nm=cfg.min_prominence_nm,
                max_shift_nm=0.15 * cfg.span_nm,
            )
        except ValueError as exc:
            errors.append(f"overview at {centre}: {exc}")
    # No line crosses more than `degree` particles: the loop fit pools the pairs of many
    # lines (see locate_line), so a line with `min_line_particles` particles will do.
    for image in images:
        try:
            return image, choose_line(
                image,
                degree=MIN_LINE_PARTICLES - 1,
                axis=axis,
                min_prominence_nm=cfg.min_prominence_nm,
                max_shift_nm=0.15 * cfg.span_nm,
            )
        except ValueError as exc:
            errors.append(str(exc))
    raise ValueError("; ".join(errors) if errors else "no overview fits inside the range.")


def locate_line(
    instrument: Instrument,
    cfg: AcquisitionConfig,
    axis: str,
    line: LineChoice,
    wf: IdentificationWaveform,
    speed: float,
    *,
    degree: int,
    accept_best: bool = False,
    search_nm: float = LINE_SEARCH_NM,
    pairs_factor: int = LOOP_PAIRS_FACTOR,
) -> tuple[float, int, list[tuple[Peaks, Peaks]]]:
    """Get the tip back onto a line crossing enough particles, collecting loop pairs.

    With ``accept_best`` (re-locating a line lost while settling), a search that meets no
    line satisfying every requirement returns to the line that paired the most particles if
    it paired :data:`MIN_LINE_PARTICLES` (approached from below again, as in the search).

    The slow axis has its own hysteresis and creep (tens of nm after the overview), so returning to
    the overview row's command does not return to the same true row, and particles are ~15 nm wide.
    From ``search_nm`` below the row's command, single full cycles of the line are scanned at
    increasing slow commands (steps of :data:`LINE_SEARCH_STEP_NM`; the slow axis only ascends, as
    in the raster) until one pairs at least :data:`MIN_LINE_PARTICLES` particles over half the span
    and the lines scanned so far have given more than ``pairs_factor * (degree + 1)`` pairs
    (``degree``: the loop's, eq 23); the tip stays there. Every scanned line runs the same fast-axis
    cycle as part A (continuous cycling, so the same steady loop), so its paired peaks are equations
    (23) of that loop too
    (:meth:`~piezocomp.identification.loop.symmetric.SymmetricLoop.from_line_pairs`). Instrument
    calls only.

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
    lo = line.slow_nm - search_nm
    hi = line.slow_nm + search_nm
    limit = instrument.range_nm / 2
    lo, hi = max(lo, -limit), min(hi, limit)

    def go(slow: float) -> None:
        xy = (wf.u_nm[0], slow) if axis == "x" else (slow, wf.u_nm[0])
        instrument.move_to(xy[0], xy[1], speed)

    go(lo)
    best = (-1, lo)
    pairs: list[tuple[Peaks, Peaks]] = []
    n_total = 0
    need = pairs_factor * (degree + 1)
    for slow in np.arange(lo, hi + 1e-9, LINE_SEARCH_STEP_NM):
        go(float(slow))
        rec = instrument.run(axis_command(axis, cycle, float(slow)))
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
        if n >= MIN_LINE_PARTICLES and spread >= 0.5 * cfg.span_nm and n_total > need:
            return float(slow), n, pairs
    if accept_best and best[0] >= MIN_LINE_PARTICLES:
        go(lo)
        go(best[1])
        return best[1], best[0], pairs
    raise ValueError(
        f"no line between slow commands {lo:.1f} and {hi:.1f} nm near the chosen overview line "
        f"pairs at least {MIN_LINE_PARTICLES} particles over half the "
        f"span with more than {need} pairs collected (best line: {best[0]} at "
        f"{best[1]:.1f} nm; {n_total} pairs). Choose another area or lower the requirements."
    )
