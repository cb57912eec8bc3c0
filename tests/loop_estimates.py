"""Synthetic Section IV results for tests of the frame map and the acquisition."""

from __future__ import annotations

import numpy as np

from piezocomp.identification.loop.fit import LoopEstimate
from piezocomp.identification.loop.profile import HeightProfile
from piezocomp.identification.loop.symmetric import SymmetricLoop


def trace_estimate(u_lo: float, u_hi: float, centres, heights) -> LoopEstimate:
    """A LoopEstimate whose forward trace shows Gaussian particles, identity loop."""
    loop = SymmetricLoop(np.array([0.0, 1.0]), u_lo, u_hi)
    u = np.linspace(u_lo, u_hi, int(u_hi - u_lo) + 1)
    z = sum(h * np.exp(-0.5 * ((u - c) / 8.0) ** 2) for c, h in zip(centres, heights, strict=True))
    prof = HeightProfile.from_samples(u, z, lam=1e-6)
    e = np.empty(0)
    return LoopEstimate(u, z, u[::-1], z[::-1], e, e, loop, prof)
