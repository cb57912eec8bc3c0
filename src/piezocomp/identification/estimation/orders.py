"""Choice of the model orders ``N_H`` (play operators) and ``N_c`` (creep operators).

More operators always fit the fitted samples better; only held-out samples tell whether
they also predict better. :func:`select_orders` fits every candidate, scores it on
held-out data and keeps, among the models whose score is within a tolerance of the best,
the smallest (fewest parameters of eq 15, ``2 N_c + 2 N_H + 2``: extra operators must earn
their place) or, with ``prefer="largest"``, the largest (the sensorless identification's
choice: its held-out heights cannot tell 16 play operators from 32 while the truth prefers
32).

It is generic: the caller supplies ``fit_fn(n_play, n_creep) -> (fitted, fit_error)`` and
``score_fn(fitted) -> validation_error``, so the same selection serves the sensorless
identification (scoring a candidate on held-out topography through ``h``) and the fit to a
sensor record (:func:`piezocomp.sensor.orders.select_sensor_orders`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from piezocomp._validation import check_finite_scalar

__all__ = [
    "DEFAULT_N_CREEP",
    "DEFAULT_N_PLAY",
    "OrderSelection",
    "OrderTrial",
    "select_orders",
]

DEFAULT_N_PLAY = (4, 8, 12, 16, 24, 32)
DEFAULT_N_CREEP = (0, 1, 2, 3, 4)


@dataclass(frozen=True)
class OrderTrial:
    """One candidate: its orders, size and errors (units of the caller's error)."""

    n_play: int
    n_creep: int
    fit_error: float
    validation_error: float

    @property
    def n_parameters(self) -> int:
        """``2 N_c + 2 N_H + 2`` (eq 15)."""
        return 2 * self.n_creep + 2 * self.n_play + 2


@dataclass(frozen=True)
class OrderSelection:
    """Outcome of :func:`select_orders`.

    Attributes
    ----------
    n_play, n_creep : int
        The chosen orders.
    trials : tuple of OrderTrial
        Every candidate tried, in the order given.
    best_validation_error : float
        The smallest validation error among the trials.
    tolerance : float
        Relative tolerance used: chosen ``<= best * (1 + tolerance)``.
    fitted : object
        What ``fit_fn`` returned for the chosen orders.
    """

    n_play: int
    n_creep: int
    trials: tuple[OrderTrial, ...]
    best_validation_error: float
    tolerance: float
    fitted: Any

    def table(self) -> list[dict[str, float | int | bool]]:
        """The trials as rows (for printing or JSON), the chosen one marked."""
        return [
            {
                "n_play": t.n_play,
                "n_creep": t.n_creep,
                "n_parameters": t.n_parameters,
                "fit_error": t.fit_error,
                "validation_error": t.validation_error,
                "chosen": (t.n_play, t.n_creep) == (self.n_play, self.n_creep),
            }
            for t in self.trials
        ]


def select_orders(
    candidates: Iterable[tuple[int, int]],
    fit_fn: Callable[[int, int], tuple[Any, float]],
    score_fn: Callable[[Any], float],
    *,
    tolerance: float = 0.02,
    workers: int = 1,
    prefer: str = "smallest",
) -> OrderSelection:
    """Pick the smallest (or largest) orders whose validation error is within ``tolerance``
    of the best.

    Parameters
    ----------
    candidates : iterable of (n_play, n_creep)
        Orders to try.
    fit_fn : callable
        ``fit_fn(n_play, n_creep) -> (fitted, fit_error)``: fit a candidate on the fit data.
    score_fn : callable
        ``score_fn(fitted) -> validation_error``: its error on held-out data (lower is
        better; any non-negative unit).
    tolerance : float
        Relative: a candidate qualifies if its validation error is at most
        ``best * (1 + tolerance)``. Among qualifying candidates the one with the fewest
        parameters (eq 15) wins; ties go to the lower validation error.
    workers : int
        Candidates fitted at once, on threads (``fit_fn`` and ``score_fn`` must then be
        thread-safe; the compiled kernels release the GIL). The result does not depend on it.
    prefer : {"smallest", "largest"}
        Which qualifying candidate wins: the fewest parameters (default: extra operators must
        earn their place) or the most (where a smoothness prior holds the extra operators,
        so that more of them refine the grid of thresholds rather than add freedom, and the
        held-out error cannot tell the candidates apart).

    Returns
    -------
    OrderSelection
    """
    tol = check_finite_scalar("tolerance", tolerance)
    if tol < 0:
        raise ValueError(f"tolerance must be >= 0. Got {tol}.")
    if prefer not in ("smallest", "largest"):
        raise ValueError(f"prefer must be 'smallest' or 'largest'. Got {prefer!r}.")
    if isinstance(workers, bool) or not (int(workers) == workers >= 1):
        raise ValueError(f"workers must be an integer >= 1. Got {workers!r}.")
    pairs: list[tuple[int, int]] = []
    for pair in candidates:
        nh, nc = (int(v) for v in pair)
        if (nh, nc) not in pairs:
            pairs.append((nh, nc))

    def trial(pair: tuple[int, int]) -> tuple[Any, float, float]:
        obj, fit_err = fit_fn(*pair)
        return obj, float(fit_err), float(score_fn(obj))

    if int(workers) > 1 and len(pairs) > 1:
        with ThreadPoolExecutor(max_workers=min(int(workers), len(pairs))) as pool:
            results = list(pool.map(trial, pairs))
    else:
        results = [trial(p) for p in pairs]
    trials: list[OrderTrial] = []
    fitted: dict[tuple[int, int], Any] = {}
    for (nh, nc), (obj, fit_err, val_err) in zip(pairs, results, strict=True):
        if not np.isfinite(val_err):
            raise ValueError(
                f"score_fn returned a non-finite error ({val_err}) for n_play={nh}, n_creep={nc}."
            )
        fitted[(nh, nc)] = obj
        trials.append(OrderTrial(nh, nc, fit_err, val_err))
    if not trials:
        raise ValueError("candidates must name at least one (n_play, n_creep) pair. Got none.")
    best = min(t.validation_error for t in trials)
    ok = [t for t in trials if t.validation_error <= best * (1.0 + tol)]
    sign = 1 if prefer == "smallest" else -1
    chosen = min(ok, key=lambda t: (sign * t.n_parameters, t.validation_error))
    return OrderSelection(
        n_play=chosen.n_play,
        n_creep=chosen.n_creep,
        trials=tuple(trials),
        best_validation_error=best,
        tolerance=tol,
        fitted=fitted[(chosen.n_play, chosen.n_creep)],
    )
