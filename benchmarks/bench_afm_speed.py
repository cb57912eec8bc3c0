"""Speed of the virtual AFM (issue 3 targets: 256 x 256 image < 2 s, 10-min session < 5 s).

Usage::

    PYTHONPATH=src python benchmarks/bench_afm_speed.py

Prints the wall time of: building the cpr5 instrument, a 256 x 256 image (forward +
backward, 1 Hz), and a 10-minute session at 8 ms sampling (75,000 samples, both axes,
with topography). The first image includes numba compilation when the kernel cache is
cold; the figures after it are warm.
"""

from __future__ import annotations

import time

import numpy as np

from piezocomp.virtual_afm import VirtualAFM


def _timed(label: str, fn):
    t0 = time.perf_counter()
    out = fn()
    dt = time.perf_counter() - t0
    print(f"{label:<58s} {dt:7.3f} s")
    return out, dt


def main() -> int:
    afm, _ = _timed("build VirtualAFM.from_preset('cpr5')", lambda: VirtualAFM.from_preset("cpr5"))
    _timed(
        "256 x 256 image, first call (may compile)",
        lambda: afm.scan_image((0, 0), 1000.0, 256, 1.0),
    )
    _, t_img = _timed(
        "256 x 256 image (forward + backward), warm",
        lambda: afm.scan_image((0, 0), 1000.0, 256, 1.0),
    )
    n = 75_000
    t = np.arange(n) * afm.sample_period_s
    u = np.column_stack([1500 * np.sin(2 * np.pi * t / 37.0), 1200 * np.sin(2 * np.pi * t / 53.0)])
    afm.move_to(*u[0], 2000.0)
    _, t_run = _timed("10-min session at 8 ms (75,000 samples, 2 axes), warm", lambda: afm.run(u))
    print(f"targets: image < 2 s: {t_img < 2.0}; session < 5 s: {t_run < 5.0}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
