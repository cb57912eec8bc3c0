"""Command waveforms for identification (Fig. 7a) and for validation.

All waveforms are piecewise-linear ramps at one constant speed between turning points, with
optional dwells (the command held still, which shows creep). They are built for one axis
(the *fast* axis of the chosen line) in nominal nm; the other axis is held by the caller.

* :func:`identification_waveform`: Fig. 7a. Part A, ``n_steady`` full cycles
  ``u_min -> u_max -> u_min`` (a steady loop, Section IV, for the loop ``f_a`` and ``h(y)``);
  part B, cycles of decreasing amplitude (every reversal size from the full span down to a
  few per cent of it, so every play operator of eq (4) switches between clamped and free) then
  random minor loops with dwells (creep, eq (2)).
* :func:`validation_waveform`: a fresh trajectory of random turning points (minor loops
  nested in major ones) with dwells, for scoring.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar, readonly

__all__ = [
    "IdentificationWaveform",
    "identification_waveform",
    "ramps",
    "validation_waveform",
]


MIN_RAMP_SAMPLES = 10
"""A ramp of part A must take at least this many samples (the loop is read off them)."""

MAX_SAMPLES = 20_000_000
"""Largest waveform built (a few arrays of this length must fit in memory)."""


def _positive(name: str, value: float) -> float:
    v = check_finite_scalar(name, value)
    if v <= 0:
        raise ValueError(f"{name} must be > 0. Got {v}.")
    return v


def _span(center_nm: float, span_nm: float) -> tuple[float, float]:
    c = check_finite_scalar("center_nm", center_nm)
    s = _positive("span_nm", span_nm)
    return c - s / 2, c + s / 2


def ramps(
    turning_points_nm: ArrayLike,
    speed_nm_per_s: float | ArrayLike,
    sample_period_s: float,
    dwells_s: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Samples of straight ramps at constant speed through the given turning points.

    Parameters
    ----------
    turning_points_nm : array_like, shape (m,)
        Command at each turning point (nm). The first is the start (included as sample 0).
    speed_nm_per_s : float or array_like, shape (m,)
        Ramp speed (nm/s, > 0), one for every ramp or one per turning point (the speed of
        the ramp arriving there; entry 0 is not used). Each ramp takes
        ``ceil(|du| / (speed T))`` samples, so the speed is never exceeded.
    sample_period_s : float
        Sample period ``T`` (s, > 0).
    dwells_s : array_like, shape (m,), optional
        Time held at each turning point after arriving (s, >= 0). Default none.

    Returns
    -------
    ndarray, shape (n,)
        The command, one sample per period, ending exactly on the last turning point.
    """
    tp = as_finite_1d("turning_points_nm", turning_points_nm)
    if tp.size < 1:
        raise ValueError("turning_points_nm must hold at least one point.")
    if np.ndim(speed_nm_per_s) == 0:
        v = np.full(tp.size, _positive("speed_nm_per_s", speed_nm_per_s))  # type: ignore[arg-type]
    else:
        v = as_finite_1d("speed_nm_per_s", speed_nm_per_s)
        if v.shape != tp.shape:
            raise ValueError(
                f"speed_nm_per_s must be one number or one per turning point ({tp.size}). "
                f"Got {v.size}."
            )
        if np.any(v[1:] <= 0):
            i = 1 + int(np.flatnonzero(v[1:] <= 0)[0])
            raise ValueError(f"speed_nm_per_s must be > 0. Got speed_nm_per_s[{i}] = {v[i]}.")
    T = _positive("sample_period_s", sample_period_s)
    dw = np.zeros(tp.size) if dwells_s is None else as_finite_1d("dwells_s", dwells_s)
    if dw.shape != tp.shape:
        raise ValueError(f"dwells_s must have one entry per turning point. Got {dw.size}.")
    if np.any(dw < 0):
        raise ValueError("dwells_s must be >= 0.")
    pieces = [np.array([tp[0]]), np.full(round(dw[0] / T), tp[0])]
    for k in range(1, tp.size):
        du = tp[k] - tp[k - 1]
        n = int(np.ceil(abs(du) / (v[k] * T) - 1e-9))
        if n > 0:
            seg = tp[k - 1] + du * np.arange(1, n + 1) / n
            seg[-1] = tp[k]  # exactly on the turning point (no rounding past the span)
            pieces.append(seg)
        pieces.append(np.full(round(dw[k] / T), tp[k]))
    return np.concatenate(pieces)


@dataclass(frozen=True)
class IdentificationWaveform:
    """The identification input of Fig. 7a for one axis.

    Attributes
    ----------
    u_nm : ndarray, shape (n,)
        Command samples (nm); sample 0 is ``u_min_nm``.
    u_min_nm, u_max_nm : float
        Extremes of the steady cycles of part A (the span of the line used).
    sample_period_s : float
        ``T`` (s).
    half_cycle_samples : int
        ``m``: samples of one ramp of part A. Cycle ``i`` ascends over samples
        ``[2 m i, 2 m i + m]`` and descends over ``[2 m i + m, 2 m (i + 1)]`` (inclusive).
    n_steady : int
        Number of steady cycles in part A.
    """

    u_nm: NDArray[np.float64]
    u_min_nm: float
    u_max_nm: float
    sample_period_s: float
    half_cycle_samples: int
    n_steady: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "u_nm", readonly(self.u_nm))

    @property
    def part_a(self) -> slice:
        """Samples of part A (steady cycles)."""
        return slice(0, 2 * self.half_cycle_samples * self.n_steady + 1)

    @property
    def part_b(self) -> slice:
        """Samples of part B (varied amplitudes), starting right after part A."""
        return slice(self.part_a.stop, self.u_nm.size)

    def ascending(self, cycle: int) -> slice:
        """Samples of the ascending ramp (forward trace) of steady cycle ``cycle`` of part A."""
        i = self._cycle(cycle)
        m = self.half_cycle_samples
        return slice(2 * m * i, 2 * m * i + m + 1)

    @property
    def forward_traces(self) -> list[slice]:
        """The ascending ramps of steady cycles 1 to ``n_steady - 1`` (cycle 0 starts from
        rest): the forward traces ``h(y)`` is built from and re-indexed on."""
        return [self.ascending(c) for c in range(1, self.n_steady)]

    def descending(self, cycle: int) -> slice:
        """Samples of the descending ramp (backward trace) of steady cycle ``cycle``."""
        i = self._cycle(cycle)
        m = self.half_cycle_samples
        return slice(2 * m * i + m, 2 * m * (i + 1) + 1)

    def _cycle(self, cycle: int) -> int:
        i = int(cycle) + (self.n_steady if cycle < 0 else 0)
        if not 0 <= i < self.n_steady:
            raise IndexError(f"cycle must be in [-{self.n_steady}, {self.n_steady}). Got {cycle}.")
        return i

    @property
    def domain_nm(self) -> tuple[float, float]:
        """``(u_min_nm, u_max_nm)``: the command interval a model identified on this waveform
        was informed over (:attr:`~piezocomp.model.ScannerModel.domain_nm`)."""
        return (float(self.u_min_nm), float(self.u_max_nm))

    @property
    def duration_s(self) -> float:
        """Length of the waveform (s)."""
        return self.u_nm.size * self.sample_period_s


def identification_waveform(
    center_nm: float,
    span_nm: float,
    speed_nm_per_s: float,
    sample_period_s: float,
    *,
    n_steady: int = 4,
    n_decaying: int = 12,
    n_random: int = 30,
    max_dwell_s: float = 4.0,
    speed_factors: ArrayLike = (1.0,),
    max_speed_nm_per_s: float = np.inf,
    rng: np.random.Generator | int | None = 0,
) -> IdentificationWaveform:
    """The identification waveform of Fig. 7a for a line, span, speed and sample period.

    Parameters
    ----------
    center_nm, span_nm : float
        The line covers ``[center - span/2, center + span/2]`` (nm of command).
    speed_nm_per_s : float
        Ramp speed (nm/s); the same throughout so that the steady loop of part A is the loop
        seen at the speed of part B.
    sample_period_s : float
        ``T`` (s).
    n_steady : int
        Full cycles of part A (the last ones are steady; the first wipe out the history).
    n_decaying : int
        Reversals of decreasing amplitude (full span down to 5 % of it) at the start of part B.
    n_random : int
        Random turning points (minor loops inside major ones) after them, each reversal size
        drawn uniformly in ``[0.03, 1] * span`` within the span.
    max_dwell_s : float
        Largest dwell at a random turning point (uniform in ``[0, max_dwell_s]``), s.
    speed_factors : array_like of float
        Part B's ramps run at ``speed_nm_per_s`` times these factors in turn (ramp ``k`` at
        ``speed_factors[k % len]``), capped at ``max_speed_nm_per_s``; part A and the closing
        sweep run at ``speed_nm_per_s``. At one speed the lag of the fast creep modes (about
        ``c_i tau_i`` times the speed) looks like a narrow play operator; two or more speeds
        tell them apart (``docs/identification-design.md``, "Three ramp speeds").
    max_speed_nm_per_s : float
        The instrument's speed limit (nm/s).
    rng : numpy.random.Generator or int or None
        Randomness of part B (the turning points and dwells; the speeds do not draw from it).

    Returns
    -------
    IdentificationWaveform
    """
    lo, hi = _span(center_nm, span_nm)
    T = _positive("sample_period_s", sample_period_s)
    v = _positive("speed_nm_per_s", speed_nm_per_s)
    _check_counts(n_steady, n_decaying, n_random)
    max_dwell = check_finite_scalar("max_dwell_s", max_dwell_s)
    if max_dwell < 0:
        raise ValueError(f"max_dwell_s must be >= 0. Got {max_dwell}.")
    factors = as_finite_1d("speed_factors", speed_factors)
    if factors.size < 1 or np.any(factors <= 0):
        raise ValueError(f"speed_factors must hold at least one factor, all > 0. Got {factors}.")
    v_max = float(max_speed_nm_per_s)
    if np.isnan(v_max) or v_max <= 0:
        raise ValueError(f"max_speed_nm_per_s must be > 0. Got {max_speed_nm_per_s}.")
    if v > v_max:
        raise ValueError(f"speed_nm_per_s = {v:g} is above the instrument's limit {v_max:g} nm/s.")
    gen = np.random.default_rng(rng)
    span = hi - lo
    ramp = span / (v * T)
    if ramp < MIN_RAMP_SAMPLES:
        raise ValueError(
            f"a ramp of {span:g} nm at {v:g} nm/s takes {ramp:.3g} samples of {T:g} s, fewer "
            f"than {MIN_RAMP_SAMPLES}: lower the speed or the sample period."
        )
    ramps_b = int(n_decaying) + int(n_random) + 3
    budget = ramp * (2 * int(n_steady) + ramps_b / float(np.min(factors))) + ramps_b * max_dwell / T
    if budget > MAX_SAMPLES:
        raise ValueError(
            f"the waveform would take about {budget:.3g} samples, more than {MAX_SAMPLES:.0e}: "
            "shorten the span, raise the speed or the sample period, or use fewer ramps."
        )
    m = int(np.ceil(ramp - 1e-9))
    up = lo + span * np.arange(1, m + 1) / m
    down = hi - span * np.arange(1, m + 1) / m
    part_a = np.concatenate([[lo]] + [np.concatenate((up, down))] * int(n_steady))
    tps, dwells = _turning_points(lo, hi, int(n_decaying), int(n_random), max_dwell, gen)
    # End with one full sweep so every operator's state is known at the end.
    tps += [lo, hi, lo]
    dwells += [0.0, 0.0, 0.0]
    n_b = len(tps) - 3  # ramps of part B before the closing sweep (entry 0 is the start)
    speeds = np.full(len(tps), v)
    speeds[1:n_b] = np.minimum(v * factors[np.arange(n_b - 1) % factors.size], v_max)
    part_b = ramps(tps, speeds, T, dwells)[1:]
    return IdentificationWaveform(
        u_nm=np.concatenate((part_a, part_b)),
        u_min_nm=lo,
        u_max_nm=hi,
        sample_period_s=T,
        half_cycle_samples=m,
        n_steady=int(n_steady),
    )


def _check_counts(n_steady: int, n_decaying: int, n_random: int) -> None:
    """The waveform's cycle and reversal counts are non-negative integers, ``n_steady >= 2``."""
    for name, val in (("n_steady", n_steady), ("n_decaying", n_decaying), ("n_random", n_random)):
        if int(val) != val or val < 0:
            raise ValueError(f"{name} must be a non-negative integer. Got {val!r}.")
    if n_steady < 2:
        raise ValueError(
            f"n_steady must be >= 2 (one cycle to settle, one steady). Got {n_steady}."
        )


def _turning_points(
    lo: float, hi: float, n_decaying: int, n_random: int, max_dwell: float, gen: np.random.Generator
) -> tuple[list[float], list[float]]:
    """Part B's turning points (from ``lo``) and the dwell at each (s): first decaying
    amplitudes, alternate ends, from the span to 5 % of it, centred alternately on the middle
    and near the ends (minor loops at both ends); then random reversals."""
    span = hi - lo
    tps = [lo]
    dwells = [0.0]
    amps = np.geomspace(1.0, 0.05, n_decaying) * span if n_decaying else np.empty(0)
    for j, amp in enumerate(amps):
        prev = tps[-1]
        going_up = j % 2 == 0
        target = prev + amp if going_up else prev - amp
        target = min(max(target, lo), hi)
        tps.append(target)
        dwells.append(gen.uniform(0.0, max_dwell) if j % 3 == 2 else 0.0)
    for _ in range(n_random):
        prev = tps[-1]
        going_up = len(tps) < 2 or tps[-1] <= tps[-2]
        room = hi - prev if going_up else prev - lo
        if room < 0.03 * span:
            going_up = not going_up
            room = hi - prev if going_up else prev - lo
        size = gen.uniform(0.03, 1.0) * span
        size = min(size, room)
        tps.append(min(max(prev + size if going_up else prev - size, lo), hi))
        dwells.append(gen.uniform(0.0, max_dwell) if gen.random() < 0.4 else 0.0)
    return tps, dwells


def validation_waveform(
    center_nm: float,
    span_nm: float,
    speed_nm_per_s: float,
    sample_period_s: float,
    *,
    n_turns: int = 24,
    max_dwell_s: float = 3.0,
    start_nm: float | None = None,
    rng: np.random.Generator | int | None = 1,
) -> NDArray[np.float64]:
    """A fresh validation trajectory with minor loops over the span.

    Starts with a full sweep ``start -> lo -> hi`` (so that both the scanner and the model
    have a known history), then ``n_turns`` random turning points whose reversal sizes are
    drawn log-uniformly in ``[0.02, 1] * span`` (many nested minor loops), with random dwells.

    Parameters
    ----------
    center_nm, span_nm, speed_nm_per_s, sample_period_s : float
        As in :func:`identification_waveform`.
    n_turns : int
        Random turning points after the initial sweep.
    max_dwell_s : float
        Largest dwell at a turning point (s).
    start_nm : float, optional
        First sample (default the low end of the span).
    rng : numpy.random.Generator or int or None
        Randomness of the turning points.

    Returns
    -------
    ndarray, shape (n,)
        Command samples (nm).
    """
    lo, hi = _span(center_nm, span_nm)
    T = _positive("sample_period_s", sample_period_s)
    v = _positive("speed_nm_per_s", speed_nm_per_s)
    if int(n_turns) != n_turns or n_turns < 0:
        raise ValueError(f"n_turns must be a non-negative integer. Got {n_turns!r}.")
    start = lo if start_nm is None else check_finite_scalar("start_nm", start_nm)
    gen = np.random.default_rng(rng)
    span = hi - lo
    tps = [start, lo, hi]
    dwells = [0.0, 0.0, gen.uniform(0.0, max_dwell_s)]
    for _ in range(int(n_turns)):
        prev = tps[-1]
        going_up = tps[-1] < tps[-2]
        room = hi - prev if going_up else prev - lo
        if room < 0.02 * span:
            going_up = not going_up
            room = hi - prev if going_up else prev - lo
        size = min(span * np.exp(gen.uniform(np.log(0.02), 0.0)), room)
        tps.append(min(max(prev + size if going_up else prev - size, lo), hi))
        dwells.append(gen.uniform(0.0, max_dwell_s) if gen.random() < 0.5 else 0.0)
    return ramps(tps, v, T, dwells)
