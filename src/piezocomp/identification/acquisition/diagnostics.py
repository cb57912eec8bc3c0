"""Checks that a record can identify the model at all (persistent excitation).

A parameter is identifiable only if the record moves the part of the model it belongs to:

- a play operator of threshold ``r`` leaves its initial band only if the input sweeps more
  than ``2 r`` peak to peak (eq 4), so thresholds above half the span are not identified;
- a creep operator (eq 2) whose time constant exceeds the record cannot be told apart from
  a drift of the offset;
- a regressor column (eq 14 is linear in ``a``, ``w_j``, ``c_i``, ``y0``) that is constant or
  a combination of others leaves its weight undetermined.

:func:`check_excitation` returns the findings as sentences; :func:`warn_excitation` issues
them as :class:`ExcitationWarning`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar

__all__ = ["ExcitationWarning", "check_excitation", "warn_excitation"]

CONSTANT_TOL = 1e-6
"""A column whose centred norm is below this fraction of its norm counts as constant."""

CONDITION_LIMIT = 1e7
"""Condition number of the centred, normalised regressor above which it counts as collinear."""


class ExcitationWarning(UserWarning):
    """The record did not excite the model enough to identify every parameter."""


def check_excitation(
    u_nm: ArrayLike,
    sample_period_s: float,
    thresholds_nm: ArrayLike = (),
    time_constants_s: ArrayLike = (),
    regressor: NDArray[np.float64] | None = None,
    column_names: Sequence[str] | None = None,
) -> tuple[str, ...]:
    """Findings (sentences a user can act on) about a record's excitation of a model.

    Parameters
    ----------
    u_nm : array_like, shape (n,)
        The command of the samples used for the fit, nominal nm.
    sample_period_s : float
        ``T``, s; the record lasts ``n T``.
    thresholds_nm, time_constants_s : array_like
        The model's play thresholds and creep time constants.
    regressor : ndarray, shape (n, m), optional
        Columns of the linear part (e.g. ``[u, z_j, x_i]``, without the constant column:
        each column is centred, which is the same as including a constant column).
    column_names : sequence of str, optional
        Names of the regressor's columns, for the messages.

    Returns
    -------
    tuple of str
        Empty when nothing was found.
    """
    u = as_finite_1d("u_nm", u_nm)
    T = check_finite_scalar("sample_period_s", sample_period_s)
    r = as_finite_1d("thresholds_nm", thresholds_nm)
    tau = as_finite_1d("time_constants_s", time_constants_s)
    found: list[str] = []
    half_span = 0.5 * float(np.ptp(u)) if u.size else 0.0
    if r.size and r.max() >= half_span:
        n_idle = int(np.count_nonzero(r >= half_span))
        found.append(
            f"the input's half peak-to-peak span ({half_span:.4g} nm) is not larger than the "
            f"largest threshold ({r.max():.4g} nm): {n_idle} play operator(s) never leave their "
            "initial band and their weights are not identified; sweep a wider range or use "
            "smaller thresholds"
        )
    duration = u.size * T
    if tau.size and tau.max() > duration:
        n_long = int(np.count_nonzero(tau > duration))
        found.append(
            f"{n_long} creep time constant(s) (largest {tau.max():.4g} s) exceed the fitted "
            f"record ({duration:.4g} s): the record sees only the start of those modes, so "
            "their gains trade against the offset and the slower gains; creep over times "
            f"longer than {duration:.4g} s after a large move is extrapolated by the model, "
            "not measured (expected with the default waveform; a longer part B, e.g. "
            "'piezocomp waveform --n-random', measures more of it)"
        )
    if regressor is not None:
        found.extend(_regressor_findings(np.asarray(regressor, dtype=float), column_names))
    return tuple(found)


def _regressor_findings(a: NDArray[np.float64], names: Sequence[str] | None) -> list[str]:
    if a.ndim != 2:
        raise ValueError(f"regressor must be 2-D. Got shape {a.shape}.")
    m = a.shape[1]
    labels = list(names) if names is not None else [f"column {j}" for j in range(m)]
    if len(labels) != m:
        raise ValueError(f"column_names must have {m} entries. Got {len(labels)}.")
    if a.shape[0] < 2 or m == 0:
        return []
    found = []
    centred = a - a.mean(axis=0)
    norm = np.linalg.norm(a, axis=0)
    cnorm = np.linalg.norm(centred, axis=0)
    constant = cnorm <= CONSTANT_TOL * np.maximum(norm, np.finfo(float).tiny)
    if constant.any():
        which = [labels[j] for j in np.flatnonzero(constant)]
        found.append(
            f"regressor column(s) {', '.join(which)} are (nearly) constant over the fit: "
            "their parameters trade off against the offset"
        )
    keep = np.flatnonzero(~constant)
    if keep.size >= 2:
        b = centred[:, keep] / cnorm[keep]
        # eigenvalues of the small Gram matrix (m x m) instead of an SVD of the tall b:
        # same singular values (squared), resolvable up to a condition number ~1e8
        lam, vec = np.linalg.eigh(b.T @ b)
        s_min, s_max = np.sqrt(max(lam[0], 0.0)), np.sqrt(lam[-1])
        cond = s_max / s_min if s_min > 0 else np.inf
        if cond > CONDITION_LIMIT:
            v = np.abs(vec[:, 0])
            involved = [labels[keep[j]] for j in np.argsort(v)[::-1][:3] if v[j] > 0.1]
            found.append(
                f"regressor columns are (nearly) collinear (condition number {cond:.3g}), "
                f"mostly {', '.join(involved)}: the record does not separate those operators"
            )
    return found


def warn_excitation(findings: Sequence[str], stacklevel: int = 2) -> None:
    """Issue one :class:`ExcitationWarning` per finding."""
    for text in findings:
        warnings.warn(text, ExcitationWarning, stacklevel=stacklevel + 1)
