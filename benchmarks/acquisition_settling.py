"""Acquisition diagnosis (issue 4): how far the TRUE slow axis moves during the x record.

Runs :func:`~piezocomp.identification.sensorless.identify_axis` (full-range calibration) on
the virtual AFM with the given configuration overrides, then reads the simulator's ground
truth FOR DIAGNOSIS ONLY: the true slow-axis (y) positions during the identification record
(peak to peak over the record, part A and part B), and scores the models with
:func:`~piezocomp.identification.sensorless.score_on_truth`. Prints one JSON document.

Usage::

    python benchmarks/acquisition_settling.py --preset cpr5 --seed 1 \\
        [--config '{"line_settle_s": 0, "check_cycles": 0}']
"""

from __future__ import annotations

import argparse
import json
import warnings
from typing import Any

import numpy as np

from piezocomp.afm import VirtualAFM
from piezocomp.identification.sensorless import SensorlessConfig, identify_axis, score_on_truth


class _Recorder:
    """Forwards the instrument; keeps the true positions of every record (diagnosis)."""

    def __init__(self, afm: VirtualAFM) -> None:
        self._afm = afm
        self.records: list[tuple[float, np.ndarray]] = []

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._afm, name)
        if name not in ("run", "move_to", "wait", "scan_image"):
            return attr

        def call(*args: Any, **kw: Any) -> Any:
            t0 = self._afm.time_s
            out = attr(*args, **kw)
            self.records.append((t0, np.array(self._afm.truth.last_record_positions_nm)))
            return out

        return call


def run(preset: str, seed: int, overrides: dict[str, Any]) -> dict[str, Any]:
    afm = VirtualAFM.from_preset(preset, seed=seed, sample_period_s=0.008)
    rec = _Recorder(afm)
    cfg = SensorlessConfig(calibration_span_nm=afm.range_nm, **overrides)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ident = identify_axis(rec, cfg, "x")  # type: ignore[arg-type]
    n = ident.u_nm.size
    t0, pos = [r for r in rec.records if r[1].shape[0] == n][-1]
    y = pos[:, 1]
    wf = ident.waveform
    score = score_on_truth(afm, ident, {"rls": ident.rls_model, "batch": ident.batch_model})
    st = ident.line_stability
    return {
        "preset": preset,
        "seed": seed,
        "config": overrides,
        "record_start_s": t0,
        "true_slow_axis_ptp_nm": {
            "record": float(np.ptp(y)),
            "part_a": float(np.ptp(y[wf.part_a])),
            "part_b": float(np.ptp(y[wf.part_b])),
        },
        "line_stability": None
        if st is None
        else {
            "height_change_rms_nm": st.height_change_rms_nm,
            "height_change_max_nm": st.height_change_max_nm,
            "noise_rms_nm": st.noise_rms_nm,
            "peak_height_change_nm": st.peak_height_change_nm.tolist(),
        },
        "frame_map": ident.frame_map,
        "heldout_height_rms_nm": ident.heldout_rms_nm,
        "methods": {m: score[m] for m in ("rls", "batch")},
        "warnings": sorted({str(w.message) for w in caught}),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="cpr5")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--config", default="{}", help="SensorlessConfig overrides (JSON)")
    a = p.parse_args()
    print(json.dumps(run(a.preset, a.seed, json.loads(a.config)), indent=2))


if __name__ == "__main__":
    main()
