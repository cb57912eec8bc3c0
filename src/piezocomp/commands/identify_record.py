"""``piezocomp identify --record``: the sensorless identification offline, on a run of
``piezocomp waveform`` recorded with any instrument
(:mod:`piezocomp.identification.offline`), scaled by recorded grating runs if given.

The waveform file fixes span, speed and sample period, and there is no ground truth to score
against. Not a subcommand (no ``register``): :mod:`.identify` calls :func:`run_record`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from piezocomp._atomic import atomic_write_text
from piezocomp.commands._common import record_range
from piezocomp.commands.identify_outputs import (
    config_of,
    figures,
    refused,
    save_config,
    warn,
)
from piezocomp.identification.acquisition.diagnostics import ExcitationWarning
from piezocomp.identification.estimation.findings import line_drift_text
from piezocomp.io.model_files import save_model

if TYPE_CHECKING:
    from piezocomp.identification.config import IdentifyConfig
    from piezocomp.identification.reference.grating import GratingRecord

__all__ = ["run_record"]


def run_record(args: argparse.Namespace, out: Path) -> int:
    """Offline identification from a recorded run (:mod:`piezocomp.identification.offline`)."""
    from piezocomp.identification.offline import identify_record, waveform_from_metadata
    from piezocomp.io.signals import read_signal

    signal = read_signal(args.record)
    _, params = waveform_from_metadata(signal.metadata, str(args.record))
    range_nm, range_from = _record_range(args, params)
    reference = _grating_reference(args) if args.grating_record else None
    if args.grating_pitch_nm is not None and not args.grating_record:
        raise ValueError("--grating-pitch-nm goes with --grating-record (the grating's records).")
    if getattr(args, "grating_path", None) is not None:
        raise ValueError(
            f"--grating-path {args.grating_path} is for the virtual lab's grating: the "
            "--grating-record files say which path they ran (piezocomp waveform --grating-line)."
        )
    tol = 1e-3 if args.command_tolerance_nm is None else args.command_tolerance_nm
    if not tol > 0:
        raise ValueError(f"--command-tolerance-nm must be > 0. Got {tol}.")
    # offline: the waveform file fixes the acquisition, the grating records the reference
    cfg = config_of(args).updated(grating=reference is not None)
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ExcitationWarning)
        result = identify_record(signal, cfg, axis=args.axis, tolerance_nm=tol, reference=reference)
    est = result.estimation
    warn(None, list(dict.fromkeys([str(w.message) for w in caught] + list(result.findings))))
    meta: dict[str, Any] = {
        "procedure": "sensorless, offline record (Mokaberi & Requicha 2008, Secs. III.C-IV)",
        "source": str(args.record),
        "range_nm_from": range_from,
    }
    if reference is not None:
        meta["reference"] = f"grating, pitch {reference.pitch_nm:g} nm, {args.grating_record}"
    batch = replace(result.batch_model, range_nm=range_nm)
    rls = replace(result.rls_model, range_nm=range_nm)
    save_model(out / "model.json", batch, {**meta, "method": "batch"})
    save_model(out / "model_rls.json", rls, {**meta, "method": "rls"})
    if range_nm is None:
        note = "the models state no range_nm (the scanner's full travel; the waveform file "
        warn(None, [note + "predates it): give --range-nm, or compensate will ask for it"])
    summary = {
        "source": str(args.record),
        "mode": "record",
        "waveform": params,
        "settings": _offline_settings(cfg),
        "grating": None
        if reference is None
        else {"pitch_nm": reference.pitch_nm, "files": [str(f) for f in args.grating_record]},
        **result.summary(),
    }
    summary["timing_s"] = {**result.timing_s, "total_wall": time.perf_counter() - t0}
    if not args.no_figures:
        summary["figures"] = figures(result, out)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    save_config(out / "config.toml", cfg, str(args.record))
    if result.reference is None:
        scale = "no length reference: the scale is unchecked"
    else:
        f = result.reference["batch"]
        angle = "angle not measured" if math.isnan(f.angle_deg) else f"angle {f.angle_deg:.2f} deg"
        if not math.isnan(f.drift_nm_per_s):  # the tip's drift: the grating slid the other way
            angle += f" (the grating slid {-f.drift_nm_per_s:+.3f} nm/s along the axis, taken out)"
        scale = f"scaled by the grating: alpha {f.alpha:.5f} +- {f.alpha_std:.5f}, {angle}"
    print(
        f"identified {args.record}: orders N_H={est.selection.n_play}, "
        f"N_c={est.selection.n_creep}; held-out height rms RLS "
        f"{est.heldout_rms_nm['rls']:.2f} nm, batch {est.heldout_rms_nm['batch']:.2f} nm; "
        f"{scale}; wrote {out / 'model.json'} and {out / 'summary.json'}"
    )
    if result.line_drift:
        print("drift measured: " + line_drift_text(result.line_drift))
    return refused({result.axis: result}, quick=args.quick)


def _offline_settings(cfg: IdentifyConfig) -> dict[str, Any]:
    """The settings of an offline run (JSON-ready): the waveform file fixes the acquisition,
    but for the peak finding."""
    out = cfg.as_dict()
    out["acquisition"] = {"min_prominence_nm": cfg.acquisition.min_prominence_nm}
    return out


def _grating_reference(args: argparse.Namespace) -> GratingRecord:
    """The grating records of ``--grating-record`` (with ``--grating-pitch-nm``)."""
    from piezocomp.identification.offline import grating_record_from_signals
    from piezocomp.io.signals import read_signal

    if args.grating_pitch_nm is None:
        raise ValueError("--grating-record needs --grating-pitch-nm, the grating's pitch.")
    if not args.grating_pitch_nm > 0:
        raise ValueError(f"--grating-pitch-nm must be > 0. Got {args.grating_pitch_nm}.")
    signals = [read_signal(f) for f in args.grating_record]
    reference = grating_record_from_signals(signals, args.grating_pitch_nm, axis=args.axis)
    other = "y_nm" if args.axis == "x" else "x_nm"
    if len(signals) > 1 and not all(other in s for s in signals):
        print(
            f"piezocomp identify: warning: the grating records have no {other} column: "
            "the grating's angle is not measured (a tilted grating scales the model by "
            "the cosine of its angle)",
            file=sys.stderr,
        )
    return reference


def _record_range(args: argparse.Namespace, params: dict[str, Any]) -> tuple[float | None, str]:
    """The scanner range of an offline identification and where it comes from: --range-nm,
    the waveform's, or the record's ``range_nm`` metadata."""
    if args.range_nm is not None:
        if not (math.isfinite(args.range_nm) and args.range_nm > 0):
            raise ValueError(f"--range-nm must be a finite number > 0. Got {args.range_nm}.")
        return float(args.range_nm), "--range-nm"
    if params.get("range_nm") is not None:
        return float(params["range_nm"]), f"the waveform in {args.record}"
    found, where = record_range(args.record)
    return found, (where or "not stated")
