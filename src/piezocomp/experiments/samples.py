"""The headline figures as statistics over samples: median and worst over sample seeds.

One run of ``piezocomp reproduce`` is one sample (particles, substrate, noise); a figure on
the virtual AFM means something only over several. :func:`headline` reads the figures a
user quotes from one run's ``results.json``; :func:`over_samples` gathers them over runs:
each figure's median and worst (largest error, smallest success rate) with every run's own.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Literal, NotRequired, TypedDict, get_args

import numpy as np

from piezocomp.experiments.results import Results, session_methods

__all__ = [
    "FIGURES",
    "HEADLINE_METHODS",
    "LARGEST_IS_WORST",
    "Figure",
    "FigureStat",
    "Headline",
    "OverSamples",
    "SeedRun",
    "headline",
    "over_samples",
    "parse_seeds",
    "statistics",
]

HEADLINE_METHODS = ("uncompensated", "compensated", "both")
"""The methods whose figures the summary over samples gives: ``both`` (the default on a
drifting scanner: creep and hysteresis compensated inside the drift compensator) where the
run has it."""

Figure = Literal["table1_true_nm", "table1_measured_nm", "fig9_true_nm", "fig9_measured_nm",
                 "fig10_true_success", "session_true_worst_nm", "session_true_final_nm",
                 "session_measuring"]  # fmt: skip
"""The name of a headline figure."""

FIGURES: tuple[Figure, ...] = get_args(Figure)
"""The headline figures of a method; the session's only where the run had one (drifting
scanners): its largest and final true error and the fraction of its time spent measuring
drift."""

LARGEST_IS_WORST = frozenset(FIGURES) - {"fig10_true_success"}
"""The figures whose worst is their largest (the rest: their smallest)."""


class Headline(TypedDict):
    """One method's headline figures in one run (nm, or a fraction); ``None`` where the run
    has none."""

    table1_true_nm: float | None
    table1_measured_nm: float | None
    fig9_true_nm: float | None
    fig9_measured_nm: float | None
    fig10_true_success: float | None
    session_true_worst_nm: float | None
    session_true_final_nm: float | None
    session_measuring: float | None


class FigureStat(TypedDict):
    """A figure's median and worst over the ``n`` runs that have it (``None`` with none)."""

    median: float | None
    worst: float | None
    n: int


class SeedRun(TypedDict):
    """One sample's headline figures by method, and how many of its parts failed."""

    headline: dict[str, Headline]
    failures: int


class OverSamples(TypedDict):
    """``samples.json``: the seeds, each figure's statistics by method, each seed's own
    figures, the seeds whose run failed (with the error) and those with failed parts."""

    seeds: list[int]
    statistics: dict[str, dict[Figure, FigureStat]]
    per_seed: dict[str, SeedRun]
    failed_seeds: dict[str, str]
    runs_with_failures: list[str]
    command: NotRequired[str]
    environment: NotRequired[dict[str, Any]]  # piezocomp.environment.environment()


def parse_seeds(text: str) -> tuple[int, ...]:
    """Seeds from ``"1-10"``, ``"1,4,8"`` or a mix (``"1-3,7"``); each a whole number >= 0,
    at most 1000 of them."""
    seeds: list[int] = []
    for part in text.split(","):
        lo, sep, hi = part.strip().partition("-")
        try:
            a = int(lo)
            b = int(hi) if sep else a
        except ValueError:
            raise ValueError(
                f"--seeds takes whole numbers and ranges such as 1-10 or 1,4,8. Got {text!r}."
            ) from None
        if a < 0 or b < a:
            raise ValueError(
                f"--seeds takes seeds >= 0 and ranges from low to high (such as 2-5). "
                f"Got {part.strip()!r}."
            )
        if b - a >= 1000 or len(seeds) + b - a + 1 > 1000:
            raise ValueError(f"--seeds names at most 1000 seeds. Got {text!r}.")
        seeds += range(a, b + 1)
    return tuple(dict.fromkeys(seeds))


def _num(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(float(v)) else float(v)


def _worst(values: list[float | None]) -> float | None:
    """The largest, or ``None`` when any is missing (a distance with no figure)."""
    got = [v for v in values if v is not None]
    return max(got) if got and len(got) == len(values) else None


def headline(results: Results, methods: Sequence[str] = HEADLINE_METHODS) -> dict[str, Headline]:
    """One run's headline figures (:data:`FIGURES`), per method of ``methods`` (by default
    :data:`HEADLINE_METHODS`): Table I's worst distance (mean over its experiments, at the
    paper's speed; true and measured), Fig. 9 (true and measured), Fig. 10's true success
    rate and, on a drifting scanner, the drift session's; ``None`` where a method has none.

    ``both``'s Fig. 10 is the one run inside the drift compensator (``fig10_drift``); the
    session's methods carry the same names (also read from an older ``results.json``:
    :func:`~piezocomp.experiments.results.session_methods`).
    """
    v0 = results["paper"]["speed_nm_per_s"]
    drift10 = session_methods(results["fig10_drift"]) if "fig10_drift" in results else {}
    session = session_methods(results["drift_session"]) if "drift_session" in results else {}
    out: dict[str, Headline] = {}
    for m in methods:
        rows = [r["methods"].get(m) for r in results["table1"] if r["speed_nm_per_s"] == v0]
        cells = [r for r in rows if r]
        f9 = results["fig9"]["methods"].get(m)
        f10 = drift10.get("both") if m == "both" else results["fig10"]["methods"].get(m)
        ds = session.get(m)
        final = ds.get("true_final_error_nm") if ds is not None and "error" not in ds else None
        out[m] = {
            "table1_true_nm": _worst([_num(c["true_max_error_nm"]["mean"]) for c in cells]),
            "table1_measured_nm": _worst([_num(c["max_error_nm"]["mean"]) for c in cells]),
            "fig9_true_nm": None if f9 is None else _num(f9["true_error_nm"]),
            "fig9_measured_nm": None if f9 is None else _num(f9["error_nm"]),
            "fig10_true_success": None if f10 is None else f10["true_success_rate"],
            "session_true_worst_nm": None if ds is None else _num(ds["true_max_error_nm"]),
            "session_true_final_nm": _num(final),
            "session_measuring": None if ds is None else _num(ds["measurement_overhead_fraction"]),
        }  # fmt: skip
    return out


def statistics(
    runs: Sequence[Mapping[str, Headline]], methods: Sequence[str] = HEADLINE_METHODS
) -> dict[str, dict[Figure, FigureStat]]:
    """Each headline figure's median and worst (largest error, smallest success rate) by
    method of ``methods``, over the runs' :func:`headline` figures that are not ``None``."""
    stats: dict[str, dict[Figure, FigureStat]] = {}
    for m in methods:
        stats[m] = {}
        for k in FIGURES:
            a = np.array([v for h in runs if (v := h[m][k]) is not None], dtype=float)
            worst = None
            if a.size:
                worst = float(a.max()) if k in LARGEST_IS_WORST else float(a.min())
            stats[m][k] = {
                "median": float(np.median(a)) if a.size else None,
                "worst": worst,
                "n": int(a.size),
            }
    return stats


def over_samples(runs: Sequence[tuple[int, Results | str]]) -> OverSamples:
    """Median and worst of each headline figure over ``(seed, results or error text)``.

    A run that failed counts as failed in every figure (``failed_seeds``); the statistics
    are over the runs that produced the figure, with their number ``n``.
    """
    per_seed: dict[str, SeedRun] = {}
    failed: dict[str, str] = {}
    for seed, res in runs:
        if isinstance(res, str):
            failed[str(seed)] = res
            continue
        per_seed[str(seed)] = {"headline": headline(res), "failures": len(res["failures"])}
    return {
        "seeds": [s for s, _ in runs],
        "statistics": statistics([s["headline"] for s in per_seed.values()]),
        "per_seed": per_seed,
        "failed_seeds": failed,
        "runs_with_failures": sorted(s for s, v in per_seed.items() if v["failures"]),
    }
