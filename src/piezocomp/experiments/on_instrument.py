"""The paper's experiments on one instrument, in turn: what ``reproduce --instrument`` runs.

On a real sample the experiments that need no particular layout make sense: Table I (back to
an area after random moves), Fig. 8 (ramps over a line of particles) and Fig. 9 (back to the
start after a path). Fig. 10 assembles particles placed for its pattern, and the drift
session needs a simulated drift: they stay with the virtual AFM (``piezocomp drift
--instrument`` measures a real instrument's drift).

Every trial runs on the one instrument, one after the other: the uncompensated ones first,
then those through the compensator of the given model, initialised once (the paper's first
large cycle) and again after a trial that stopped mid-motion (its predicted state is then
unknown). A trial refused or stopped with a ``ValueError`` (a command outside the range, a
path whose timing broke the tolerance, no particles where the overview showed them) is
reported and the run goes on; an ``OSError`` (the instrument stopped answering, or refused a
command) stops the run, whose finished trials are kept.

Errors are measured as the paper did: by image cross-correlation (Table I, Fig. 9) and on
the particles' peaks (Fig. 8). The true errors need a ground truth no real instrument has:
they are ``None``, and the results say so, unless ``truth`` is given (the virtual AFM run
the same way, for comparing a rehearsal with the direct run).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from piezocomp._validation import check_finite_scalar
from piezocomp.experiments import fig8, fig9, table1
from piezocomp.experiments.methods import MethodModels, instrument_for, working_half_width
from piezocomp.experiments.truth import Truth
from piezocomp.instrument import Instrument
from piezocomp.model import ScannerModel2D

__all__ = [
    "EXPERIMENTS",
    "METHODS",
    "NO_TRUTH",
    "TABLE1_MARGIN_NM",
    "InstrumentRun",
    "InstrumentRunSettings",
    "run_experiments",
    "run_trials",
    "summarise",
    "table1_area_nm",
]

EXPERIMENTS = ("table1", "fig8", "fig9")
"""The experiments that make sense on a real sample, in the order they run."""

METHODS = ("uncompensated", "compensated")
"""The commands sent as they are, and through the compensator of the given model."""

NO_TRUTH = (
    "unavailable: a real instrument has no ground truth; only the measured figures (image "
    "cross-correlation and peak positions, as the paper measured) are reported"
)
"""What the results say of the true errors on a real instrument."""

TABLE1_MARGIN_NM = 10.0
"""Table I keeps this far inside the working area and the scanner's range."""


@dataclass(frozen=True)
class InstrumentRunSettings:
    """What runs on the instrument.

    Parameters
    ----------
    experiments : tuple of str
        Among :data:`EXPERIMENTS`.
    methods : tuple of str
        Among :data:`METHODS` (``compensated`` needs a model).
    distances_nm : tuple of float
        Table I's distances between the areas' centres, nm (the paper's 645, 951, 1150).
    table1_experiments : int
        Table I's experiments per distance (the paper's 5).
    speed_nm_per_s : float
        Speed of every move, nm/s (the paper's 1 um/s).
    settle_s : float
        Table I's rest at the origin after its overview, s.
    pixels : int, optional
        Pixels of Table I's area images and Fig. 9's images (default theirs: 64, 128).
    overview_pixels : int, optional
        Pixels of Table I's and Fig. 8's overviews (default theirs: 128, 192).
    """

    experiments: tuple[str, ...] = ("table1", "fig9")
    methods: tuple[str, ...] = METHODS
    distances_nm: tuple[float, ...] = tuple(table1.PAPER)
    table1_experiments: int = 5
    speed_nm_per_s: float = 1000.0
    settle_s: float = table1.Table1Settings().settle_s
    pixels: int | None = None
    overview_pixels: int | None = None

    def __post_init__(self) -> None:
        for name, allowed in (("experiments", EXPERIMENTS), ("methods", METHODS)):
            chosen = tuple(getattr(self, name))
            if not chosen or any(c not in allowed for c in chosen):
                raise ValueError(f"{name} must be among {allowed}. Got {chosen}.")
            object.__setattr__(self, name, tuple(c for c in allowed if c in chosen))
        if not self.distances_nm or any(
            check_finite_scalar("distances_nm", d) <= 0 for d in self.distances_nm
        ):
            raise ValueError(f"distances_nm must be > 0. Got {self.distances_nm}.")
        object.__setattr__(self, "distances_nm", tuple(float(d) for d in self.distances_nm))
        n = self.table1_experiments
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"table1_experiments must be an integer >= 1. Got {n!r}.")
        if check_finite_scalar("speed_nm_per_s", self.speed_nm_per_s) <= 0:
            raise ValueError(f"speed_nm_per_s must be > 0. Got {self.speed_nm_per_s}.")
        if check_finite_scalar("settle_s", self.settle_s) < 0:
            raise ValueError(f"settle_s must be >= 0. Got {self.settle_s}.")
        for name, low in (("pixels", 8), ("overview_pixels", 16)):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < low):
                raise ValueError(f"{name} must be an integer >= {low}. Got {v!r}.")

    def table1_trial(self, d_nm: float, experiment: int, area_nm: float) -> table1.Table1Settings:
        """Table I's settings of one experiment."""
        st = table1.Table1Settings(d_nm=d_nm, speed_nm_per_s=self.speed_nm_per_s,
                                   experiment=experiment, area_nm=area_nm,
                                   settle_s=self.settle_s)  # fmt: skip
        if self.pixels is not None:
            st = replace(st, pixels=self.pixels)
        if self.overview_pixels is not None:
            st = replace(st, overview_pixels=self.overview_pixels)
        return st


def table1_area_nm(range_nm: float, model: ScannerModel2D | None, sample_period_s: float) -> float:
    """Half-width of Table I's area (nm): the default's (750), within the scanner's range and
    the model's working area, :data:`TABLE1_MARGIN_NM` inside both."""
    area = min(table1.Table1Settings().area_nm, 0.5 * float(range_nm) - TABLE1_MARGIN_NM)
    if model is not None:
        models = MethodModels({"compensated": model}, sample_period_s)
        area = min(area, working_half_width(models, sample_period_s) - TABLE1_MARGIN_NM)
    return area


def _stats(values: list[float | None]) -> dict[str, Any]:
    a = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if a.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(a.mean()), "std": float(a.std()), "n": int(a.size)}


def _num(v: Any) -> float | None:
    """A finite float, or None (JSON has no NaN)."""
    return None if v is None or not math.isfinite(float(v)) else float(v)


def _trials(settings: InstrumentRunSettings, area_nm: float) -> list[tuple[str, Any]]:
    """Every experiment of one method, in order: (name, settings)."""
    s = settings
    out: list[tuple[str, Any]] = []
    if "table1" in s.experiments:
        for d in s.distances_nm:
            out += [("table1", s.table1_trial(d, k, area_nm)) for k in range(s.table1_experiments)]
    if "fig8" in s.experiments:
        st8 = fig8.Fig8Settings(speed_nm_per_s=s.speed_nm_per_s)
        if s.overview_pixels is not None:
            st8 = replace(st8, overview_pixels=s.overview_pixels)
        out.append(("fig8", st8))
    if "fig9" in s.experiments:
        st9 = fig9.Fig9Settings(speed_nm_per_s=s.speed_nm_per_s, keep_images=True)
        out.append(("fig9", st9 if s.pixels is None else replace(st9, pixels=s.pixels)))
    return out


_RUNNERS: dict[str, Callable[..., Any]] = {"table1": table1.run, "fig8": fig8.run,
                                           "fig9": fig9.run}  # fmt: skip


@dataclass(frozen=True)
class InstrumentRun:
    """The trials of a run on an instrument, as they ended.

    Attributes
    ----------
    settings : InstrumentRunSettings
    outcomes : tuple of (str, str, object)
        ``(method, experiment, result or the error text)`` in the order they ran; Fig. 9's
        results keep their two images (for the report's figure).
    area_nm : float
        Table I's area half-width.
    has_truth : bool
        The instrument was the virtual AFM, its truth given.
    stopped : str or None
        Why the instrument stopped the run, if it did.
    """

    settings: InstrumentRunSettings
    outcomes: tuple[tuple[str, str, Any], ...]
    area_nm: float
    has_truth: bool
    stopped: str | None


def run_experiments(
    instrument: Instrument,
    model: ScannerModel2D | None,
    settings: InstrumentRunSettings,
    *,
    truth: Truth | None = None,
    report: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the experiments of ``settings`` on ``instrument`` in turn (see the module notes);
    the results, JSON-ready (:func:`summarise` of :func:`run_trials`). ``report`` is told
    one line per trial."""
    return summarise(run_trials(instrument, model, settings, truth=truth, report=report))


def run_trials(
    instrument: Instrument,
    model: ScannerModel2D | None,
    settings: InstrumentRunSettings,
    *,
    truth: Truth | None = None,
    report: Callable[[str], None] | None = None,
) -> InstrumentRun:
    """Run the experiments of ``settings`` on ``instrument`` in turn (see the module notes);
    every trial's outcome. ``report`` is told one line per trial.

    Raises
    ------
    ValueError
        ``compensated`` without a model, or Table I's distances do not fit the area (before
        anything moves).
    """
    s = settings
    T = float(instrument.sample_period_s)
    if "compensated" in s.methods and model is None:
        raise ValueError("the compensated method needs a model (a 2-D model file).")
    area = table1_area_nm(instrument.range_nm, model if "compensated" in s.methods else None, T)
    if "table1" in s.experiments:
        for d in s.distances_nm:
            size = table1.Table1Settings().size_nm
            if 0.5 * d + size > area:
                raise ValueError(
                    f"Table I at {d:g} nm needs an area of +-{0.5 * d + size:g} nm (half the "
                    f"distance and an image); the range and the model's working area give "
                    f"+-{area:g} nm: choose smaller distances."
                )
    models = MethodModels({} if model is None else {"compensated": model}, T)
    outcomes: list[tuple[str, str, Any]] = []  # (method, experiment, result or error text)
    stopped = None
    for method in s.methods:
        if stopped:
            break
        inst, origin = None, (0.0, 0.0)
        for name, st in _trials(s, area):
            try:
                if inst is None:  # the compensator (re-)initialised before its next trial
                    inst, origin = instrument_for(method, instrument, models)
                out: Any = _RUNNERS[name](inst, st, origin_nm=origin, truth=truth)
            except ValueError as exc:
                out = f"{type(exc).__name__}: {exc}"
                inst = None if method == "compensated" else inst
            except OSError as exc:
                stopped = f"{type(exc).__name__}: {exc}"
                outcomes.append((method, name, stopped))
                break
            outcomes.append((method, name, out))
            if report is not None:
                report(_line(method, name, st, out))
    return InstrumentRun(s, tuple(outcomes), area, truth is not None, stopped)


def _line(method: str, name: str, st: Any, out: Any) -> str:
    """One trial, one line."""
    what = f"{name} d = {st.d_nm:g} nm #{st.experiment}" if name == "table1" else name
    if isinstance(out, str):
        return f"{what} / {method} failed: {out}"
    if name == "fig8":
        spread = out.spread_nm
        value = float(np.max(spread)) if np.all(np.isfinite(spread)) else float("nan")
        return f"{what} / {method}: largest peak spread {value:.2f} nm (measured)"
    value = out.max_error_nm if name == "table1" else out.error_nm
    return f"{what} / {method}: {value:.2f} nm (measured)"


def summarise(run: InstrumentRun) -> dict[str, Any]:
    """The results of a run, JSON-ready: Table I's errors by distance and method (their
    statistics and each experiment's), Fig. 8's spreads, Fig. 9's errors, the failures."""
    s, outcomes, area, has_truth, stopped = (
        run.settings, run.outcomes, run.area_nm, run.has_truth, run.stopped
    )  # fmt: skip
    ok = [(m, n, r) for m, n, r in outcomes if not isinstance(r, str)]
    rows = []
    for d in s.distances_nm if "table1" in s.experiments else ():
        per: dict[str, Any] = {}
        for m in s.methods:
            rs = [r for mm, n, r in ok if mm == m and n == "table1" and r.settings.d_nm == d]
            per[m] = {
                "max_error_nm": _stats([r.max_error_nm for r in rs]),
                "true_max_error_nm": _stats([r.true_max_error_nm for r in rs])
                if has_truth
                else None,
                "trials": [
                    {
                        "experiment": r.settings.experiment,
                        "error_nm": {a: _num(v) for a, v in r.error_nm.items()},
                        "true_error_nm": None
                        if r.true_error_nm is None
                        else {a: _num(v) for a, v in r.true_error_nm.items()},
                    }
                    for r in rs
                ],
            }
        rows.append({"d_nm": d, "speed_nm_per_s": s.speed_nm_per_s, "methods": per})
    f9 = {
        m: {"error_nm": _num(r.error_nm), "true_error_nm": _num(r.true_error_nm)}
        for m, n, r in ok
        if n == "fig9"
    }
    f8 = {
        m: {
            "spread_nm": _num(np.max(r.spread_nm)) if np.all(np.isfinite(r.spread_nm)) else None,
            "per_particle_nm": [_num(v) for v in r.spread_nm],
            "true_per_particle_nm": None
            if r.true_spread_nm is None
            else [_num(v) for v in r.true_spread_nm],
            "ramps_seeing_each_particle": [int(v) for v in r.seen],
        }
        for m, n, r in ok
        if n == "fig8"
    }
    return {
        "experiments": list(s.experiments),
        "methods": list(s.methods),
        "true_errors": "from the simulator's ground truth" if has_truth else NO_TRUTH,
        "table1": rows,
        "table1_area_half_width_nm": area,
        "fig8": f8 if "fig8" in s.experiments else None,
        "fig9": f9 if "fig9" in s.experiments else None,
        "failures": [
            {"method": m, "experiment": n, "error": r} for m, n, r in outcomes if isinstance(r, str)
        ],
        "stopped": stopped,
    }
