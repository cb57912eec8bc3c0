"""What every experiment of ``piezocomp reproduce`` provides, and what it is given.

An experiment module (:mod:`~piezocomp.experiments.table1`, :mod:`~piezocomp.experiments.fig9`,
:mod:`~piezocomp.experiments.fig8`, :mod:`~piezocomp.experiments.fig10`,
:mod:`~piezocomp.experiments.drift_session`) is an :class:`Experiment`: its ``NAME``, the
trials it runs for a :class:`Plan` (``plan``), how one trial runs on a fresh virtual AFM
(``run_trial``), and its sections of ``results.json`` from every outcome of the run
(``summarise``). :mod:`~piezocomp.experiments.reproduce` loops over a tuple of them; a new
experiment is a new module with these four names, added to that tuple.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from piezocomp.experiments.results import Stat

if TYPE_CHECKING:
    from piezocomp.experiments.methods import MethodModels
    from piezocomp.virtual_afm import AFMConfig

__all__ = [
    "DRIFT_METHOD",
    "Experiment",
    "Outcome",
    "Plan",
    "Trial",
    "default_first",
    "finite_or_none",
    "plain",
    "shown_methods",
    "stats",
    "succeeded",
]

DRIFT_METHOD = "both"
"""The method name of Table I, Fig. 9 and Fig. 10 run inside the drift compensator (around
``compensated``) on a drifting scanner, as the drift session names it."""


@dataclass(frozen=True)
class Trial:
    """One experiment of one method on a fresh virtual AFM.

    Attributes
    ----------
    experiment : str
        The ``NAME`` of the experiment module that runs it.
    method : str
    settings : object
        The experiment's own settings for this trial (e.g. a
        :class:`~piezocomp.experiments.table1.Table1Settings`).
    keep : bool
        Keep its heavy parts (images) for the report's figures.
    """

    experiment: str
    method: str
    settings: Any
    keep: bool = False


Outcome = tuple[Trial, Any]
"""A trial and its result, or the text of the error that stopped it."""


@dataclass(frozen=True)
class Plan:
    """What the experiments are asked to run (from
    :class:`~piezocomp.experiments.reproduce.ReproduceSettings` and the working area the
    identified models allow).

    Attributes
    ----------
    methods : tuple of str
        The methods whose models are usable.
    speeds_nm_per_s : tuple of float
        Speeds of Fig. 9, the paper's first.
    table1_speeds_nm_per_s : tuple of float
        Speeds of Table I.
    distances_nm : tuple of float
    table1_experiments, fig10_trials : int
    drifts : bool
        The scanner drifts: Table I, Fig. 9 and Fig. 10 also run inside the drift
        compensator (:data:`DRIFT_METHOD`).
    session_minutes : float
        Length of the drift session (0: none).
    area_half_nm : float
        Table I's area half-width, inside every method's working area.
    paper_speed_nm_per_s : float
        The paper's speed (1 um/s), reported first.
    """

    methods: tuple[str, ...]
    speeds_nm_per_s: tuple[float, ...]
    table1_speeds_nm_per_s: tuple[float, ...]
    distances_nm: tuple[float, ...]
    table1_experiments: int
    fig10_trials: int
    drifts: bool
    session_minutes: float
    area_half_nm: float
    paper_speed_nm_per_s: float = 1000.0

    @property
    def drift_compensated(self) -> bool:
        """Whether the experiments also run inside the drift compensator."""
        return self.drifts and "compensated" in self.methods


class Experiment(Protocol):
    """The four names an experiment module provides."""

    NAME: str

    def plan(self, plan: Plan) -> list[Trial]: ...

    def run_trial(
        self, trial: Trial, config: AFMConfig, seed: int, models: MethodModels
    ) -> Any: ...

    def summarise(self, plan: Plan, outcomes: list[Outcome]) -> dict[str, Any]: ...


def succeeded(outcomes: list[Outcome], experiment: str) -> list[Outcome]:
    """The outcomes of ``experiment`` that gave a result (not an error)."""
    return [(t, r) for t, r in outcomes if t.experiment == experiment and not isinstance(r, str)]


def shown_methods(plan: Plan, outcomes: list[Outcome]) -> tuple[str, ...]:
    """The plan's methods, and :data:`DRIFT_METHOD` after them when any trial ran it."""
    tracked = any(t.method == DRIFT_METHOD for t, _ in outcomes)
    return (*plan.methods, DRIFT_METHOD) if tracked else plan.methods


def default_first(methods: Iterable[str]) -> list[str]:
    """``methods`` with the package's default first: :data:`DRIFT_METHOD` (the default on a
    drifting scanner), then ``compensated`` (the default model alone), then the others in
    their order. Every table and figure of the report lists its methods so."""
    ms = list(methods)
    head = [m for m in (DRIFT_METHOD, "compensated") if m in ms]
    return head + [m for m in ms if m not in head]


def plain(d: dict[str, Any]) -> dict[str, Any]:
    """Tuples as lists (JSON)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def finite_or_none(v: Any) -> float | None:
    """A finite float, or None (JSON has no NaN)."""
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def stats(values: list[float]) -> Stat:
    """Mean, standard deviation and count of the finite values (None where there are none)."""
    a = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if a.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(a.mean()), "std": float(a.std()), "n": int(a.size)}
