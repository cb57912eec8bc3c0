"""``piezocomp reproduce``: the paper's experiments end to end on the virtual AFM.

Identifies both axes without a sensor (and the comparison models), runs Table I, Figs 8-10
and the speed sweep for every method (:mod:`piezocomp.experiments.reproduce`), and writes
``DIR/results.json``, the figures and ``DIR/report.html``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any

from piezocomp._atomic import atomic_write_text
from piezocomp.commands._common import output_folder

NAME = "reproduce"


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        NAME,
        help="the paper's experiments (Table I, Figs 8-10) end to end on the virtual AFM",
        description=(
            "Identify both axes of a virtual AFM without a sensor, then run Table I, Fig. 8, "
            "Fig. 9, Fig. 10 and the speed sweep for six methods (uncompensated, static "
            "linearisation, PI without creep, the paper's RLS, the default batch model, the "
            "oracle), with errors measured as the paper did and true. Writes "
            "DIR/results.json, DIR/report.html and the figures."
        ),
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument("--preset", default="cpr5", help="virtual AFM preset (default cpr5)")
    src.add_argument("--scanner", help="virtual AFM configuration file (TOML)")
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    p.add_argument("--seed", type=int, default=1, help="sample seed (default 1)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="reduced run: Table I at 1 um/s only with the paper's 5 experiments per "
        "distance (the full run: 20, at every speed), two assemblies per method",
    )
    p.add_argument(
        "--drift-minutes",
        type=float,
        help="length of the drift session run with and without each compensator (default: 20, "
        "5 with --quick, on a scanner that drifts such as cpr5-drift; 0: none)",
    )
    p.add_argument("--workers", type=int, help="parallel processes (default: one per processor)")
    p.add_argument(
        "--dask",
        metavar="ADDRESS",
        help="run the trials on the Dask scheduler at ADDRESS (tcp://host:port) instead",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def _command(args: argparse.Namespace) -> str:
    parts = ["piezocomp", NAME]
    parts += ["--scanner", args.scanner] if args.scanner else ["--preset", args.preset]
    parts += ["--seed", str(args.seed)]
    if args.quick:
        parts.append("--quick")
    if args.drift_minutes is not None:
        parts += ["--drift-minutes", f"{args.drift_minutes:g}"]
    parts += ["--out", args.out]
    return " ".join(shlex.quote(p) for p in parts)


def run(args: argparse.Namespace) -> int:
    """Run the command in its output folder (removed again if it fails while empty)."""
    with output_folder(args.out) as out:
        return _run(args, out)


def _run(args: argparse.Namespace, out: Path) -> int:
    from piezocomp.experiments.report import write_figures, write_report
    from piezocomp.experiments.reproduce import ReproduceSettings, reproduce
    from piezocomp.virtual_afm import load_config
    from piezocomp.virtual_afm.config import list_presets

    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0. Got {args.seed}.")
    if args.drift_minutes is not None and not 0 <= args.drift_minutes <= 600:
        raise ValueError(f"--drift-minutes must be in [0, 600]. Got {args.drift_minutes}.")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1. Got {args.workers}.")
    if args.scanner:
        source: Any = args.scanner
        config = load_config(args.scanner)
    else:
        if args.preset not in list_presets():
            raise ValueError(f"unknown preset {args.preset!r}. Known: {', '.join(list_presets())}.")
        source = args.preset
        config = load_config(args.preset)
    settings = ReproduceSettings(
        config=config.with_seed(args.seed),
        source=str(source),
        seed=args.seed,
        workers=args.workers,
        dask_address=args.dask,
        drift_minutes=args.drift_minutes,
    )
    if args.quick:
        settings = settings.quick_run()
    rep = reproduce(settings, progress=not args.no_progress and sys.stderr.isatty())
    command = _command(args)
    rep.results["command"] = command
    atomic_write_text(out / "results.json", json.dumps(rep.results, indent=2) + "\n")
    write_figures(rep, out)
    write_report(rep, out, command=command, config_source=settings.config)
    _summary(rep.results, out)
    if rep.results["failures"]:
        for f in rep.results["failures"]:
            print(
                f"piezocomp reproduce: warning: {f['experiment']} / {f['method']} "
                f"({f['settings']}) failed: {f['error']}",
                file=sys.stderr,
            )
        return 1
    return 0


def _summary(res: dict[str, Any], out: Path) -> None:
    """What the run found, in a few lines."""
    v0 = res["paper"]["speed_nm_per_s"]
    print(
        f"piezocomp reproduce on {res['preset']} (seed {res['seed']}): true (measured) errors, nm"
    )
    for r in res["table1"]:
        if r["speed_nm_per_s"] != v0:
            continue
        cells = []
        for m in ("uncompensated", "compensated"):
            if m in r["methods"]:
                t, e = r["methods"][m]["true_max_error_nm"], r["methods"][m]["max_error_nm"]
                cells.append(f"{m} {_n(t['mean'])} ({_n(e['mean'])})")
        print(f"  Table I d = {r['d_nm']:g} nm: " + ", ".join(cells))
    f9 = res["fig9"]["methods"]
    print("  Fig. 9: " + ", ".join(
        f"{m} {_n(f9[m]['true_error_nm'])} ({_n(f9[m]['error_nm'])})"
        for m in ("uncompensated", "compensated") if m in f9
    ))  # fmt: skip
    f10 = res["fig10"]["methods"]
    print("  Fig. 10 success: " + ", ".join(
        f"{m} {100 * f10[m]['true_success_rate']:.0f} %"
        for m in ("uncompensated", "compensated") if m in f10
    ))  # fmt: skip
    fd = res.get("fig10_drift")
    if fd and fd["methods"].get("both"):
        both = fd["methods"]["both"]
        rate, worst = both["true_success_rate"], both["true_max_error_nm"]["mean"]
        print(f"  Fig. 10 inside the drift compensator: {100 * rate:.0f} % "
              f"(worst true error {_n(worst)} nm on average)")  # fmt: skip
    ds = res.get("drift_session")
    if ds:
        print(f"  drift session ({ds['minutes']:g} min), worst true error: " + ", ".join(
            f"{m} {_n(r['true_max_error_nm'])}"
            + ("" if r["measurement_overhead_fraction"] is None
               else f" ({100 * r['measurement_overhead_fraction']:.0f} % measuring)")
            for m, r in ds["methods"].items()
        ))  # fmt: skip
    print(f"wrote {out / 'results.json'} and {out / 'report.html'}")


def _n(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"
