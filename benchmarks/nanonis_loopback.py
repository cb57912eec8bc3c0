"""The Nanonis backend over loopback sockets against its emulator, and the virtual AFM directly.

The acceptance figures of issue 31, each side by side (same preset, seed and settings):

1. **Identification.** The sensorless identification of both axes on the virtual AFM directly
   (``identify_virtual``, x then y on one instrument, as ``piezocomp identify`` does), and
   ``piezocomp identify --instrument nanonis://127.0.0.1:PORT --emulator`` against
   ``piezocomp emulate`` (a subprocess each). Both model files are scored the same way on the
   ground truth of a fresh virtual AFM (:func:`~piezocomp.experiments.scoring.
   score_model_on_truth`: validation over +-1000 nm); printed: the validation max and RMS
   of each, their ratio (sockets / direct; the target is <= 1.5), the held-out heights and
   the orders. The two runs are statistically alike, not identical: where the virtual AFM
   scans an image it draws no height noise for the approach to the first pixel, which the
   backend streams (one Z reading a sample), so the noise draws part after the first image.
2. **Table I, compensated** with the direct run's 2-D model, one instrument each:
   :func:`~piezocomp.experiments.on_instrument.run_experiments` on the virtual AFM directly,
   and ``piezocomp reproduce --instrument ... --methods compensated`` against a fresh
   emulator. Everything the compensator sends is streamed, so the two see the same samples:
   the measured errors (each area, each experiment) must agree within 0.1 nm. Then the same
   uncompensated (the controller's own scans: statistically alike only, as above).
3. **Overhead.** Wall time of each pair, the emulator's scanner time, and the cost of one
   sample: the virtual AFM in one batch, one sample per call, and over the sockets
   (``FolMe.XYPosSet`` + ``ZCtrl.ZPosGet``, the emulator included) unpaced.

The socket runs are paced ``--speedup`` times faster than real time (default 4) with
``--timing flag``: on this shared machine the client cannot always keep 2 ms slots, and the
emulator's clock is the set-point stream, so a late set-point changes no height it measures
(the timing log of each run is printed). 72 minutes on two loaded cores with the standard
settings (docs/instruments.md, "Measured over loopback"); ``--quick`` (both sides) is shorter,
with models far from the standard ones::

    python benchmarks/nanonis_loopback.py [--quick] [--speedup 4] [--out DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import re
import subprocess
import sys
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp.drivers.nanonis import NanonisInstrument
from piezocomp.experiments.on_instrument import InstrumentRunSettings, run_experiments
from piezocomp.experiments.scoring import score_model_on_truth
from piezocomp.experiments.virtual_identification import calibration_record, identify_virtual
from piezocomp.identification.config import IdentifyConfig
from piezocomp.io import atomic_write_text
from piezocomp.io.model_files import load_model, save_model
from piezocomp.model import ScannerModel2D
from piezocomp.virtual_afm import VirtualAFM

PY = [sys.executable, "-m", "piezocomp"]


@contextlib.contextmanager
def emulator(preset: str, seed: int, log: Path) -> Iterator[dict[str, Any]]:
    """``piezocomp emulate`` in a subprocess; yields ``{"url"}``, then (stopped) its summary
    line's figures: set-points, streamed and total scanner time."""
    proc = subprocess.Popen(
        [*PY, "emulate", "--preset", preset, "--seed", str(seed), "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    line = proc.stdout.readline()
    found = re.search(r"listening on (\S+):(\d+)", line)
    if found is None:
        proc.kill()
        raise RuntimeError(f"the emulator did not start: {line!r} {proc.communicate()[1]}")
    info: dict[str, Any] = {"url": f"nanonis://{found[1]}:{found[2]}"}
    try:
        yield info
    finally:
        proc.terminate()  # SIGTERM: stops it as Ctrl-C would (SIGINT may be ignored here)
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
        log.write_text(err)
        done = re.search(r"served (\d+) set-points \((\S+) s of scanner time streamed\), "
                         r"virtual scanner time (\S+) s", err)  # fmt: skip
        if done:
            info.update(set_points=int(done[1]), streamed_s=float(done[2]),
                        scanner_s=float(done[3]))  # fmt: skip


def cli(argv: list[str], log: Path) -> float:
    """Run ``piezocomp ARGV``; its wall time, s (its output in ``log``)."""
    t0 = time.perf_counter()
    proc = subprocess.run([*PY, *argv], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    log.write_text(proc.stdout + proc.stderr)
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"piezocomp {argv[0]} failed ({proc.returncode}); see {log}")
    return wall


def sample_costs(preset: str, seed: int, out: Path, n: int = 2000) -> dict[str, float]:
    """ms per sample: batch, one sample per call, over the sockets unpaced."""
    u = np.column_stack([100.0 * np.sin(0.01 * np.arange(n)), np.zeros(n)])
    afm = VirtualAFM(preset, seed=seed)
    t0 = time.perf_counter()
    afm.run(u)
    batch = time.perf_counter() - t0
    afm = VirtualAFM(preset, seed=seed)
    afm.run(u[:1])  # compiled code loaded
    t0 = time.perf_counter()
    for k in range(1, n):
        afm.run(u[k : k + 1])
    per_call = time.perf_counter() - t0
    with emulator(preset, seed, out / "emulate_costs.log") as emu:
        inst = NanonisInstrument.connect(
            emu["url"], sample_period_s=afm.sample_period_s, max_speed_nm_per_s=2e4,
            speedup=1e6, emulator=True, timing="flag",
        )  # fmt: skip
        inst.run(u[:1])
        t0 = time.perf_counter()
        inst.run(u[1:])
        sockets = time.perf_counter() - t0
        inst.close()
    return {"batch_ms": 1e3 * batch / n, "per_call_ms": 1e3 * per_call / (n - 1),
            "sockets_ms": 1e3 * sockets / (n - 1)}  # fmt: skip


def identification(a: argparse.Namespace, out: Path) -> dict[str, Any]:
    """Both axes, directly and over the sockets; both scored on a fresh virtual AFM."""
    quality = "quick" if a.quick else "standard"
    afm = VirtualAFM(a.preset, seed=a.seed)
    cfg = (IdentifyConfig.quick() if a.quick else IdentifyConfig()).updated(grating=False)
    scan = calibration_record(afm)  # the lab's record, stated to both paths
    if scan is None:
        raise ValueError(f"{a.preset}: no calibration speed was found; choose another preset.")
    cfg = cfg.updated(calibration_speed_nm_per_s=scan.speed_nm_per_s)
    t0 = time.perf_counter()
    direct = {axis: identify_virtual(afm, cfg, axis) for axis in ("x", "y")}
    wall_direct = time.perf_counter() - t0
    model = ScannerModel2D(direct["x"].batch_model, direct["y"].batch_model)
    save_model(out / "direct_model.json", model)
    argv = ["identify", "--instrument", "", "--emulator", "--speedup", f"{a.speedup:g}",
            "--timing", a.timing, "--timing-tolerance", "10",
            "--max-speed-nm-per-s", f"{afm.max_speed_nm_per_s!r}",
            "--sample-period-s", f"{afm.sample_period_s!r}",
            "--calibration-speed-nm-per-s", f"{scan.speed_nm_per_s!r}",
            "--reference", "none", "--no-figures",
            "--out", str(out / "sockets_identify")]  # fmt: skip
    argv += ["--quick"] if a.quick else []
    with emulator(a.preset, a.seed, out / "emulate_identify.log") as emu:
        argv[2] = emu["url"]
        wall_sockets = cli(argv, out / "identify_sockets.log")
    summary = json.loads((out / "sockets_identify" / "summary.json").read_text())
    sockets = load_model(out / "sockets_identify" / "model.json")
    assert isinstance(sockets, ScannerModel2D)
    axes = {}
    for axis in ("x", "y"):
        score = {
            side: score_model_on_truth(VirtualAFM(a.preset, seed=a.seed), getattr(m, axis), axis,
                                       span_nm=cfg.acquisition.span_nm,
                                       speed_nm_per_s=cfg.acquisition.speed_nm_per_s)
            for side, m in (("direct", model), ("sockets", sockets))
        }  # fmt: skip
        s_axis = summary["axes"][axis]
        axes[axis] = {
            "validation": score,
            "ratio_max": score["sockets"]["validation_max_error_nm"]
            / score["direct"]["validation_max_error_nm"],
            "ratio_rms": score["sockets"]["validation_rms_error_nm"]
            / score["direct"]["validation_rms_error_nm"],
            "heldout_batch_nm": {"direct": direct[axis].heldout_rms_nm["batch"],
                                 "sockets": s_axis["heldout_height_rms_nm"]["batch"]},
            "orders": {"direct": [direct[axis].orders.n_play, direct[axis].orders.n_creep],
                       "sockets": [s_axis["orders"]["n_play"], s_axis["orders"]["n_creep"]]},
            "line_slow_nm": {"direct": direct[axis].line.slow_nm if direct[axis].line else None,
                             "sockets": (s_axis["line"] or {}).get("slow_nm")},
        }  # fmt: skip
    return {"settings": quality, "axes": axes, "wall_direct_s": wall_direct,
            "wall_sockets_s": wall_sockets, "emulator": emu,
            "timing": summary["timing"]}  # fmt: skip


def table1(a: argparse.Namespace, out: Path, method: str) -> dict[str, Any]:
    """Table I of ``method`` with the direct run's model, directly and over the sockets."""
    st = InstrumentRunSettings(experiments=("table1",), methods=(method,),
                               distances_nm=tuple(a.distances_nm),
                               table1_experiments=a.experiments)  # fmt: skip
    model = load_model(out / "direct_model.json")
    afm = VirtualAFM(a.preset, seed=a.seed)
    t0 = time.perf_counter()
    direct = run_experiments(afm, model, st, truth=afm.truth)
    wall_direct = time.perf_counter() - t0
    folder = out / f"sockets_table1_{method}"
    argv = ["reproduce", "--instrument", "", "--emulator", "--speedup", f"{a.speedup:g}",
            "--timing", a.timing, "--timing-tolerance", "10",
            "--max-speed-nm-per-s", f"{afm.max_speed_nm_per_s!r}",
            "--sample-period-s", f"{afm.sample_period_s!r}", "--methods", method,
            "--experiments", "table1", "--distances-nm", *(f"{d:g}" for d in a.distances_nm),
            "--table1-experiments", str(a.experiments), "--out", str(folder)]  # fmt: skip
    argv += ["--model", str(out / "direct_model.json")] if method == "compensated" else []
    with emulator(a.preset, a.seed, out / f"emulate_table1_{method}.log") as emu:
        argv[2] = emu["url"]
        wall_sockets = cli(argv, out / f"table1_{method}_sockets.log")
    sockets = json.loads((folder / "results.json").read_text())
    pairs = []
    for rd, rs in zip(direct["table1"], sockets["table1"], strict=True):
        for td, ts in zip(rd["methods"][method]["trials"], rs["methods"][method]["trials"],
                          strict=True):  # fmt: skip
            for area in ("A", "B"):
                pairs.append({"d_nm": rd["d_nm"], "experiment": td["experiment"], "area": area,
                              "direct_nm": td["error_nm"][area],
                              "sockets_nm": ts["error_nm"][area],
                              "true_nm": td["true_error_nm"][area]})  # fmt: skip
    diffs = [abs(p["direct_nm"] - p["sockets_nm"]) for p in pairs
             if p["direct_nm"] is not None and p["sockets_nm"] is not None]  # fmt: skip
    return {"pairs": pairs, "max_difference_nm": max(diffs) if diffs else None,
            "failures": {"direct": direct["failures"], "sockets": sockets["failures"]},
            "wall_direct_s": wall_direct, "wall_sockets_s": wall_sockets, "emulator": emu,
            "timing": sockets["timing"]}  # fmt: skip


def _n(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def report(res: dict[str, Any], a: argparse.Namespace) -> None:
    c = res["costs"]
    print(f"one sample: batch {c['batch_ms']:.4f} ms, one per call {c['per_call_ms']:.3f} ms, "
          f"over the sockets unpaced {c['sockets_ms']:.3f} ms")  # fmt: skip
    idn = res["identification"]
    print(f"identification ({idn['settings']} settings, --reference none, full-range "
          f"calibration), validation on a fresh {a.preset} seed {a.seed}:")  # fmt: skip
    for axis, r in idn["axes"].items():
        d, s = r["validation"]["direct"], r["validation"]["sockets"]
        print(
            f"  {axis}: max {d['validation_max_error_nm']:.2f} direct / "
            f"{s['validation_max_error_nm']:.2f} sockets nm (ratio {r['ratio_max']:.2f}), rms "
            f"{d['validation_rms_error_nm']:.2f} / {s['validation_rms_error_nm']:.2f} nm "
            f"(ratio {r['ratio_rms']:.2f}); held-out heights {r['heldout_batch_nm']['direct']:.2f}"
            f" / {r['heldout_batch_nm']['sockets']:.2f} nm; orders {r['orders']['direct']} / "
            f"{r['orders']['sockets']}; line at {_n(r['line_slow_nm']['direct'])} / "
            f"{_n(r['line_slow_nm']['sockets'])} nm"
        )
    e = idn["emulator"]
    streamed, total = e.get("streamed_s", float("nan")), e.get("scanner_s", float("nan"))
    print(f"  wall: direct {idn['wall_direct_s']:.0f} s, sockets {idn['wall_sockets_s']:.0f} s "
          f"(speedup {a.speedup:g}: {e.get('set_points')} set-points, {streamed:.0f} s streamed "
          f"of {total:.0f} s of scanner time); timing: {idn['timing']}")  # fmt: skip
    for method in ("compensated", "uncompensated"):
        t = res[f"table1_{method}"]
        print(f"Table I {method}, per area (direct / sockets, measured; true on the direct run):")
        for p in t["pairs"]:
            print(
                f"  d = {p['d_nm']:g} nm #{p['experiment']} {p['area']}: "
                f"{_n(p['direct_nm'])} / {_n(p['sockets_nm'])} nm (true {_n(p['true_nm'])})"
            )
        e = t["emulator"]
        print(f"  largest difference {_n(t['max_difference_nm'])} nm; wall: direct "
              f"{t['wall_direct_s']:.1f} s, sockets {t['wall_sockets_s']:.0f} s ("
              f"{e.get('set_points')} set-points, {e.get('scanner_s', float('nan')):.0f} s of "
              f"scanner time); failures {t['failures']}; timing: {t['timing']}")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="cpr5-nodrift")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--quick", action="store_true", help="--quick identification, both sides")
    p.add_argument("--speedup", type=float, default=4.0)
    p.add_argument("--timing", choices=("flag", "raise"), default="flag")
    p.add_argument("--distances-nm", type=float, nargs="+", default=[645.0])
    p.add_argument("--experiments", type=int, default=1, help="Table I's, per distance")
    p.add_argument("--out", default="nanonis_loopback", help="folder for the runs' files")
    a = p.parse_args()
    warnings.simplefilter("ignore")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any] = {"costs": sample_costs(a.preset, a.seed, out)}
    print(f"costs done: {res['costs']}", flush=True)
    res["identification"] = identification(a, out)
    print("identification done", flush=True)
    for method in ("compensated", "uncompensated"):
        res[f"table1_{method}"] = table1(a, out, method)
        print(f"Table I {method} done", flush=True)
    atomic_write_text(out / "benchmark.json", json.dumps(res, indent=2) + "\n")
    report(res, a)


if __name__ == "__main__":
    main()
