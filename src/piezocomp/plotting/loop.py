"""Figure of a Section IV loop correction: the fitted loop and traces before and after."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from piezocomp.plotting import new_figure, save_figure

if TYPE_CHECKING:
    from piezocomp.imaging.loop_correction import LoopCorrection

__all__ = ["plot_loop_correction"]


def plot_loop_correction(
    result: LoopCorrection,
    forward_raw_nm: np.ndarray,
    backward_raw_nm: np.ndarray,
    path: str | os.PathLike[str],
    *,
    title: str = "",
) -> None:
    """Write a PNG: the loop (eqs (21)-(23)) with its pairs, one line before/after, shifts.

    Parameters
    ----------
    result : LoopCorrection
        Output of :func:`piezocomp.imaging.loop_correction.correct_scan`.
    forward_raw_nm, backward_raw_nm : ndarray, shape (ny, nx)
        The raw traces (for the "before" panel).
    path : path-like
        PNG destination.
    title : str, optional
        Figure title.
    """
    loop = result.loop
    u = np.asarray(result.u_nm)
    fig, axes = new_figure(2, 2, figsize=(12, 8), layout="constrained")
    ax = axes[0, 0]
    ax.plot(u, loop.ascending(u) - u, label="f_a(u) - u (forward)")
    ax.plot(u, loop.descending(u) - u, label="f_d(u) - u (backward)")
    ax.set_xlabel("command u (nm)")
    ax.set_ylabel("true minus nominal position (nm)")
    ax.set_title("fitted symmetric loop, eq (22)")
    ax.legend(fontsize=8)
    ax = axes[0, 1]
    pa, pd = result.pairs.u_ascending_nm, result.pairs.u_descending_nm
    ax.plot(pa, pa - pd, ".", ms=1.5, alpha=0.4, label="pairs: u_a - u_d")
    y = loop.ascending(u)
    width = u - loop.descending_inverse(y)
    ax.plot(u, width, "k-", lw=1.5, label="loop: u - f_d^-1(f_a(u))")
    ax.set_xlabel("forward position u_a (nm)")
    ax.set_ylabel("forward - backward (nm)")
    ax.set_title(f"{len(result.pairs)} feature pairs, eq (23)")
    ax.legend(fontsize=8)
    # A line with a large signal: the row with the highest variance.
    row = int(np.argmax(np.var(forward_raw_nm, axis=1)))
    ax = axes[1, 0]
    f0 = forward_raw_nm[row] - np.median(forward_raw_nm[row])
    b0 = backward_raw_nm[row] - np.median(backward_raw_nm[row])
    ax.plot(u, f0, lw=1, label="forward, raw")
    ax.plot(u, b0, lw=1, label="backward, raw")
    x = np.asarray(result.position_nm)
    off = 1.2 * float(np.ptp(f0)) if np.ptp(f0) > 0 else 1.0
    f1 = result.forward_nm[row] - np.median(result.forward_nm[row]) - off
    b1 = result.backward_nm[row] - np.median(result.backward_nm[row]) - off
    ax.plot(x, f1, lw=1, label="forward, corrected")
    ax.plot(x, b1, lw=1, label="backward, corrected")
    ax.set_xlabel("position (nm)")
    ax.set_ylabel("height (nm, offset)")
    ax.set_title(f"line {row}")
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    lines = np.arange(result.before.shifts_nm.size)
    ax.plot(lines, result.before.shifts_nm, ".", ms=3, label="before")
    ax.plot(lines, result.after.shifts_nm, ".", ms=3, label="after")
    ax.set_xlabel("line")
    ax.set_ylabel("forward - backward shift (nm)")
    both = np.concatenate([result.before.shifts_nm, result.after.shifts_nm])
    both = both[np.isfinite(both)]
    outside = 0
    if both.size:  # a few lines matched astray must not squash the rest
        lo, hi = np.percentile(both, [1.0, 99.0])
        pad = 0.1 * max(hi - lo, 1.0)
        ax.set_ylim(lo - pad, hi + pad)
        outside = int(np.sum((both < lo - pad) | (both > hi + pad)))
    clipped = f" ({outside} beyond the axis)" if outside else ""
    ax.set_title(
        f"mismatch: median |shift| {result.before.median_abs_nm:.2f} -> "
        f"{result.after.median_abs_nm:.2f} nm{clipped}"
    )
    ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    save_figure(fig, path)
