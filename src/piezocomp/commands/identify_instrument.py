"""``piezocomp identify --instrument nanonis://HOST:PORT``: the identification on a real instrument.

The same sensorless procedure as on the virtual AFM
(:func:`~piezocomp.identification.sensorless.identify_axis`), through
:class:`~piezocomp.drivers.nanonis.NanonisInstrument`. What the controller does not state
is given by flags (:mod:`.instrument_options`): the slew limit, the sample period, the
travel to use, and the speed of the scan the scanner's calibration was made at
(``--calibration-speed-nm-per-s``: the calibration cycles then run over the whole range at
it, as on the virtual AFM; without it the calibration condition is the working span's).
The length reference comes from grating runs recorded earlier on the same instrument
(``--grating-record``, one axis) or is left out (``--reference none``, flagged). There is no
ground truth: the summary holds what the instrument measured (held-out heights, orders, the
drift along the line), never a validation error.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

from piezocomp._atomic import atomic_write_text
from piezocomp.commands.identify_outputs import (
    budget_seconds,
    config_of,
    drift_lines,
    figures,
    instrument_time_line,
    plan_summary,
    refused,
    save_config,
    save_models,
    total_instrument_time,
    warn,
)
from piezocomp.commands.instrument_options import connect_instrument, instrument_settings

__all__ = ["run_instrument"]


def _reference(args: argparse.Namespace, axes: tuple[str, ...]) -> Any:
    """The grating record of ``--grating-record`` (one axis), or ``None`` with
    ``--reference none``; refused otherwise, before anything connects."""
    from piezocomp.identification.offline import grating_record_from_signals
    from piezocomp.io.signals import read_signal

    if getattr(args, "grating_path", None) is not None:
        raise ValueError(
            f"--grating-path {args.grating_path} is for the virtual lab's grating: the "
            "--grating-record files say which path they ran (piezocomp waveform --grating-line)."
        )
    if args.grating_record:
        if len(axes) != 1:
            raise ValueError(
                "--grating-record holds one axis' grating runs (lines across that axis): "
                "identify that axis alone (--axis x or --axis y), or both with --reference none."
            )
        if args.grating_pitch_nm is None or not args.grating_pitch_nm > 0:
            raise ValueError("--grating-record needs --grating-pitch-nm > 0, the grating's pitch.")
        signals = [read_signal(f) for f in args.grating_record]
        return grating_record_from_signals(signals, args.grating_pitch_nm, axis=axes[0])
    if args.reference != "none":
        raise ValueError(
            "--instrument takes its length reference from a grating run made earlier on the "
            "same instrument (--grating-record FILES --grating-pitch-nm P), or runs without "
            "one: --reference none."
        )
    return None


def _calibration(args: argparse.Namespace) -> float | None:
    """The calibration scan's speed, nm/s, and ``args.calibrate`` filled (unless a
    configuration file states it): ``full-range`` with a speed, ``span`` without one unless
    asked."""
    speed = args.calibration_speed_nm_per_s
    if speed is not None and not speed > 0:
        raise ValueError(f"--calibration-speed-nm-per-s must be > 0. Got {speed}.")
    if speed is not None and args.calibrate == "span":
        raise ValueError(
            "--calibration-speed-nm-per-s goes with --calibrate full-range (the calibration "
            "cycles over the whole range)."
        )
    if args.calibrate is None and not args.config:
        args.calibrate = "span" if speed is None else "full-range"
    return None if speed is None else float(speed)


def run_instrument(args: argparse.Namespace, out: Path) -> int:
    """Sensorless identification of one axis or both on a real instrument; write the model
    files and ``summary.json`` (no scoring: no ground truth)."""
    from piezocomp.identification.acquisition.diagnostics import ExcitationWarning
    from piezocomp.identification.planning import within_budget
    from piezocomp.identification.sensorless import identify_axis

    instrument_settings(args)  # every check before anything connects
    for flag in ("seed", "command_tolerance_nm"):
        if getattr(args, flag) is not None:
            raise ValueError(f"--{flag.replace('_', '-')} does not go with --instrument.")
    axes = ("x", "y") if args.axis in (None, "both") else (args.axis,)
    reference = _reference(args, axes)
    args.reference = "grating" if reference is not None else "none"
    calibration_speed = _calibration(args)
    config = config_of(args)  # checked before anything connects
    budget = budget_seconds(args)
    idents: dict[str, Any] = {}
    texts: dict[str, list[str]] = {}
    t0 = time.perf_counter()
    with connect_instrument(args, "identify") as inst:
        plan = within_budget(inst, config, axes, budget)
        cfg = plan.config
        print(f"piezocomp identify: {plan.describe()}", flush=True)
        for axis in axes:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", ExcitationWarning)
                idents[axis] = identify_axis(inst, cfg, axis, reference=reference)
            texts[axis] = [str(w.message) for w in caught] + list(idents[axis].findings)
        address, controller, range_nm = inst.address, inst.controller.summary(), inst.range_nm
        timing = inst.timing_log
    wall = time.perf_counter() - t0
    for axis in axes:
        warn(axis if len(axes) > 1 else None, list(dict.fromkeys(texts[axis])))
    if reference is None:
        warn(None, ["no length reference: the model's scale is unchecked (--reference none)"])
    print(f"piezocomp identify: timing: {timing.summary()}", file=sys.stderr)
    save_models(out, idents, axes, address, f"the controller ({controller})")
    summary: dict[str, Any] = {
        "source": address,
        "mode": "instrument",
        "controller": controller,
        "range_nm": range_nm,
        "calibration": cfg.acquisition.calibrate,
        "calibration_speed_nm_per_s": calibration_speed,
        "reference": args.reference,
        "settings": cfg.as_dict(),
        **plan_summary(plan, args.budget_min),
        "axes": {axis: idents[axis].summary() for axis in axes},
        "timing": timing.as_dict(),
        "timing_s": {"total_wall": wall},
        "instrument_s": total_instrument_time(idents),
    }
    if not args.no_figures:
        for axis in axes:
            summary["axes"][axis]["figures"] = figures(idents[axis], out)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    save_config(out / "config.toml", cfg, address)
    held = ", ".join(
        f"{a} {idents[a].heldout_rms_nm['batch']:.2f} nm (N_H={idents[a].orders.n_play}, "
        f"N_c={idents[a].orders.n_creep})"
        for a in axes
    )
    print(
        f"identified axis {','.join(axes)} of {address}: held-out height rms of the batch "
        f"model {held}; wrote {out / 'model.json'} and {out / 'summary.json'}"
    )
    for line in drift_lines(summary):
        print(line)
    print(instrument_time_line(summary))
    return refused(idents, quick=args.quick)
