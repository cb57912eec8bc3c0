"""Figures of a sensor-based fit: prediction, prediction error, identified loop."""

from __future__ import annotations

import os

import numpy as np
from numpy.typing import ArrayLike

from piezocomp._validation import as_finite_1d, check_finite_scalar
from piezocomp.plotting import legend_right, new_figure, save_figure
from piezocomp.sensor.fit import SensorFit

__all__ = ["plot_sensor_fit"]


def plot_sensor_fit(
    fit: SensorFit,
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    path: str | os.PathLike[str],
    title: str | None = None,
) -> None:
    """Write a three-panel PNG: measured vs predicted, error over time, the loop ``y(u)``.

    The error panel shades the warm-up (grey), the fitted part (blue) and the held-out
    part (orange) differently; the loop panel draws the measured and predicted ``y``
    against ``u`` on the held-out part (the fitted part if nothing was held out).

    Parameters
    ----------
    fit : SensorFit
        The fit (its ``predicted_nm`` is drawn).
    u_nm, y_nm : array_like, shape (n,)
        The record the fit was made on.
    sample_period_s : float
        ``T``, s.
    path : path-like
        PNG written atomically.
    title : str, optional
        Figure title.
    """
    u = as_finite_1d("u_nm", u_nm)
    y = as_finite_1d("y_nm", y_nm)
    T = check_finite_scalar("sample_period_s", sample_period_s)
    pred = fit.predicted_nm
    if not (u.size == y.size == pred.size):
        raise ValueError(
            f"u_nm, y_nm and the fit's prediction must have the same length. "
            f"Got {u.size}, {y.size}, {pred.size}."
        )
    t = np.arange(u.size) * T
    warm, split = fit.warmup_samples, fit.split_index
    err = pred - y
    fig, axes = new_figure(3, 1, figsize=(8, 10))
    ax0, ax1, ax2 = axes
    ax0.plot(t, y / 1e3, lw=0.8, label="measured")
    ax0.plot(t, pred / 1e3, lw=0.8, ls="--", label="predicted")
    ax0.set_xlabel("time (s)")
    ax0.set_ylabel("y (µm)")
    legend_right(ax0)
    spans = [(0, warm, "0.8", "warm-up"), (warm, split, "tab:blue", "fit")]
    if split < u.size:
        spans.append((split, u.size, "tab:orange", "held out"))
    for a, b, colour, label in spans:
        if b > a:
            ax1.axvspan(t[a], t[b - 1], color=colour, alpha=0.15, label=label)
    ax1.plot(t, err, lw=0.6, color="k")
    shown = err[warm:]  # the warm-up's transient would set the scale otherwise
    if shown.size and np.ptp(shown) > 0:
        pad = 0.1 * float(np.ptp(shown))
        ax1.set_ylim(float(shown.min()) - pad, float(shown.max()) + pad)
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("predicted - measured (nm)")
    figs = [f"fit rms {fit.fit_errors.rms_percent_of_range:.3g} %"]
    if fit.validation_errors is not None:
        figs.append(f"held-out rms {fit.validation_errors.rms_percent_of_range:.3g} %")
    ax1.set_title(", ".join(figs) + " of range")
    legend_right(ax1)
    part = slice(split, u.size) if split < u.size else slice(warm, split)
    ax2.plot(u[part] / 1e3, y[part] / 1e3, lw=0.8, label="measured")
    ax2.plot(u[part] / 1e3, pred[part] / 1e3, lw=0.8, ls="--", label="predicted")
    ax2.set_xlabel("u (nominal µm)")
    ax2.set_ylabel("y (µm)")
    ax2.set_title("loop, " + ("held-out part" if split < u.size else "fitted part"))
    legend_right(ax2)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path)
