"""``piezocomp bench``: throughput of the core kernels (see :mod:`piezocomp.bench`)."""

from __future__ import annotations

import argparse
import json

from piezocomp.commands import COMMANDS


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "bench",
        help=COMMANDS["bench"][1],
        description=(
            "Time the forward model, the inverse (compensator) and the plain-Python reference "
            "inverse for N_c=2, N_H=8, one streaming step, and the forward and inverse of the same "
            "model with the creep coupling and four dead zones. Compilation is excluded."
        ),
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--samples", type=int, default=1_000_000, help="trajectory length")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from piezocomp.bench import run_core_benchmark

    figures = run_core_benchmark(args.samples)
    if args.json:
        print(json.dumps(figures))
        return 0
    print(f"forward:   {figures['forward_samples_per_s'] / 1e6:8.1f} M samples/s")
    print(f"inverse:   {figures['inverse_samples_per_s'] / 1e6:8.1f} M samples/s")
    print(
        f"reference: {figures['reference_inverse_samples_per_s'] / 1e3:8.1f} k samples/s "
        f"(inverse is {figures['inverse_speedup_over_reference']:.0f}x faster)"
    )
    print(f"stream step: {figures['stream_step_us']:.2f} us per sample")
    print(
        f"with the creep coupling and {figures['asymmetric_dead_zones']} dead zones: forward "
        f"{figures['asymmetric_forward_samples_per_s'] / 1e6:.1f}, inverse "
        f"{figures['asymmetric_inverse_samples_per_s'] / 1e6:.1f} M samples/s"
    )
    return 0
