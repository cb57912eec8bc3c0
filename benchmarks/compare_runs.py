"""Compare two output folders of piezocomp commands key by key, timings aside.

Every JSON file present in both folders (``summary.json``, ``model.json``, ``results.json``,
...) is walked as a tree; each leaf that differs is printed with its path. Keys that hold a
timing (``timing``, ``timing_s``, ``computing_s``, ``cpu_s``, ``total_wall``, ...), the run's
own paths and the keys given with ``--ignore`` are skipped. Numbers are equal when they are
equal to ``--rtol`` (default 0: identical). Files present in one folder only are listed.

    python benchmarks/compare_runs.py BEFORE_DIR AFTER_DIR [--ignore settings] [--rtol 0]

Exit status 0 when nothing differs, 1 otherwise. Used to check that a restructuring of the
code changes no figure (issue 46).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

TIMING_KEYS = {
    "timing", "timing_s", "computing_s", "cpu_s", "total_wall", "wall_s", "elapsed_s",
    "identification_computing_per_axis", "total_computing",
}  # fmt: skip
"""Keys whose values are measured times, never compared."""


def _leaves_differ(a: Any, b: Any, path: str, rtol: float, ignore: set[str], out: list[str]):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in TIMING_KEYS or k in ignore:
                continue
            if k not in a or k not in b:
                out.append(f"{path}/{k}: only in {'after' if k not in a else 'before'}")
                continue
            _leaves_differ(a[k], b[k], f"{path}/{k}", rtol, ignore, out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: length {len(a)} != {len(b)}")
            return
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _leaves_differ(x, y, f"{path}[{i}]", rtol, ignore, out)
    elif (
        isinstance(a, (int, float))
        and isinstance(b, (int, float))
        and not isinstance(a, bool)
        and not isinstance(b, bool)
    ):
        same = a == b or (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=rtol)
        if not same:
            out.append(f"{path}: {a!r} != {b!r}")
    elif a != b:
        out.append(f"{path}: {str(a)[:80]!r} != {str(b)[:80]!r}")


def compare(before: Path, after: Path, rtol: float = 0.0, ignore: set[str] | None = None):
    """The differences between the JSON files of two folders (recursively), as lines."""
    ignore = set() if ignore is None else ignore
    out: list[str] = []
    names_a = {p.relative_to(before) for p in before.rglob("*.json")}
    names_b = {p.relative_to(after) for p in after.rglob("*.json")}
    for name in sorted(names_a ^ names_b):
        out.append(f"{name}: only in {'before' if name in names_a else 'after'}")
    for name in sorted(names_a & names_b):
        a = json.loads((before / name).read_text())
        b = json.loads((after / name).read_text())
        _leaves_differ(a, b, str(name), rtol, ignore, out)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("before", type=Path)
    p.add_argument("after", type=Path)
    p.add_argument("--rtol", type=float, default=0.0, help="relative tolerance (default 0)")
    p.add_argument("--ignore", nargs="*", default=[], help="further keys to skip")
    args = p.parse_args(argv)
    for d in (args.before, args.after):
        if not d.is_dir():
            print(f"compare_runs: {d} is not a folder", file=sys.stderr)
            return 2
    diffs = compare(args.before, args.after, args.rtol, set(args.ignore))
    for line in diffs:
        print(line)
    n = len(list(args.before.rglob("*.json")))
    print(f"{len(diffs)} difference(s) over {n} JSON file(s) of {args.before}")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
