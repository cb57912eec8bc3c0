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
from scipy.optimize import brentq
from scipy.signal import find_peaks

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.reference.grating import GratingRecord, measure_grating
from piezocomp.instrument import Instrument, ScanCalibration

__all__ = ["CALIBRATION_SPEEDS_NM_PER_S", "CalibrationScan", "measure_calibration_scan"]

CALIBRATION_SPEEDS_NM_PER_S = (100.0, 10000.0)
"""The speeds searched by default, nm/s (line rates of 0.01-1 Hz on a 5 um range)."""

MIN_CRESTS = 3
"""Fewest crests a ramp must cross to count."""

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
    finds where it is 1, to ``rtol`` of the speed. A scanner without creep is as wide as
    commanded at every speed: the speed found is then one of them.

    Raises
    ------
    ValueError
        If the speeds are not ``0 < low < high``, ``rtol`` not in (0, 1), a ramp crosses
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
    hi = min(hi, float(instrument.max_speed_nm_per_s))
    span = float(instrument.range_nm)
    ratios: dict[float, float] = {}
    busy = [0.0]

    def excess(log_v: float) -> float:
        v = {math.log(lo): lo, math.log(hi): hi}.get(log_v, math.exp(log_v))
        if v in ratios:  # Brent's method asks for the bracket's ends again
            return ratios[v] - 1.0
        record = measure_grating(
            instrument, pitch_nm, axis=axis, span_nm=span, speed_nm_per_s=v,
            n_cycles=n_cycles, skip_cycles=skip_cycles, n_lines=n_lines,
            angle_line_offset_nm=None,
        )  # fmt: skip
        busy[0] += record.u_nm.size * record.sample_period_s
        ratio = width_ratio(record)
        if not 0.5 < ratio < 2.0:
            raise ValueError(
                f"the scan at {v:.4g} nm/s reads {ratio:.3g} times as wide as commanded on a "
                f"grating of pitch {pitch_nm:g} nm: is the pitch right?"
            )
        ratios[v] = ratio
        return ratio - 1.0

    f_lo, f_hi = excess(math.log(lo)), excess(math.log(hi))
    if f_lo < 0 or f_hi > 0:  # not as wide as commanded anywhere between
        scan = None
    else:
        v = math.exp(brentq(excess, math.log(lo), math.log(hi), xtol=math.log1p(tol)))
        scan = ScanCalibration(span, v)
    return CalibrationScan(scan, tuple(ratios.items()), busy[0])


def width_ratio(record: GratingRecord) -> float:
    """The scan's width over the command's on a grating record (the grating taken as square
    to the axis).

    On each pass (a ramp) the crests and troughs of the heights (prominent by a quarter of
    the record's height range) are placed in command at the apex of a parabola through their
    sample and its neighbours: they are the profile's phases ``0`` and ``pi`` (mod
    ``2 pi``), so between the first and the last the phase is counted. At each end the
    phase is read from the end's height between the pass's median crest and trough on the
    grating's profile ``(1 + cos(phase)) / 2``, up to its sign and whole turns, which a
    quadratic in the command through the :data:`END_ANCHORS` crests and troughs nearest
    that end, extrapolated to it, settles (the nearer candidate). The width
    is the phase over the pass times ``pitch / 2 pi``; the ratio, the median over the
    passes (ascending and descending ones in equal numbers: the drift's first-order stretch
    cancels; one pass whose end sits on a crest does not move it).

    Raises
    ------
    ValueError
        If a pass crosses fewer than :data:`MIN_CRESTS` crests.
    """
    prominence = 0.25 * float(np.ptp(record.height_nm))
    ratios = []
    for a, b in record.passes:
        u, z = record.u_nm[a:b], record.height_nm[a:b]
        crests, _ = find_peaks(z, prominence=prominence)
        troughs, _ = find_peaks(-z, prominence=prominence)
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
        at, kind = at[(at > 0) & (at < z.size - 1)], kind[(at > 0) & (at < z.size - 1)]
        sign = np.where(kind == 0, 1.0, -1.0)  # apexes of z (crests) or of -z (troughs)
        z0, z1, z2 = sign * z[at - 1], sign * z[at], sign * z[at + 1]
        curv = z0 - 2 * z1 + z2
        off = np.where(curv < 0, 0.5 * (z0 - z2) / np.where(curv < 0, curv, -1.0), 0.0)
        pos = u[at] + np.clip(off, -0.5, 0.5) * (u[at + 1] - u[at - 1]) / 2
        step = np.where(kind[1:] != kind[:-1], math.pi, 2.0 * math.pi)  # a missed one: 2 pi
        phase = np.concatenate([[math.pi * kind[0]], math.pi * kind[0] + np.cumsum(step)])
        n = min(END_ANCHORS, pos.size)
        crest = float(np.median(z[crests]))
        trough = float(np.median(z[troughs])) if troughs.size else float(z.min())
        start = _end_phase(float(np.polyval(np.polyfit(pos[:n] - u[0], phase[:n], 2), 0.0)),
                           float(z[0]), crest, trough)  # fmt: skip
        end = _end_phase(float(np.polyval(np.polyfit(pos[-n:] - u[-1], phase[-n:], 2), 0.0)),
                         float(z[-1]), crest, trough)  # fmt: skip
        width = (end - start) * record.pitch_nm / (2.0 * math.pi)
        ratios.append(width / abs(float(u[-1] - u[0])))
    return float(np.median(ratios))


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
