"""``piezocomp reproduce``: the paper's experiments end to end on the virtual AFM.

Identifies both axes without a sensor (and the comparison models), runs Table I, Figs 8-10
and the speed sweep for every method (:mod:`piezocomp.experiments.reproduce`), and writes
``DIR/results.json``, the figures and ``DIR/report.html``. With ``--instrument``, the
experiments that make sense on a real sample run on it with a given model
(:mod:`.reproduce_instrument`).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from piezocomp._atomic import atomic_write_text, commit_so_far
from piezocomp.commands import COMMANDS
from piezocomp.commands._common import output_folder
from piezocomp.commands.instrument_options import (
    add_instrument_options,
    refuse_instrument_options,
)
from piezocomp.environment import environment

if TYPE_CHECKING:
    from piezocomp.experiments.results import Failure, Results
    from piezocomp.experiments.samples import OverSamples

NAME = "reproduce"


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        NAME,
        help=COMMANDS[NAME][1],
        description=(
            "Identify both axes of a virtual AFM without a sensor, then run Table I, Fig. 8, "
            "Fig. 9, Fig. 10 and the speed sweep for seven methods (uncompensated, static "
            "linearisation, PI without creep, the paper's method as published, the regularised "
            "RLS, the default batch model, the oracle), with errors measured as the paper did "
            "and true; on a drifting scanner (the default cpr5) also the default model inside "
            "the drift compensator ('both', the default method there) and a drift session. "
            "Writes DIR/results.json, DIR/report.html and the figures. With "
            "--instrument: Table I, Fig. 8 and Fig. 9 on a real instrument, uncompensated "
            "and with a given model (--model), measured errors only."
        ),
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument("--preset", default="cpr5", help="virtual AFM preset (default cpr5)")
    src.add_argument("--scanner", help="virtual AFM configuration file (TOML)")
    add_instrument_options(p, src)
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    p.add_argument("--seed", type=int, help="sample seed (default 1)")
    p.add_argument(
        "--seeds",
        metavar="LIST",
        help="run once per sample seed (e.g. 1-10 or 1,4,8), each into DIR/seed-N, and write "
        "DIR/samples.json with the median and worst of the headline figures over them",
    )
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
        "5 with --quick, on a scanner that drifts such as the default cpr5; 0: none)",
    )
    p.add_argument("--workers", type=int, help="parallel processes (default: one per processor)")
    p.add_argument(
        "--dask",
        metavar="ADDRESS",
        help="run the trials on the Dask scheduler at ADDRESS (tcp://host:port) instead",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    g = p.add_argument_group("the experiments on an instrument (with --instrument)")
    g.add_argument("--model", help="the 2-D model file of the compensated method")
    g.add_argument(
        "--experiments",
        nargs="+",
        choices=("table1", "fig8", "fig9"),
        help="which (default table1 fig9)",
    )
    g.add_argument(
        "--methods",
        nargs="+",
        choices=("uncompensated", "compensated"),
        help="which (default uncompensated and compensated with --model, else uncompensated)",
    )
    g.add_argument(
        "--distances-nm", type=float, nargs="+", help="Table I's distances (default 645 951 1150)"
    )
    g.add_argument("--table1-experiments", type=int, help="per distance (default 5)")
    g.add_argument("--speed-nm-per-s", type=float, help="speed of the moves (default 1000)")
    g.add_argument("--settle-s", type=float, help="Table I's rest after its overview (default 300)")
    g.add_argument("--pixels", type=int, help="Table I's and Fig. 9's images (default 64, 128)")
    g.add_argument(
        "--overview-pixels", type=int, help="Table I's and Fig. 8's overviews (default 128, 192)"
    )
    p.set_defaults(func=run)


INSTRUMENT_RUN_OPTIONS = (
    "model", "experiments", "methods", "distances_nm", "table1_experiments", "speed_nm_per_s",
    "settle_s", "pixels", "overview_pixels",
)  # fmt: skip
"""The options of the experiments on an instrument (refused without --instrument)."""

VIRTUAL_RUN_OPTIONS = ("seed", "seeds", "quick", "drift_minutes", "workers", "dask")
"""The virtual run's options (refused with --instrument)."""


def _command(args: argparse.Namespace, seed: int | None = None) -> str:
    parts = ["piezocomp", NAME]
    parts += ["--scanner", args.scanner] if args.scanner else ["--preset", args.preset]
    if seed is None and args.seeds is not None:
        parts += ["--seeds", args.seeds]
    else:
        parts += ["--seed", str(args.seed if seed is None else seed)]
    if args.quick:
        parts.append("--quick")
    if args.drift_minutes is not None:
        parts += ["--drift-minutes", f"{args.drift_minutes:g}"]
    out = args.out if seed is None or args.seeds is None else f"{args.out}/seed-{seed}"
    parts += ["--out", out]
    return " ".join(shlex.quote(p) for p in parts)


def run(args: argparse.Namespace) -> int:
    """Run the command in its output folder (removed again if it fails while empty)."""
    if args.instrument:
        from piezocomp.commands.reproduce_instrument import run_instrument

        given = [k for k in VIRTUAL_RUN_OPTIONS if getattr(args, k) not in (None, False)]
        if given:
            flags = ", ".join("--" + k.replace("_", "-") for k in given)
            raise ValueError(f"{flags}: virtual AFM option(s), not used with --instrument.")
        with output_folder(args.out) as out:
            return run_instrument(args, out)
    refuse_instrument_options(args, also=("sample_period_s", "range_nm", *INSTRUMENT_RUN_OPTIONS))
    if args.seed is not None and args.seeds is not None:
        raise ValueError(
            f"--seed {args.seed} and --seeds {args.seeds}: give one (--seeds runs each of its "
            "seeds; --seed runs one)."
        )
    if args.seed is None:
        args.seed = 1
    with output_folder(args.out) as out:
        return _run(args, out)


def _run(args: argparse.Namespace, out: Path) -> int:
    from piezocomp.experiments.samples import over_samples, parse_seeds
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
    seeds = (args.seed,) if args.seeds is None else parse_seeds(args.seeds)
    if args.seeds is None:
        return _one(args, out, args.seed, config, source)[0]
    runs: list[tuple[int, Results | str]] = []
    codes = []
    for seed in seeds:
        print(f"piezocomp reproduce: sample seed {seed} ({len(runs) + 1} of {len(seeds)})")
        try:
            code, results = _one(args, out / f"seed-{seed}", seed, config, source)
        except (ValueError, RuntimeError) as exc:  # one sample's failure is a figure too
            runs.append((seed, f"{type(exc).__name__}: {exc}"))
            codes.append(1)
            print(f"piezocomp reproduce: seed {seed} failed: {exc}", file=sys.stderr)
            continue
        codes.append(code)
        runs.append((seed, results))
        commit_so_far()  # a sample done is kept if a later one is interrupted
    summary = over_samples(runs)
    summary["command"] = _command(args)
    summary["environment"] = environment()
    atomic_write_text(out / "samples.json", json.dumps(summary, indent=2) + "\n")
    _samples_summary(summary, out)
    return max(codes)


def _one(
    args: argparse.Namespace, out: Path, seed: int, config: Any, source: Any
) -> tuple[int, Results]:
    """One sample's run into ``out``: the exit code and the results."""
    from piezocomp.experiments.report import write_figures, write_report
    from piezocomp.experiments.reproduce import ReproduceSettings, reproduce
    from piezocomp.io.model_files import save_model

    settings = ReproduceSettings(
        config=config.with_seed(seed),
        source=str(source),
        seed=seed,
        workers=args.workers,
        dask_address=args.dask,
        drift_minutes=args.drift_minutes,
    )
    if args.quick:
        settings = settings.quick_run()
    rep = reproduce(settings, progress=not args.no_progress and sys.stderr.isatty())
    command = _command(args, seed)
    rep.results["command"] = command
    rep.results["environment"] = environment()
    atomic_write_text(out / "results.json", json.dumps(rep.results, indent=2) + "\n")
    default = rep.models.models.get("compensated")
    if default is not None:  # the run's default model, to reuse or to look into a result
        save_model(out / "model.json", default, {
            "written_by": "piezocomp reproduce", "method": "compensated",
            "source": str(source), "seed": seed, "command": command,
        })  # fmt: skip
    write_figures(rep, out)
    write_report(rep, out, command=command, config_source=settings.config)
    _summary(rep.results, out)
    if default is not None:
        print(f"wrote the default model {out / 'model.json'}")
    fails = rep.results["failures"]
    for f in fails:
        where = f" ({f['settings']})" if f["settings"] else ""
        print(
            f"piezocomp reproduce: warning: {f['experiment']} / {f['method']}{where} "
            f"failed: {f['error']}",
            file=sys.stderr,
        )
    return (1 if fatal_failures(fails) else 0), rep.results


def fatal_failures(failures: list[Failure]) -> list[Failure]:
    """The failures that fail the run: the default method's, alone or inside the drift
    compensator. A comparison method that failed (no usable model, or a trial its model
    could not run: commands beyond the instrument's limits) is reported, not fatal."""
    from piezocomp.experiments.contract import DRIFT_METHOD

    return [f for f in failures if f["method"] in ("compensated", DRIFT_METHOD)]


def _samples_summary(summary: OverSamples, out: Path) -> None:
    """The figures over samples, in a few lines."""
    from piezocomp.experiments.contract import default_first
    from piezocomp.experiments.samples import HEADLINE_METHODS, FigureStat

    st = summary["statistics"]
    n = len(summary["seeds"])
    print(f"over {n} sample seeds: median / worst (true errors, nm; measured in brackets)")

    def of(fig: FigureStat) -> str:  # the count behind a statistic, when not every seed
        return "" if fig["n"] >= n else f", {fig['n']} of {n}"

    for m in default_first(HEADLINE_METHODS):
        s = st[m]
        if not any(v["n"] for v in s.values()):
            continue  # no drift compensator on a scanner that does not drift
        line = (
            f"  {m}: Table I {_n(s['table1_true_nm']['median'])} / "
            f"{_n(s['table1_true_nm']['worst'])}{of(s['table1_true_nm'])} "
            f"({_n(s['table1_measured_nm']['median'])} / "
            f"{_n(s['table1_measured_nm']['worst'])}{of(s['table1_measured_nm'])}), Fig. 9 "
            f"{_n(s['fig9_true_nm']['median'])} / {_n(s['fig9_true_nm']['worst'])}"
            f"{of(s['fig9_true_nm'])}, Fig. 10 success "
            f"{_pc(s['fig10_true_success']['median'])} / {_pc(s['fig10_true_success']['worst'])}"
        )
        if s["session_true_worst_nm"]["n"]:
            line += (
                f", session worst {_n(s['session_true_worst_nm']['median'])} / "
                f"{_n(s['session_true_worst_nm']['worst'])}, final "
                f"{_n(s['session_true_final_nm']['median'])} / "
                f"{_n(s['session_true_final_nm']['worst'])}"
            )
            if s["session_measuring"]["n"]:
                line += (f" ({_pc(s['session_measuring']['median'])} / "
                         f"{_pc(s['session_measuring']['worst'])} measuring)")  # fmt: skip
        print(line)
    bad = summary["failed_seeds"]
    if bad or summary["runs_with_failures"]:
        print(f"  failed: {sorted(bad) or 'none'}; with failed parts: "
              f"{summary['runs_with_failures'] or 'none'}")  # fmt: skip
    print(f"wrote {out / 'samples.json'}")


def _pc(v: float | None) -> str:
    return "n/a" if v is None else f"{100 * v:.0f} %"


def _summary(res: Results, out: Path) -> None:
    """What the run found, in a few lines."""
    from piezocomp.experiments.contract import DRIFT_METHOD, default_first
    from piezocomp.experiments.drift_session import unresolved_note
    from piezocomp.experiments.fig10 import outcome_text
    from piezocomp.experiments.results import session_methods
    from piezocomp.experiments.samples import HEADLINE_METHODS

    v0 = res["paper"]["speed_nm_per_s"]
    print(
        f"piezocomp reproduce on {res['preset']} (seed {res['seed']}): true (measured) errors, nm"
    )
    for r in res["table1"]:
        if r["speed_nm_per_s"] != v0:
            continue
        cells = []
        for m in default_first(HEADLINE_METHODS):
            if m in r["methods"]:
                t, e = r["methods"][m]["true_max_error_nm"], r["methods"][m]["max_error_nm"]
                part = f", {e['n']} of {t['n']} measurable" if e["n"] < t["n"] else ""
                cells.append(f"{m} {_n(t['mean'])} ({_n(e['mean'])}{part})")
        print(f"  Table I d = {r['d_nm']:g} nm: " + ", ".join(cells))
    f9 = res["fig9"]["methods"]
    print("  Fig. 9: " + ", ".join(
        f"{m} {_n(f9[m]['true_error_nm'])} ({_n(f9[m]['error_nm'])})"
        for m in default_first(HEADLINE_METHODS) if m in f9
    ))  # fmt: skip
    f10 = res["fig10"]["methods"]
    inside = session_methods(res["fig10_drift"]) if "fig10_drift" in res else {}
    for m in default_first(("uncompensated", "compensated", DRIFT_METHOD)):
        got = inside.get(m) if m == DRIFT_METHOD else f10.get(m)
        if got is not None:
            where = " (inside the drift compensator)" if m == DRIFT_METHOD else ""
            print(f"  Fig. 10 / {m}{where}: {outcome_text(got)}")
    comp = f10.get("compensated")
    if comp is not None and "failed_pushes" in comp:
        fp = comp["failed_pushes"]
        rec = comp.get("recoveries") or {}
        print(f"  Fig. 10 / compensated: {sum(fp.values())} failed pushes seen in its images ("
              + ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in fp.items())
              + "); the planner responded: " + ", ".join(
                  f"{v} {_RECOVERY.get(k, k)}" for k, v in rec.items())
              + f"; at the end, the sites of {comp.get('unrecovered', 0)} of these "
              f"{sum(fp.values())} failed pushes still had no particle within "
              f"{res['fig10']['success_nm']:g} nm, retries included (a site can fail more "
              "than once)")  # fmt: skip
    ds = res.get("drift_session")
    if ds:
        print(f"  drift session ({ds['minutes']:g} min), true error worst / final: " + ", ".join(
            f"{m} {_n(sr['true_max_error_nm'])} / "
            f"{_n(None if 'error' in sr else sr['true_final_error_nm'])}"
            + ("" if sr["measurement_overhead_fraction"] is None
               else f" ({100 * sr['measurement_overhead_fraction']:.0f} % measuring)")
            for m, sr in session_methods(ds).items()
        ))  # fmt: skip
        for m, sr in session_methods(ds).items():  # limits by design: said, not failures
            if "error" in sr:
                continue
            name = m
            err = sr["scanner_error_nm"]
            if sr["stopped"]:
                print(f"  drift session / {name} stopped after {sr['images']} images (by design: "
                      f"{sr['limitation']}): {sr['stopped']}")  # fmt: skip
            elif err:
                sx, sy = err
                print(
                    f"  drift session / {name}: its landmarks saw the scanner's own error, "
                    f"{sx:.1f} / {sy:.1f} nm (x / y, a sighting), along with the drift"
                )
            noise = sr["drift_noise"]
            if noise:
                n = noise["learnt_from_measurements"]
                how = (
                    f"learnt from {n} measurements{unresolved_note(noise, ds['minutes'])}"
                    if n
                    else "the generic prior (too few to learn)"
                )
                walk = noise["position_nm_per_sqrt_s"]
                print(f"  drift session / {name}: drift noise {walk:.3g} nm/sqrt(s), {how}")
    stages = res.get("stages_s")
    if stages:
        cpu = sum(st["cpu_s"] for st in stages.values())
        print(f"  computing: {res['timing_s']['total_s']:.0f} s on the clock, {cpu:.0f} s of "
              "processor time in its jobs (" + ", ".join(
                  f"{name} {st['cpu_s']:.0f} s" for name, st in stages.items()) + ")")  # fmt: skip
    print(f"wrote {out / 'results.json'} and {out / 'report.html'}")


_RECOVERY = {
    "pushed_again": "pushed again",
    "another_particle": "took another particle",
    "none": "left alone",
}
"""How the printed summary names what the planner did about a failed push."""


def _n(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"
