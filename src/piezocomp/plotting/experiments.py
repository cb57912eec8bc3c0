"""Figures of the paper's experiments redrawn from a run (Figs 8-10, Table I, speeds).

Each function writes one PNG atomically. ``results`` is the dictionary of
:func:`piezocomp.experiments.reproduce.aggregate` (``results.json``, typed in
:mod:`piezocomp.experiments.results`); the other arguments
are the experiments' result objects, by method.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

from piezocomp.plotting import new_figure, save_figure

if TYPE_CHECKING:
    from piezocomp.experiments.results import DriftSession, Results

__all__ = [
    "METHOD_STYLE",
    "plot_fig8",
    "plot_fig9",
    "plot_fig10",
    "plot_speeds",
    "plot_table1",
]

Path = str | os.PathLike[str]

METHOD_STYLE = {
    "uncompensated": ("uncompensated", "tab:red"),
    "static": ("static", "tab:orange"),
    "pi_no_creep": ("pi_no_creep", "tab:purple"),
    "paper": ("paper", "tab:brown"),
    "rls": ("rls", "tab:olive"),
    "compensated": ("compensated", "tab:blue"),
    "oracle": ("oracle", "tab:gray"),
    "both": ("both", "tab:green"),
    "drift_only": ("drift_only", "tab:purple"),
}
"""Label and colour of each method in every figure: the label is the method's one name, as
``results.json`` and the console give it (the report's table of methods says what each is)."""


def _label(method: str) -> str:
    return METHOD_STYLE.get(method, (method, "k"))[0]


def _colour(method: str) -> str:
    return METHOD_STYLE.get(method, (method, "k"))[1]


def plot_fig8(by_method: dict[str, Any], path: Path) -> None:
    """Fig. 8b/c: topography against the desired extension on every ramp, per method
    (``by_method``: :class:`~piezocomp.experiments.fig8.Fig8Result` by method name)."""
    methods = list(by_method)
    fig, axes = new_figure(
        len(methods), 1, figsize=(9, 2.6 * len(methods)), squeeze=False, layout="constrained"
    )
    for ax, m in zip(axes[:, 0], methods, strict=True):
        r = by_method[m]
        for i, (x, h) in enumerate(zip(r.ramps_x_nm, r.ramps_height_nm, strict=True)):
            ax.plot(x, h, lw=0.7, color=("tab:blue" if i % 2 == 0 else "tab:orange"), alpha=0.8)
        for p in r.particles_nm:
            ax.axvline(p, color="0.7", lw=0.5, ls=":")
        true = r.true_spread_nm
        tt = "" if true is None else f", true {np.nanmax(true):.2f} nm"
        meas = r.spread_nm
        worst, seen = r.measured_spread_nm, int(np.isfinite(meas).sum())
        of = "" if seen == meas.size else f" ({seen} of {meas.size} particles)"
        mt = f"{worst:.2f} nm{of}" if np.isfinite(worst) else "not measurable"
        ax.set_title(f"{_label(m)}: peak spread {mt}{tt}", fontsize=9)
        ax.set_ylabel("height (nm)")
        lo, hi = np.min(r.particles_nm), np.max(r.particles_nm)
        ax.set_xlim(lo - 60, hi + 60)
    axes[-1, 0].set_xlabel(
        "desired extension x (nm, from the origin); blue forward, orange backward"
    )
    save_figure(fig, path)


def _image(ax: Any, img: Any, title: str) -> Any:
    """The forward topography, levelled to its median; the image handle (one colour scale,
    -1 to 16 nm, for every image of a figure)."""
    z = np.asarray(img.forward_nm)
    z = z - np.median(z)
    ext = (img.x_nm[0], img.x_nm[-1], img.y_nm[0], img.y_nm[-1])
    im = ax.imshow(z, origin="lower", extent=ext, cmap="afmhot", vmin=-1, vmax=16)
    ax.set_title(title, fontsize=8)
    ax.set_xlabel("x (nm)", fontsize=7)
    ax.set_ylabel("y (nm)", fontsize=7)
    ax.tick_params(labelsize=6)
    return im


def _height_bar(fig: Any, im: Any, axes: Any) -> None:
    """One colour bar for the images of ``axes``, in nm of height."""
    bar = fig.colorbar(im, ax=axes, shrink=0.8, pad=0.02)
    bar.set_label("height above the median (nm)", fontsize=7)
    bar.ax.tick_params(labelsize=6)


def plot_fig9(by_method: dict[str, Any], path: Path) -> None:
    """Fig. 9: the images before and after the path, per method
    (:class:`~piezocomp.experiments.fig9.Fig9Result` with images)."""
    methods = [m for m, r in by_method.items() if r.images is not None]
    fig, axes = new_figure(
        len(methods), 2, figsize=(6.4, 3.2 * len(methods)), squeeze=False, layout="constrained"
    )
    for row, m in zip(axes, methods, strict=True):
        r = by_method[m]
        before, after = r.images
        _image(row[0], before, f"{_label(m)}: before")
        true = "" if r.true_error_nm is None else f", true {r.true_error_nm:.2f} nm"
        im = _image(row[1], after, f"after: shift {r.error_nm:.2f} nm{true}")
    _height_bar(fig, im, axes)
    save_figure(fig, path)


def plot_fig10(by_method: dict[str, list[Any]], path: Path, per_row: int = 5) -> None:
    """Fig. 10: every assembly of each method, failures included: the first assembly's
    image before, then each assembly's last image with the target sites (``per_row`` to a
    row), titled with its outcome (truly a success or not, its worst site's true error) and,
    per method, how many of them succeeded (``by_method``: each method's
    :class:`~piezocomp.experiments.fig10.Fig10Result` with images, in trial order, or the
    error text of an assembly that stopped)."""
    methods = [m for m, rs in by_method.items() if any(_has_images(r) for r in rs)]
    blocks = {m: max(1, math.ceil(len(by_method[m]) / per_row)) for m in methods}
    n_rows = sum(blocks.values())
    cols = 1 + min(per_row, max((len(by_method[m]) for m in methods), default=1))
    fig, axes = new_figure(n_rows, cols, figsize=(2.6 * cols + 0.8, 2.9 * n_rows),
                           squeeze=False, layout="constrained")  # fmt: skip
    for ax in axes.flat:
        ax.set_axis_off()
    im = None
    row = 0
    for m in methods:
        rs = by_method[m]
        ok = sum(1 for r in rs if not isinstance(r, str) and r.true_success)
        first = next(k for k, r in enumerate(rs) if _has_images(r))
        shown = rs[first]
        ax = axes[row, 0]
        ax.set_axis_on()
        im = _image(ax, shown.assembly.images[0],
                    f"{_label(m)}: {ok} of {len(rs)} truly succeeded\n"
                    f"before (assembly {first + 1})")  # fmt: skip
        ax.plot(shown.sites_nm[:, 0], shown.sites_nm[:, 1], "c+", ms=6, mew=0.8,
                label="target site")  # fmt: skip
        for k, r in enumerate(rs):
            ax = axes[row + k // per_row, 1 + k % per_row]
            if not _has_images(r):
                why = r if isinstance(r, str) else "no image"
                ax.set_title(f"assembly {k + 1}: stopped", fontsize=8, color="tab:red")
                ax.text(0.5, 0.5, why[:80], ha="center", va="center", fontsize=6, wrap=True,
                        transform=ax.transAxes)  # fmt: skip
                continue
            ax.set_axis_on()
            t = r.true_max_error_nm
            worst = "a particle lost" if t is None or not np.isfinite(t) else f"{t:.1f} nm"
            verdict = "success" if r.true_success else "FAILED"
            im = _image(ax, r.assembly.images[-1],
                        f"assembly {k + 1} ({r.assembly.n_pushes} pushes): {verdict}\n"
                        f"worst site truly {worst}")  # fmt: skip
            ax.title.set_color("tab:green" if r.true_success else "tab:red")
            ax.plot(r.sites_nm[:, 0], r.sites_nm[:, 1], "c+", ms=6, mew=0.8)
        row += blocks[m]
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles[:1], labels[:1], loc="outside lower center", fontsize=7)
    if im is not None:
        _height_bar(fig, im, axes)
    save_figure(fig, path)


def _has_images(r: Any) -> bool:
    return not isinstance(r, str) and bool(r.assembly.images)


def plot_table1(results: Results, path: Path, methods: Sequence[str] | None = None) -> None:
    """Table I at the paper's speed: each method's maximum error (true: bars with the
    spread over experiments; measured by cross-correlation: dots, the mean over the
    experiments it could measure) by distance, with the paper's figures; a mean over fewer
    than the experiments run says how many (``n/N`` over its bar or beside its dot).
    Without true errors (an instrument: ``true_max_error_nm`` ``None``), the bars are the
    measured errors. ``methods``: which and in what order (default: as in ``results``)."""
    v0 = results["paper"]["speed_nm_per_s"]
    rows = [r for r in results["table1"] if r["speed_nm_per_s"] == v0]
    if methods is None:
        methods = list(rows[0]["methods"]) if rows else []
    methods = [m for m in methods if rows and m in rows[0]["methods"]]
    n_run = results["table1_settings"]["experiments"]
    cells = [r["methods"][m] for r in rows for m in methods]
    has_truth = any(c["true_max_error_nm"] is not None for c in cells)
    fig, ax = new_figure(figsize=(9, 4.6), layout="constrained")
    width = 0.8 / max(len(methods), 1)
    stats = [c[k] for c in cells for k in ("true_max_error_nm", "max_error_nm") if c[k]]
    paper = results["paper"]["table1"]
    shown = [p[k][0] for r in rows if (p := paper.get(str(int(r["d_nm"]))))
             for k in ("uncompensated", "compensated")]  # fmt: skip
    means = [v for v in (s["mean"] for s in stats) if v] + shown  # the paper's lines too
    floor = 0.5 * min(means) if means else 0.01  # the axis' bottom: bars of std stop there
    for i, m in enumerate(methods):
        x = np.arange(len(rows)) + (i - 0.5 * (len(methods) - 1)) * width
        meas = [r["methods"][m]["max_error_nm"] for r in rows]
        bars = [r["methods"][m]["true_max_error_nm"] for r in rows] if has_truth else meas
        mean = np.array([t["mean"] or np.nan for t in bars])
        std = np.array([t["std"] or 0.0 for t in bars])
        low = np.minimum(std, np.maximum(mean - floor, 0.0))  # mean - std, kept on the axis
        ax.bar(x, mean, width, yerr=[low, std], color=_colour(m), label=_label(m), alpha=0.85,
               capsize=2)  # fmt: skip
        for xi, t, y in zip(x, bars, mean + std, strict=True):
            if t["n"] < n_run and np.isfinite(y):
                ax.annotate(f"{t['n']}/{n_run}", (xi, y), ha="center", va="bottom", fontsize=5)
        if not has_truth:
            continue
        dots = [t["mean"] or np.nan for t in meas]
        ax.plot(x, dots, "k.", ms=4)
        for xi, t, y in zip(x, meas, dots, strict=True):
            if 0 < t["n"] < n_run:
                ax.annotate(f"{t['n']}/{n_run}", (xi, y), xytext=(2, -2),
                            textcoords="offset points", fontsize=5)  # fmt: skip
    for j, r in enumerate(rows):
        p = paper.get(str(int(r["d_nm"])))
        if p:
            ax.plot([j - 0.45, j + 0.45], [p["uncompensated"][0]] * 2, "r--", lw=1)
            ax.plot([j - 0.45, j + 0.45], [p["compensated"][0]] * 2, "b--", lw=1)
    ax.set_yscale("log")
    ax.set_ylim(bottom=floor)
    _log_ticks(ax)
    ax.set_xticks(np.arange(len(rows)), [f"d = {r['d_nm']:g} nm" for r in rows])
    ax.set_ylabel("maximum error (nm)")
    what = (
        "bars true (mean; error bar: std, cut at the axis' bottom), dots measured (mean over\n"
        "the experiments cross-correlation could measure; n/N: a mean over n of the N)"
        if has_truth
        else "bars measured by cross-correlation (no true errors on an instrument;\nmean, "
        "error bar: std, cut at the axis' bottom; n/N: a mean over the n of N it could measure)"
    )
    ax.set_title(
        f"Table I at {v0:g} nm/s, {n_run} experiments per distance: {what}; dashed: the paper "
        "without (red) and with (blue) compensation",
        fontsize=8,
    )
    fig.legend(loc="outside lower center", fontsize=7, ncol=len(methods) or 1)
    save_figure(fig, path)


def _log_ticks(ax: Any) -> None:
    """Labels at 1, 2 and 5 of each decade of a log axis, written plainly (0.2, 5, 20)."""
    ax.yaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())


def plot_speeds(
    results: Results, path: Path, methods: Sequence[str] | None = None, note: str = ""
) -> None:
    """Table I (mean over the distances) and Fig. 9, true errors against the move speed;
    Fig. 9 alone when Table I ran at one speed (``--quick``). ``methods``: which and in what
    order (default: Table I's); ``note``: a caption under the axes (what changes with the
    speed besides the speed). Each point is one path (Fig. 9) or the mean of Table I's
    experiments at that speed (how many: the report's table)."""
    speeds = sorted({r["speed_nm_per_s"] for r in results["table1"]})
    if len(speeds) > 1:
        fig, (ax0, ax1) = new_figure(1, 2, figsize=(11, 4.4), layout="constrained")
        panels = [(ax0, "Table I, mean over distances"), (ax1, "Fig. 9")]
    else:
        fig, ax1 = new_figure(figsize=(7, 4.4), layout="constrained")
        ax0 = None
        panels = [(ax1, "Fig. 9 against the move speed (Table I ran at the paper's speed only)")]
    if methods is None:
        methods = list(results["table1"][0]["methods"]) if results["table1"] else []
    for m in methods:
        ys = []
        for v in speeds:
            means = [r["methods"][m]["true_max_error_nm"]["mean"] for r in results["table1"]
                     if r["speed_nm_per_s"] == v and m in r["methods"]]  # fmt: skip
            vals = [x for x in means if x is not None]
            ys.append(np.mean(vals) if vals else np.nan)
        if ax0 is not None:
            ax0.plot(speeds, ys, "o-", color=_colour(m), label=_label(m))
        f9 = sorted(results["fig9"]["speeds"], key=lambda s: s["speed_nm_per_s"])
        xs = [s["speed_nm_per_s"] for s in f9 if m in s["methods"]]
        ax1.plot(xs, [s["methods"][m]["true_error_nm"] for s in f9 if m in s["methods"]], "o-",
                 color=_colour(m), label=_label(m))  # fmt: skip
    ticks = sorted(set(speeds) | {s["speed_nm_per_s"] for s in results["fig9"]["speeds"]})
    for ax, title in panels:
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(ticks, [f"{v:g}" for v in ticks])
        ax.minorticks_off()
        _log_ticks(ax)
        ax.set_xlabel("move speed (nm/s)")
        ax.set_ylabel("true error (nm)")
        ax.set_title(title, fontsize=9)
        ax.axvline(results["paper"]["speed_nm_per_s"], color="0.6", ls=":", lw=1,
                   label="the paper's speed")  # fmt: skip
    handles, labels = ax1.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right center", fontsize=7)
    if note:
        fig.text(0.01, 0.0, note, ha="left", va="bottom", fontsize=7, wrap=True)
        fig.get_layout_engine().set(rect=(0, 0.1, 1, 0.9))
    save_figure(fig, path)


def plot_drift_session(session: DriftSession, path: Path) -> None:
    """The drift session: each image's true error against the session time, per method
    (named and coloured as in every figure, :data:`METHOD_STYLE`)."""
    fig, ax = new_figure(figsize=(8, 4), layout="constrained")
    for m, r in session["methods"].items():
        if "error" not in r and r["true_errors_nm"]:
            label = _label(m) + (" (stopped)" if r.get("stopped") else "")
            ax.plot(np.asarray(r["times_s"]) / 60.0, r["true_errors_nm"], "o-", ms=3,
                    color=_colour(m), label=label)  # fmt: skip
    ax.set_yscale("log")
    _log_ticks(ax)
    ax.set_xlabel("time since the session started (min; the drift compensator's overview and "
                  "landmarks first)")  # fmt: skip
    ax.set_ylabel("true error of the image (nm)")
    ax.set_title(f"Table I moves on a drifting sample: a {session['minutes']:g}-minute session "
                 "(its last image starts once that time is up)", fontsize=9)  # fmt: skip
    paper = "the paper's worst compensated Table I error (1.01 nm)"
    ax.axhline(1.01, color="0.6", ls=":", lw=1, label=paper)
    fig.legend(loc="outside lower center", fontsize=7, ncol=3)
    save_figure(fig, path)
