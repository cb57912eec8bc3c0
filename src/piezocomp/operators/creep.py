"""First-order creep operators, eqs (1)-(2), discretised exactly for a sample period."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar
from piezocomp.operators import _kernels

__all__ = ["creep_bank", "creep_poles"]


def creep_poles(time_constants_s: ArrayLike, sample_period_s: float) -> NDArray[np.float64]:
    """Discrete poles ``p_i = exp(-lambda_i T) = exp(-T / tau_i)`` of eq (2).

    Parameters
    ----------
    time_constants_s : array_like
        ``tau_i = 1 / lambda_i`` (> 0), s.
    sample_period_s : float
        Sample period ``T`` (> 0), s.
    """
    tau = as_finite_1d("time_constants_s", time_constants_s)
    T = check_finite_scalar("sample_period_s", sample_period_s)
    if T <= 0:
        raise ValueError(f"sample_period_s must be > 0. Got {T}.")
    if np.any(tau <= 0):
        i = int(np.flatnonzero(tau <= 0)[0])
        raise ValueError(f"time_constants_s must be > 0. Got time_constants_s[{i}] = {tau[i]}.")
    return np.exp(-T / tau)


def creep_bank(
    u_nm: ArrayLike,
    time_constants_s: ArrayLike,
    sample_period_s: float,
    state: ArrayLike | None = None,
    u_prev_nm: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """States ``x_i(k) = p_i x_i(k-1) + (1 - p_i) u(k-1)`` of a bank of creep operators, eq (2).

    Returns ``x`` with shape (n, m) and the final states (``u(n-1)`` is the next ``u_prev``).
    """
    u = as_finite_1d("u_nm", u_nm)
    p = creep_poles(time_constants_s, sample_period_s)
    x0 = np.zeros(p.size) if state is None else as_finite_1d("state", state).copy()
    if x0.shape != p.shape:
        raise ValueError(f"state must have shape {p.shape}. Got {x0.shape}.")
    out = np.empty((u.size, p.size))
    _kernels.creep_bank(u, p, x0, check_finite_scalar("u_prev_nm", u_prev_nm), out)
    return out, x0
