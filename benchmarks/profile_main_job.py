"""Where the main job's computing goes: ``piezocomp reproduce --quick`` stage by stage.

Usage::

    python benchmarks/profile_main_job.py --seeds 1-5 [--preset cpr5] [--json out.json]
    python benchmarks/profile_main_job.py --seeds 1 --cprofile 30
    python benchmarks/profile_main_job.py --runs DIR      # what piezocomp reproduce --seeds saved

For each seed it runs ``reproduce --quick`` (as the command does, on every core) and prints
each stage's computing from ``results.json``'s ``stages_s``: every kind of identification
(both axes) and every experiment's trials, with the number of jobs, their wall-clock seconds
added up over the processes that ran them and their processor seconds (threads included).
Then the run's wall clock and processor time, and over several seeds the median and worst
of the wall clock a sample. ``--runs DIR`` reads the same from the ``results.json`` files a
``piezocomp reproduce --quick --seeds ...`` run saved in ``DIR`` (its wall clock a sample is
then the run's own, without starting the processes). ``--cprofile N`` runs the seeds in
this one process instead
(``workers=1``: slower, every job in turn) under :mod:`cProfile` and prints the ``N``
functions that took the most time of their own. Timings depend on the machine and on what
else runs on it: run it on an idle machine to compare.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import statistics
import sys
import time
from pathlib import Path

from piezocomp._atomic import atomic_write_text
from piezocomp.experiments.reproduce import ReproduceSettings, reproduce
from piezocomp.experiments.samples import parse_seeds
from piezocomp.virtual_afm import load_config
from piezocomp.virtual_afm.config import list_presets


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--seeds", help="sample seeds, e.g. 1-5 (default 1; with --runs, every seed-N saved)"
    )
    p.add_argument("--preset", default="cpr5", help="virtual AFM preset (default cpr5)")
    p.add_argument(
        "--cprofile", type=int, metavar="N", default=0,
        help="run in this process under cProfile and print the N costliest functions",
    )  # fmt: skip
    p.add_argument("--json", type=Path, help="write the per-seed stage tables here")
    p.add_argument("--runs", type=Path, help="read the seeds' results.json from this folder")
    args = p.parse_args(argv)
    if args.preset not in list_presets():
        p.error(f"--preset must be one of {', '.join(list_presets())}. Got {args.preset!r}.")
    if args.cprofile < 0:
        p.error(f"--cprofile must be >= 0. Got {args.cprofile}.")
    if args.runs is not None and args.cprofile:
        p.error("--runs reads saved runs; --cprofile runs them: give one.")
    if args.runs is not None and not args.runs.is_dir():
        p.error(f"--runs {args.runs}: no such folder.")
    if args.json is not None and not args.json.parent.is_dir():
        p.error(f"--json {args.json}: its folder does not exist.")
    if args.seeds is None and args.runs is not None:
        found = sorted(int(d.name[5:]) for d in args.runs.glob("seed-*") if d.name[5:].isdigit())
        if not found:
            p.error(f"--runs {args.runs}: no seed-N folder in it.")
        args.seeds = ",".join(map(str, found))
    try:
        args.seed_list = parse_seeds(args.seeds or "1")
    except ValueError as exc:
        p.error(str(exc))
    return args


def _table(stages: dict, wall: float, cpu: float) -> None:
    print(f"  {'stage':<36s} {'jobs':>5s} {'wall s':>8s} {'CPU s':>8s} {'share':>6s}")
    total = sum(st["cpu_s"] for st in stages.values()) or 1.0
    for name, st in stages.items():
        print(f"  {name:<36s} {st['n']:5.0f} {st['wall_s']:8.1f} {st['cpu_s']:8.1f} "
              f"{100 * st['cpu_s'] / total:5.0f} %")  # fmt: skip
    print(f"  {'the run: wall clock / processor time':<36s} {'':5s} {wall:8.1f} {cpu:8.1f}")


def _saved(runs: Path, seeds: tuple[int, ...]) -> list[dict]:
    """The stage tables of a ``reproduce --seeds`` run saved in ``runs``."""
    rows = []
    for seed in seeds:
        path = runs / f"seed-{seed}" / "results.json"
        if not path.is_file():
            raise SystemExit(f"profile_main_job: {path}: no such file")
        res = json.loads(path.read_text())
        if "stages_s" not in res or not res.get("quick"):
            raise SystemExit(f"profile_main_job: {path}: not a reproduce --quick run with stages")
        stages = res["stages_s"]
        rows.append({
            "seed": seed, "wall_s": res["timing_s"]["total_s"],
            "cpu_s": sum(st["cpu_s"] for st in stages.values()), "stages_s": stages,
        })  # fmt: skip
        print(f"{res['preset']}, seed {seed}, reproduce --quick (saved in {runs}):")
        _table(stages, rows[-1]["wall_s"], rows[-1]["cpu_s"])
    return rows


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    config = load_config(args.preset)
    profile = cProfile.Profile() if args.cprofile else None
    rows = [] if args.runs is None else _saved(args.runs, args.seed_list)
    for seed in args.seed_list if args.runs is None else ():
        settings = ReproduceSettings(
            config=config.with_seed(seed), source=args.preset, seed=seed,
            workers=1 if profile else None,
        ).quick_run()  # fmt: skip
        c0, t0 = time.process_time(), time.perf_counter()
        if profile:
            profile.enable()
        rep = reproduce(settings, progress=False)
        if profile:
            profile.disable()
        wall = time.perf_counter() - t0
        stages = rep.results["stages_s"]
        cpu = sum(st["cpu_s"] for st in stages.values()) + (
            0.0 if profile else time.process_time() - c0  # the parent's own, beside its workers'
        )
        print(f"{args.preset}, seed {seed}, reproduce --quick"
              + (" in one process under cProfile" if profile else "") + ":")  # fmt: skip
        _table(stages, wall, cpu)
        rows.append({"seed": seed, "wall_s": wall, "cpu_s": cpu, "stages_s": stages})
    if len(rows) > 1:
        names = list(dict.fromkeys(n for r in rows for n in r["stages_s"]))
        median = {
            n: {k: statistics.median(r["stages_s"][n][k] for r in rows if n in r["stages_s"])
                for k in ("n", "wall_s", "cpu_s")}
            for n in names
        }  # fmt: skip
        print(f"median over {len(rows)} seeds:")
        _table(median, statistics.median(r["wall_s"] for r in rows),
               statistics.median(r["cpu_s"] for r in rows))  # fmt: skip
        walls = [r["wall_s"] for r in rows]
        cpus = [r["cpu_s"] for r in rows]
        print(f"over {len(rows)} seeds, a sample: wall clock median "
              f"{statistics.median(walls):.0f} s, worst {max(walls):.0f} s; processor time "
              f"median {statistics.median(cpus):.0f} s, worst {max(cpus):.0f} s")  # fmt: skip
    if profile:
        print(f"the {args.cprofile} functions with the most time of their own:")
        pstats.Stats(profile, stream=sys.stdout).sort_stats("tottime").print_stats(args.cprofile)
    if args.json is not None:
        atomic_write_text(args.json, json.dumps({"preset": args.preset, "runs": rows}, indent=2))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
