"""The floor of the model family: PI + creep fitted to the TRUE extension (for DIAGNOSIS).

Runs the default identification waveform (``SensorlessConfig``) on a virtual scanner, after
60 steady cycles about its centre, and fits the model family to the TRUE ``(u, y)`` of that
record (non-negative least squares, thresholds over the span, creep time constants fixed on
a spectrum; :func:`identify_error_budget.sensor_fit`), for several orders and creep spectra;
then scores each fit on the validation trajectory of
:func:`~piezocomp.experiments.scoring.score_on_truth` (max error, offset removed). This
is the best any identification can do with that family and record: the sensorless ones
come on top of it. Scanner variants switch off parts of the virtual physics to see which
one sets the floor.

About 10 s with the default variants. Usage::

    python benchmarks/model_floor.py [--preset cpr5-nodrift] [--variants base nocreep symmetric ...]

Prints one line of JSON per variant (keys ``n_play/spectrum``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from identify_error_budget import sensor_fit

from piezocomp.identification.acquisition import axis_command
from piezocomp.identification.config import SensorlessConfig
from piezocomp.identification.prediction import record_state
from piezocomp.identification.waveforms import (
    identification_waveform,
    validation_waveform,
)
from piezocomp.model import simulate
from piezocomp.virtual_afm import VirtualAFM, load_config

VARIANTS = {
    "base": {},
    "linear_creep": {"creep_domain_fraction": 0.0},
    "domain_creep_half": {"creep_domain_fraction": 0.5},
    "quiet": {"position_noise_nm": 0.0, "position_flicker_nm": 0.0},
    "nocreep": {"creep": 0.0},
    "symmetric": {"hysteresis_asymmetry": 0.0},
    "symmetric_nocreep": {"creep": 0.0, "hysteresis_asymmetry": 0.0},
    "nosaturation": {"hysteresis_saturation": 0.0},
}
SPECTRA = {
    "19@0.05-2000s": (0.05, 2000.0, 19),
    "19@0.01-2000s": (0.01, 2000.0, 19),
    "40@0.01-5000s": (0.01, 5000.0, 40),
}
T = 0.008


def floor(preset: str, variant: str, n_plays: list[int]) -> dict[str, float]:
    base = load_config(preset)
    scanner = dataclasses.replace(base.scanner, **VARIANTS[variant])
    afm = VirtualAFM(dataclasses.replace(base, scanner=scanner), sample_period_s=T)
    c = SensorlessConfig()
    wf = identification_waveform(
        0.0, c.span_nm, c.speed_nm_per_s, T, n_steady=c.n_steady, n_decaying=c.n_decaying,
        n_random=c.n_random, max_dwell_s=c.max_dwell_s, rng=c.seed,
    )  # fmt: skip
    cycle = wf.u_nm[: 2 * wf.half_cycle_samples + 1]
    afm.move_to(cycle[0], 0.0, c.speed_nm_per_s)
    for _ in range(60):
        afm.run(axis_command("x", cycle, 0.0))
    rec = afm.run(axis_command("x", wf.u_nm, 0.0))
    u = rec.command_nm[:, 0]
    y = afm.truth.last_record_extension_nm[:, 0]
    n = u.size
    n_fit = n - round(c.holdout_fraction * (n - wf.part_b.start))
    fit = np.zeros(n, bool)
    fit[:n_fit] = True
    v = validation_waveform(0.0, c.span_nm, c.speed_nm_per_s, T, n_turns=24, rng=12345)
    move = afm.move_to(v[0], 0.0, c.speed_nm_per_s)
    val = afm.run(axis_command("x", v, 0.0))
    truth = afm.truth.last_record_extension_nm[:, 0]
    history = np.concatenate([u, move.command_nm[:, 0], val.command_nm[:, 0]])
    first = int(np.argmax(v >= v.max() - 1e-9))
    out = {}
    for nh in n_plays:
        for name, (lo, hi, nc) in SPECTRA.items():
            m = sensor_fit(
                u, y, T, fit, 2 * wf.half_cycle_samples, nh, np.geomspace(lo, hi, nc), 0.0
            )
            pred, _ = simulate(m, history, T, record_state(m, u[0], 0.0))
            d = truth[first:] - pred[-v.size :][first:]
            out[f"{nh}/{name}"] = round(float(np.max(np.abs(d - d.mean()))), 3)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="cpr5-nodrift")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--n-play", type=int, nargs="+", default=[16, 32])
    a = p.parse_args()
    for variant in a.variants:
        print(
            json.dumps(
                {"preset": a.preset, "variant": variant, **floor(a.preset, variant, a.n_play)}
            ),
            flush=True,
        )


if __name__ == "__main__":
    main()
