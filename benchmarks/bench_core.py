"""Core kernel throughput; the same figures as ``piezocomp bench --json``.

Run: ``python benchmarks/bench_core.py [n_samples]``.
"""

import json
import sys

from piezocomp.bench import run_core_benchmark

if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    print(json.dumps(run_core_benchmark(n), indent=2))
