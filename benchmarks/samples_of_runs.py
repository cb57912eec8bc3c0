"""``samples.json`` of the seeds a ``piezocomp reproduce --seeds`` run completed.

A run over many seeds writes ``DIR/samples.json`` only at its end; one stopped early (a
session's time ran out, the machine was needed) leaves a folder ``DIR/seed-N`` per seed it
finished, each with its ``results.json``. This reads those, forms the same median and worst
over them (:func:`piezocomp.experiments.samples.over_samples`) and writes ``DIR/samples.json``
with the command the finished seeds correspond to, so that ``docs/figures.py read`` can quote
them with their true count of seeds::

    python benchmarks/samples_of_runs.py DIR --preset cpr5 --quick

A seed folder without ``results.json`` (the seed that was running when the run stopped) is
left out and listed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from piezocomp._atomic import atomic_write_text
from piezocomp.experiments.samples import over_samples


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path, help="the --out folder of a reproduce --seeds run")
    p.add_argument("--preset", default="cpr5", help="the run's preset (for the command line)")
    p.add_argument("--quick", action="store_true", help="the run was --quick")
    args = p.parse_args(argv)
    done, unfinished = [], []
    for d in sorted(args.folder.glob("seed-*"), key=lambda d: int(d.name[5:] or 0)):
        if not d.name[5:].isdigit():
            continue
        path = d / "results.json"
        if path.is_file():
            done.append((int(d.name[5:]), json.loads(path.read_text(encoding="utf-8"))))
        else:
            unfinished.append(d.name)
    if not done:
        print(f"samples_of_runs: no seed-N/results.json under {args.folder}", file=sys.stderr)
        return 2
    seeds = ",".join(str(s) for s, _ in done)
    summary = over_samples(done)
    quick = " --quick" if args.quick else ""
    summary["command"] = (
        f"piezocomp reproduce --preset {args.preset} --seeds {seeds}{quick} --out {args.folder}"
    )
    atomic_write_text(args.folder / "samples.json", json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.folder / 'samples.json'}: seeds {seeds}")
    if unfinished:
        print(f"left out (no results.json): {', '.join(unfinished)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
