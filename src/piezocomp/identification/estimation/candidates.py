"""The candidate models of the estimation: creep spectrum, thresholds and the start.

* **Creep as a fixed spectrum.** A logarithmic creep (``~ log t`` over decades) is a dense
  spectrum of first-order modes. ``N_c`` creep operators with time constants placed
  log-uniformly over :data:`DEFAULT_CREEP_TAU_RANGE_S` (:func:`creep_spectrum`), only their
  gains ``c_i >= 0`` estimated (poles held), represent it far better than two to four free
  poles, and keep eq (14) linear in the estimated parameters but for the thresholds.
* **Thresholds over the span** (:func:`thresholds_over_span`), held during the estimation.
* **The start** (:func:`initial_from_loop`): a model whose steady loop matches the loop
  ``f_a`` of Section IV, from which the RLS of every candidate order starts.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

from piezocomp._validation import check_finite_scalar
from piezocomp.identification.loop.symmetric import SymmetricLoop
from piezocomp.model import ScannerModel
from piezocomp.operators import play_bank

__all__ = [
    "DEFAULT_CREEP_TAU_RANGE_S",
    "creep_spectrum",
    "initial_from_loop",
    "thresholds_over_span",
]

DEFAULT_CREEP_TAU_RANGE_S = (0.01, 2000.0)
"""Shortest and longest creep time constant (s) of :func:`creep_spectrum`: from about the
sample period of 8 ms (faster modes act as part of the gain ``a``) to well beyond a record
of minutes (slower modes hold the memory of earlier commands). The modes between the
sample period and 50 ms make the lag after each reversal: a spectrum from 50 ms leaves
0.45 nm of structural error on the cpr5 scanner's true extension, one from 10 ms 0.18 nm
(``benchmarks/model_floor.py``)."""


def creep_spectrum(
    n_creep: int, tau_range_s: tuple[float, float] = DEFAULT_CREEP_TAU_RANGE_S
) -> NDArray[np.float64]:
    """``n_creep`` creep time constants log-uniform over ``tau_range_s`` (ends included).

    One operator sits at the geometric mean of the range; none gives an empty array.
    """
    if isinstance(n_creep, bool) or int(n_creep) != n_creep or n_creep < 0:
        raise ValueError(f"n_creep must be a non-negative integer. Got {n_creep!r}.")
    lo = check_finite_scalar("tau_range_s[0]", tau_range_s[0])
    hi = check_finite_scalar("tau_range_s[1]", tau_range_s[1])
    if not 0 < lo < hi:
        raise ValueError(f"tau_range_s must satisfy 0 < lo < hi. Got ({lo}, {hi}).")
    n = int(n_creep)
    if n == 0:
        return np.zeros(0)
    if n == 1:
        return np.array([np.sqrt(lo * hi)])
    return np.geomspace(lo, hi, n)


def thresholds_over_span(n_play: int, span_nm: float) -> NDArray[np.float64]:
    """Thresholds ``r_j = j span / (2 (N_H + 1))``: the kinks of the steady loop's branches
    (at ``u_min + 2 r_j``) spread evenly over the span actually used."""
    return span_nm / (2.0 * (n_play + 1)) * np.arange(1, n_play + 1, dtype=np.float64)


def initial_from_loop(
    loop: SymmetricLoop,
    n_play: int,
    n_creep: int,
    *,
    thresholds_nm: NDArray[np.float64] | None = None,
    time_constants_s: NDArray[np.float64] | None = None,
    n_samples: int = 400,
) -> ScannerModel:
    """A starting model whose steady loop matches the estimated loop ``f_a``, ``f_d``.

    The paper starts the RLS from zeros and lets a few large cycles settle it; here the
    Prandtl-Ishlinskii part (``a``, ``w``, ``y0``, thresholds fixed over the span) is fitted
    by non-negative least squares to the loop of eqs (21)-(22) on a steady cycle, and the
    creep gains start at 0 (time constants spread log-uniformly over 0.3-30 s). It puts the
    predictor within a fraction of a particle of the truth, where (17)-(18) are informative.
    """
    lo, hi = loop.u_min_nm, loop.u_max_nm
    r = thresholds_over_span(n_play, hi - lo) if thresholds_nm is None else thresholds_nm
    up = np.linspace(lo, hi, n_samples)
    down = up[::-1]
    u = np.concatenate([up, down, up, down])
    zs, _ = play_bank(u, np.asarray(r, float), np.full(n_play, lo))
    m = 2 * n_samples
    target = np.concatenate([loop.ascending(up), loop.descending(down)])
    ones = np.ones(m)
    design = np.column_stack([u[m:], zs[m:], ones, -ones])
    coef, _ = nnls(design, target)
    a = max(float(coef[0]), 1e-3)
    w = np.maximum(coef[1 : 1 + n_play], 1e-4)
    y0 = float(coef[-2] - coef[-1])
    tau = np.geomspace(0.3, 30.0, n_creep) if time_constants_s is None else time_constants_s
    return ScannerModel(
        offset_nm=y0,
        gain=a,
        thresholds_nm=r,
        weights=w,
        creep_time_constants_s=tau,
        creep_gains=np.zeros(n_creep),
    )
