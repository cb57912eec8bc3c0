"""``piezocomp loop``: Section IV on a real image's forward and backward traces.

Finds features seen on both traces, pairs them, fits one symmetric loop ``f_a`` for the fast
axis (eqs (21)-(23)), writes the corrected images (NPZ, PNG, Gwyddion ``.gwy``), a figure and
``summary.json`` with the trace/retrace mismatch before and after.
"""

from __future__ import annotations

import argparse
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp._atomic import atomic_write_bytes, atomic_write_text
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import output_folder

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``loop`` subcommand."""
    p = subparsers.add_parser(
        "loop",
        help=COMMANDS["loop"][1],
        description=(
            "Fit the fast axis' symmetric hysteresis loop f_a from features seen on the "
            "forward and backward traces of a real AFM image (Mokaberi & Requicha 2008, Sec. "
            "IV, eqs 21-23), remap both traces onto true position and report the "
            "trace/retrace mismatch before and after."
        ),
    )
    p.add_argument(
        "--scan",
        required=True,
        help="AFM file (.nid, .gwy, .ibw, .spm, .000..., .sxm, .jpk, .jpk-qi-image; a movie "
        "such as .asd with --frame)",
    )
    p.add_argument("--frame", type=int, default=None, help="frame of a movie (from 0)")
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    p.add_argument("--channel", default=None, help="channel name (default: topography)")
    p.add_argument("--degree", type=int, default=5, help="degree of f_a (default 5)")
    p.add_argument(
        "--max-shift-nm",
        type=float,
        default=None,
        help="largest trace/retrace shift searched, nm (default 10%% of the scan width)",
    )
    p.set_defaults(func=run)


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def run(args: argparse.Namespace) -> int:
    """Run ``piezocomp loop``; return the exit status."""
    from piezocomp.imaging.loop_correction import correct_scan
    from piezocomp.io.afm_files import read_scan

    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise ValueError(f"{args.out}: exists and is not a folder")
    scan = read_scan(args.scan, channel=args.channel, frame=args.frame)
    result = correct_scan(scan, degree=args.degree, max_shift_nm=args.max_shift_nm)
    with output_folder(args.out) as out:
        return _write(out, scan, result)


def _write(out: Path, scan: Any, result: Any) -> int:
    """Write the corrected scan, the figures and the summary into ``out``."""
    from piezocomp.io.afm_files import write_gwy
    from piezocomp.io.afm_scan import AfmScan
    from piezocomp.plotting.loop import plot_loop_correction

    summary: dict[str, Any] = {
        "scan": str(scan.source),
        "channel": scan.channel,
        "image_shape": list(scan.shape),
        "pixel_nm": list(scan.pixel_nm),
        "line_time_s": scan.line_time_s,
        "mismatch_measure": (
            "per-line shift between forward and backward trace by normalised "
            "cross-correlation with parabolic sub-pixel peak; mismatch = median over lines of "
            "|shift|, spread = inter-quartile range of the signed shift"
        ),
        **result.summary(),
    }
    summary["mismatch_reduction"] = _finite_or_none(
        result.before.median_abs_nm / result.after.median_abs_nm
        if result.after.median_abs_nm > 0
        else math.inf
    )
    buf = io.BytesIO()
    np.savez_compressed(
        buf,
        position_nm=result.position_nm,
        forward_nm=result.forward_nm,
        backward_nm=result.backward_nm,
        u_nm=result.u_nm,
        forward_raw_nm=scan.forward_nm,
        backward_raw_nm=np.asarray(scan.backward_nm),
        shifts_before_nm=result.before.shifts_nm,
        shifts_after_nm=result.after.shifts_nm,
        loop_coefficients=result.loop.coefficients,
        pairs_u_ascending_nm=result.pairs.u_ascending_nm,
        pairs_u_descending_nm=result.pairs.u_descending_nm,
        pairs_line=result.pairs.line,
    )
    atomic_write_bytes(out / "corrected.npz", buf.getvalue())
    corrected = AfmScan(
        forward_nm=result.forward_nm,
        backward_nm=result.backward_nm,
        size_nm=(result.pixel_nm * result.forward_nm.shape[1], scan.size_nm[1]),
        pixel_nm=(result.pixel_nm, scan.pixel_nm[1]),
        line_time_s=scan.line_time_s,
        channel=f"{scan.channel} loop-corrected",
        source=str(scan.source),
    )
    write_gwy(out / "corrected.gwy", corrected)
    _write_images_png(out / "corrected.png", scan, result)
    plot_loop_correction(
        result,
        np.asarray(scan.forward_nm),
        np.asarray(scan.backward_nm),
        out / "loop.png",
        title=f"{Path(scan.source).name} ({scan.channel})",
    )
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    print(
        f"{Path(scan.source).name}: {len(result.pairs)} pairs on "
        f"{summary['lines_with_pairs']} lines; trace/retrace mismatch "
        f"{result.before.median_abs_nm:.2f} nm -> {result.after.median_abs_nm:.2f} nm "
        f"(median over lines); results in {out}"
    )
    return 0


def _write_images_png(path: Path, scan: Any, result: Any) -> None:
    """The traces raw and corrected, and their difference (forward - backward): the images
    look alike, the difference shows what the correction took out."""
    from piezocomp.plotting import new_figure, save_figure

    fig, axes = new_figure(2, 3, figsize=(13.5, 8), layout="constrained")
    raw = [("forward, raw", scan.forward_nm), ("backward, raw", scan.backward_nm)]
    cor = [("forward, corrected", result.forward_nm), ("backward, corrected", result.backward_nm)]
    levelled = [
        np.asarray(img) - np.median(np.asarray(img), axis=1, keepdims=True) for _, img in raw + cor
    ]
    lo, hi = np.percentile(np.concatenate([a.ravel() for a in levelled]), [1, 99])
    for ax, (name, _), a in zip(axes[:, :2].ravel(), raw + cor, levelled, strict=True):
        im = ax.imshow(a, cmap="afmhot", vmin=lo, vmax=hi, aspect="auto", interpolation="nearest")
        ax.set_title(name)
        ax.set_xlabel("pixel")
        ax.set_ylabel("line")
    bar = fig.colorbar(im, ax=axes[:, :2], shrink=0.8, location="left")
    bar.set_label("height above each line's median (nm)")
    diffs = [levelled[0] - levelled[1], levelled[2] - levelled[3]]
    span = float(np.nanpercentile(np.abs(diffs[0]), 99)) or 1.0
    for ax, d, name in zip(axes[:, 2], diffs, ("raw", "corrected"), strict=True):
        dm = ax.imshow(d, cmap="RdBu_r", vmin=-span, vmax=span, aspect="auto",
                       interpolation="nearest")  # fmt: skip
        ax.set_title(f"forward - backward, {name}")
        ax.set_xlabel("pixel")
        ax.set_ylabel("line")
    dbar = fig.colorbar(dm, ax=axes[:, 2], shrink=0.8)
    dbar.set_label("difference of the traces (nm)")
    save_figure(fig, path, dpi=90)
