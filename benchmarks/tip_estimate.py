"""How well the assembly planner knows its tip: the apex radius estimated from images.

The virtual AFM draws each sample's tip (apex radius and cone half-angle) and never tells
the software; :func:`piezocomp.imaging.tip_estimate.estimate_tip_radius` estimates the
radius from the particles' apparent profiles in an image, with the cone's half-angle taken
from the tip's datasheet (20 degrees). Per seed this images an 800 nm area of the drift-free
``cpr5-nodrift`` sample (200 pixels, 2 lines/s: a small area, so that the scanner's own
distortion stays small), estimates the radius with the datasheet's angle and, for
diagnosis, with the drawn angle (the simulator's, read for scoring only), and prints both
against the drawn radius: what the unknown angle costs beside the estimate's own error.
The planner's contact distance moves about 0.8 nm per nm of radius (15 nm particles, 10 nm
tip, 1 nm push height). About 2 s a seed::

    python benchmarks/tip_estimate.py --seeds 1-10 --json tip.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from piezocomp._atomic import atomic_write_text
from piezocomp.experiments.samples import parse_seeds
from piezocomp.imaging.features import find_particles
from piezocomp.imaging.tip_estimate import estimate_tip_radius
from piezocomp.virtual_afm import VirtualAFM


def one_seed(preset: str, seed: int) -> dict[str, float]:
    """The drawn tip and the two estimates of its radius on one seed's image."""
    afm = VirtualAFM(preset, seed=seed)
    image = afm.scan_image((0.0, 0.0), 800.0, 200, 2.0)
    found = find_particles(image)
    datasheet = estimate_tip_radius(image, found)
    tip = afm.truth.tip  # scoring only
    drawn = estimate_tip_radius(image, found, half_angle_deg=tip.half_angle_deg)
    return {
        "seed": seed, "radius_nm": tip.radius_nm, "half_angle_deg": tip.half_angle_deg,
        "estimate_nm": datasheet.radius_nm, "estimate_std_nm": datasheet.std_nm,
        "estimate_drawn_angle_nm": drawn.radius_nm, "particles": len(found),
    }  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpr5-nodrift")
    ap.add_argument("--seeds", default="1-10", help="e.g. 1-10")
    ap.add_argument("--json", type=Path, help="also write every seed's figures here")
    a = ap.parse_args()
    try:
        seeds = parse_seeds(a.seeds)
        rows = [one_seed(a.preset, s) for s in seeds]
    except ValueError as exc:
        ap.error(str(exc))
    print(f"{'seed':>4s} {'radius':>7s} {'angle':>6s} {'estimate':>9s} {'+-':>5s} "
          f"{'drawn angle':>11s}  (nm, degrees)")  # fmt: skip
    for r in rows:
        print(f"{r['seed']:4d} {r['radius_nm']:7.2f} {r['half_angle_deg']:6.1f} "
              f"{r['estimate_nm']:9.2f} {r['estimate_std_nm']:5.2f} "
              f"{r['estimate_drawn_angle_nm']:11.2f}")  # fmt: skip
    err = np.abs([r["estimate_nm"] - r["radius_nm"] for r in rows])
    err_drawn = np.abs([r["estimate_drawn_angle_nm"] - r["radius_nm"] for r in rows])
    moved = np.abs([r["estimate_nm"] - r["estimate_drawn_angle_nm"] for r in rows])
    summary = {
        "radius_error_nm": [float(np.median(err)), float(err.max())],
        "radius_error_drawn_angle_nm": [float(np.median(err_drawn)), float(err_drawn.max())],
        "angle_effect_nm": [float(np.median(moved)), float(moved.max())],
    }
    for key, (med, worst) in summary.items():
        print(f"{key}: median {med:.2f}, worst {worst:.2f} over {len(rows)} seeds")
    if a.json is not None:
        out = {"command": "python benchmarks/tip_estimate.py " + " ".join(sys.argv[1:]),
               "seeds": list(seeds), "summary": summary, "rows": rows}  # fmt: skip
        atomic_write_text(a.json, json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
