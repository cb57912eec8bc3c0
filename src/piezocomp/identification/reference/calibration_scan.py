"""The scanner's calibration record, measured on a grating: the scan under which its nominal
sensitivity holds.

A lateral calibration sets the nominal sensitivity (nm per volt) so that a steady
full-range scan at the calibration line rate is as wide as commanded; with creep that holds
at one speed only (:class:`~piezocomp.instrument.ScanCalibration`). Section IV's calibration
condition ``f_a(u_max) - f_a(u_min) = u_max - u_min`` needs that speed, and the sensorless
identification runs its calibration cycles there.

An instrument whose sensitivity was set by someone else states the speed in its record. One
that does not can measure it: :func:`measure_calibration_scan` scans a grating of known
pitch (mounted instead of the sample, lines perpendicular to the axis) over the whole range
in steady cycles, measures the scan's width against the command as a calibration does (the
crests counted between the first and the last one of each ramp, their command positions
refined to a fraction of a sample: the hysteresis bends a full-range ramp too much for one
period to fit it), and searches the speed at which the two agree. It uses the instrument interface
only, so its record carries what a real calibration carries: the grating's roughness,
noise, drift during the cycles, the precision of the period's fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq
from scipy.signal import find_peaks

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.reference.grating import GratingRecord, measure_grating
from piezocomp.instrument import Instrument, ScanCalibration

__all__ = [
    "CALIBRATION_SPEEDS_NM_PER_S",
    "CalibrationScan",
    "measure_calibration_scan",
    "width_ratio",
]

CALIBRATION_SPEEDS_NM_PER_S = (100.0, 10000.0)
"""The speeds searched by default, nm/s (line rates of 0.01-1 Hz on a 5 um range)."""

MIN_CRESTS = 3
"""Fewest crests a ramp must cross to count."""

MAX_STEPS = 20
"""Most steps of Brent's method (a scan each) after the bracket's two."""

MIN_SAMPLES_PER_PITCH = 10.0
"""The fastest scan searched samples the grating this many times a pitch (the crests'
parabolas and the ends' heights need them)."""

END_ANCHORS = 5
"""Crests and troughs nearest an end through which the phase is extrapolated to it."""


@dataclass(frozen=True)
class CalibrationScan:
    """What :func:`measure_calibration_scan` found.

    Attributes
    ----------
    scan : ScanCalibration or None
        The record: the span scanned and the speed at which it is as wide as commanded;
        ``None`` when no speed searched satisfies it.
    width_ratios : tuple of (float, float)
        ``(speed, width / command)`` at every speed scanned, in the order scanned.
    instrument_s : float
        Instrument time the cycles took (moves included), s.
    """

    scan: ScanCalibration | None
    width_ratios: tuple[tuple[float, float], ...]
    instrument_s: float


def measure_calibration_scan(
    instrument: Instrument,
    pitch_nm: float,
    *,
    axis: str = "x",
    speeds_nm_per_s: tuple[float, float] = CALIBRATION_SPEEDS_NM_PER_S,
    n_cycles: int = 3,
    skip_cycles: int = 1,
    n_lines: int = 2,
    rtol: float = 0.01,
) -> CalibrationScan:
    """The speed at which a steady scan over the whole range is as wide as commanded,
    measured on a grating of pitch ``pitch_nm`` (its lines perpendicular to ``axis``).

    At each speed tried, :func:`~piezocomp.identification.reference.grating.measure_grating`
    scans ``n_lines`` lines of ``n_cycles`` steady cycles over the whole range (as the
    identification's calibration cycles run; the first ``skip_cycles`` settle the loop),
    and :func:`width_ratio` reads the scan's width over the command's. The width falls as
    the speed rises (a slower cycle creeps further), so Brent's method on ``log(speed)``
    finds where it is 1, to ``rtol`` of the speed, searching ``speeds_nm_per_s`` up to the
    fastest scan that samples the grating :data:`MIN_SAMPLES_PER_PITCH` times a pitch (and
    the slew limit). A scanner with little creep is as wide as commanded, within the
    measurement, over much of the range: the search may then find no crossing (``None``),
    and the speed matters little for it.

    Raises
    ------
    ValueError
        If the speeds are not ``0 < low < high`` or start above the fastest scan searched,
        ``rtol`` is not in (0, 1), the pitch not > 0, a ramp crosses
        fewer than :data:`MIN_CRESTS` crests (:func:`width_ratio`), or a width is not within
        a factor of two of the command (a wrong pitch).
    """
    lo = check_finite_scalar("speeds_nm_per_s[0]", speeds_nm_per_s[0])
    hi = check_finite_scalar("speeds_nm_per_s[1]", speeds_nm_per_s[1])
    if not 0 < lo < hi:
        raise ValueError(f"speeds_nm_per_s must satisfy 0 < low < high. Got ({lo}, {hi}).")
    tol = check_finite_scalar("rtol", rtol)
    if not 0 < tol < 1:
        raise ValueError(f"rtol must be in (0, 1). Got {tol}.")
    pitch = check_finite_scalar("pitch_nm", pitch_nm)
    if pitch <= 0:
        raise ValueError(f"pitch_nm must be > 0. Got {pitch}.")
    top = min(float(instrument.max_speed_nm_per_s),
              pitch / (MIN_SAMPLES_PER_PITCH * float(instrument.sample_period_s)))  # fmt: skip
    if lo >= top:
        raise ValueError(
            f"speeds_nm_per_s starts at {lo:g} nm/s, at or above the fastest scan that "
            f"samples the grating {MIN_SAMPLES_PER_PITCH:g} times a pitch within the slew "
            f"limit ({top:.4g} nm/s): lower it."
        )
    hi = min(hi, top)
    span = float(instrument.range_nm)
    ratios: dict[float, float] = {}
    busy = [0.0]

    def excess(log_v: float) -> float:
        v = {math.log(lo): lo, math.log(hi): hi}.get(log_v, math.exp(log_v))
        if v in ratios:  # Brent's method asks for the bracket's ends again
            return ratios[v] - 1.0
        record = measure_grating(
            instrument, pitch, axis=axis, span_nm=span, speed_nm_per_s=v,
            n_cycles=n_cycles, skip_cycles=skip_cycles, n_lines=n_lines,
            angle_line_offset_nm=None,
        )  # fmt: skip
        busy[0] += record.u_nm.size * record.sample_period_s
        ratio = width_ratio(record)
        if not 0.5 < ratio < 2.0:
            raise ValueError(
                f"the scan at {v:.4g} nm/s reads {ratio:.3g} times as wide as commanded on a "
                f"grating of pitch {pitch:g} nm: is the pitch right?"
            )
        ratios[v] = ratio
        return ratio - 1.0

    f_lo, f_hi = excess(math.log(lo)), excess(math.log(hi))
    if f_lo < 0 or f_hi > 0:  # not as wide as commanded anywhere between
        scan = None
    else:
        try:
            root = brentq(excess, math.log(lo), math.log(hi), xtol=math.log1p(tol),
                          maxiter=MAX_STEPS)  # fmt: skip
        except RuntimeError:  # each step is minutes of instrument time
            raise ValueError(
                f"the calibration speed was not found to {tol:g} within {MAX_STEPS} steps of "
                f"Brent's method (widths {sorted(ratios.values())}): raise rtol"
            ) from None
        scan = ScanCalibration(span, math.exp(root))
    return CalibrationScan(scan, tuple(ratios.items()), busy[0])


def width_ratio(record: GratingRecord) -> float:
    """The scan's width over the command's on a grating record (the grating taken as square
    to the axis: an angle ``a`` reads the width ``cos(a)`` short, 0.14 % at 3 degrees).

    On each pass (a ramp) the crests and troughs of the heights (prominent by a quarter of
    the pass's robust height range, 2nd to 98th percentile) are placed in command, with
    their heights, at the apex of a parabola through their sample and its neighbours: they
    are the profile's phases ``0`` and ``pi`` (mod ``2 pi``), so between the first and the
    last the phase is counted, half a period from one to the next (more where the spacing
    against its neighbours' says one was missed). At each end the phase is read from the
    end's height between the pass's median crest and trough on the grating's profile
    ``(1 + cos(phase)) / 2``, up to its sign and whole turns, which a quadratic in the
    command through the :data:`END_ANCHORS` crests and troughs nearest that end,
    extrapolated to it, settles (the nearer candidate). Near a crest or a trough the height
    says less (an error growing as the root of noise over depth), but less than the
    extrapolation's bias over the pitch's fraction there. The width is the phase over
    the pass times ``pitch / 2 pi``; the ratio, the median over the passes (ascending and
    descending ones in equal numbers: the drift's first-order stretch cancels).

    Raises
    ------
    ValueError
        If a pass crosses fewer than :data:`MIN_CRESTS` crests.
    """
    ratios = []
    for a, b in record.passes:
        u, z = record.u_nm[a:b], record.height_nm[a:b]
        lo_z, hi_z = np.percentile(z, [2.0, 98.0])
        prominence = 0.25 * float(hi_z - lo_z)
        crests, _ = find_peaks(z, prominence=prominence)
        troughs, _ = find_peaks(-z, prominence=prominence)
        crests = crests[(crests > 0) & (crests < z.size - 1)]
        troughs = troughs[(troughs > 0) & (troughs < z.size - 1)]
        if crests.size < MIN_CRESTS:
            raise ValueError(
                f"the grating's ramp [{a}, {b}) crosses {crests.size} crests, and a width "
                f"needs {MIN_CRESTS}: is the pitch ({record.pitch_nm:g} nm) right, and the "
                "range scanned over the grating?"
            )
        at = np.concatenate([crests, troughs])
        kind = np.concatenate([np.zeros(crests.size), np.ones(troughs.size)])  # 1: trough
        order = np.argsort(at)
        at, kind = at[order], kind[order]
        sign = np.where(kind == 0, 1.0, -1.0)  # apexes of z (crests) or of -z (troughs)
        z0, z1, z2 = sign * z[at - 1], sign * z[at], sign * z[at + 1]
        curv = z0 - 2 * z1 + z2
        safe = np.where(curv < 0, curv, -1.0)
        off = np.clip(np.where(curv < 0, 0.5 * (z0 - z2) / safe, 0.0), -0.5, 0.5)
        pos = u[at] + off * (u[at + 1] - u[at - 1]) / 2
        apex = sign * np.where(curv < 0, z1 - (z2 - z0) ** 2 / (8.0 * safe), z1)
        phase = np.concatenate([[math.pi * kind[0]], math.pi * kind[0] + np.cumsum(
            math.pi * _half_periods(np.abs(np.diff(pos)), kind[1:] != kind[:-1])
        )])  # fmt: skip
        crest = float(np.median(apex[kind == 0]))
        trough = float(np.median(apex[kind == 1])) if np.any(kind == 1) else float(z.min())
        n = min(END_ANCHORS, pos.size)
        start = _end_phase(float(np.polyval(np.polyfit(pos[:n] - u[0], phase[:n], 2), 0.0)),
                           float(z[0]), crest, trough)  # fmt: skip
        end = _end_phase(float(np.polyval(np.polyfit(pos[-n:] - u[-1], phase[-n:], 2), 0.0)),
                         float(z[-1]), crest, trough)  # fmt: skip
        width = (end - start) * record.pitch_nm / (2.0 * math.pi)
        ratios.append(width / abs(float(u[-1] - u[0])))
    return float(np.median(ratios))


def _half_periods(gaps: NDArray[np.float64], alternate: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Half periods between consecutive anchors: one between a crest and a trough, two
    between two of a kind, more where a gap is a multiple of its neighbours' (a crest and a
    trough missed), with the parity the kinds require."""
    counts = np.where(alternate, 1, 2)
    unit = gaps / counts  # each gap's half period, if nothing was missed
    for k, gap in enumerate(gaps):
        near = np.r_[unit[max(0, k - 3) : k], unit[k + 1 : k + 4]]
        if near.size == 0:
            continue
        m = gap / float(np.median(near))
        odd = bool(alternate[k])
        fits = [c for c in range(1, int(m) + 3) if (c % 2 == 1) == odd]
        counts[k] = min(fits, key=lambda c: abs(c - m))
    return counts


def _end_phase(extrapolated: float, z_end: float, crest: float, trough: float) -> float:
    """The profile's phase at a ramp's end: ``+-acos(2 level - 1)`` plus whole turns from
    its height, the candidate nearest ``extrapolated``."""
    depth = crest - trough
    level = 0.5 if depth <= 0 else min(max((z_end - trough) / depth, 0.0), 1.0)
    theta = math.acos(2.0 * level - 1.0)
    turn = 2.0 * math.pi
    candidates = (turn * round((extrapolated - theta) / turn) + theta,
                  turn * round((extrapolated + theta) / turn) - theta)  # fmt: skip
    return min(candidates, key=lambda c: abs(c - extrapolated))
