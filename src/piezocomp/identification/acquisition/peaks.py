"""Features seen on both traces of a line: sub-sample peaks and their pairing (Section IV).

Section IV of Mokaberi & Requicha (2008) localises the scanner with features that do not
change between scans, the peaks of round particles. A particle seen at ``u_a`` on the forward
(ascending) trace and at ``u_d`` on the backward (descending) trace gives one equation (23).
This module finds the peaks of one trace with sub-sample precision (:func:`find_peaks`) and
pairs the peaks of the forward trace with those of the backward trace: by one typical shift
(:func:`pair_peaks`), or, for the loop fit of eq (23), by an order-preserving alignment of
heights (:func:`aligned_pairs`) checked against a smooth shift model pooled over the lines
of one steady cycle (:func:`guided_pairs`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize
import scipy.signal
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar, readonly

__all__ = ["Peaks", "aligned_pairs", "find_peaks", "guided_pairs", "pair_peaks"]


@dataclass(frozen=True)
class Peaks:
    """Peaks of one trace, sorted by increasing position.

    Attributes
    ----------
    position_nm : ndarray, shape (n,)
        Sub-sample position of each peak on the trace's position axis (nm).
    height_nm : ndarray, shape (n,)
        Height of each peak (nm), the largest sample of the peak.
    prominence_nm : ndarray, shape (n,)
        Prominence of each peak (nm): how far it rises above the higher of the two
        lowest points separating it from higher terrain (:func:`scipy.signal.peak_prominences`).
    """

    position_nm: NDArray[np.float64]
    height_nm: NDArray[np.float64]
    prominence_nm: NDArray[np.float64]

    def __post_init__(self) -> None:
        arrays = {}
        for name in ("position_nm", "height_nm", "prominence_nm"):
            arrays[name] = as_finite_1d(name, getattr(self, name))
        n = {a.size for a in arrays.values()}
        if len(n) != 1:
            raise ValueError(
                "position_nm, height_nm and prominence_nm must have the same length. Got "
                + ", ".join(f"{k}: {v.size}" for k, v in arrays.items())
                + "."
            )
        if np.any(np.diff(arrays["position_nm"]) < 0):
            raise ValueError("position_nm must be sorted in increasing order.")
        for name, a in arrays.items():
            object.__setattr__(self, name, readonly(a))

    def __len__(self) -> int:
        return int(self.position_nm.size)


def _index_to_position(index: NDArray[np.float64], position: NDArray[np.float64]) -> Any:
    """Map fractional sample indices onto the (monotone) position axis, linearly."""
    return np.interp(index, np.arange(position.size, dtype=float), position)


def find_peaks(
    position_nm: ArrayLike,
    height_nm: ArrayLike,
    *,
    min_prominence_nm: float,
    min_separation_nm: float = 0.0,
) -> Peaks:
    """Find the peaks of one trace with sub-sample positions.

    Parameters
    ----------
    position_nm : array_like, shape (n,)
        Position of each sample (nm): the command ``u`` of the trace. Strictly monotone,
        increasing or decreasing, not necessarily uniform.
    height_nm : array_like, shape (n,)
        Measured height ``z_m`` at each sample (nm).
    min_prominence_nm : float
        Smallest prominence of a peak (nm, > 0); lower bumps are noise.
    min_separation_nm : float, optional
        Smallest distance between two peaks (nm, >= 0); of two closer peaks the higher is kept.

    Returns
    -------
    Peaks
        Peaks sorted by increasing position. Peaks at the first or last sample are not
        reported (their shape is cut).

    Notes
    -----
    A peak's sub-sample position is the middle of the feature where it rises above half its
    prominence (interpolated crossings, robust for broad features). Positions are found in
    sample-index space and mapped onto ``position_nm`` by linear interpolation, so any
    monotone axis works.
    """
    u = as_finite_1d("position_nm", position_nm)
    z = as_finite_1d("height_nm", height_nm)
    if u.size != z.size:
        raise ValueError(
            f"position_nm and height_nm must have the same length. Got {u.size} and {z.size}."
        )
    prom = check_finite_scalar("min_prominence_nm", min_prominence_nm)
    if prom <= 0:
        raise ValueError(f"min_prominence_nm must be > 0. Got {prom}.")
    sep = check_finite_scalar("min_separation_nm", min_separation_nm)
    if sep < 0:
        raise ValueError(f"min_separation_nm must be >= 0. Got {sep}.")
    empty = Peaks(np.empty(0), np.empty(0), np.empty(0))
    if u.size < 3:
        return empty
    du = np.diff(u)
    if not (np.all(du > 0) or np.all(du < 0)):
        raise ValueError("position_nm must be strictly monotone (increasing or decreasing).")
    step = float(np.mean(np.abs(du)))
    distance = max(1.0, sep / step)
    idx, props = scipy.signal.find_peaks(z, prominence=prom, distance=distance)
    if idx.size == 0:
        return empty
    prominence = props["prominences"]
    _, _, left, right = scipy.signal.peak_widths(
        z,
        idx,
        rel_height=0.5,
        prominence_data=(prominence, props["left_bases"], props["right_bases"]),
    )
    frac = 0.5 * (left + right)
    pos = _index_to_position(frac, u)
    order = np.argsort(pos, kind="stable")
    return Peaks(pos[order], z[idx][order], prominence[order])


def pair_peaks(
    forward_nm: ArrayLike,
    backward_nm: ArrayLike,
    *,
    max_shift_nm: float,
    tolerance_nm: float | None = None,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Pair the peaks of the forward trace with their counterparts on the backward trace.

    The shift ``forward - backward`` of one feature between the two traces (its width of the
    hysteresis loop at that height, eqs (21)-(23)) varies slowly along the line. The pairing:

    1. estimates the typical shift as the densest cluster (width ``tolerance_nm``) of all
       candidate shifts within ``max_shift_nm`` (true pairs share one shift; ties go to the
       smallest shift);
    2. assigns peaks one-to-one (Hungarian algorithm,
       :func:`scipy.optimize.linear_sum_assignment`) on the cost ``|shift - typical|``,
       forbidding pairs whose cost exceeds ``tolerance_nm`` or whose shift exceeds
       ``max_shift_nm``;
    3. rejects ambiguous pairs (another candidate within the tolerance on either side) and
       pairs that break the order of the features along the line.

    Parameters
    ----------
    forward_nm, backward_nm : array_like, shape (n_f,), (n_b,)
        Peak positions on the forward and backward traces (nm), on the same command axis.
    max_shift_nm : float
        Largest ``|forward - backward|`` shift a pair may have (nm, > 0).
    tolerance_nm : float, optional
        Largest deviation of a pair's shift from the typical shift (nm, > 0). Default
        ``max_shift_nm / 4``.

    Returns
    -------
    idx_forward, idx_backward : ndarray of int
        Indices of the paired peaks, sorted by forward position; ``forward_nm[idx_forward[i]]``
        and ``backward_nm[idx_backward[i]]`` are the same feature.
    """
    f = as_finite_1d("forward_nm", forward_nm)
    b = as_finite_1d("backward_nm", backward_nm)
    max_shift = check_finite_scalar("max_shift_nm", max_shift_nm)
    if max_shift <= 0:
        raise ValueError(f"max_shift_nm must be > 0. Got {max_shift}.")
    tol = (
        max_shift / 4.0
        if tolerance_nm is None
        else check_finite_scalar("tolerance_nm", tolerance_nm)
    )
    if tol <= 0:
        raise ValueError(f"tolerance_nm must be > 0. Got {tol}.")
    none = (np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp))
    if f.size == 0 or b.size == 0:
        return none
    shift = f[:, None] - b[None, :]
    near = np.abs(shift) <= max_shift
    if not near.any():
        return none
    # Typical shift: the densest cluster of candidate shifts (true pairs share one shift).
    cand = np.sort(shift[near])
    count = np.searchsorted(cand, cand + tol, "right") - np.searchsorted(cand, cand - tol, "left")
    best = np.flatnonzero(count == count.max())
    centre = cand[best[np.argmin(np.abs(cand[best]))]]
    typical = float(np.median(cand[np.abs(cand - centre) <= tol]))
    deviation = np.abs(shift - typical)
    allowed = near & (deviation <= tol)
    if not allowed.any():
        return none
    big = 1e6 * (tol + max_shift)
    cost = np.where(allowed, deviation, big)
    rows, cols = scipy.optimize.linear_sum_assignment(cost)
    keep = allowed[rows, cols]
    rows, cols = rows[keep], cols[keep]
    # Ambiguity: a second candidate inside the gate on either side.
    unique = (allowed[rows].sum(axis=1) == 1) & (allowed[:, cols].sum(axis=0) == 1)
    rows, cols = rows[unique], cols[unique]
    order = np.argsort(f[rows], kind="stable")
    rows, cols = rows[order], cols[order]
    # Order preservation: features keep their order along the line on both traces.
    if rows.size > 1:
        monotone = np.ones(rows.size, dtype=bool)
        bpos = b[cols]
        monotone[1:] &= np.diff(bpos) > 0
        monotone[:-1] &= np.diff(bpos) > 0
        rows, cols = rows[monotone], cols[monotone]
    return rows.astype(np.intp), cols.astype(np.intp)


def aligned_pairs(
    pf: Peaks,
    pb: Peaks,
    *,
    max_shift_nm: float,
    height_tolerance_nm: float = 1.5,
    min_shift_nm: float | None = None,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Order-preserving alignment of forward and backward peaks by their heights.

    The particles of a line appear in the same order on both traces, each with the same
    height, the forward one shifted by ``0 <= u_a - u_d <= max_shift_nm`` (the loop's width
    there). A dynamic programme (sequence alignment) finds the order-preserving matching with
    the most pairs (ties: closest heights) among height-consistent candidates; it does not
    assume one typical shift, so it works when the shift exceeds the particle spacing
    (large spans). ``min_shift_nm`` (default ``-0.02 max_shift_nm``) is the smallest shift.
    """
    f, b = pf.position_nm, pb.position_nm
    nf, nb = f.size, b.size
    shift = f[:, None] - b[None, :]
    dh = np.abs(pf.height_nm[:, None] - pb.height_nm[None, :])
    lo = -0.02 * max_shift_nm if min_shift_nm is None else min_shift_nm
    ok = (shift >= lo) & (shift <= max_shift_nm) & (dh <= height_tolerance_nm)
    gain = np.where(ok, 1.0 - 0.5 * dh / height_tolerance_nm, -np.inf)
    score = np.zeros((nf + 1, nb + 1))
    move = np.zeros((nf + 1, nb + 1), dtype=np.int8)  # 0 diag, 1 skip forward, 2 skip back
    for i in range(1, nf + 1):
        for j in range(1, nb + 1):
            best, mv = score[i - 1, j - 1] + gain[i - 1, j - 1], 0
            if score[i - 1, j] > best:
                best, mv = score[i - 1, j], 1
            if score[i, j - 1] > best:
                best, mv = score[i, j - 1], 2
            score[i, j] = best
            move[i, j] = mv
        move[i, 0] = 1
    move[0, 1:] = 2
    i, j = nf, nb
    rows, cols = [], []
    while i > 0 and j > 0:
        mv = move[i, j]
        if mv == 0:
            rows.append(i - 1)
            cols.append(j - 1)
            i, j = i - 1, j - 1
        elif mv == 1:
            i -= 1
        else:
            j -= 1
    return np.array(rows[::-1], dtype=np.intp), np.array(cols[::-1], dtype=np.intp)


def guided_pairs(
    lines: Sequence[tuple[Peaks, Peaks]],
    *,
    max_shift_nm: float,
    tolerance_nm: float = 3.0,
    height_tolerance_nm: float = 1.5,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Pair forward and backward peaks of several lines of one steady cycle (eq 23 pairs).

    The forward-backward shift of a particle is the loop's width where it sits: it varies
    along the line (from 0 at the ends to its largest in the middle), so one typical shift
    (:func:`pair_peaks`) mis-pairs neighbours, and on large spans the shift exceeds the
    particle spacing. Each line is aligned by :func:`aligned_pairs` (order and height);
    then a smooth shift model ``s(u_a)`` (robust polynomial of degree up to 4, pooled over
    the lines) rejects the pairs whose shift departs from it by more than
    ``max(tolerance_nm, 4 MAD)`` (mis-pairs).

    Returns
    -------
    list of (u_ascending, u_descending)
        One entry per line (possibly empty arrays).
    """
    per_line = []
    for pf, pb in lines:
        i, j = aligned_pairs(
            pf, pb, max_shift_nm=max_shift_nm, height_tolerance_nm=height_tolerance_nm
        )
        per_line.append((pf.position_nm[i], pb.position_nm[j]))
    ua = np.concatenate([a for a, _ in per_line]) if per_line else np.empty(0)
    sh = np.concatenate([a - d for a, d in per_line]) if per_line else np.empty(0)
    deg = min(4, np.unique(np.round(ua)).size - 2)
    if deg < 1:
        return per_line
    scale = max(float(np.max(np.abs(ua))), 1.0)
    keep = np.ones(ua.size, dtype=bool)
    for _ in range(4):  # fit, reject gross mis-pairs, refit
        coef = np.polyfit(ua[keep] / scale, sh[keep], deg)
        res = sh - np.polyval(coef, ua / scale)
        mad = 1.4826 * np.median(np.abs(res[keep] - np.median(res[keep])))
        new = np.abs(res) <= max(tolerance_nm, 4.0 * mad)
        if np.array_equal(new, keep) or np.unique(np.round(ua[new])).size <= deg:
            break
        keep = new
    out = []
    start = 0
    for a, d in per_line:
        k = keep[start : start + a.size]
        out.append((a[k], d[k]))
        start += a.size
    return out
