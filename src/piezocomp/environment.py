"""What a figure was computed with: the package, the numerical libraries and the processor.

The virtual AFM and the identification are deterministic for a seed, but only on the same
software and processor: the sensorless estimation iterates thousands of least-squares and
recursive updates, and another numpy, scipy or numba (or a processor whose vector units make
the compiler group sums differently) rounds some operations differently, which the
iterations carry into the figures. ``results.json`` and the docs' generated figures record
this environment, so that a figure can be compared with the run that made it.
"""

from __future__ import annotations

import platform
from importlib import metadata
from typing import Any

__all__ = ["LIBRARIES", "environment"]

LIBRARIES = ("numpy", "scipy", "numba", "llvmlite", "scikit-image", "joblib")
"""The distributions whose versions are recorded."""


def environment() -> dict[str, Any]:
    """The package's version, Python, each of :data:`LIBRARIES` (``None`` if absent), the
    machine and the processor the compiled kernels target (llvmlite's host CPU name)."""
    versions: dict[str, str | None] = {}
    for name in ("piezocomp", *LIBRARIES):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    try:
        import llvmlite.binding as llvm

        cpu = str(llvm.get_host_cpu_name())
    except (ImportError, RuntimeError):  # pragma: no cover - numba needs llvmlite
        cpu = None
    return {
        "python": platform.python_version(),
        "versions": versions,
        "machine": platform.machine(),
        "cpu": cpu,
    }
