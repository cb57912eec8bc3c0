"""Calibration check of the ``cpr5`` preset against the paper's UNCOMPENSATED numbers.

Runs, on the virtual AFM without any compensation, the experiments of Mokaberi & Requicha
(2008) whose uncompensated figures calibrate the scanner, and prints what it measures:

- Fig. 1: a 1000 nm step in y, then successive 100 x 100 nm images (64 px, 18 Hz) for
  180 s: how far the particles appear to move (from the true tip positions).
- Fig. 2: forward/backward line scans of 910 nm at 2 Hz: offset between the traces.
- Fig. 9: path (0.3,0.3) -> (-0.5,-0.3) -> (0.45,0.45) -> (-0.4,-0.4) -> (0.3,0.3) um at
  1 um/s, 253 x 253 nm images before and after: displacement (paper: 14.3 nm).
- Table I: areas A, B (117 x 117 nm) at d = 645, 951, 1150 nm; scan A, random straight
  moves (3 segments) to B, scan B, back to A, scan A, to B, scan B; max of the A-A and B-B
  displacements, mean over 5 experiments (paper: 6.45, 7.03, 9.53 nm).

Displacements are measured two ways: from the ground truth (mean difference of the true
tip positions over the pixels of the two images) and by sub-pixel cross-correlation of
the forward images (scikit-image), as the paper did. The acceptance band is +-30 %.

Usage::

    PYTHONPATH=src python benchmarks/calibrate_cpr5.py [--preset cpr5-nodrift] [--set k=v ...]

``--set scanner.creep=0.04`` (repeatable) overrides a key, for calibration sweeps.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict

import numpy as np
from skimage.registration import phase_cross_correlation

from piezocomp.virtual_afm import VirtualAFM, load_config
from piezocomp.virtual_afm.config import AFMConfig, SampleConfig, ScannerConfig

SPEED = 1000.0  # nm/s, nanomanipulation moves (paper, Section I)
PATH_SPREAD = 0.25  # random intermediate points: +- this fraction of d around the A-B segment
FIG9_IMAGE = (128, 2.0)  # pixels, line rate (Hz)
TABLE_IMAGE = (64, 2.0)
PAPER = {"fig9": 14.3, 645: 6.45, 951: 7.03, 1150: 9.53}


def displacement(afm: VirtualAFM, a, b, img_a, img_b) -> tuple[float, float]:
    """(ground-truth, cross-correlation) displacement between two images, nm."""
    pa = a[0].reshape(-1, 2)
    pb = b[0].reshape(-1, 2)
    truth = float(np.hypot(*(pb - pa).mean(axis=0)))
    shift, _, _ = phase_cross_correlation(
        img_a.forward_nm, img_b.forward_nm, upsample_factor=50, normalization=None
    )
    xc = float(np.hypot(*shift) * img_a.pixel_nm)
    return truth, xc


def image(afm: VirtualAFM, center, size, pixels=128, rate=4.0):
    img = afm.scan_image(center, size, pixels, rate)
    return img, afm.truth.last_image_positions_nm


def fig1(cfg: AFMConfig) -> float:
    afm = VirtualAFM(cfg, start_nm=(0.0, -500.0))
    afm.wait(10.0)
    afm.move_to(0.0, 500.0, afm.max_speed_nm_per_s)  # the step, as fast as the slew limit allows
    ys = []
    t0 = afm.time_s
    while afm.time_s - t0 < 180.0:
        afm.scan_image((0.0, 500.0), 100.0, 64, 18.0)
        ys.append(afm.truth.last_image_positions_nm[0][..., 1].mean())
    return float(ys[-1] - ys[0])


def fig2(cfg: AFMConfig) -> tuple[float, float, float]:
    afm = VirtualAFM(cfg)
    T = afm.sample_period_s
    x0, x1 = -455.0, 455.0
    afm.move_to(x0, 0.0, SPEED)
    n = round(0.25 / T)  # 2 Hz: 0.25 s per trace
    ramp = np.linspace(x0, x1, n)
    line = np.concatenate([ramp, ramp[::-1]])
    for _ in range(3):
        afm.run(np.column_stack([line, np.zeros_like(line)]))
    pos = afm.truth.last_record_positions_nm[:, 0]
    fwd, bwd = pos[:n], pos[n:][::-1]
    d = bwd - fwd
    # where a feature at true position p appears on each trace (command), p in the overlap
    p = np.linspace(max(fwd.min(), bwd.min()), min(fwd.max(), bwd.max()), 200)
    shift = np.interp(p, fwd, ramp) - np.interp(p, bwd, ramp)
    return float(np.max(np.abs(d))), float(np.mean(np.abs(d))), float(np.max(np.abs(shift)))


def fig9(cfg: AFMConfig) -> tuple[float, float]:
    afm = VirtualAFM(cfg)
    afm.move_to(300.0, 300.0, SPEED)
    a = image(afm, (300.0, 300.0), 253.0, *FIG9_IMAGE)
    pa = afm.truth.last_image_positions_nm
    for x, y in [(-500, -300), (450, 450), (-400, -400), (300, 300)]:
        afm.move_to(x, y, SPEED)
    b = image(afm, (300.0, 300.0), 253.0, *FIG9_IMAGE)
    return displacement(afm, pa, afm.truth.last_image_positions_nm, a[0], b[0])


def table1(cfg: AFMConfig, d: float, seed: int, from_rest: bool = False) -> tuple[float, float]:
    rng = np.random.default_rng(1000 + seed)
    afm = VirtualAFM(cfg.with_seed(seed))
    phi = rng.uniform(0, 2 * np.pi)
    mid = rng.uniform(-300, 300, 2)
    u = np.array([np.cos(phi), np.sin(phi)])
    A, B = mid - 0.5 * d * u, mid + 0.5 * d * u
    size = 117.0
    corner = np.array([-size / 2, -size / 2])

    def random_path(p0, p1):
        # two random intermediate points near the segment: three straight segments
        pts = []
        for f in sorted(rng.uniform(0.15, 0.85, 2)):
            pts.append(p0 + f * (p1 - p0) + rng.uniform(-PATH_SPREAD * d, PATH_SPREAD * d, 2))
        return [*pts, p1 + corner]

    # the tip comes from area B (as after a previous experiment): B's corner, a scan of
    # B, then random moves to A. Every leg draws its own random moves. With from_rest,
    # the tip goes straight from rest at (0, 0) (demagnetised) to A instead.
    if from_rest:
        afm.move_to(*(A + corner), SPEED)
    else:
        afm.move_to(*(B + corner), SPEED)
        image(afm, tuple(B), size, *TABLE_IMAGE)
    shots = {}
    for tag, target, origin in (("A1", A, B), ("B1", B, A), ("A2", A, B), ("B2", B, A)):
        if not (from_rest and tag == "A1"):
            for p in random_path(origin, target):
                afm.move_to(*p, SPEED)
        img, _ = image(afm, tuple(target), size, *TABLE_IMAGE)
        shots[tag] = (img, afm.truth.last_image_positions_nm)
    ea = displacement(afm, shots["A1"][1], shots["A2"][1], shots["A1"][0], shots["A2"][0])
    eb = displacement(afm, shots["B1"][1], shots["B2"][1], shots["B1"][0], shots["B2"][0])
    return max(ea[0], eb[0]), max(ea[1], eb[1])


def _override(cfg: AFMConfig, sets: list[str]) -> AFMConfig:
    sc, sa = asdict(cfg.scanner), asdict(cfg.sample)
    for item in sets:
        key, _, val = item.partition("=")
        sec, _, name = key.partition(".")
        target = {"scanner": sc, "sample": sa}[sec]
        if name not in target:
            raise SystemExit(f"unknown key {key}")
        target[name] = type(target[name])(float(val)) if name != "seed" else int(val)
    return AFMConfig(ScannerConfig(**sc), SampleConfig(**sa), cfg.description)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5-nodrift")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--runs", type=int, default=20, help="experiments per Table I row")
    ap.add_argument(
        "--from-rest",
        action="store_true",
        help="Table I variant: go from rest at (0, 0) straight to A (first visit on the "
        "virgin curve) instead of arriving from B",
    )
    args = ap.parse_args(argv)
    cfg = _override(load_config(args.preset), args.set)
    t0 = time.perf_counter()
    s = cfg.scanner
    print(
        f"preset {args.preset}: hysteresis {s.hysteresis}, hysteresis_small {s.hysteresis_small}, "
        f"creep {s.creep}, asymmetry {s.hysteresis_asymmetry}, saturation "
        f"{s.hysteresis_saturation}"
    )
    print(f"Fig. 1  y shift of the images from the first to the one at 180 s: {fig1(cfg):7.2f} nm")
    mx, mean, shift = fig2(cfg)
    print(
        f"Fig. 2  forward/backward true offset, 910 nm at 2 Hz: max {mx:.2f} nm, mean "
        f"{mean:.2f} nm; apparent shift of a particle between the traces up to {shift:.1f} nm"
    )
    ok = True
    tr, xc = fig9(cfg)
    lo, hi = 0.7 * PAPER["fig9"], 1.3 * PAPER["fig9"]
    ok &= lo <= tr <= hi
    print(
        f"Fig. 9  back-to-start displacement: truth {tr:6.2f} nm, cross-corr {xc:6.2f} nm "
        f"(paper 14.3, band [{lo:.1f}, {hi:.1f}])"
    )
    for d in (645, 951, 1150):
        res = np.array([table1(cfg, float(d), k, args.from_rest) for k in range(args.runs)])
        m, sd = res.mean(axis=0), res.std(axis=0)
        lo, hi = 0.7 * PAPER[d], 1.3 * PAPER[d]
        ok &= lo <= m[0] <= hi
        print(
            f"Table I d={d:5d} nm: truth {m[0]:5.2f} +- {sd[0]:4.2f} nm, cross-corr "
            f"{m[1]:5.2f} +- {sd[1]:4.2f} nm (paper {PAPER[d]}, band [{lo:.2f}, {hi:.2f}])"
        )
    print(f"all ground-truth figures within +-30 %: {ok}  ({time.perf_counter() - t0:.1f} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
