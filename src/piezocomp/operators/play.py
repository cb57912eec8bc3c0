"""The play (backlash) operator, eqs (3)-(5), and a bank of them, eq (6)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d
from piezocomp.operators import _kernels

__all__ = ["check_thresholds", "play_bank", "play_operator"]


def check_thresholds(name: str, thresholds: ArrayLike) -> NDArray[np.float64]:
    """Return thresholds as a finite 1-D array, refusing non-positive or non-increasing ones."""
    r = as_finite_1d(name, thresholds)
    if r.size and r[0] <= 0:
        raise ValueError(f"{name} must be > 0. Got {name}[0] = {r[0]}.")
    bad = np.flatnonzero(np.diff(r) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(
            f"{name} must be strictly increasing. Got {name}[{i}] = {r[i]} "
            f"after {name}[{i - 1}] = {r[i - 1]}."
        )
    return r


def play_bank(
    u_nm: ArrayLike, thresholds_nm: ArrayLike, state: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Outputs of a bank of play operators, eq (4): ``z_r(k) = max(u - r, min(z_r(k-1), u + r))``.

    Parameters
    ----------
    u_nm : array_like, shape (n,)
        Input samples.
    thresholds_nm : array_like, shape (m,)
        Thresholds ``0 < r_1 < ... < r_m``.
    state : array_like, shape (m,), optional
        Operator outputs before the first sample (``z_r(-1)``); zeros by default.

    Returns
    -------
    z : ndarray, shape (n, m)
        ``z[k, i] = z_{r_i}(k)``.
    state : ndarray, shape (m,)
        Outputs after the last sample, to continue a stream.
    """
    u = as_finite_1d("u_nm", u_nm)
    r = check_thresholds("thresholds_nm", thresholds_nm)
    z0 = np.zeros(r.size) if state is None else as_finite_1d("state", state).copy()
    if z0.shape != r.shape:
        raise ValueError(f"state must have shape {r.shape}. Got {z0.shape}.")
    out = np.empty((u.size, r.size))
    _kernels.play_bank(u, r, z0, out)
    return out, z0


def play_operator(
    u_nm: ArrayLike, threshold_nm: float, state: float = 0.0
) -> tuple[NDArray[np.float64], float]:
    """One play operator, eq (4); returns its outputs and its final state."""
    z, zf = play_bank(u_nm, [threshold_nm], [state])
    return z[:, 0], float(zf[0])
