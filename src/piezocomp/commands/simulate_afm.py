"""``piezocomp simulate-afm``: acquire an image on the virtual AFM and write it to a folder.

Writes into ``--out``:

- ``forward.png``, ``backward.png``: the two traces as images (nm colour scale);
- ``image.npz``: ``forward_nm``, ``backward_nm`` (ny, nx), ``x_nm``, ``y_nm`` (command
  axes), ``line_time_s``, ``t_start_s``, ``units``;
- ``config.toml``: the configuration actually used (reloadable with ``--scanner``);
- ``truth_particles.csv``: true particle centres and diameters (nm, sample frame);
- ``truth_tip_nm.npz``: true tip positions of every pixel, forward and backward (ny, nx, 2);
- ``image.gwy``: both traces for Gwyddion (when the ``files`` extra is installed).
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

import numpy as np

from piezocomp._atomic import atomic_write_bytes, atomic_write_text
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import output_folder

__all__ = ["register", "run"]

DESCRIPTION = """Acquire an image on the virtual AFM and write into --out:

  forward.png, backward.png  the two traces as images (nm colour scale)
  image.npz                  forward_nm, backward_nm (ny, nx), x_nm, y_nm (command axes),
                             line_time_s, t_start_s, units
  config.toml                the configuration used (reloadable with --scanner)
  truth_particles.csv        true particle centres and diameters (nm, sample frame)
  truth_tip_nm.npz           true tip position of every pixel, forward and backward
  image.gwy                  both traces for Gwyddion (with the files extra installed)
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``simulate-afm`` subcommand."""
    p = subparsers.add_parser(
        "simulate-afm",
        help=COMMANDS["simulate-afm"][1],
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument("--preset", default=None, help="named preset (default cpr5)")
    src.add_argument("--scanner", default=None, metavar="FILE.toml", help="configuration file")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--seed", type=int, default=None, help="overrides sample.seed")
    p.add_argument("--center-nm", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"))
    p.add_argument("--size-nm", type=float, default=500.0, help="image size (default 500)")
    p.add_argument("--pixels", type=int, default=256, help="pixels per line (default 256)")
    p.add_argument("--line-rate-hz", type=float, default=2.0, help="lines per s (default 2)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the command in its output folder (removed again if it fails while empty)."""
    with output_folder(args.out) as out:
        return _run(args, out)


def _run(args: argparse.Namespace, out: Path) -> int:
    """Run the command; return 0 on success."""
    from piezocomp.io.afm_files import write_gwy
    from piezocomp.io.afm_scan import AfmScan, MissingReaderError
    from piezocomp.plotting.afm import plot_topography
    from piezocomp.virtual_afm import VirtualAFM, config_to_toml, load_config

    cfg = load_config(args.scanner if args.scanner else (args.preset or "cpr5"))
    if args.seed is not None:
        cfg = cfg.with_seed(args.seed)
    afm = VirtualAFM(cfg)
    from tqdm.auto import tqdm

    with tqdm(total=100, disable=not sys.stderr.isatty(), leave=False, desc="image") as bar:

        def progress(fraction: float) -> None:
            bar.update(round(100 * fraction) - bar.n)

        img = afm.scan_image(
            tuple(args.center_nm), args.size_nm, args.pixels, args.line_rate_hz,
            progress=progress,
        )  # fmt: skip
    fwd_true, bwd_true = afm.truth.last_image_positions_nm  # type: ignore[misc]

    buf = io.BytesIO()
    np.savez(
        buf,
        forward_nm=img.forward_nm,
        backward_nm=img.backward_nm,
        x_nm=img.x_nm,
        y_nm=img.y_nm,
        line_time_s=img.line_time_s,
        t_start_s=img.t_start_s,
        units=json.dumps({"heights": "nm", "axes": "nominal command nm", "time": "s"}),
    )
    atomic_write_bytes(out / "image.npz", buf.getvalue())
    buf = io.BytesIO()
    np.savez(buf, forward_nm=fwd_true, backward_nm=bwd_true, x_nm=img.x_nm, y_nm=img.y_nm)
    atomic_write_bytes(out / "truth_tip_nm.npz", buf.getvalue())
    atomic_write_text(out / "config.toml", config_to_toml(cfg))
    parts = afm.truth.particles()
    lines = ["x_nm,y_nm,diameter_nm"]
    lines += [
        f"{x:.6f},{y:.6f},{d:.6f}" for (x, y), d in zip(parts.xy_nm, parts.diameter_nm, strict=True)
    ]
    atomic_write_text(out / "truth_particles.csv", "\n".join(lines) + "\n")
    h = img.pixel_nm / 2
    extent = [img.x_nm[0] - h, img.x_nm[-1] + h, img.y_nm[0] - h, img.y_nm[-1] + h]
    plot_topography(out / "forward.png", img.forward_nm, extent, "forward (trace)")
    plot_topography(out / "backward.png", img.backward_nm, extent, "backward (retrace)")
    written = "forward.png, backward.png, image.npz, config.toml, truth_*"
    scan = AfmScan(
        img.forward_nm,
        img.backward_nm,
        size_nm=(args.size_nm, args.size_nm),
        line_time_s=img.line_time_s,
        channel="height",
        source="piezocomp virtual AFM",
    )
    try:
        write_gwy(out / "image.gwy", scan)
        written += ", image.gwy"
    except MissingReaderError as exc:
        print(f"piezocomp simulate-afm: warning: image.gwy not written: {exc}", file=sys.stderr)
    print(f"wrote {written} to {out}")
    return 0
