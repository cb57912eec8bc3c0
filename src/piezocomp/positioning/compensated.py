"""Compensated positioning: an instrument whose positions are true nanometres (eqs 8-13, 2-D).

:class:`CompensatedInstrument` wraps any :class:`~piezocomp.instrument.Instrument` and a
model of each axis and is itself an ``Instrument``: ``move_to``, ``run``, ``scan_image``,
``push`` and ``wait`` take positions in the model's frame (true nanometres, scaled by the
identification's length reference, from an origin the identification cannot observe) and
send the raw instrument the commands that the inverse model computes for them, axis by axis
as the paper does (Sec. V: the x-y coupling is neglected). So code written against
``Instrument`` (the experiments, particle assembly, drift compensation) runs unchanged on
the raw or the compensated instrument.

State. One predicted plant state per axis is carried across every call (images, moves,
pushes, waits), so a long run stays consistent. The compensator enters as the paper does
(Sec. V): :meth:`CompensatedInstrument.initialise` assumes the scanner has rested near its
present command (its slow creep settled), then drives one large cycle over the model's
domain, which sets every play operator's state whatever the history was (the wiping-out
property of hysteresis), and follows it with the model. Creep from motions the compensator
did not see (tens of minutes back) is not known: wait before initialising
(``settle_s``) after such motions.

Safety. Every block of commands is computed in full and checked before anything is sent:
against the raw instrument's range and slew limit and against the model's domain (the
command interval it was identified over), unless extrapolation is allowed. A refused block
leaves the instrument and the predicted state unchanged.

The per-axis compensators (:mod:`.axis_compensation`) are small strategy objects
with explicit state passed in and returned.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar
from piezocomp.instrument import Instrument, Raster, Record, ScanImage, line_path
from piezocomp.limits import CommandLimits
from piezocomp.model import ScannerModel, ScannerModel2D
from piezocomp.positioning.axis_compensation import (
    INITIAL_CYCLE_SPEED_NM_PER_S,
    AxisCompensator,
    ModelAxis,
    working_interval,
)

__all__ = ["CompensatedInstrument"]


class CompensatedInstrument:
    """An :class:`~piezocomp.instrument.Instrument` in true lengths: the raw instrument
    driven through the inverse model of each axis.

    Parameters
    ----------
    instrument : Instrument
        The raw instrument (virtual or real).
    model : ScannerModel2D or (AxisCompensator, AxisCompensator)
        The scanner's model (e.g. a file written by ``piezocomp identify``), or one
        compensator per axis.
    allow_extrapolation : bool
        Send commands outside a model's domain (the command interval it was identified
        over). Default False: such a block is refused before anything moves.
    domain_tolerance : float
        Commands may leave the domain by this fraction of its width before they count as
        outside it (the edge of a steady loop needs a little more command than a slow
        approach).

    Notes
    -----
    Call :meth:`initialise` first (the paper's first large cycle); every motion before it
    is refused. All motion must then go through this object: a motion of the raw
    instrument that it did not send leaves its predicted state wrong.
    """

    def __init__(
        self,
        instrument: Instrument,
        model: ScannerModel2D | tuple[AxisCompensator, AxisCompensator],
        *,
        allow_extrapolation: bool = False,
        domain_tolerance: float = 0.01,
    ) -> None:
        if not isinstance(instrument, Instrument):
            raise TypeError(
                f"instrument must implement Instrument. Got {type(instrument).__name__}."
            )
        if isinstance(model, ScannerModel2D):
            axes: tuple[AxisCompensator, AxisCompensator] = (ModelAxis(model.x), ModelAxis(model.y))
        elif (
            isinstance(model, tuple)
            and len(model) == 2
            and all(isinstance(a, AxisCompensator) for a in model)
        ):
            axes = model
        elif isinstance(model, ScannerModel):
            raise TypeError(
                "model must be a ScannerModel2D (both axes) or a pair of axis compensators. "
                "Got a one-axis ScannerModel: identify both axes over the area you will work "
                "in, e.g. piezocomp identify --axis both --span-nm 2000 "
                "--speed-factors 0.5 1 2 4 8 --out DIR"
            )
        else:
            raise TypeError(
                "model must be a ScannerModel2D or a pair of axis compensators. "
                f"Got {type(model).__name__}."
            )
        tol = check_finite_scalar("domain_tolerance", domain_tolerance)
        if tol < 0:
            raise ValueError(f"domain_tolerance must be >= 0. Got {tol}.")
        self._raw = instrument
        self._axes = axes
        self._extrapolate = bool(allow_extrapolation)
        self._tolerance = tol
        self._limits = CommandLimits.symmetric(
            float(instrument.range_nm), float(instrument.max_speed_nm_per_s)
        )
        self._states: list[Any] | None = None
        self._position = (math.nan, math.nan)
        self._area: tuple[tuple[float, float], tuple[float, float]] | None = None
        self.last_command_nm: NDArray[np.float64] = np.zeros((0, 2))
        """Raw commands of the last block sent (nominal nm), for inspection."""

    # ------------------------------------------------------------------ properties
    @property
    def raw(self) -> Instrument:
        """The wrapped instrument."""
        return self._raw

    @property
    def axes(self) -> tuple[AxisCompensator, AxisCompensator]:
        """The compensators of x and y."""
        return self._axes

    @property
    def sample_period_s(self) -> float:
        """The raw instrument's sample period, s."""
        return float(self._raw.sample_period_s)

    @property
    def range_nm(self) -> float:
        """The raw instrument's command travel, nm (true positions are limited by the
        domain instead: :attr:`working_area_nm`)."""
        return float(self._raw.range_nm)

    @property
    def max_speed_nm_per_s(self) -> float:
        """The raw instrument's slew limit, nm/s (true speeds differ from command speeds by
        the scanner's sensitivity; a block whose commands break the limit is refused)."""
        return float(self._raw.max_speed_nm_per_s)

    @property
    def command_nm(self) -> tuple[float, float]:
        """Position the tip is at now, as the model predicts it (true nm; NaN before
        :meth:`initialise`)."""
        return self._position

    @property
    def time_s(self) -> float:
        """The raw instrument's clock (session time of its next sample), s, if it has one."""
        t = getattr(self._raw, "time_s", None)
        if t is None:
            raise AttributeError("the raw instrument tells no time (time_s).")
        return float(t)

    @property
    def states(self) -> tuple[Any, Any]:
        """Predicted plant state of x and y (e.g. :class:`~piezocomp.model.ModelState`)."""
        return self._require_ready()

    @property
    def working_area_nm(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``((x_lo, x_hi), (y_lo, y_hi))``, true nm: where the tip can be sent with the
        commands inside every domain (:func:`working_interval`)."""
        if self._area is None:
            T = self.sample_period_s
            self._area = (working_interval(self._axes[0], T), working_interval(self._axes[1], T))
        return self._area

    # ------------------------------------------------------------------ entry
    def initialise(
        self,
        *,
        cycles: int = 1,
        speed_nm_per_s: float | None = None,
        settle_s: float = 0.0,
    ) -> Record:
        """Set the model's initial conditions as the paper does: one large cycle.

        The scanner is taken to have rested near its present command (creep settled), after
        waiting ``settle_s`` there. Both axes then run ``cycles`` triangles over their
        domains (to the top corner, to the bottom corner) and go to the domain's centre,
        commanded directly; the models follow. Afterwards every play operator's state is
        set by the cycle alone.

        Returns
        -------
        Record
            The raw record of the cycle (commands, not positions).
        """
        if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 1:
            raise ValueError(f"cycles must be an integer >= 1. Got {cycles!r}.")
        doms = [a.domain_nm for a in self._axes]
        if any(d is None for d in doms):
            raise ValueError(
                "a model states no domain_nm (the command interval it was identified over): "
                "the initial cycle needs it; use a model file written by piezocomp identify."
            )
        lo = [d[0] for d in doms if d is not None]
        hi = [d[1] for d in doms if d is not None]
        v = min(
            INITIAL_CYCLE_SPEED_NM_PER_S if speed_nm_per_s is None else speed_nm_per_s,
            self.max_speed_nm_per_s,
        )
        v = check_finite_scalar("speed_nm_per_s", v)
        if v <= 0:
            raise ValueError(f"speed_nm_per_s must be > 0. Got {speed_nm_per_s}.")
        settle = check_finite_scalar("settle_s", settle_s)
        if settle < 0:
            raise ValueError(f"settle_s must be >= 0. Got {settle}.")
        T = self.sample_period_s
        u0 = np.asarray(self._raw.command_nm, dtype=float)
        corners = [np.array(hi), np.array(lo)] * cycles + [0.5 * (np.array(lo) + np.array(hi))]
        pieces = [np.tile(u0, (round(settle / T), 1))]
        prev = u0
        for c in corners:
            pieces.append(line_path(prev, c, v, T))
            prev = c
        u = np.vstack(pieces)
        self._limits_check(u, T)
        rec = self._raw.run(u)
        states, pos = [], []
        for k, axis in enumerate(self._axes):
            y, st = axis.follow(axis.rest_state(float(u0[k])), u[:, k], T)
            states.append(st)
            pos.append(float(y[-1]))
        self._states = states
        self._position = (pos[0], pos[1])
        self.last_command_nm = u
        return rec

    # ------------------------------------------------------------------ Instrument API
    def run(
        self,
        command_nm: ArrayLike,
        *,
        sample_period_s: float | None = None,
        z_feedback: bool = True,
    ) -> Record:
        """Put the tip along a trajectory of true positions (n, 2), one row per sample.

        The returned :class:`~piezocomp.instrument.Record` holds the desired positions in
        ``command_nm`` (the raw commands are in :attr:`last_command_nm`).
        """
        yd = as_finite_array("positions", command_nm, ndim=2)
        if yd.shape[1] != 2:
            raise ValueError(f"positions must have shape (n, 2). Got {yd.shape}.")
        dt = self.sample_period_s if sample_period_s is None else _period(sample_period_s)
        return self._send(yd, dt, z_feedback=z_feedback, what="run")

    def move_to(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Move along a straight line (true lengths) to ``(x_nm, y_nm)`` at
        ``speed_nm_per_s``, Z feedback on."""
        return self._send(self._line(x_nm, y_nm, speed_nm_per_s), self.sample_period_s,
                          what="move_to")  # fmt: skip

    def push(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Move along a straight line (true lengths) to ``(x_nm, y_nm)`` with Z feedback off,
        pushing what lies in the way."""
        yd = self._line(x_nm, y_nm, speed_nm_per_s)
        return self._send(yd, self.sample_period_s, z_feedback=False, what="push")

    def wait(self, duration_s: float) -> Record:
        """Hold the tip still for ``duration_s`` (rounded to whole samples): the commands
        change as the model's creep requires."""
        d = check_finite_scalar("duration_s", duration_s)
        if d < 0:
            raise ValueError(f"duration_s must be >= 0. Got {d}.")
        self._require_ready()
        yd = np.tile(np.asarray(self._position, float), (round(d / self.sample_period_s), 1))
        return self._send(yd, self.sample_period_s, what="wait")

    def scan_image(
        self,
        center_nm: tuple[float, float],
        size_nm: float,
        pixels: int,
        line_rate_hz: float,
        *,
        fast_axis: str = "x",
    ) -> ScanImage:
        """A square raster image whose pixels are at true positions: the raster is
        compensated line by line at the pixel rate (``1 / (2 pixels line_rate_hz)``).

        Same layout as the raw instrument's images: the tip first moves to the first pixel
        (at the fast-scan speed), each line is forward then backward along ``fast_axis``,
        the other axis steps one pixel per line; pixel ``i`` is at
        ``center - size/2 + (i + 1/2) size/pixels`` (true nm).
        """
        raster = Raster.square(center_nm, size_nm, pixels, line_rate_hz, fast_axis=fast_axis)
        speed = raster.speed_nm_per_s
        if speed > self.max_speed_nm_per_s:
            raise ValueError(
                f"scan speed 2 * size_nm * line_rate_hz = {speed:.6g} nm/s is above "
                f"max_speed_nm_per_s = {self.max_speed_nm_per_s:.6g}; lower line_rate_hz or "
                "size_nm."
            )
        self._require_ready()
        path = raster.positions_nm
        approach = self._line(float(path[0, 0]), float(path[0, 1]), speed)
        # both blocks are planned and checked before the first is sent
        first = self._plan(approach, self.sample_period_s, what="scan_image approach")
        second = self._plan(path, raster.sample_period_s, after=first, what="scan_image")
        self._commit(first, approach, self.sample_period_s)
        rec = self._commit(second, path, raster.sample_period_s)
        return raster.image(rec.height_nm, float(rec.t_s[0]))

    # ------------------------------------------------------------------ internals
    def _require_ready(self) -> tuple[Any, Any]:
        if self._states is None:
            raise RuntimeError(
                "the compensated instrument is not initialised: call initialise() first (a "
                "first large cycle sets the model's initial conditions, as in the paper)."
            )
        return self._states[0], self._states[1]

    def _line(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> NDArray[np.float64]:
        x = check_finite_scalar("x_nm", x_nm)
        y = check_finite_scalar("y_nm", y_nm)
        v = check_finite_scalar("speed_nm_per_s", speed_nm_per_s)
        if v <= 0:
            raise ValueError(f"speed_nm_per_s must be > 0. Got {v}.")
        if v > self.max_speed_nm_per_s:
            raise ValueError(
                f"speed_nm_per_s must be <= max_speed_nm_per_s = {self.max_speed_nm_per_s}. "
                f"Got {v}."
            )
        self._require_ready()
        return line_path(np.asarray(self._position, float), np.array([x, y]), v,
                        self.sample_period_s)  # fmt: skip

    def _limits_check(self, u: NDArray[np.float64], dt: float, prev: Any = None) -> None:
        before = self._raw.command_nm if prev is None else prev
        for k, name in enumerate("xy"):
            self._limits.check(u[:, k], dt, previous_nm=float(before[k]), name=f"command {name}")

    def _plan(
        self,
        yd: NDArray[np.float64],
        dt: float,
        *,
        after: tuple[list[Any], NDArray[np.float64]] | None = None,
        what: str = "motion",
    ) -> tuple[list[Any], NDArray[np.float64]]:
        """Commands for ``yd`` (from the present state, or from ``after``'s), checked
        against the limits and the domains; the states after them."""
        states = list(self._require_ready()) if after is None else list(after[0])
        prev = None if after is None else after[1][-1]
        u = np.empty_like(yd)
        for k, axis in enumerate(self._axes):
            u[:, k], states[k] = axis.command(states[k], yd[:, k], dt)
        if not np.all(np.isfinite(u)):
            raise ValueError(f"{what}: the compensator gave non-finite commands; nothing was sent.")
        self._domain_check(u, yd, what)
        try:
            self._limits_check(u, dt, prev)
        except ValueError as exc:
            raise ValueError(f"{what}: {exc}") from None
        return states, u

    def _domain_check(self, u: NDArray[np.float64], yd: NDArray[np.float64], what: str) -> None:
        if self._extrapolate or u.shape[0] == 0:
            return
        for k, axis in enumerate(self._axes):
            dom = axis.domain_nm
            if dom is None:
                continue
            lo, hi = dom
            slack = self._tolerance * (hi - lo)
            bad = np.flatnonzero((u[:, k] < lo - slack) | (u[:, k] > hi + slack))
            if bad.size:
                i = int(bad[0])
                name = "xy"[k]
                a0, a1 = self.working_area_nm[k]
                where = (
                    f"outside the working area's {name} [{a0:.0f}, {a1:.0f}] nm"
                    if not a0 <= yd[i, k] <= a1
                    else f"inside the working area's {name} [{a0:.0f}, {a1:.0f}] nm, but its "
                    "edge is for steady cycles: the creep of where the tip has been carries "
                    "the command further"
                )
                raise ValueError(
                    f"{what}: position {name} = {yd[i, k]:.1f} nm needs the command "
                    f"{u[i, k]:.1f} nm, outside the model's domain [{lo:g}, {hi:g}] nm (where "
                    f"it was identified; {bad.size} samples outside); nothing was sent. It "
                    f"is {where}: keep farther inside, identify over a larger span, or allow "
                    "extrapolation."
                )

    def _send(
        self, yd: NDArray[np.float64], dt: float, *, z_feedback: bool = True, what: str = "run"
    ) -> Record:
        return self._commit(self._plan(yd, dt, what=what), yd, dt, z_feedback)

    def _commit(
        self,
        plan: tuple[list[Any], NDArray[np.float64]],
        yd: NDArray[np.float64],
        dt: float,
        z_feedback: bool = True,
    ) -> Record:
        """Send planned commands; only once the raw instrument took them, the state moves."""
        states, u = plan
        period = None if dt == self.sample_period_s else dt
        rec = self._raw.run(u, sample_period_s=period, z_feedback=z_feedback)
        self._states = states
        if yd.shape[0]:
            self._position = (float(yd[-1, 0]), float(yd[-1, 1]))
        self.last_command_nm = u
        return Record(rec.t_s, yd, rec.height_nm, rec.timing)


def _period(sample_period_s: float) -> float:
    dt = check_finite_scalar("sample_period_s", sample_period_s)
    if dt <= 0:
        raise ValueError(f"sample_period_s must be > 0. Got {dt}.")
    return dt
