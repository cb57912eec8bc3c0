"""An instrument whose scanner IS a given model (eq 14): for checking the mathematics of the
compensated instrument only, never for validating an identification.

Heights: Gaussian bumps of 10 nm at fixed true positions (``bumps_nm``), so images have
features. Every true position is logged for the tests.
"""

from __future__ import annotations

import math

import numpy as np

from piezocomp.instrument import Raster, Record
from piezocomp.limits import CommandLimits
from piezocomp.model import ModelState, ScannerModel2D, simulate


class ModelInstrument:
    """Exact-model plant of both axes, at rest at ``start_nm``."""

    def __init__(
        self,
        model: ScannerModel2D,
        *,
        sample_period_s: float = 0.008,
        range_nm: float = 5000.0,
        max_speed_nm_per_s: float = 20000.0,
        start_nm: tuple[float, float] = (0.0, 0.0),
        bumps_nm: np.ndarray | None = None,
    ) -> None:
        self.model = model
        self._T = sample_period_s
        self._range = range_nm
        self._vmax = max_speed_nm_per_s
        self._limits = CommandLimits.symmetric(range_nm, max_speed_nm_per_s)
        self._u = (float(start_nm[0]), float(start_nm[1]))
        axes = (model.x, model.y)
        self.states = [ModelState.at_rest(m, u) for m, u in zip(axes, self._u, strict=True)]
        self._t = 0.0
        self.bumps_nm = np.zeros((0, 2)) if bumps_nm is None else np.asarray(bumps_nm, float)
        self.true_log: list[np.ndarray] = []
        self.pushed: list[np.ndarray] = []

    sample_period_s = property(lambda self: self._T)
    range_nm = property(lambda self: self._range)
    max_speed_nm_per_s = property(lambda self: self._vmax)
    command_nm = property(lambda self: self._u)

    def _heights(self, pos: np.ndarray) -> np.ndarray:
        h = np.zeros(pos.shape[0])
        for b in self.bumps_nm:
            h += 10.0 * np.exp(-np.sum((pos - b) ** 2, axis=1) / (2 * 8.0**2))
        return h

    def run(self, command_nm, *, sample_period_s=None, z_feedback=True):
        u = np.asarray(command_nm, float)
        dt = self._T if sample_period_s is None else float(sample_period_s)
        for k in range(2):
            self._limits.check(u[:, k], dt, previous_nm=self._u[k])
        pos = np.empty_like(u)
        for k, m in enumerate((self.model.x, self.model.y)):
            pos[:, k], self.states[k] = simulate(m, u[:, k], dt, self.states[k])
        t = self._t + dt * np.arange(u.shape[0])
        self._t += dt * u.shape[0]
        if u.shape[0]:
            self._u = (float(u[-1, 0]), float(u[-1, 1]))
        self.true_log.append(pos)
        if not z_feedback:
            self.pushed.append(pos)
        h = self._heights(pos) if z_feedback else np.full(u.shape[0], np.nan)
        return Record(t, u, h)

    def _line(self, x, y, v):
        x0, y0 = self._u
        n = max(1, math.ceil(math.hypot(x - x0, y - y0) / (v * self._T)))
        f = np.arange(1, n + 1) / n
        return np.column_stack([x0 + (x - x0) * f, y0 + (y - y0) * f])

    def move_to(self, x_nm, y_nm, speed_nm_per_s):
        return self.run(self._line(x_nm, y_nm, speed_nm_per_s))

    def push(self, x_nm, y_nm, speed_nm_per_s):
        return self.run(self._line(x_nm, y_nm, speed_nm_per_s), z_feedback=False)

    def wait(self, duration_s):
        return self.run(np.tile(self._u, (round(duration_s / self._T), 1)))

    def scan_image(self, center_nm, size_nm, pixels, line_rate_hz, *, fast_axis="x"):
        raster = Raster.square(center_nm, size_nm, pixels, line_rate_hz, fast_axis=fast_axis)
        self.move_to(*raster.positions_nm[0], raster.speed_nm_per_s)
        rec = self.run(raster.positions_nm, sample_period_s=raster.sample_period_s)
        return raster.image(rec.height_nm, float(rec.t_s[0]))
