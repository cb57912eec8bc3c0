"""A simulator's truth displaced by a known amount no image shows: for testing that a
measured figure is measured (from the instrument's images and records) and a true one true.

:class:`DisplacedTruth` wraps a :class:`~piezocomp.virtual_afm.GroundTruth` and moves
everything it reports by ``velocity_nm_per_s * t``: the tip positions at sample times ``t``
and the particles at the simulator's time now. The instrument is untouched, so its images
and records are exactly those of the real truth. An experiment scored with it must give the
same measured figure as with the real truth and a true figure that follows the displacement:
a measured figure formed from the truth, or a true figure formed from the images, fails.

:class:`DisplacedAFM` is a :class:`~piezocomp.virtual_afm.VirtualAFM` whose ``truth`` is so
displaced, to stand in for the simulator inside ``run_trial`` functions (``monkeypatch``).
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np

from piezocomp.virtual_afm import VirtualAFM

VELOCITY_NM_PER_S = (0.1, 0.05)
"""Default displacement rate of the truth, nm/s: 11 nm over Table I's A1 -> A2 interval of
about 100 s, tens of nm over Fig. 10's assembly."""


class DisplacedTruth:
    """``truth`` moved by ``velocity_nm_per_s * t`` (``clock()`` is the simulator's time now)."""

    def __init__(
        self,
        truth: Any,
        clock: Callable[[], float],
        velocity_nm_per_s: tuple[float, float] = VELOCITY_NM_PER_S,
    ) -> None:
        self.real = truth
        self._clock = clock
        self.velocity_nm_per_s = np.asarray(velocity_nm_per_s, dtype=float)

    def positions_at(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return self.real.positions_at(t) + t[..., None] * self.velocity_nm_per_s

    def particles(self):
        p = self.real.particles()
        return SimpleNamespace(xy_nm=np.asarray(p.xy_nm) + self._clock() * self.velocity_nm_per_s)

    def __getattr__(self, name: str) -> Any:  # push_state, last_record_*, ...: as they are
        return getattr(self.real, name)


class DisplacedAFM(VirtualAFM):
    """A virtual AFM whose ``truth`` is a :class:`DisplacedTruth` (``velocity_nm_per_s``
    keyword, default :data:`VELOCITY_NM_PER_S`); every one made is kept in ``made``."""

    made: ClassVar[list[DisplacedAFM]] = []

    def __init__(
        self, *args: Any, velocity_nm_per_s: tuple[float, float] = VELOCITY_NM_PER_S, **kw: Any
    ) -> None:
        super().__init__(*args, **kw)
        self.truth = DisplacedTruth(self.truth, lambda: self.time_s, velocity_nm_per_s)
        DisplacedAFM.made.append(self)
