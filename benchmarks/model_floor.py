"""The floor of the model family: PI + creep fitted to the TRUE extension (for DIAGNOSIS).

Runs the default identification waveform (``IdentifyConfig``'s, on a 1 um span) on a virtual
scanner, after 60 steady cycles about its centre, and fits the model family to the TRUE
``(u, y)`` of that record (non-negative least squares, thresholds over the span, creep time
constants fixed on a spectrum; :func:`identify_error_budget.sensor_fit`), for several orders
and creep spectra; then scores each fit on the validation trajectory of
:func:`~piezocomp.experiments.scoring.score_on_truth` (max error, offset removed). This is
the best any identification can do with that family and record: the sensorless ones come on
top of it. Scanner variants switch off parts of the virtual physics to see which one sets
the floor.

Two families side by side: the paper's (creep driven by the command, eq 2) and the one
with the creep coupling of eq (2') (creep driven by ``u + beta H``): ``beta`` by a bounded
search on the fitting residual (:func:`~piezocomp.sensor.fit.choose_creep_coupling`, same
thresholds, time constants and starting state), the coupled family kept only if it
predicts the record's held-out part (its last quarter of part B, not fitted) better than
``beta = 0``. The validation trajectory scored is another record, never used by the fits.

About 10 s per variant for the paper's family; with the coupling about 4 minutes per
variant (six settings) on a busy 2-core machine (``--no-coupling`` leaves it out). Usage::

    python benchmarks/model_floor.py [--preset cpr5-nodrift] [--variants base nocreep ...]
        [--seed 1] [--spectra 19@0.05-2000s 19@0.01-2000s]

Prints one line of JSON per variant: ``n_play/spectrum`` the paper's family as before;
``n_play/spectrum+coupling`` the family chosen with the coupling, ``.../beta`` the ``beta``
the search found and ``.../family`` which family the held-out part kept. ``--asymmetry``:
``n_play/spectrum+coupling+asymmetry``, that model with Kuhnen's four dead zones (eq 8')
added as ``piezocomp fit`` adds them (:func:`~piezocomp.sensor.fit.fit_asymmetry`), and
``.../kept`` whether the record's held-out part prefers it by the margin ``fit`` asks.

``--fit``: ``piezocomp fit``'s own pipeline (:func:`~piezocomp.sensor.fit.fit_sensor`) on the
same TRUE record, fitted part and held-out part, as a user with a sensor record would run
it: not told the starting state (``fit/<state>/...`` for ``rest``, ``estimate`` and
``auto``, the command's default), its default orders (``8x2``), ``--select-orders``
(``selected``) and the reference it reports (``reference``, 16 x 19 by plain NNLS), each
with ``--creep-coupling fit`` too (``+coupling``); scored on the same validation
trajectory, the model started from the state it assumed. Last, ``fit/auto/8x2/tau0.05``: the
default command with ``--min-time-constant-s 0.05``, the floor's shortest time constant
(``fit``'s own default is 0.1 s).
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

from piezocomp.identification.acquisition.line_search import axis_command
from piezocomp.identification.acquisition.waveforms import (
    identification_waveform,
    validation_waveform,
)
from piezocomp.identification.config import IdentifyConfig
from piezocomp.identification.estimation.candidates import thresholds_over_span
from piezocomp.identification.estimation.prediction import record_state
from piezocomp.identification.estimation.problem import HOLDOUT_FRACTION
from piezocomp.io import atomic_write_text
from piezocomp.model import ModelState, simulate
from piezocomp.sensor.fit import ASYMMETRY_TOLERANCE, choose_creep_coupling, fit_asymmetry
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


def floor(
    preset: str,
    variant: str,
    n_plays: list[int],
    spectra: list[str] | None = None,
    coupling: bool = True,
    seed: int | None = None,
    with_fit: bool = False,
    asymmetry: bool = False,
) -> dict[str, float | str]:
    base = load_config(preset)
    scanner = dataclasses.replace(base.scanner, **VARIANTS[variant])
    cfg = dataclasses.replace(base, scanner=scanner)
    afm = VirtualAFM(cfg, sample_period_s=T, seed=seed)
    c = IdentifyConfig().updated(span_nm=1000.0).acquisition  # as the figures were measured
    w = c.waveform
    wf = identification_waveform(
        0.0, c.span_nm, c.speed_nm_per_s, T, n_steady=w.n_steady, n_decaying=w.n_decaying,
        n_random=w.n_random, max_dwell_s=w.max_dwell_s, rng=w.seed,
    )  # fmt: skip
    cycle = wf.u_nm[: 2 * wf.half_cycle_samples + 1]
    afm.move_to(cycle[0], 0.0, c.speed_nm_per_s)
    for _ in range(60):
        afm.run(axis_command("x", cycle, 0.0))
    rec = afm.run(axis_command("x", wf.u_nm, 0.0))
    u = rec.command_nm[:, 0]
    y = afm.truth.last_record_extension_nm[:, 0]
    n = u.size
    n_fit = n - round(HOLDOUT_FRACTION * (n - wf.part_b.start))
    fit = np.zeros(n, bool)
    fit[:n_fit] = True
    v = validation_waveform(0.0, c.span_nm, c.speed_nm_per_s, T, n_turns=24, rng=12345)
    move = afm.move_to(v[0], 0.0, c.speed_nm_per_s)
    val = afm.run(axis_command("x", v, 0.0))
    truth = afm.truth.last_record_extension_nm[:, 0]
    history = np.concatenate([u, move.command_nm[:, 0], val.command_nm[:, 0]])
    first = int(np.argmax(v >= v.max() - 1e-9))
    warm = 2 * wf.half_cycle_samples
    fit_rows = fit.copy()
    fit_rows[:warm] = False

    def score(m):
        pred, _ = simulate(m, history, T, record_state(m, u[0], 0.0))
        d = truth[first:] - pred[-v.size :][first:]
        return round(float(np.max(np.abs(d - d.mean()))), 3)

    def heldout_rms(m, start):  # on the record's held-out part, as fit_sensor judges
        pred, _ = simulate(m, u, T, start)
        return float(np.sqrt(np.mean((pred[~fit] - y[~fit]) ** 2)))

    out: dict[str, float | str] = {}
    for nh in n_plays:
        for name in spectra or list(SPECTRA):
            lo, hi, nc = SPECTRA[name]
            taus = np.geomspace(lo, hi, nc)
            m = sensor_fit(u, y, T, fit, warm, nh, taus, 0.0)
            out[f"{nh}/{name}"] = score(m)
            if not coupling:
                continue
            start = ModelState(np.full(nh, u[0]), np.zeros(nc), u[0])  # record_state(., 0)
            chosen, _, choice = choose_creep_coupling(
                u, y, T, thresholds_over_span(nh, float(np.ptp(u))), taus, fit_rows=fit_rows,
                validation_rows=~fit, initial_state=start,
            )  # fmt: skip
            out[f"{nh}/{name}+coupling"] = score(chosen)
            out[f"{nh}/{name}/beta"] = round(choice.best_coupling, 3)
            if asymmetry:  # Kuhnen's dead zones (eq 8') on the family chosen, as fit adds them
                asym, _ = fit_asymmetry(chosen, u, y, T, rows=fit_rows, initial_state=start)
                if asym is not None:
                    out[f"{nh}/{name}+coupling+asymmetry"] = score(asym)
                    held = [heldout_rms(mm, start) for mm in (chosen, asym)]
                    kept = held[1] < (1.0 - ASYMMETRY_TOLERANCE) * held[0]
                    out[f"{nh}/{name}+coupling+asymmetry/kept"] = "yes" if kept else "no"
            out[f"{nh}/{name}/family"] = choice.family
    if with_fit:
        out.update(user_fits(u, y, n_fit, warm, history, truth, v.size, first))
    return out


FLOOR_MIN_TAU_S = 0.05
"""The floor's shortest creep time constant (``--spectra 19@0.05-2000s``), given to ``fit``'s
``--min-time-constant-s`` in the last row of ``--fit``."""


def user_fits(u, y, n_fit, warm, history, truth, n_val, first) -> dict[str, float | str]:
    """``piezocomp fit``'s pipeline on the TRUE record (see the module docstring)."""
    import warnings

    from piezocomp.sensor.fit import fit_sensor, initial_state
    from piezocomp.sensor.orders import select_sensor_orders

    def score(m, kind):
        pred, _ = simulate(m, history, T, initial_state(m, history, kind))
        d = truth[first:] - pred[-n_val:][first:]
        return round(float(np.max(np.abs(d - d.mean()))), 3)

    out: dict[str, float | str] = {}
    common = {"split_index": n_fit, "warmup_samples": warm}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for kind in ("rest", "estimate", "auto"):
            sel = select_sensor_orders(u[:n_fit], y[:n_fit], T, warmup_samples=warm,
                                       initial_state=kind)  # fmt: skip
            for coupling in (0.0, "fit"):
                tag = "+coupling" if coupling == "fit" else ""
                for orders, (nh, nc) in (("8x2", (8, 2)), ("selected", (sel.n_play, sel.n_creep))):
                    f = fit_sensor(u, y, T, n_play=nh, n_creep=nc, initial_state=kind,
                                   creep_coupling=coupling, **common)  # fmt: skip
                    out[f"fit/{kind}/{orders}{tag}"] = score(f.model, f.rest_command_nm)
                    out[f"fit/{kind}/{orders}{tag}/chosen"] = f.chosen
                    if orders == "8x2" and f.reference is not None:
                        ref = f.reference
                        out[f"fit/{kind}/reference{tag}"] = score(ref.model, ref.rest_command_nm)
                out[f"fit/{kind}/selected/orders"] = f"{sel.n_play}x{sel.n_creep}"
                out[f"fit/{kind}/state{tag}"] = f.initial_state
                out[f"fit/{kind}/rest_command_nm{tag}"] = round(float(f.rest_command_nm), 1)
        # the default command with the floor's shortest creep time constant (fit's is 0.1 s)
        for coupling in (0.0, "fit"):
            tag = "+coupling" if coupling == "fit" else ""
            f = fit_sensor(u, y, T, n_play=8, n_creep=2, creep_coupling=coupling,
                           min_time_constant_s=FLOOR_MIN_TAU_S, **common)  # fmt: skip
            out[f"fit/auto/8x2/tau0.05{tag}"] = score(f.model, f.rest_command_nm)
            out[f"fit/auto/8x2/tau0.05{tag}/chosen"] = f.chosen
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", nargs="+", default=["cpr5-nodrift"], help="one or more presets")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--n-play", type=int, nargs="+", default=[16, 32])
    p.add_argument("--spectra", nargs="+", choices=list(SPECTRA), default=list(SPECTRA))
    p.add_argument("--no-coupling", action="store_true", help="the paper's family only")
    p.add_argument("--fit", action="store_true", help="also piezocomp fit's own pipeline")
    p.add_argument(
        "--asymmetry", action="store_true",
        help="also Kuhnen's dead zones (eq 8') on the coupled family, as piezocomp fit adds them",
    )  # fmt: skip
    p.add_argument("--seed", type=int, help="the virtual AFM's seed (default: the preset's)")
    p.add_argument("--json", type=Path, help="also write every row, with the command, here")
    a = p.parse_args()
    rows = []
    for preset in a.preset:
        for variant in a.variants:
            figs = floor(preset, variant, a.n_play, a.spectra, not a.no_coupling, a.seed, a.fit,
                         a.asymmetry)  # fmt: skip
            rows.append({"preset": preset, "variant": variant, "seed": a.seed, **figs})
            print(json.dumps(rows[-1]), flush=True)
    if a.json is not None:
        command = "python benchmarks/model_floor.py " + " ".join(
            arg for arg in sys.argv[1:] if arg != str(a.json) and arg != "--json"
        )
        a.json.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(a.json, json.dumps({"command": command, "rows": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
