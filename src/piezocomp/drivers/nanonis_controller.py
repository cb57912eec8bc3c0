"""What the Nanonis backend reads from and sets on a controller when it connects.

:func:`read_controller` reads the lateral range (``Piezo.RangeGet``) and calibration
(``Piezo.SensGet``), refuses a controller whose Z feedback is off (``ZCtrl.OnOffGet``), and
switches the controller's constant-velocity drift ramp off (``Piezo.DriftCompGet``,
``Piezo.DriftCompSet``) or keeps it and says so, so that two drift corrections never stack.
The result is a :class:`ControllerState` (nm, nm/s), reported by every command that connects.

:data:`EMULATOR_CLOCK_COMMAND` is the one call that is not Nanonis's: the emulator
(:mod:`.nanonis_emulator`) runs its virtual scanner one sample per set-point, so it must be
told the period of each path, and how much faster than real time the client paces (its own
scans and waiting moves then last as long on the client's clock); the backend sends it only
when told it talks to the emulator, never to a controller (which runs in real time).

Imports only the framing (:mod:`.nanonis_protocol`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlparse

from piezocomp.drivers.nanonis_protocol import NanonisError

__all__ = [
    "EMULATOR_CLOCK_COMMAND",
    "NM",
    "ControllerState",
    "parse_address",
    "read_controller",
]

NM = 1e-9
"""Metres per nanometre (the unit conversion at the boundary)."""

EMULATOR_CLOCK_COMMAND = "PiezoComp.ClockSet"
"""The emulator's own call: the sample period (float64, s) of the set-points that follow and
the client's speedup (float64: instrument seconds per wall-clock second)."""

Call = Callable[..., list[Any]]
"""``call(name, codes=(), values=(), reply=())``: one checked request and its reply's values."""


def parse_address(address: str) -> tuple[str, int]:
    """``(host, port)`` of ``nanonis://HOST:PORT``."""
    parsed = urlparse(address)
    try:
        port = parsed.port
    except ValueError:
        port = None
    if parsed.scheme != "nanonis" or not parsed.hostname or port is None or parsed.path:
        raise ValueError(
            f"an instrument address must be nanonis://HOST:PORT (e.g. nanonis://127.0.0.1:6501)."
            f" Got {address!r}."
        )
    return parsed.hostname, port


@dataclass(frozen=True)
class ControllerState:
    """What was read from the controller at connection (lengths nm, speeds nm/s).

    Attributes
    ----------
    range_nm : tuple of float
        Lateral ranges of x and y from ``Piezo.RangeGet``, nm.
    sensitivity_nm_per_v : tuple of float
        Calibration of x and y from ``Piezo.SensGet``, nm/V (reported, not used: the
        controller converts metres to volts itself).
    drift_ramp_nm_per_s : tuple of float
        The constant-velocity drift ramp of ``Piezo.DriftCompGet`` (x, y), nm/s.
    drift_ramp_was_on : bool
        Whether the ramp was on when we connected.
    drift_ramp_on : bool
        Whether it is on now (only with ``drift_ramp="keep"``: then the positions this
        instrument reports carry the controller's ramp, and no drift compensation of
        piezocomp may run on top).
    """

    range_nm: tuple[float, float]
    sensitivity_nm_per_v: tuple[float, float]
    drift_ramp_nm_per_s: tuple[float, float]
    drift_ramp_was_on: bool
    drift_ramp_on: bool

    def summary(self) -> str:
        """One line for the terminal."""
        v = self.drift_ramp_nm_per_s
        ramp = f"drift ramp ({v[0]:.3g}, {v[1]:.3g}) nm/s " + (
            "ON, kept (do not stack another drift correction)"
            if self.drift_ramp_on
            else ("switched off" if self.drift_ramp_was_on else "off")
        )
        return (
            f"range {self.range_nm[0]:.6g} x {self.range_nm[1]:.6g} nm, calibration "
            f"{self.sensitivity_nm_per_v[0]:.4g} / {self.sensitivity_nm_per_v[1]:.4g} nm/V, {ramp}"
        )


def read_controller(call: Call, drift_ramp: str) -> ControllerState:
    """Read the controller's range, calibration, Z feedback and drift ramp through ``call``;
    switch the ramp off (``drift_ramp="off"``) or keep it (``"keep"``).

    Raises
    ------
    ValueError
        Z feedback is off (nothing was sent that moves anything).
    NanonisError
        The controller states a range or calibration that is not > 0, or its drift ramp
        stayed on after being switched off.
    """
    rx, ry, _ = call("Piezo.RangeGet", reply=("f", "f", "f"))
    sx, sy, _ = call("Piezo.SensGet", reply=("f", "f", "f"))
    if min(rx, ry) <= 0 or min(sx, sy) <= 0:
        raise NanonisError(
            f"the controller states a range ({rx:g}, {ry:g}) m or a calibration "
            f"({sx:g}, {sy:g}) m/V that is not > 0"
        )
    (z_on,) = call("ZCtrl.OnOffGet", reply=("I",))
    if not z_on:
        raise ValueError(
            "Z feedback is off at the controller: switch it on (the tip must track the "
            "surface before anything moves laterally); nothing was sent."
        )
    codes: Sequence[str] = ("I", "f", "f", "f", "I", "I", "I", "f")
    on, vx, vy, vz, _, _, _, sat = call("Piezo.DriftCompGet", reply=codes)
    now_on = bool(on)
    if on and drift_ramp == "off":
        call("Piezo.DriftCompSet", ("I", "f", "f", "f", "f"), (2, vx, vy, vz, sat))
        now_on = bool(call("Piezo.DriftCompGet", reply=codes)[0])
        if now_on:
            raise NanonisError("the controller's drift ramp is still on after switching it off")
    # float32 on the wire: ranges to the picometre
    return ControllerState(
        (round(rx / NM, 3), round(ry / NM, 3)), (sx / NM, sy / NM), (vx / NM, vy / NM),
        bool(on), now_on,
    )  # fmt: skip
