"""One axis' compensation: the paper's inverse model, or a static linearisation.

:class:`~piezocomp.positioning.compensated.CompensatedInstrument` drives each axis through an
:class:`AxisCompensator`: :class:`ModelAxis` (the inverse of eqs 8-13 with the model's
state carried) or :class:`StaticAxis` (a memoryless polynomial through the middle of the
steady loop, as instrument software does). :func:`steady_cycle` and
:func:`working_interval` say where an axis' compensated positions can go.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.inverse import compensate
from piezocomp.model import ModelState, ScannerModel, simulate

__all__ = [
    "AREA_MARGIN",
    "INITIAL_CYCLE_SPEED_NM_PER_S",
    "AxisCompensator",
    "ModelAxis",
    "StaticAxis",
    "steady_cycle",
    "working_interval",
]

INITIAL_CYCLE_SPEED_NM_PER_S = 1000.0
"""Speed of the initialising cycle (capped at the instrument's slew limit). Play states after
a cycle do not depend on its speed; the model follows the creep it causes."""

AREA_MARGIN = 0.02
"""The working area is the extension a steady cycle over the domain reaches, less this
fraction of its width on each side (creep and the approach make the edge uncertain)."""


@runtime_checkable
class AxisCompensator(Protocol):
    """What the compensated instrument needs per axis.

    ``state`` is opaque to the instrument: it is created by :meth:`rest_state`, passed in
    and returned, never changed in place.
    """

    @property
    def domain_nm(self) -> tuple[float, float] | None:
        """Command interval the compensator is valid over (``None``: not stated)."""
        ...

    def rest_state(self, u_nm: float) -> Any:
        """State of a scanner that has rested at command ``u_nm``."""
        ...

    def command(
        self, state: Any, y_desired_nm: NDArray[np.float64], sample_period_s: float
    ) -> tuple[NDArray[np.float64], Any]:
        """Commands that put the axis at ``y_desired_nm``; the state after them."""
        ...

    def follow(
        self, state: Any, u_nm: NDArray[np.float64], sample_period_s: float
    ) -> tuple[NDArray[np.float64], Any]:
        """Predicted extension for commands ``u_nm`` sent as they are; the state after."""
        ...


@dataclass(frozen=True)
class ModelAxis:
    """The paper's compensator of one axis: the exact inverse of a creep + PI model.

    Parameters
    ----------
    model : ScannerModel
        The identified forward model (eq 14); its ``domain_nm`` is the compensator's.
    """

    model: ScannerModel

    def __post_init__(self) -> None:
        if not isinstance(self.model, ScannerModel):
            raise TypeError(f"model must be a ScannerModel. Got {type(self.model).__name__}.")

    @property
    def domain_nm(self) -> tuple[float, float] | None:
        """The model's identified command interval."""
        return self.model.domain_nm

    def rest_state(self, u_nm: float) -> ModelState:
        """Play operators centred on ``u_nm``, creep settled there
        (:meth:`ModelState.at_rest`)."""
        return ModelState.at_rest(self.model, u_nm)

    def command(
        self, state: ModelState, y_desired_nm: NDArray[np.float64], sample_period_s: float
    ) -> tuple[NDArray[np.float64], ModelState]:
        """Eqs (9)-(13): creep from past commands, then the inverse PI operator."""
        r = compensate(self.model, y_desired_nm, sample_period_s, state)
        return r.command_nm, r.state

    def follow(
        self, state: ModelState, u_nm: NDArray[np.float64], sample_period_s: float
    ) -> tuple[NDArray[np.float64], ModelState]:
        """Eq (14)."""
        return simulate(self.model, u_nm, sample_period_s, state)


@dataclass(frozen=True)
class StaticAxis:
    """A memoryless linearisation ``y = g(u)`` and its inverse: what an instrument's software
    does to correct the scanner's nonlinearity without hysteresis or creep.

    Parameters
    ----------
    coefficients : array_like
        Polynomial ``g`` (highest power first, :func:`numpy.polyval`), increasing over the
        domain.
    domain_nm : (float, float)
        Command interval the polynomial was fitted over; ``g`` continues linearly beyond
        it (with its slope at the ends).
    """

    coefficients: NDArray[np.float64]
    domain_nm: tuple[float, float]

    def __post_init__(self) -> None:
        c = readonly(as_finite_array("coefficients", self.coefficients, ndim=1))
        lo, hi = (check_finite_scalar("domain_nm", v) for v in self.domain_nm)
        if not lo < hi:
            raise ValueError(f"domain_nm must be lo < hi. Got {self.domain_nm!r}.")
        u = np.linspace(lo, hi, 2001)
        if np.any(np.diff(np.polyval(c, u)) <= 0):
            raise ValueError("coefficients must give a strictly increasing g over domain_nm.")
        object.__setattr__(self, "coefficients", c)
        object.__setattr__(self, "domain_nm", (lo, hi))

    @classmethod
    def from_model(
        cls,
        model: ScannerModel,
        sample_period_s: float,
        *,
        speed_nm_per_s: float = INITIAL_CYCLE_SPEED_NM_PER_S,
        degree: int = 3,
    ) -> StaticAxis:
        """The linearisation a calibration would give for this scanner: the mean of the
        ascending and descending branches of ``model``'s steady cycle over its domain at
        ``speed_nm_per_s``, fitted by a polynomial of ``degree``."""
        if model.domain_nm is None:
            raise ValueError("the model states no domain_nm: a static fit needs its span.")
        lo, hi = model.domain_nm
        up, y_up, down, y_down = steady_cycle(
            ModelAxis(model), sample_period_s, speed_nm_per_s=speed_nm_per_s
        )
        grid = np.linspace(lo, hi, 401)
        mean = 0.5 * (np.interp(grid, up, y_up) + np.interp(grid, down[::-1], y_down[::-1]))
        g = np.polyfit(grid, mean, int(degree))
        return cls(g, (lo, hi))

    def rest_state(self, u_nm: float) -> None:
        """A memoryless map has no state."""
        return None

    def _table(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        lo, hi = self.domain_nm
        u = np.linspace(lo, hi, 4001)
        return u, np.asarray(np.polyval(self.coefficients, u), dtype=np.float64)

    def command(
        self, state: None, y_desired_nm: NDArray[np.float64], sample_period_s: float
    ) -> tuple[NDArray[np.float64], None]:
        """``g^-1(y)`` (tabulated; linear beyond the domain)."""
        u, y = self._table()
        yd = np.asarray(y_desired_nm, dtype=float)
        out = np.interp(yd, y, u)
        s_lo, s_hi = (u[1] - u[0]) / (y[1] - y[0]), (u[-1] - u[-2]) / (y[-1] - y[-2])
        out = np.where(yd < y[0], u[0] + (yd - y[0]) * s_lo, out)
        out = np.where(yd > y[-1], u[-1] + (yd - y[-1]) * s_hi, out)
        return out, None

    def follow(
        self, state: None, u_nm: NDArray[np.float64], sample_period_s: float
    ) -> tuple[NDArray[np.float64], None]:
        """``g(u)`` (linear beyond the domain)."""
        u, y = self._table()
        uu = np.asarray(u_nm, dtype=float)
        out = np.interp(uu, u, y)
        s_lo, s_hi = (y[1] - y[0]) / (u[1] - u[0]), (y[-1] - y[-2]) / (u[-1] - u[-2])
        out = np.where(uu < u[0], y[0] + (uu - u[0]) * s_lo, out)
        out = np.where(uu > u[-1], y[-1] + (uu - u[-1]) * s_hi, out)
        return out, None


def steady_cycle(
    axis: AxisCompensator,
    sample_period_s: float,
    *,
    speed_nm_per_s: float = INITIAL_CYCLE_SPEED_NM_PER_S,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """An axis' predicted steady cycle over its domain at ``speed_nm_per_s``.

    From rest at the domain's centre: up to its top, then two triangles; the last
    ascending and descending branches are returned as ``(u_up, y_up, u_down, y_down)``
    (commands and predicted extensions, in the order they were run).
    """
    if axis.domain_nm is None:
        raise ValueError("the axis states no domain_nm: its steady cycle is unknown.")
    lo, hi = axis.domain_nm
    T = check_finite_scalar("sample_period_s", sample_period_s)
    v = check_finite_scalar("speed_nm_per_s", speed_nm_per_s)
    n = max(8, math.ceil((hi - lo) / (v * T)))
    up = np.linspace(lo, hi, n + 1)[1:]
    down = np.linspace(hi, lo, n + 1)[1:]
    start = np.linspace(0.5 * (lo + hi), hi, n // 2 + 2)[1:]
    u = np.concatenate([start, down, up, down, up, down])
    y, _ = axis.follow(axis.rest_state(0.5 * (lo + hi)), u, T)
    return up, y[-2 * n : -n], down, y[-n:]


def working_interval(
    axis: AxisCompensator,
    sample_period_s: float,
    *,
    speed_nm_per_s: float = INITIAL_CYCLE_SPEED_NM_PER_S,
    margin: float = AREA_MARGIN,
) -> tuple[float, float]:
    """The extension interval (true nm) an axis can be sent to within its domain.

    The ends of its :func:`steady_cycle` (the top of the ascending branch, the bottom of
    the descending one), less ``margin`` of the width on each side.
    """
    _, y_up, _, y_down = steady_cycle(axis, sample_period_s, speed_nm_per_s=speed_nm_per_s)
    top, bottom = float(y_up[-1]), float(y_down[-1])
    m = margin * (top - bottom)
    return bottom + m, top - m
