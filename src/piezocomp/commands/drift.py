"""``piezocomp drift``: how much an instrument drifts, from a series of images of one area.

Real AFM files (``--scans``: files, folders, glob patterns or movies such as ``.asd``, in any
format ``piezocomp loop`` reads, dated by the files' own times where they hold them), a movie
taken on a real
instrument (``--instrument nanonis://HOST:PORT``, measured only) or one taken on the virtual
AFM (``--preset``/``--scanner``, scored on its ground truth). Each frame is
registered against a reference frame, the shifts are filtered by the drift Kalman filter with
its noise estimated from the series, and the command writes ``drift.csv``, ``drift.png`` and
``summary.json`` (drift rate, the noise to give the drift compensator, frames refused).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp._atomic import atomic_write_text
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import output_folder, write_series
from piezocomp.commands.instrument_options import (
    add_instrument_options,
    connect_instrument,
    instrument_settings,
    refuse_instrument_options,
)

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``drift`` subcommand."""
    p = subparsers.add_parser(
        "drift",
        help=COMMANDS["drift"][1],
        description=(
            "Register each image of a series of the same area against a reference frame, "
            "filter the shifts with the drift Kalman filter (noise estimated from the series "
            "by maximum likelihood) and write drift.csv, drift.png and summary.json with the "
            "drift rate and the noise for the drift compensator. Give real AFM files "
            "(--scans, in the order taken: files, folders, glob patterns or movies such as "
            ".asd; dated by the files' times, or --interval-s), take a movie on a real "
            "instrument (--instrument nanonis://HOST:PORT) or on the virtual AFM (--preset "
            "or --scanner), the latter scored on its ground truth."
        ),
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--scans",
        nargs="+",
        metavar="FILE",
        help="AFM files in the order taken: files, folders (their images sorted by name), glob "
        "patterns or movies (.asd: every frame)",
    )
    src.add_argument("--preset", help="virtual AFM preset (e.g. cpr5, cpr5-warmup)")
    src.add_argument("--scanner", help="virtual AFM configuration file (TOML)")
    add_instrument_options(p, src)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument(
        "--interval-s",
        type=float,
        default=None,
        help="time from the start of one frame to the start of the next, s (real files: "
        "optional when the files state when they started, .sxm, .jpk and .asd do, or their line "
        "time and the frames ran back to back; a file whose time contradicts it is reported; "
        "movies: default 60)",
    )
    p.add_argument("--channel", default=None, help="channel of the files (default: topography)")
    p.add_argument("--frames", type=int, help="frames of the movie (default 20)")
    p.add_argument("--size-nm", type=float, help="movie frame side, nm (default 600)")
    p.add_argument("--pixels", type=int, help="movie frame pixels per side (default 64)")
    p.add_argument("--line-rate-hz", type=float, help="movie line rate, Hz (default 2)")
    p.add_argument(
        "--center-nm",
        type=float,
        nargs=2,
        metavar=("X", "Y"),
        help="centre of the movie's frames, nm (default 0 0)",
    )
    p.add_argument("--seed", type=int, help="virtual AFM seed (default 1)")
    p.add_argument(
        "--model",
        default=None,
        help="movies: take the movie through the compensator with this 2-D model (from "
        "'piezocomp identify --axis both'), so shifts are in true nm; without it they are "
        "in the raw scanner's nominal nm",
    )
    p.add_argument(
        "--order",
        type=int,
        choices=(2, 3),
        default=3,
        help="filter state: 2 = drift and rate, 3 = also its change (warm-up)",
    )
    p.add_argument("--no-fit", action="store_true", help="keep the default noise (no estimate)")
    p.set_defaults(func=run)


VIRTUAL_DEFAULTS: dict[str, Any] = {
    "frames": 20,
    "size_nm": 600.0,
    "pixels": 64,
    "line_rate_hz": 2.0,
    "center_nm": (0.0, 0.0),
    "seed": 1,
    "model": None,
}
"""The movie's options and their defaults (refused with --scans; ``seed`` is the virtual
AFM's only)."""

MATCH_ERROR_FINDING = 0.6
"""A frame whose registration error exceeds this is named in a finding (0 is a perfect
match, near 1 nothing matches): a tip change or a repetitive sample may have matched the
wrong features."""


def _check_options(args: argparse.Namespace) -> None:
    """Refuse the options that do not apply to the source given; fill the virtual defaults."""
    if args.interval_s is not None and not (math.isfinite(args.interval_s) and args.interval_s > 0):
        raise ValueError(f"--interval-s must be a finite time > 0. Got {args.interval_s}.")
    if not args.instrument:
        refuse_instrument_options(args, also=("sample_period_s", "range_nm"))
    if args.scans:
        given = [
            f"--{k.replace('_', '-')}" for k in VIRTUAL_DEFAULTS if getattr(args, k) is not None
        ]
        if given:
            raise ValueError(f"{', '.join(given)}: movie option(s), not used with --scans.")
        return
    if args.channel is not None:
        raise ValueError("--channel: an option of --scans (the files' channel).")
    if args.instrument:
        instrument_settings(args)  # checked before a movie is planned
        if args.seed is not None:
            raise ValueError("--seed: a virtual AFM option, not used with --instrument.")
    for key, value in VIRTUAL_DEFAULTS.items():
        if getattr(args, key) is None:
            setattr(args, key, value)


FILE_MIN_FEATURE_NM = 0.02
"""Real files: an image whose levelled heights span less than this is flat (an STM image's
atomic corrugation is a tenth of a nanometre; the virtual AFM's particles are nanometres)."""

INTERVAL_TOLERANCE_S = 1.5
"""A file's start time contradicts ``--interval-s`` when they differ by more than this (the
files state whole seconds) and :data:`INTERVAL_TOLERANCE_FRACTION` of the interval."""

INTERVAL_TOLERANCE_FRACTION = 0.02


def _file_frames(
    args: argparse.Namespace,
) -> tuple[list[Any], list[str], dt.datetime | None, str]:
    """The files as upright images on one grid, dated by the files' start times, by
    ``--interval-s`` or as taken back to back; the notes, the clock time of the first frame's
    start (when the files state it) and what dated the frames."""
    from piezocomp.instrument import ScanImage
    from piezocomp.io.afm_files import read_series

    scans = read_series(args.scans, channel=args.channel)
    if len(scans) < 2:
        raise ValueError(
            f"{scans[0].source}: a drift series needs at least 2 images of one area; "
            "--scans gave 1."
        )
    notes: list[str] = []
    first = scans[0]
    for s in scans[1:]:
        if s.shape != first.shape or not np.allclose(s.pixel_nm, first.pixel_nm, rtol=1e-6):
            raise ValueError(
                f"{s.source}: {s.shape} pixels of {s.pixel_nm} nm, the first file "
                f"{first.shape} of {first.pixel_nm} nm: every frame must have the same grid."
            )
        angle = s.metadata.get("scan_angle"), first.metadata.get("scan_angle")
        if angle[0] != angle[1]:
            raise ValueError(
                f"{s.source}: scan angle {angle[0]}, the first file {angle[1]}: every frame "
                "must be taken in the same frame of the scanner."
            )
    ny, nx = first.shape
    starts = [s.started_at for s in scans]
    file_t = None
    if all(t is not None for t in starts):
        file_t = [(t - starts[0]).total_seconds() for t in starts]  # type: ignore[operator]
        for k in range(1, len(scans)):
            if file_t[k] <= file_t[k - 1]:
                raise ValueError(
                    f"{scans[k].source}: started at {starts[k]}, not after "
                    f"{scans[k - 1].source} ({starts[k - 1]}): give the files in the order taken."
                )
    line_times = [
        s.line_time_s
        if s.line_time_s is not None
        else (s.acquisition_s / ny if s.acquisition_s is not None else None)
        for s in scans
    ]
    longest = max((ny * lt for lt in line_times if lt is not None), default=0.0)
    if args.interval_s is not None:
        if args.interval_s < longest:
            raise ValueError(
                f"--interval-s {args.interval_s:g} s is shorter than a frame ({ny} lines of the "
                f"files' line time: {longest:g} s)."
            )
        t0s = [k * float(args.interval_s) for k in range(len(scans))]
        dated = "--interval-s"
        if file_t is not None:
            tol = max(INTERVAL_TOLERANCE_S, INTERVAL_TOLERANCE_FRACTION * args.interval_s)
            for k in range(1, len(scans)):
                step = file_t[k] - file_t[k - 1]
                if abs(step - args.interval_s) > tol:
                    notes.append(
                        f"{scans[k].source}: the file says it started {step:g} s after "
                        f"{scans[k - 1].source}, --interval-s says {args.interval_s:g} s; "
                        "the frames are dated by --interval-s (leave it out to use the files' "
                        "times)"
                    )
    elif file_t is not None:
        t0s, dated = file_t, "the files' start times"
    elif all(lt is not None for lt in line_times):
        t0s = list(np.cumsum([0.0] + [ny * float(lt) for lt in line_times[:-1]]))  # type: ignore[arg-type]
        dated = "the files' line times, back to back"
        notes.append(
            "frames dated as taken back to back from the files' line times (the files do not "
            "say when they started, and no --interval-s); give --interval-s if there were "
            "pauses between them"
        )
    else:
        missing = next(s.source for s, lt in zip(scans, line_times, strict=True) if lt is None)
        raise ValueError(
            f"--interval-s is needed: {missing} states neither when it started nor its line "
            "time, so nothing says when each frame was taken."
        )
    images = []
    for k, s in enumerate(scans):
        lt = line_times[k]
        if lt is None:
            gap = t0s[k + 1] - t0s[k] if k + 1 < len(t0s) else t0s[k] - t0s[k - 1]
            lt = gap / ny
        img = s.image_nm  # upright; the retrace of a file that holds only the retrace
        images.append(ScanImage(
            forward_nm=img,
            backward_nm=s.backward_nm if s.backward_nm is not None else img,
            x_nm=np.arange(nx, dtype=np.float64) * float(s.pixel_nm[0]),
            y_nm=np.arange(ny, dtype=np.float64) * float(s.pixel_nm[1]),
            line_time_s=float(lt), t_start_s=float(t0s[k]),
        ))  # fmt: skip
    return images, notes, starts[0], dated


def _movie_interval(args: argparse.Namespace) -> float:
    """The movie's options checked; the time between frame starts, s."""
    interval = 60.0 if args.interval_s is None else float(args.interval_s)
    if args.frames < 2:
        raise ValueError(f"--frames must be >= 2. Got {args.frames}.")
    if args.pixels < 8:
        raise ValueError(f"--pixels must be >= 8. Got {args.pixels}.")
    for name in ("size_nm", "line_rate_hz"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"--{name.replace('_', '-')} must be finite and > 0. Got {v}.")
    if not all(math.isfinite(c) for c in args.center_nm):
        raise ValueError(f"--center-nm must be finite. Got {list(args.center_nm)}.")
    frame_s = args.pixels / args.line_rate_hz
    if interval < frame_s:
        raise ValueError(
            f"--interval-s {interval:g} s is shorter than one frame ({args.pixels} lines at "
            f"{args.line_rate_hz:g} Hz = {frame_s:g} s)."
        )
    return interval


def _model_2d(path: str) -> Any:
    """The 2-D model of ``--model``, read before anything moves."""
    from piezocomp.io import load_model
    from piezocomp.model import ScannerModel2D

    model = load_model(path)
    if not isinstance(model, ScannerModel2D):
        raise ValueError(
            f"{path}: a one-axis model; the movie needs both axes (identify with --axis both)."
        )
    return model


def _movie(inst: Any, args: argparse.Namespace, interval: float, model: Any) -> list[Any]:
    """``--frames`` images of one area ``interval`` apart on ``inst`` (raw, or through the
    compensator of ``model``, initialised first)."""
    if model is not None:
        from piezocomp.positioning.compensated import CompensatedInstrument

        inst = CompensatedInstrument(inst, model)
        inst.initialise()
    center = (float(args.center_nm[0]), float(args.center_nm[1]))
    images = []
    for _ in range(args.frames):
        t0 = inst.time_s
        images.append(inst.scan_image(center, args.size_nm, args.pixels, args.line_rate_hz))
        inst.wait(max(0.0, interval - (inst.time_s - t0)))
    return images


def _virtual_frames(args: argparse.Namespace) -> tuple[list[Any], Any]:
    """A movie of one area on the virtual AFM: ``--frames`` images ``--interval-s`` apart."""
    from piezocomp.virtual_afm import VirtualAFM

    interval = _movie_interval(args)
    model = None if args.model is None else _model_2d(args.model)
    if args.scanner:
        afm = VirtualAFM.from_config(args.scanner, seed=args.seed)
    else:
        afm = VirtualAFM.from_preset(args.preset, seed=args.seed)
    return _movie(afm, args, interval, model), afm.truth


def _instrument_frames(
    args: argparse.Namespace,
) -> tuple[list[Any], str, list[str], dict[str, Any]]:
    """The same movie on a real instrument (no ground truth); its address, notes and
    timing."""
    interval = _movie_interval(args)
    model = None if args.model is None else _model_2d(args.model)
    with connect_instrument(args, "drift") as inst:
        notes = []
        if inst.controller.drift_ramp_on:
            v = inst.controller.drift_ramp_nm_per_s
            notes.append(
                f"the controller's drift ramp ({v[0]:.3g}, {v[1]:.3g}) nm/s was kept on: the "
                "drift measured is what it leaves"
            )
        images = _movie(inst, args, interval, model)
        print(f"piezocomp drift: timing: {inst.timing_log.summary()}", file=sys.stderr)
        return images, inst.address, notes, inst.timing_log.as_dict()


def run(args: argparse.Namespace) -> int:
    """Run ``piezocomp drift``; return the exit status."""
    _check_options(args)
    with output_folder(args.out) as out:  # checked before a movie of minutes is taken
        return _measure(out, args)


def _measure(out: Path, args: argparse.Namespace) -> int:
    """The frames, their drift series, and the outputs."""
    from piezocomp.drift.filter import DriftNoise
    from piezocomp.drift.series import MIN_FRAMES_TO_FIT, track_series
    from piezocomp.imaging.registration import MIN_FEATURE_NM

    truth, timing, clock, dated = None, None, None, None
    if args.scans:
        images, notes, clock, dated = _file_frames(args)
        source = [str(f) for f in args.scans]
    else:
        if args.instrument:
            images, address, notes, timing = _instrument_frames(args)
            source = [address]
        else:
            images, truth = _virtual_frames(args)
            notes, source = [], [str(args.scanner or args.preset)]
        if args.model is None:
            notes.append(
                "the movie was taken on the raw scanner: its shifts are in the images' nominal "
                "nm, which differ from true nm by the scanner's sensitivity and hysteresis at "
                "this span (--model takes it through the compensator)"
            )
    series = track_series(
        images,
        DriftNoise(order=args.order),
        fit=not args.no_fit,
        min_feature_nm=FILE_MIN_FEATURE_NM if args.scans else MIN_FEATURE_NM,
    )
    if not series.noise_fitted and not args.no_fit:
        notes.append(
            f"only {series.t_s.size} frames registered (fewer than {MIN_FRAMES_TO_FIT}): the "
            "default noise was used, not one estimated from this series"
        )
    notes += [f"frame {k} not registered: {why}" for k, why in series.refused]
    poor = [k for k, e in zip(series.frames, series.match_error, strict=True)
            if e > MATCH_ERROR_FINDING]  # fmt: skip
    if poor:
        notes.append(
            f"frame(s) {poor} matched poorly (registration error above "
            f"{MATCH_ERROR_FINDING:g}): a tip change or a repetitive sample may have matched "
            "the wrong features; check those frames in drift.csv (match_error)"
        )
    return _write(out, args, series, images, truth, notes, source, timing, clock, dated)


def _write(
    out: Path, args: argparse.Namespace, series: Any, images: list[Any], truth: Any,
    notes: list[str], source: list[str], timing: dict[str, Any] | None,
    clock: dt.datetime | None = None, dated: str | None = None,
) -> int:  # fmt: skip
    from piezocomp.experiments.truth import true_image_position

    columns = {
        "t_s": series.t_s,
        "measured_x_nm": series.measured_nm[:, 0], "measured_y_nm": series.measured_nm[:, 1],
        "filtered_x_nm": series.filtered_nm[:, 0], "filtered_y_nm": series.filtered_nm[:, 1],
        "sigma_x_nm": series.sigma_nm[:, 0], "sigma_y_nm": series.sigma_nm[:, 1],
        "match_error": series.match_error,
    }  # fmt: skip
    true_nm = None
    if truth is not None:  # the content moves opposite to the tip's true position
        pos = np.array([true_image_position(truth, images[k]) for k in series.frames])
        true_nm = -(pos - pos[0])
        columns |= {"true_x_nm": true_nm[:, 0], "true_y_nm": true_nm[:, 1]}
    write_series(out / "drift.csv", columns)
    summary: dict[str, Any] = {
        "source": source,
        "frames": len(images),
        "registered": int(series.t_s.size),
        "duration_s": float(series.t_s[-1] - series.t_s[0]),
        "rate_nm_per_s": series.rate_nm_per_s,
        "velocity_end_nm_per_s": series.velocity_nm_per_s[-1].tolist(),
        "drift_end_nm": series.filtered_nm[-1].tolist(),
        "noise": asdict(series.noise),
        "noise_fitted": series.noise_fitted,
        "units": "true nm (through the compensator)"
        if getattr(args, "model", None)
        else "nominal nm of the images (a raw scanner's are not true nm)",
        "findings": notes,
    }
    if dated is not None:
        summary["frames_dated_by"] = dated
    if clock is not None:  # t_s = 0 is the first frame's start, in the files' clock
        summary["clock_at_t0"] = clock.isoformat()
    if timing is not None:  # a real instrument's paths, paced by the client
        summary["timing"] = timing
    if true_nm is not None:
        summary["true_max_error_nm"] = {
            "measured": float(np.max(np.hypot(*(series.measured_nm - true_nm).T))),
            "filtered": float(np.max(np.hypot(*(series.filtered_nm - true_nm).T))),
        }
    from piezocomp.plotting.drift import plot_drift_series

    plot_drift_series(series, out / "drift.png", true_nm=true_nm, clock_at_t0=clock)
    summary["figures"] = ["drift.png"]
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    for text in notes:
        print(f"piezocomp drift: warning: {text}", file=sys.stderr)
    tail = ""
    if true_nm is not None:
        tail = f"; filtered within {summary['true_max_error_nm']['filtered']:.2f} nm of the truth"
    print(
        f"drift over {summary['duration_s'] / 60:.1f} min ({series.t_s.size} frames): "
        f"{series.rate_nm_per_s:.3f} nm/s, {np.hypot(*series.filtered_nm[-1]):.1f} nm in all"
        f"{tail}; wrote {out / 'drift.csv'} and {out / 'summary.json'}"
    )
    return 0
