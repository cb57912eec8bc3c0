"""One-sided dead zones and the static asymmetry map of Kuhnen's modified PI, eq (8').

A one-sided dead zone of threshold ``d`` (nm of the hysteresis output, ``d != 0``) is

``q_d(h) = max(h - d, 0)`` for ``d > 0``,  ``q_d(h) = min(h - d, 0)`` for ``d < 0``,

and the asymmetry map is their weighted superposition added to the identity,

``S(h) = h + sum_l g_l q_{d_l}(h)``,   eq (8'),

a continuous, piecewise-linear map with ``S(0) = 0`` and slope ``1`` between the innermost
thresholds. K. Kuhnen (Eur. J. Control 9(4), 2003) composes such a map with the
Prandtl-Ishlinskii output, ``y = S[P[u]]``, so that the two branches of the loop differ in
shape: the asymmetric loops of real piezo actuators, which a PI operator alone (odd-symmetric
about its centre) cannot follow. ``S`` is strictly increasing when every slope it takes is
positive: ``1 + sum_{0 < d_m <= d_l} g_m > 0`` above zero and
``1 + sum_{d_l <= d_m < 0} g_m > 0`` below it (:func:`check_dead_zones`). Its inverse is a
map of the same kind (:func:`inverse_dead_zones`): thresholds ``S(d_l)``, gains
``1 / s_l - 1 / s_{l-1}`` for the slopes ``s_l`` going outwards from zero. The map holds no
state, so composing it with the model keeps the model's state unchanged.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d

__all__ = ["check_dead_zones", "dead_zone_columns", "dead_zone_map", "inverse_dead_zones"]


def check_dead_zones(
    thresholds: ArrayLike, gains: ArrayLike, name: str = "dead_zones_nm"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Thresholds and gains of eq (8') as finite 1-D arrays, refused unless the thresholds are
    non-zero and strictly increasing, one gain each, and the map strictly increasing."""
    d = as_finite_1d(name, thresholds)
    g = as_finite_1d("dead_zone_gains", gains)
    if g.shape != d.shape:
        raise ValueError(
            f"dead_zone_gains must have one entry per dead zone ({d.size}). Got {g.size}."
        )
    if np.any(d == 0):
        raise ValueError(f"{name} must be non-zero (a dead zone opens above or below zero).")
    bad = np.flatnonzero(np.diff(d) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(
            f"{name} must be strictly increasing. Got {name}[{i}] = {d[i]} "
            f"after {name}[{i - 1}] = {d[i - 1]}."
        )
    for above, side in ((True, "above"), (False, "below")):
        slope = _slopes(d, g, above=above)
        if slope.size and np.min(slope) <= 0:
            raise ValueError(
                f"dead_zone_gains make the map (8') decreasing {side} zero (slope "
                f"{float(np.min(slope)):.3g}); every slope 1 + sum g must be > 0."
            )
    return d, g


def _slopes(d: NDArray[np.float64], g: NDArray[np.float64], *, above: bool) -> NDArray[np.float64]:
    """Slopes of ``S`` beyond each threshold of one side, going outwards from zero."""
    side = d > 0 if above else d < 0
    gs = g[side] if above else g[side][::-1]
    return 1.0 + np.cumsum(gs)


def dead_zone_columns(h_nm: ArrayLike, thresholds_nm: ArrayLike) -> NDArray[np.float64]:
    """``q_{d_l}(h)`` of eq (8'), one column per threshold: shape ``(h.size, d.size)``."""
    h = np.asarray(h_nm, dtype=float).ravel()
    d = np.asarray(thresholds_nm, dtype=float)
    return np.where(d > 0, np.maximum(h[:, None] - d, 0.0), np.minimum(h[:, None] - d, 0.0))


def dead_zone_map(h: ArrayLike, thresholds: ArrayLike, gains: ArrayLike) -> NDArray[np.float64]:
    """``S(h)`` of eq (8'), ``h`` of any shape (unchecked parameters: see
    :func:`check_dead_zones`)."""
    hh = np.asarray(h, dtype=float)
    q = dead_zone_columns(hh, thresholds)
    return (hh.ravel() + q @ np.asarray(gains, dtype=float)).reshape(hh.shape)


def inverse_dead_zones(
    thresholds: ArrayLike, gains: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Thresholds and gains of ``S^{-1}``, again of the form (8').

    Going outwards from zero on each side, the slope after the ``l``-th threshold is
    ``s_l = 1 + g_1 + ... + g_l`` (``s_0 = 1``); ``S^{-1}`` has thresholds ``S(d_l)`` and
    slope ``1 / s_l`` there, so its gains are ``1 / s_l - 1 / s_{l-1}``.
    """
    d, g = check_dead_zones(thresholds, gains)
    d_hat = dead_zone_map(d, d, g)
    g_hat = np.empty_like(g)
    for above in (True, False):
        idx = np.flatnonzero(d > 0) if above else np.flatnonzero(d < 0)[::-1]
        slopes = np.concatenate(([1.0], _slopes(d, g, above=above)))
        g_hat[idx] = 1.0 / slopes[1:] - 1.0 / slopes[:-1]
    return d_hat, g_hat
