"""Sensor-based identification on a real piezo record; prints the figures as JSON.

Data: ``data/piezo-micromanipulator/Model_Vi_Do.dat`` in this repository, with its licence
and provenance notes (``LICENSE``, ``README.md``). Origin:
github.com/yan9a/DiscreteBacklashOperator (commit 79fd060,
``MatLabCode/DiscreteBacklashModel/Model_Vi_Do.dat``), MIT licence, Copyright (c) 2019
Yan Naing Aye; reference: Y. N. Aye and W. T. Ang, "A Discrete Backlash Operator for
Identification and Compensation of Hysteresis and Non-linearity for Piezoelectric
Micromanipulator", ICSTSD 2018. A piezo micromanipulator with a capacitive displacement
sensor, 200 Hz, 8027 samples: column 1 drive voltage (V), column 5 displacement (um).

What it compares, on the same split (first 70 % fitted, last 30 % held out) and warm-up:

- the baseline: a plain PI model, 10 uniformly spaced play operators, no creep, fitted by
  non-negative least squares (:func:`~piezocomp.sensor.fit.fit_plain_pi`);
- our model (14): orders chosen on the fitted part only (inner hold-out), then the linear
  stage, the nonlinear refinement, the reference fit and the asymmetric candidate (Kuhnen's
  dead zones, eq 8'), the one kept that predicts the held-out part best
  (:func:`~piezocomp.sensor.fit.fit_sensor`, as ``piezocomp fit`` runs it).

Each model's initial state ("rest" at the first command, or "zero": held at 0 V before
the record) is chosen by its own error on the *fitted* part; both are reported, and so is
"estimate" (a rest command found from the fitted part).

Then every model predicts the instrument's other record, ``Test_Vi_Do_Di.dat`` (same
repository and licence; see the data's README): nested minor loops and holds the fitting
record never had. Its sensor offset (and, in a second row, its starting state) comes from
its first :data:`HEAD_S` seconds only; the error is scored on each of its three parts after
them. Besides the baseline and our model, the same family by plain non-negative least
squares with many placed operators (``SensorFit.reference``) predicts it too.

Usage::

    python benchmarks/piezo_record.py [--data PATH] [--test-data PATH] [--figure PNG]
        [--write-csv CSV]
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.sensor.fit import SensorFit, fit_plain_pi, fit_sensor, start_of_record
from piezocomp.sensor.orders import select_sensor_orders

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "data" / "piezo-micromanipulator" / "Model_Vi_Do.dat"
TEST_DATA = DATA.with_name("Test_Vi_Do_Di.dat")
HEAD_S = 2.0
"""Seconds at the start of the test record from which its offset (and state) are found."""
HOLD_SAMPLES = 300
"""A hold of the drive at least this long separates two parts of the test record."""
PROVENANCE = (
    "github.com/yan9a/DiscreteBacklashOperator (commit 79fd060, "
    "MatLabCode/DiscreteBacklashModel/Model_Vi_Do.dat), MIT licence, (c) 2019 Yan Naing Aye; "
    "Y. N. Aye and W. T. Ang, ICSTSD 2018"
)
SAMPLE_PERIOD_S = 0.005  # 200 Hz
FIT_FRACTION = 0.7
PERIOD_SAMPLES = 200  # the 1 Hz drive at 200 Hz
WARMUP_SAMPLES = 10
"""The first 50 ms: the record opens with a step from rest to 1.8 V and the sensor reading
rises 23 um in 30 ms, a transient of the mechanics that no rate-independent model follows."""


def load_record(path: Path = DATA) -> dict[str, Any]:
    """Command ``u`` (nominal nm) and extension ``y`` (nm) from the raw record.

    ``y`` = column 5 (um) x 1000. ``u`` = column 1 (V) x a nominal sensitivity chosen so
    that the command range maps onto the output range: ``s = ptp(y) / ptp(V)`` nm/V. The
    sign of ``u`` is flipped if ``y`` falls as the voltage rises (so that ``a > 0``).
    """
    data = np.loadtxt(path)
    volts, y = data[:, 0], 1000.0 * data[:, 4]
    sensitivity = float(np.ptp(y) / np.ptp(volts))
    flip = bool(np.corrcoef(volts, y)[0, 1] < 0)
    u = (-1.0 if flip else 1.0) * sensitivity * volts
    return {
        "u_nm": u,
        "y_nm": y,
        "sample_period_s": SAMPLE_PERIOD_S,
        "sensitivity_nm_per_V": sensitivity,
        "sign_flipped": flip,
    }


def cycle_to_cycle_rms_nm(u: np.ndarray, y: np.ndarray, start: int) -> float | None:
    """Rms of ``y`` about its mean cycle over the whole cycles from ``start`` on.

    The drive repeats exactly every :data:`PERIOD_SAMPLES`; any model of the form (14) then
    predicts (after its creep has settled) the same cycle each period, so the scatter of
    the measured cycles about their mean (sensor noise, drift, non-repeatability) is a
    reference for the error left. ``None`` if the drive does not repeat.
    """
    k = (u.size - start) // PERIOD_SAMPLES
    if k < 2:
        return None
    cu = u[start : start + k * PERIOD_SAMPLES].reshape(k, PERIOD_SAMPLES)
    if not np.allclose(cu, cu[0], rtol=0, atol=1e-9 * np.ptp(u)):
        return None
    cy = y[start : start + k * PERIOD_SAMPLES].reshape(k, PERIOD_SAMPLES)
    return float(np.sqrt(np.mean((cy - cy.mean(axis=0)) ** 2)))


def load_test_record(
    path: Path, sensitivity_nm_per_V: float, sign_flipped: bool = False
) -> dict[str, Any]:
    """The test record in the fitting record's units: the drive actually applied (column 1,
    V) times the fitting record's sensitivity (and sign), the sensor (column 5, um) x 1000,
    and its parts, split at the middle of each hold of the drive."""
    data = np.loadtxt(path)
    sign = -1.0 if sign_flipped else 1.0
    u, y = sign * sensitivity_nm_per_V * data[:, 0], 1000.0 * data[:, 4]
    still = np.concatenate(([False], np.diff(u) == 0.0, [False]))
    edges = np.flatnonzero(np.diff(still.astype(int)))
    holds = [(a, b) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= HOLD_SAMPLES]
    cuts = [0, *(int(a + b) // 2 for a, b in holds), int(u.size)]
    return {"u_nm": u, "y_nm": y, "parts": list(itertools.pairwise(cuts))}


def predict_other_record(
    model: ScannerModel, fitted_rest_nm: float, test: dict[str, Any], T: float, start: str
) -> dict[str, Any]:
    """``model``'s prediction of the test record: rms error, % of that record's output range,
    on each part after the first :data:`HEAD_S` s. The sensor's offset is found from those
    first seconds. The state: ``start="as fitted"``, held at the command the model's own
    fit assumed before the fitting record (``fitted_rest_nm``: both records start the same
    way, after the actuator rested); ``"estimate"``, a rest command found from the same
    first seconds (:func:`~piezocomp.sensor.fit.start_of_record`)."""
    u, y = test["u_nm"], test["y_nm"]
    head = np.arange(u.size) < round(HEAD_S / T)
    if start == "estimate":
        rest, offset = start_of_record(model, u, y, T, rows=head)
        state = ModelState.at_rest(model, rest)
    else:
        rest, state = fitted_rest_nm, ModelState.at_rest(model, fitted_rest_nm)
        pred0, _ = simulate(model, u, T, state)
        offset = float(np.mean(pred0[head] - y[head]))
    pred, _ = simulate(model, u, T, state)
    err = pred - offset - y
    out_range = float(np.ptp(y))
    parts = []
    for a, b in test["parts"]:
        rows = slice(max(a, int(head.sum())), b)
        e = err[rows]
        parts.append(
            {
                "samples": [int(rows.start), int(b)],
                "rms_nm": float(np.sqrt(np.mean(e**2))),
                "rms_percent_of_range": 100.0 * float(np.sqrt(np.mean(e**2))) / out_range,
                "max_nm": float(np.max(np.abs(e))),
            }
        )
    return {"start": start, "rest_command_nm": rest, "offset_nm": offset, "parts": parts}


ASYMMETRY_PAIRS = (0, 1, 2, 3)
"""Pairs of one-sided dead zones the asymmetry probe adds (0: the symmetric reference)."""


def asymmetry_probe(
    reference: ScannerModel,
    u: np.ndarray,
    y: np.ndarray,
    T: float,
    fit_rows: np.ndarray,
    val_rows: np.ndarray,
    test: dict[str, Any] | None,
) -> list[dict[str, Any]]:
    """Does an asymmetric loop help? A probe for Kuhnen's modified PI, not a model the
    package ships.

    The reference's columns (``[u, z_j, x_i]``, its thresholds and creep time constants, the
    "zero" start) plus ``2 k`` one-sided dead zones of its own hysteresis output ``H``
    (``max(H - d, 0)`` above the centre of ``H``'s fitted span, ``min(H - d, 0)`` below, at
    ``d`` spread over +-40 % of the span), refitted by least squares (the plays' and creep's
    weights >= 0, the dead zones' of either sign). Kuhnen's operator composes such dead zones
    with the PI output, which makes the loop's two branches differ in shape. Scored as the
    models are: rms, % of range, on the held-out part and on each part of the other record
    (its offset from its first :data:`HEAD_S` s, started at "zero").
    """
    from scipy.optimize import nnls as _nnls

    from piezocomp.sensor.fit import nnls_stage

    def columns(uu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        _, _, reg, _ = nnls_stage(
            uu, np.zeros(uu.size), T, reference.thresholds_nm,
            reference.creep_time_constants_s, initial_state="zero",
        )  # fmt: skip
        h = reg[:, : 1 + reference.n_play] @ np.concatenate(([reference.gain], reference.weights))
        return reg, h

    reg, h = columns(u)
    lo, hi = float(h[fit_rows].min()), float(h[fit_rows].max())
    centre, span = 0.5 * (lo + hi), hi - lo
    out_range = float(np.ptp(y[WARMUP_SAMPLES:]))
    other = None if test is None else columns(test["u_nm"])
    rows = []
    for k in ASYMMETRY_PAIRS:
        spread = np.linspace(-0.4, 0.4, 2 * k + 1) if k else np.zeros(0)
        ds = [centre + span * f for f in spread if abs(f) > 1e-9]

        def zones(hh: np.ndarray, ds: list[float] = ds) -> np.ndarray:
            z = [np.maximum(hh - d, 0.0) if d > centre else np.minimum(hh - d, 0.0) for d in ds]
            return np.column_stack(z) if z else np.zeros((hh.size, 0))

        a = np.column_stack((reg, zones(h), -zones(h)))  # free signs as two >= 0 columns
        mu, b_mu = a[fit_rows].mean(axis=0), float(y[fit_rows].mean())
        sc = np.linalg.norm(a[fit_rows] - mu, axis=0)
        sc[sc <= 0] = 1.0
        coef, _ = _nnls((a[fit_rows] - mu) / sc, y[fit_rows] - b_mu, maxiter=20 * a.shape[1])
        coef /= sc
        y0 = b_mu - float(mu @ coef)
        e = a @ coef + y0 - y
        row: dict[str, Any] = {
            "dead_zones": len(ds),
            "fit_percent_of_range": 100 * float(np.sqrt(np.mean(e[fit_rows] ** 2))) / out_range,
            "validation_percent_of_range": (
                100 * float(np.sqrt(np.mean(e[val_rows] ** 2))) / out_range
            ),
        }
        if test is not None and other is not None:
            reg_t, h_t = other
            pred = np.column_stack((reg_t, zones(h_t), -zones(h_t))) @ coef + y0
            yt = test["y_nm"]
            n_head = round(HEAD_S / T)
            et = pred - float(np.mean(pred[:n_head] - yt[:n_head])) - yt
            row["other_parts_percent_of_range"] = [
                100 * float(np.sqrt(np.mean(et[max(a0, n_head) : b0] ** 2))) / float(np.ptp(yt))
                for a0, b0 in test["parts"]
            ]
        rows.append(row)
    return rows


def _best_by_fit(fits: dict[str, SensorFit]) -> str:
    return min(fits, key=lambda k: fits[k].fit_errors.rms_nm)


def run(
    path: Path = DATA, figure: Path | None = None, test_path: Path | None = TEST_DATA
) -> dict[str, Any]:
    """Fit both models and return the figures (see the module docstring); ``test_path``:
    the instrument's other record, predicted by each (``None``: not used)."""
    rec = load_record(path)
    u, y, T = rec["u_nm"], rec["y_nm"], rec["sample_period_s"]
    split = round(FIT_FRACTION * u.size)
    common = {"split_index": split, "warmup_samples": WARMUP_SAMPLES}
    caught_all: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        base = {k: fit_plain_pi(u, y, T, initial_state=k, **common) for k in ("rest", "zero")}
        t_base = time.perf_counter() - t0
        ours: dict[str, SensorFit] = {}
        tables: dict[str, Any] = {}
        t0 = time.perf_counter()
        for kind in ("rest", "zero", "estimate", "auto"):
            sel = select_sensor_orders(
                u[:split],
                y[:split],
                T,
                warmup_samples=WARMUP_SAMPLES,
                initial_state=kind,  # type: ignore[arg-type]
            )
            tables[kind] = {"n_play": sel.n_play, "n_creep": sel.n_creep, "trials": sel.table()}
            ours[kind] = fit_sensor(
                u,
                y,
                T,
                n_play=sel.n_play,
                n_creep=sel.n_creep,
                initial_state=kind,  # type: ignore[arg-type]
                **common,
            )
        t_ours = time.perf_counter() - t0
    caught_all = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
    kb = _best_by_fit(base)
    ko = _best_by_fit({k: ours[k] for k in ("rest", "zero")})  # the two hypotheses, as before
    b, o = base[kb], ours[ko]
    if figure is not None:
        from piezocomp.plotting.fit import plot_sensor_fit

        plot_sensor_fit(
            o, u, y, T, figure,
            title=f"Real piezo record (Aye & Ang 2018, MIT): N_H={o.model.n_play}, "
            f"N_c={o.model.n_creep}, {o.model.n_dead_zones} dead zones, initial state '{ko}'",
        )  # fmt: skip
    if b.validation_errors is None or o.validation_errors is None:  # pragma: no cover
        raise RuntimeError("the split left nothing to validate on.")
    other, test = None, None
    if test_path is not None:
        test = load_test_record(test_path, rec["sensitivity_nm_per_V"], rec["sign_flipped"])
        assert o.reference is not None
        assert o.rest_command_nm is not None and b.rest_command_nm is not None
        refined = o.refinement.model if o.refinement is not None else o.nnls_model
        candidates = {  # each model with the rest command its own fit assumed
            "baseline_plain_pi10": (b.model, b.rest_command_nm),
            "ours": (o.model, o.rest_command_nm),
            "ours_refined": (refined, o.rest_command_nm),  # rest or zero: one rest command
            "reference_plain_nnls": (o.reference.model, o.reference.rest_command_nm),
            "ours_start_estimated": (ours["estimate"].model, ours["estimate"].rest_command_nm),
            "ours_auto": (ours["auto"].model, ours["auto"].rest_command_nm),
        }
        other = {
            "data": str(test_path),
            "n_samples": int(test["u_nm"].size),
            "parts": test["parts"],
            "head_s": HEAD_S,
            "output_range_nm": float(np.ptp(test["y_nm"])),
            "models": {
                name: {
                    s: predict_other_record(m, rest, test, T, s) for s in ("as fitted", "estimate")
                }
                for name, (m, rest) in candidates.items()
            },
        }
    zero = ours["zero"]
    assert zero.reference is not None
    n = u.size
    fit_rows = (np.arange(n) >= WARMUP_SAMPLES) & (np.arange(n) < split)
    asymmetry = asymmetry_probe(
        zero.reference.model, u, y, T, fit_rows, np.arange(n) >= split, test
    )
    return {
        "data": str(path),
        "provenance": PROVENANCE,
        "conversion": {
            "y_nm": "column 5 (um) x 1000",
            "u_nm": "column 1 (V) x sensitivity_nm_per_V (ptp(y) / ptp(V))",
            "sensitivity_nm_per_V": rec["sensitivity_nm_per_V"],
            "sign_flipped": rec["sign_flipped"],
        },
        "n_samples": int(u.size),
        "sample_period_s": T,
        "split_index": split,
        "warmup_samples": WARMUP_SAMPLES,
        "output_range_nm": o.output_range_nm,
        "held_out_cycle_to_cycle_rms_nm": cycle_to_cycle_rms_nm(u, y, split),
        "baseline_plain_pi10": {
            "initial_state": kb,
            "fit": b.fit_errors.as_dict(),
            "validation": b.validation_errors.as_dict(),
            "by_initial_state": {k: f.summary()["nnls"] for k, f in base.items()},
            "seconds": t_base,
        },
        "ours": {
            "initial_state": ko,
            "n_play": o.model.n_play,
            "n_creep": o.model.n_creep,
            "model": o.model.to_dict(),
            "fit": o.fit_errors.as_dict(),
            "validation": o.validation_errors.as_dict(),
            "by_initial_state": {k: f.summary() for k, f in ours.items()},
            "order_selection": tables,
            "seconds": t_ours,
        },
        "validation_rms_ratio_ours_to_baseline": (
            o.validation_errors.rms_nm / b.validation_errors.rms_nm
        ),
        "other_record": other,
        "asymmetry_probe": asymmetry,
        "warnings": caught_all,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument(
        "--test-data", type=Path, default=TEST_DATA,
        help="the instrument's other record, predicted by each model",
    )  # fmt: skip
    parser.add_argument("--figure", type=Path, help="write the fit figure (PNG) here")
    parser.add_argument("--write-csv", type=Path, help="write t_s,u_nm,y_nm for piezocomp fit")
    parser.add_argument("--json", type=Path, help="also write the figures, with the command, here")
    args = parser.parse_args(argv)
    if not args.data.is_file():
        print(f"data not found: {args.data} (see the module docstring)", file=sys.stderr)
        return 2
    if args.write_csv is not None:
        rec = load_record(args.data)
        t = np.arange(rec["u_nm"].size) * rec["sample_period_s"]
        np.savetxt(
            args.write_csv,
            np.column_stack((t, rec["u_nm"], rec["y_nm"])),
            delimiter=",",
            header="t_s,u_nm,y_nm",
            comments="",
            fmt="%.10g",
        )
    if not args.test_data.is_file():
        print(f"data not found: {args.test_data} (see the module docstring)", file=sys.stderr)
        return 2
    out = run(args.data, args.figure, args.test_data)
    trimmed = dict(out)
    trimmed["ours"] = {k: v for k, v in out["ours"].items() if k != "order_selection"}
    trimmed["ours"]["order_selection"] = {
        k: {"n_play": v["n_play"], "n_creep": v["n_creep"]}
        for k, v in out["ours"]["order_selection"].items()
    }
    print(json.dumps(trimmed, indent=2))
    if args.json is not None:
        from piezocomp._atomic import atomic_write_text

        command = "python benchmarks/piezo_record.py " + " ".join(argv or sys.argv[1:])
        atomic_write_text(args.json, json.dumps({"command": command.strip(), **trimmed}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
