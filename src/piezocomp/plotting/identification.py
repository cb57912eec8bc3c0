"""Figures of the sensorless identification (Section IV loop, ``h(y)``, Fig. 7b, diagnostics).

Each function takes an :class:`~piezocomp.identification.result.AxisIdentification` and
writes one PNG atomically.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from piezocomp.plotting import legend_above, legend_right, new_figure, save_figure

__all__ = [
    "plot_heldout_residual",
    "plot_loop",
    "plot_prediction_error",
    "plot_profile",
    "plot_rls_traces",
    "plot_waveform",
]

Path = str | os.PathLike[str]


def plot_waveform(ident: Any, path: Path) -> None:
    """Fig. 7a: the identification command, parts A and B."""
    wf = ident.waveform
    t = np.arange(wf.u_nm.size) * wf.sample_period_s
    fig, ax = new_figure(figsize=(9, 3.2), layout="constrained")
    ax.plot(t, wf.u_nm, lw=0.7)
    t_a = t[wf.part_a.stop - 1]
    ax.axvspan(0, t_a, color="0.9")
    lo, hi = float(np.min(wf.u_nm)), float(np.max(wf.u_nm))
    ax.set_ylim(lo - 0.05 * (hi - lo), hi + 0.2 * (hi - lo))  # room for the parts' names
    top = hi + 0.1 * (hi - lo)
    ax.text(0.5 * t_a, top, "A: steady cycles", ha="center", va="center", fontsize=8)
    ax.text(0.5 * (t_a + t[-1]), top, "B: excursions of varied amplitude and speed", ha="center",
            va="center", fontsize=8)  # fmt: skip
    ax.set_xlabel("time (s)")
    ax.set_ylabel("command u (nm)")
    ax.set_title(f"Identification waveform, axis {ident.axis} (Fig. 7a)")
    save_figure(fig, path)


def plot_loop(ident: Any, path: Path) -> None:
    """The steady loop (eqs 21-23): traces, paired peaks and the fitted branches."""
    le = ident.loop
    loop = le.loop
    fig, (ax0, ax1) = new_figure(1, 2, figsize=(11, 4))
    ax0.plot(le.u_forward_nm, le.forward_nm, lw=0.8, label="forward (mean of steady cycles)")
    ax0.plot(le.u_backward_nm, le.backward_nm, lw=0.8, label="backward")
    ax0.plot(le.u_ascending_peaks_nm, np.interp(le.u_ascending_peaks_nm, le.u_forward_nm,
             le.forward_nm), "v", label="paired peaks")  # fmt: skip
    ax0.set_xlabel("command u (nm)")
    ax0.set_ylabel("height (nm)")
    legend_above(ax0, ncol=3)
    u = np.linspace(loop.u_min_nm, loop.u_max_nm, 400)
    ax1.plot(u, loop.ascending(u) - u, label="f_a(u) - u")
    ax1.plot(u, loop.descending(u) - u, label="f_d(u) - u (eq 22)")
    for ua, ud in le.all_pairs:
        if len(ua):
            y = loop.ascending(ua)
            ax1.plot(ua, y - ua, "k.", ms=2)
            ax1.plot(ud, y - ud, "r.", ms=2)
    ax1.set_xlabel("command u (nm)")
    ax1.set_ylabel("y - u (nm)")
    ax1.set_title(f"loop degree {loop.degree}")
    ax1.legend(fontsize=7)
    save_figure(fig, path)


def plot_profile(ident: Any, path: Path) -> None:
    """``h(y)`` and ``h'(y)`` of the identification line."""
    le = ident.loop
    prof = ident.profile
    lo, hi = prof.y_range_nm
    y = np.linspace(lo, hi, 4000)
    fig, (ax0, ax1) = new_figure(2, 1, figsize=(9, 5), sharex=True)
    ax0.plot(le.loop.ascending(le.u_forward_nm), le.forward_nm, ".", ms=2, label="forward trace")
    ax0.plot(y, prof(y), lw=1, label="h(y)")
    ax0.set_ylabel("height (nm)")
    ax0.legend(fontsize=7)
    ax1.plot(y, prof.derivative(y), lw=1)
    ax1.set_ylabel("h'(y)")
    ax1.set_xlabel("extension y (nm)")
    save_figure(fig, path)


def plot_rls_traces(ident: Any, path: Path) -> None:
    """Fig. 7b: the estimation error (17) and several parameter estimates over time."""
    res = ident.rls
    lay = res.layout
    t = np.arange(res.error_nm.size) * ident.sample_period_s
    names = lay.names()
    picks = [lay.a, lay.y0]
    picks += list(range(lay.w.start, lay.w.stop))[:3]
    picks += list(range(lay.c.start, lay.c.stop))[:2]
    fig, axes = new_figure(3, 1, figsize=(9, 7), sharex=True)
    axes[0].plot(t, res.error_nm, lw=0.5)
    axes[0].set_ylabel("eps (nm), eq 17")
    for j in picks:
        trace = res.theta_trace[:, j]
        if j in (lay.y0,):
            axes[2].plot(t, trace, lw=0.8, label=names[j])
        else:  # each relative to its final value, so that their convergence shows alike
            final = trace[-1]
            axes[1].plot(t, trace / final if final else trace, lw=0.8, label=names[j])
    for i, k in enumerate(res.resets):
        axes[1].axvline(t[k], color="0.8", lw=0.5, label="covariance reset" if i == 0 else None)
    axes[1].set_title("a few of the parameters: the gain, the first play weights and creep "
                      "gains", fontsize=9)  # fmt: skip
    axes[1].set_ylabel("estimate / final value")
    legend_right(axes[1])
    axes[2].set_ylabel("y0 (nm)")
    legend_right(axes[2])
    axes[2].set_xlabel("time (s)")
    save_figure(fig, path)


def _working_predictions(ident: Any) -> list[tuple[str, Any]]:
    """``h(y_hat)`` of the RLS and batch models over the record, each in its working frame
    through the profile it was estimated with, from the state the estimation assumed."""
    return [
        (name.upper() if name == "rls" else name, ident.predict_heights(model, prof))
        for name, (model, prof) in ident.working_models().items()
    ]


def plot_prediction_error(ident: Any, path: Path) -> None:
    """Height prediction error ``z_m - h(y_hat)`` over the record, RLS and batch models."""
    t = np.arange(ident.u_nm.size) * ident.sample_period_s
    warm = 2 * ident.waveform.half_cycle_samples  # the unknown initial state: in no fit
    fig, ax = new_figure(figsize=(9, 3.5))
    spans = []
    for name, pred in _working_predictions(ident):
        r = ident.height_nm - pred
        ax.plot(t, r, lw=0.5, label=name)
        spans.append(float(np.nanpercentile(np.abs(r[warm:]), 99.9)))
    ax.axvspan(t[0], t[min(warm, t.size - 1)], color="0.95", label="left out of every fit")
    ax.axvspan(t[np.flatnonzero(~ident.fit_mask)[0]], t[-1], color="0.9", label="held out")
    if spans and np.isfinite(max(spans)) and max(spans) > 0:
        lim = 1.2 * max(spans)  # the first seconds' larger spikes run off the axis
        ax.set_ylim(-lim, lim)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("z_m - h(y_hat) (nm)")
    legend_above(ax)
    save_figure(fig, path)


def plot_heldout_residual(ident: Any, path: Path) -> None:
    """Measured and predicted heights over the held-out part of the record."""
    mask = ~ident.fit_mask
    t = (np.arange(ident.u_nm.size) * ident.sample_period_s)[mask]
    fig, (ax0, ax1) = new_figure(2, 1, figsize=(9, 5), sharex=True)
    ax0.plot(t, ident.height_nm[mask], lw=0.6, color="k", label="measured")
    for name, pred_all in _working_predictions(ident):
        pred = pred_all[mask]
        ax0.plot(t, pred, lw=0.6, label=name)
        ax1.plot(t, ident.height_nm[mask] - pred, lw=0.5, label=name)
    ax0.set_ylabel("height (nm)")
    ax0.legend(fontsize=7)
    ax1.set_ylabel("residual (nm)")
    ax1.set_xlabel("time (s)")
    if getattr(ident, "final_fit", False):
        ax0.set_title(
            "held-out part: it chose the orders, then the final models were fitted over it too",
            fontsize=8,
        )
    save_figure(fig, path)


def plot_reference(ident: Any, path: Path) -> None:
    """The grating record against the batch model's positions folded onto one period (in
    the grating's lengths), with the fitted profile: what set the model's scale."""
    from piezocomp.identification.reference.frames import unmapped
    from piezocomp.identification.reference.scaling import folded

    record, fit = ident.reference_record, ident.reference["batch"]
    model = unmapped(ident.batch_model, *ident.frame_map)  # the working frame, as fitted
    x, z, line = folded(model, record, fit)
    fig, (ax0, ax1) = new_figure(1, 2, figsize=(11, 4), layout="constrained")
    for k in np.unique(line):
        sel = line == k
        ax0.plot(x[sel], z[sel], ".", ms=1, alpha=0.4, label=f"line {k + 1}")
    xx = np.linspace(0.0, record.pitch_nm, 400)
    ax0.plot(xx, fit.profile(xx), "k", lw=1.2, label="fitted profile")
    ax0.set_xlabel(f"position in the period (nm of the {record.pitch_nm:g} nm grating)")
    ax0.set_ylabel("height (nm)")
    ax0.legend(fontsize=7, markerscale=6)
    n = len(fit.line_alphas)
    ax1.plot(np.arange(1, n + 1), fit.line_alphas, "o-")
    ax1.set_xticks(np.arange(1, n + 1))
    ax1.axhline(fit.alpha, color="k", lw=0.8)
    ax1.set_xlabel("grating line")
    ax1.set_ylabel("alpha = pitch / period")
    ax1.ticklabel_format(axis="y", useOffset=False)
    ax1.set_title(
        f"alpha {fit.alpha:.5f} +- {fit.alpha_std:.5f}; height residual "
        f"{fit.residual_rms_nm:.2f} nm rms"
    )
    save_figure(fig, path)
