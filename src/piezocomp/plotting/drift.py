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
    """Write a two-panel PNG (x, y): each frame's measured shift (dots), the filter's
    estimate with its two-sigma band, and, on a simulator, the truth (dashed).

    ``series`` is a :class:`~piezocomp.drift.series.DriftSeries`."""
    fig, axes = new_figure(2, 1, figsize=(8.0, 6.0), sharex=True)
    t_min = (series.t_s - series.t_s[0]) / 60.0
    for i, (ax, name) in enumerate(zip(axes, ("x", "y"), strict=True)):
        f, s = series.filtered_nm[:, i], series.sigma_nm[:, i]
        ax.fill_between(t_min, f - 2 * s, f + 2 * s, color="C0", alpha=0.2, lw=0,
                        label="filter ±2σ")  # fmt: skip
        ax.plot(t_min, f, color="C0", lw=1.5, label="filtered")
        ax.plot(t_min, series.measured_nm[:, i], "o", ms=3, color="k", label="measured")
        if true_nm is not None:
            ax.plot(t_min, true_nm[:, i], "--", color="C3", lw=1.0, label="true")
        ax.set_ylabel(f"drift {name} (nm)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[0].set_title(
        f"Drift over {t_min[-1]:.1f} min: {series.rate_nm_per_s:.3f} nm/s "
        f"({series.t_s.size} frames)"
    )
    axes[-1].set_xlabel("time since the first frame (min)")
    save_figure(fig, path)
