"""Logarithmic creep of one scanner axis as a dense spectrum of first-order modes.

Modes ``j`` with time constants ``tau_j`` spread log-uniformly (``modes_per_decade`` per
decade from ``tau_min_s`` to ``tau_max_s``) and equal weights ``w`` are driven by the
held command. With ``x_j`` relaxing towards the command,

    x_j(k) = p_j x_j(k-1) + (1 - p_j) u(k-1),      p_j = exp(-T / tau_j),
    creep(k) = sum_j w (x_j(k) - u(k)) + g_ref u(k),  g_ref = sum_j w exp(-t_ref / tau_j),

the response to a command step ``D`` at ``t = 0`` is ``D (g_ref - sum_j w exp(-t/tau_j))``:
logarithmic in time, ``~ D w n_dec log10(t) + const`` for ``tau_min << t << tau_max``
(Section II of the paper: creep of 1 % to 20 % of a step, for 10 s to minutes), zero at
``t = t_ref`` (the scanner's nominal sensitivity is that of the response ``t_ref`` after a
step, as a calibration by imaging would find). The weight is chosen so that

    (extension(100 s) - extension(0.1 s)) / D = creep          (the ``creep`` key)

exactly. A 2-pole creep model can only approximate this response. The discrete update is
exact for a command held over each sample period (zero-order hold).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar, readonly
from piezocomp.virtual_afm import _kernels as K

__all__ = ["CreepParams", "CreepState", "creep_run"]


@dataclass(frozen=True)
class CreepParams:
    """A bank of first-order creep modes.

    Parameters
    ----------
    tau_s : ndarray, shape (m,)
        Time constants, s, all > 0.
    weights : ndarray, shape (m,)
        Mode weights (fraction of a command step), all >= 0.
    reference_time_s : float
        Time after a step at which the creep response crosses zero, s.
    """

    tau_s: NDArray[np.float64]
    weights: NDArray[np.float64]
    reference_time_s: float = 1.0

    def __post_init__(self) -> None:
        tau = readonly(as_finite_1d("tau_s", self.tau_s))
        w = readonly(as_finite_1d("weights", self.weights))
        if tau.shape != w.shape:
            raise ValueError(f"tau_s and weights must have one shape. Got {tau.shape}, {w.shape}.")
        if tau.size and tau.min() <= 0:
            raise ValueError(f"tau_s must be > 0. Got {tau.min()}.")
        if w.size and w.min() < 0:
            raise ValueError(f"weights must be >= 0. Got {w.min()}.")
        t_ref = check_finite_scalar("reference_time_s", self.reference_time_s)
        if t_ref < 0:
            raise ValueError(f"reference_time_s must be >= 0. Got {t_ref}.")
        object.__setattr__(self, "tau_s", tau)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "reference_time_s", t_ref)

    @classmethod
    def logarithmic(
        cls,
        creep: float,
        tau_min_s: float = 1e-3,
        tau_max_s: float = 1800.0,
        modes_per_decade: int = 6,
        reference_time_s: float = 1.0,
    ) -> CreepParams:
        """Log-uniform spectrum whose step response creeps by ``creep`` of the step
        between 0.1 s and 100 s after it."""
        c = check_finite_scalar("creep", creep)
        if c < 0:
            raise ValueError(f"creep must be >= 0. Got {c}.")
        if not 0 < tau_min_s < tau_max_s:
            raise ValueError(
                f"tau_min_s must be > 0 and < tau_max_s. Got {tau_min_s} and {tau_max_s}."
            )
        n = max(2, round(np.log10(tau_max_s / tau_min_s) * modes_per_decade) + 1)
        tau = np.geomspace(tau_min_s, tau_max_s, n)
        unit = float(np.sum(np.exp(-0.1 / tau) - np.exp(-100.0 / tau)))
        return cls(tau, np.full(n, c / unit), reference_time_s)

    @property
    def reference_gain(self) -> float:
        """``g_ref = sum_j w_j exp(-t_ref / tau_j)``."""
        return float(np.sum(self.weights * np.exp(-self.reference_time_s / self.tau_s)))

    def step_response(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """Creep part of the response to a unit step, ``t_s`` seconds after it (exact)."""
        t = np.asarray(t_s, dtype=float)[..., None]
        return self.reference_gain - np.sum(self.weights * np.exp(-t / self.tau_s), axis=-1)


@dataclass(frozen=True)
class CreepState:
    """Mode states ``x_j`` (nm) and the command held since the last sample, ``u_prev`` (nm)."""

    x: NDArray[np.float64]
    u_prev: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "x", readonly(as_finite_1d("x", self.x)))
        object.__setattr__(self, "u_prev", check_finite_scalar("u_prev", self.u_prev))

    @classmethod
    def steady(cls, params: CreepParams, u0_nm: float = 0.0) -> CreepState:
        """Every mode settled at the command ``u0_nm``."""
        return cls(np.full(params.tau_s.size, float(u0_nm)), float(u0_nm))


def creep_run(
    params: CreepParams, u_nm: ArrayLike, sample_period_s: float, state: CreepState
) -> tuple[NDArray[np.float64], CreepState]:
    """Creep displacement (nm) for the held command ``u_nm``; returns ``(creep, new_state)``."""
    u = as_finite_1d("u_nm", u_nm)
    T = check_finite_scalar("sample_period_s", sample_period_s)
    if T <= 0:
        raise ValueError(f"sample_period_s must be > 0. Got {T}.")
    if state.x.size != params.tau_s.size:
        raise ValueError(
            f"state has {state.x.size} modes, params {params.tau_s.size}; they must agree."
        )
    poles = np.exp(-T / params.tau_s)
    x = np.array(state.x, dtype=float)
    out = np.empty(u.size)
    u_prev = K.creep_run(u, state.u_prev, poles, np.array(params.weights), x, out)
    out += params.reference_gain * u
    return out, CreepState(x, u_prev)
