"""``piezocomp reproduce --instrument nanonis://HOST:PORT``: the experiments on a real instrument.

Table I, Fig. 8 and Fig. 9 (:mod:`piezocomp.experiments.on_instrument`) run on the one
instrument, uncompensated and through the compensator of a given 2-D model (``--model``, e.g.
from ``piezocomp identify --instrument ... --axis both``), with the measured errors only: a
real instrument has no ground truth, and the true errors are reported as unavailable. Writes
``DIR/results.json``, ``DIR/report.html`` and the figures the virtual run draws for these
experiments (:mod:`piezocomp.experiments.report_instrument`); exits 1 if a trial failed or
the instrument stopped the run.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from piezocomp._atomic import atomic_write_text
from piezocomp.commands.instrument_options import connect_instrument, instrument_settings

__all__ = ["run_instrument"]


def _checked(args: argparse.Namespace) -> None:
    """The experiments' options, one line per problem, before anything connects."""
    for name, low in (("table1_experiments", 1), ("pixels", 8), ("overview_pixels", 16)):
        v = getattr(args, name)
        if v is not None and v < low:
            raise ValueError(f"--{name.replace('_', '-')} must be >= {low}. Got {v}.")
    for d in args.distances_nm or ():
        if not (math.isfinite(d) and d > 0):
            raise ValueError(f"--distances-nm must be finite and > 0. Got {d}.")
    if args.speed_nm_per_s is not None and not (
        math.isfinite(args.speed_nm_per_s) and args.speed_nm_per_s > 0
    ):
        raise ValueError(f"--speed-nm-per-s must be finite and > 0. Got {args.speed_nm_per_s}.")
    if args.settle_s is not None and not (math.isfinite(args.settle_s) and args.settle_s >= 0):
        raise ValueError(f"--settle-s must be finite and >= 0. Got {args.settle_s}.")


def _model(args: argparse.Namespace) -> Any:
    from piezocomp.io import load_model
    from piezocomp.model import ScannerModel2D

    if args.model is None:
        return None
    model = load_model(args.model)
    if not isinstance(model, ScannerModel2D):
        raise ValueError(
            f"{args.model}: a one-axis model; the experiments move in 2-D (identify with "
            "--axis both)."
        )
    return model


def _settings(args: argparse.Namespace, model: Any) -> Any:
    from piezocomp.experiments.on_instrument import InstrumentRunSettings

    methods = args.methods or (("uncompensated", "compensated") if model else ("uncompensated",))
    if "compensated" in methods and model is None:
        raise ValueError(
            "--methods compensated needs --model FILE (a 2-D model, e.g. from 'piezocomp "
            "identify --instrument ... --axis both')."
        )
    given = {
        "experiments": None if args.experiments is None else tuple(args.experiments),
        "distances_nm": None if args.distances_nm is None else tuple(args.distances_nm),
        "table1_experiments": args.table1_experiments,
        "speed_nm_per_s": args.speed_nm_per_s,
        "settle_s": args.settle_s,
        "pixels": args.pixels,
        "overview_pixels": args.overview_pixels,
    }
    return InstrumentRunSettings(
        methods=tuple(methods), **{k: v for k, v in given.items() if v is not None}
    )


def run_instrument(args: argparse.Namespace, out: Path) -> int:
    """Run the experiments on the instrument; write ``results.json`` and a summary."""
    from piezocomp.experiments.on_instrument import run_trials, summarise
    from piezocomp.experiments.report_instrument import (
        timing_note,
        write_instrument_figures,
        write_instrument_report,
    )

    instrument_settings(args)  # every check before anything connects
    _checked(args)
    model = _model(args)
    settings = _settings(args, model)
    t0 = time.perf_counter()

    def report(line: str) -> None:
        print(f"piezocomp reproduce: {line}", file=sys.stderr, flush=True)

    with connect_instrument(args, "reproduce") as inst:
        trials = run_trials(inst, model, settings, report=report)
        results = summarise(trials)
        address, controller = inst.address, inst.controller.summary()
        timing = inst.timing_log
    plain = asdict(settings)
    results = {
        "source": address,
        "mode": "instrument",
        "controller": controller,
        "model": args.model,
        "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in plain.items()},
        **results,
        "timing": timing.as_dict(),
        "timing_s": {"total_wall": time.perf_counter() - t0},
    }
    atomic_write_text(out / "results.json", json.dumps(results, indent=2) + "\n")
    write_instrument_figures(trials, results, out)
    write_instrument_report(results, out, command=_command(args), emulator=bool(args.emulator))
    _summary(results, out)
    report(f"timing: {timing.summary()}")
    note = timing_note(results["timing"], bool(args.emulator))
    if note:
        report(f"timing: {note}")
    for f in results["failures"]:
        report(f"warning: {f['experiment']} / {f['method']} failed: {f['error']}")
    if results["stopped"]:
        report(f"error: the instrument stopped the run: {results['stopped']}")
    return 1 if results["failures"] else 0


_RERUN_OPTIONS = (
    "max_speed_nm_per_s", "sample_period_s", "range_nm", "model", "table1_experiments",
    "speed_nm_per_s", "settle_s", "pixels", "overview_pixels", "timing", "timing_tolerance",
    "speedup", "timeout_s", "drift_ramp",
)  # fmt: skip


def _command(args: argparse.Namespace) -> str:
    """The command line that reruns this run (the options given, the address as given)."""
    import shlex

    parts = ["piezocomp", "reproduce", "--instrument", args.instrument]
    for name in _RERUN_OPTIONS:
        v = getattr(args, name, None)
        if v is not None:
            parts += ["--" + name.replace("_", "-"), f"{v:g}" if isinstance(v, float) else str(v)]
    for name in ("experiments", "methods", "distances_nm"):
        v = getattr(args, name, None)
        if v:
            parts += ["--" + name.replace("_", "-"), *(f"{x:g}" if isinstance(x, float)
                                                       else str(x) for x in v)]  # fmt: skip
    if args.emulator:
        parts.append("--emulator")
    parts += ["--out", args.out]
    return " ".join(shlex.quote(p) for p in parts)


def _n(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def _summary(res: dict[str, Any], out: Path) -> None:
    """What the run measured, in a few lines (no true errors: none exist)."""
    print(f"piezocomp reproduce on {res['source']}: measured errors, nm (true: not available)")
    for row in res["table1"]:
        cells = [
            f"{m} {_n(r['max_error_nm']['mean'])} (n = {r['max_error_nm']['n']})"
            for m, r in row["methods"].items()
        ]
        print(f"  Table I d = {row['d_nm']:g} nm: " + ", ".join(cells))
    if res["fig8"]:
        print("  Fig. 8 largest spread: " + ", ".join(
            f"{m} {_n(r['spread_nm'])}" for m, r in res["fig8"].items()
        ))  # fmt: skip
    if res["fig9"]:
        print("  Fig. 9: " + ", ".join(f"{m} {_n(r['error_nm'])}" for m, r in res["fig9"].items()))
    print(f"wrote {out / 'results.json'}, {out / 'report.html'} and the figures")
