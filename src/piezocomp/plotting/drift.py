"""Figure of a drift series: measured and filtered drift per axis over time."""

from __future__ import annotations

import datetime as dt
import os
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.plotting import new_figure, save_figure

__all__ = ["plot_drift_series"]


def plot_drift_series(
    series: Any,
    path: str | os.PathLike[str],
    *,
    true_nm: NDArray[np.float64] | None = None,
    clock_at_t0: dt.datetime | None = None,
) -> None:
    """Write a PNG with two panels per axis (x, y): the drift (each frame's measured shift
    as dots, the filter's estimate, and on a simulator the truth, dashed), and below it the
    same less the filter's estimate, with the filter's two-sigma band (too thin to see
    beside tens of nanometres of drift).

    ``series`` is a :class:`~piezocomp.drift.series.DriftSeries`. With ``clock_at_t0`` (the
    clock time of ``t_s = 0``, as the files state it) the time axis reads the files' clock;
    otherwise the time since the first frame. A series shorter than two minutes is drawn in
    seconds, a longer one in minutes."""
    from matplotlib.ticker import FuncFormatter

    fig, axes = new_figure(
        4, 1, figsize=(8.0, 8.5), sharex=True, height_ratios=[2, 1, 2, 1], layout="constrained"
    )
    span_s = float(series.t_s[-1] - series.t_s[0])
    scale, unit = (1.0, "s") if span_s < 120.0 else (60.0, "min")
    t_min = (series.t_s - series.t_s[0]) / scale
    for i, name in enumerate(("x", "y")):
        ax, dev = axes[2 * i], axes[2 * i + 1]
        f, s = series.filtered_nm[:, i], series.sigma_nm[:, i]
        ax.plot(t_min, f, color="C0", lw=1.5, label="filtered")
        ax.plot(t_min, series.measured_nm[:, i], "o", ms=3, color="k", label="measured")
        dev.fill_between(t_min, -2 * s, 2 * s, color="C0", alpha=0.3, lw=0.8, ec="C0",
                         label="filter ±2σ")  # fmt: skip
        dev.axhline(0.0, color="C0", lw=1.0)
        dev.plot(t_min, series.measured_nm[:, i] - f, "o", ms=3, color="k")
        if true_nm is not None:
            ax.plot(t_min, true_nm[:, i], "--", color="C3", lw=1.0, label="true")
            dev.plot(t_min, true_nm[:, i] - f, "--", color="C3", lw=1.0)
        ax.set_ylabel(f"drift {name} (nm)")
        dev.set_ylabel(f"{name} less filtered (nm)", fontsize=8)
        ax.grid(alpha=0.3)
        dev.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    h2, l2 = axes[1].get_legend_handles_labels()
    axes[0].legend(handles + h2, labels + l2, loc="best", fontsize=8)
    axes[0].set_title(
        f"Drift over {t_min[-1]:.1f} {unit}: {series.rate_nm_per_s:.3f} nm/s "
        f"({series.t_s.size} frames)"
    )
    if clock_at_t0 is None:
        axes[-1].set_xlabel(f"time since the first frame ({unit})")
    else:
        first = clock_at_t0 + dt.timedelta(seconds=float(series.t_s[0]))

        def clock(value: float, _: Any) -> str:
            return (first + dt.timedelta(seconds=value * scale)).strftime("%H:%M:%S")

        axes[-1].xaxis.set_major_formatter(FuncFormatter(clock))
        axes[-1].set_xlabel(
            f"middle of each frame, the files' clock ({first:%Y-%m-%d}; the time the files "
            "state, no time zone)"
        )
    save_figure(fig, path)
