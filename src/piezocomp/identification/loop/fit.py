"""Section IV on the steady cycles: the loop fit and its regularisation (eqs 21-23).

A particle seen at ``u_a`` on the forward (ascending) trace and at ``u_d`` on the backward
(descending) trace of a steady cycle gives one equation (23), ``f_a(u_a) = f_d(u_d)`` with
``f_d(u) = u_min + u_max - f_a(u_min + u_max - u)`` (eqs 21-22). This module turns the
steady cycles of part A of the identification waveform into the loop and ``h(y)``:

* :func:`estimate_loop`: the averaged steady traces, their particle peaks paired across the
  traces (:func:`~piezocomp.identification.acquisition.peaks.guided_pairs`), the symmetric loop
  ``f_a`` and the height profile ``h(y)`` (:class:`LoopEstimate`);
* the loop fits behind it, regularised as much as the pairs allow: eq (23)'s polynomial
  ``f_a`` (:func:`_fit_loop`) and a Prandtl-Ishlinskii branch (:func:`fit_pi_loop`), both by
  the discrepancy principle of :func:`_most_regularised`. The calibration cycles' loop
  (:class:`~piezocomp.identification.reference.frames.CalibrationFrame`) uses the PI fit.

The next stage, estimation, starts its models from this loop
(:func:`~piezocomp.identification.estimation.candidates.initial_from_loop`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.identification.acquisition.peaks import Peaks, find_peaks, guided_pairs
from piezocomp.identification.acquisition.waveforms import IdentificationWaveform
from piezocomp.identification.loop.pi_branch import PILoop
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.loop.symmetric import SymmetricLoop

__all__ = ["LoopEstimate", "estimate_loop", "fit_pi_loop"]


@dataclass(frozen=True)
class LoopEstimate:
    """Section IV on part A: the averaged traces, the paired peaks, ``f_a`` and ``h``."""

    u_forward_nm: NDArray[np.float64]
    forward_nm: NDArray[np.float64]
    u_backward_nm: NDArray[np.float64]
    backward_nm: NDArray[np.float64]
    u_ascending_peaks_nm: NDArray[np.float64]
    u_descending_peaks_nm: NDArray[np.float64]
    loop: SymmetricLoop
    profile: HeightProfile
    all_pairs: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...] = ()


def estimate_loop(
    u_nm: NDArray[np.float64],
    height_nm: NDArray[np.float64],
    waveform: IdentificationWaveform,
    *,
    degree: int = 5,
    min_prominence_nm: float = 3.0,
    max_shift_nm: float | None = None,
    extra_peaks: Sequence[tuple[Peaks, Peaks]] = (),
) -> LoopEstimate:
    """Loop and ``h(y)`` from the steady cycles of part A (Section IV, eqs 21-23).

    Cycles 1.. of part A (the first settles the history) are averaged trace by trace; peaks
    are found with sub-sample precision on both averaged traces, paired (unpaired peaks are
    rejected) and fitted by :meth:`SymmetricLoop.from_line_pairs`, together with
    the pairs of ``extra_peaks`` (each a line's forward and backward peaks) from other lines
    scanned with the same steady cycle, if any.

    Raises
    ------
    ValueError
        If fewer than ``degree + 1`` pairs are available in all (too few particles for the
        degree).
    """
    cycles = range(1, waveform.n_steady)
    u_f = u_nm[waveform.ascending(1)]
    u_b = u_nm[waveform.descending(1)]
    z_f = np.array([height_nm[waveform.ascending(c)] for c in cycles])
    z_b = np.array([height_nm[waveform.descending(c)] for c in cycles])
    f_mean, b_mean = z_f.mean(axis=0), z_b.mean(axis=0)
    step = abs(float(u_f[1] - u_f[0]))
    sep = max(2.0 * step, 5.0)
    pf = find_peaks(u_f, f_mean, min_prominence_nm=min_prominence_nm, min_separation_nm=sep)
    pb = find_peaks(u_b, b_mean, min_prominence_nm=min_prominence_nm, min_separation_nm=sep)
    span = waveform.u_max_nm - waveform.u_min_nm
    shift = 0.15 * span if max_shift_nm is None else max_shift_nm
    lines = [(pf, pb), *extra_peaks]
    paired = guided_pairs(lines, max_shift_nm=shift)
    n_line = paired[0][0].size
    n_total = sum(a.size for a, _ in paired)
    if n_line <= degree and n_total <= degree:
        raise ValueError(
            f"the line crosses too few particles for a loop of degree {degree}: "
            f"{len(pf)} peaks on the forward trace, {len(pb)} on the backward trace, "
            f"{n_line} pair up (and {n_total - n_line} pairs from other lines); eq (23) needs "
            f"more than {degree} pairs. Choose a line crossing more particles."
        )
    u_a = paired[0][0]
    u_d = paired[0][1]
    loop = _fit_loop(paired, waveform.u_min_nm, waveform.u_max_nm, degree)
    profile = HeightProfile.from_loop(loop, u_f, z_f)
    return LoopEstimate(u_f, f_mean, u_b, b_mean, u_a, u_d, loop, profile, tuple(paired))


def _most_regularised(
    fits: Sequence[Callable[[], Any]],
    paired: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    noise_nm: float,
) -> Any:
    """The discrepancy principle shared by the loop fits.

    ``fits`` build the same loop with increasing regularisation. Eq (23) determines the
    loop's width well but the odd part of ``f_a`` about the centre only weakly: with little
    regularisation the fit bends ``f_a`` to follow the noise of the peak positions (a
    residual far below that noise, a branch distorted by tens of nm). The loop kept is the
    most regularised one before the pair residual RMS first exceeds
    ``max(noise_nm, 2 * smallest residual)``; fits that fail (``ValueError``: e.g. an
    ``f_a`` that is not increasing) are skipped.
    """
    ua = np.concatenate([np.asarray(a, float) for a, _ in paired])
    ud = np.concatenate([np.asarray(d, float) for _, d in paired])
    results: list[tuple[float, Any]] = []
    errors = []
    for fit in fits:
        try:
            loop = fit()
        except ValueError as exc:
            errors.append(str(exc))
            continue
        results.append((float(np.sqrt(np.mean(loop.pair_residuals_nm(ua, ud) ** 2))), loop))
    if not results:
        raise ValueError(errors[-1])
    bound = max(noise_nm, 2.0 * min(r for r, _ in results))
    best = results[0][1]
    for res, loop in results:
        if res > bound:
            break
        best = loop
    return best


def _fit_loop(
    paired: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    u_min: float,
    u_max: float,
    degree: int,
    *,
    noise_nm: float = 0.5,
    rconds: Sequence[float] = (1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3),
) -> SymmetricLoop:
    """:meth:`SymmetricLoop.from_line_pairs` regularised as much as the pairs allow.

    The fit picks the least-curved solution among those the pairs do not tell apart,
    ``rcond`` deciding which; the largest ``rcond`` allowed by :func:`_most_regularised`.
    """
    fits = [
        partial(SymmetricLoop.from_line_pairs, paired, u_min, u_max, degree, rcond=rc)
        for rc in sorted(rconds)
    ]
    loop: SymmetricLoop = _most_regularised(fits, paired, noise_nm)
    return loop


def fit_pi_loop(
    paired: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    u_min: float,
    u_max: float,
    *,
    noise_nm: float = 0.5,
    ridges: Sequence[float] = tuple(np.geomspace(0.01, 3.0, 11)),
) -> PILoop:
    """:meth:`PILoop.from_line_pairs` regularised as much as the pairs allow.

    The Prandtl-Ishlinskii structure (a convex ascending branch) narrows, but does not close,
    eq (23)'s blindness to odd distortions; the ridge on the hysteretic weights picks the
    loop: the largest ``ridge`` allowed by :func:`_most_regularised` (unregularised first).
    """
    fits = [
        partial(PILoop.from_line_pairs, paired, u_min, u_max, ridge=ridge)
        for ridge in (0.0, *sorted(ridges))
    ]
    loop: PILoop = _most_regularised(fits, paired, noise_nm)
    return loop
