"""Figure of a drift series: measured and filtered drift per axis over time."""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.plotting import new_figure, save_figure

__all__ = ["plot_drift_series"]


def plot_drift_series(
    series: Any, path: str | os.PathLike[str], *, true_nm: NDArray[np.float64] | None = None
) -> None:
    """Write a PNG with two panels per axis (x, y): the drift (each frame's measured shift
    as dots, the filter's estimate, and on a simulator the truth, dashed), and below it the
    same less the filter's estimate, with the filter's two-sigma band (too thin to see
    beside tens of nanometres of drift).

    ``series`` is a :class:`~piezocomp.drift.series.DriftSeries`."""
    fig, axes = new_figure(
        4, 1, figsize=(8.0, 8.5), sharex=True, height_ratios=[2, 1, 2, 1], layout="constrained"
    )
    t_min = (series.t_s - series.t_s[0]) / 60.0
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
        f"Drift over {t_min[-1]:.1f} min: {series.rate_nm_per_s:.3f} nm/s "
        f"({series.t_s.size} frames)"
    )
    axes[-1].set_xlabel("time since the first frame (min)")
    save_figure(fig, path)
