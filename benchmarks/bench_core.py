"""Core kernel throughput; the same figures as ``piezocomp bench --json``.

Run: ``python benchmarks/bench_core.py [--samples N] [--json PATH]`` (the figures printed, and
written to ``PATH`` with the command and the machine: docs/core.md's speed table,
``python docs/figures.py run core-speed``).
"""

import argparse
import json
import shlex
import sys
from pathlib import Path

from piezocomp.bench import run_core_benchmark
from piezocomp.io import atomic_write_text


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1_000_000, help="trajectory length")
    ap.add_argument("--json", type=Path, help="write the figures to this file too")
    a = ap.parse_args()
    if a.samples < 1000:
        ap.error(f"--samples must be at least 1000. Got {a.samples}.")
    if a.json is not None and not a.json.resolve().parent.is_dir():
        ap.error(f"--json must be in an existing folder. Got {str(a.json)!r}.")
    figures = run_core_benchmark(a.samples)
    text = json.dumps(figures, indent=2)
    print(text)
    if a.json is not None:
        command = shlex.join(["python", "benchmarks/bench_core.py", *sys.argv[1:]])
        atomic_write_text(a.json, json.dumps({"command": command, **figures}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
