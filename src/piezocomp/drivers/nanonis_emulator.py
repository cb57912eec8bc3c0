"""A Nanonis controller emulated on loopback, the virtual AFM behind it (``piezocomp emulate``).

It speaks the framing of :mod:`.nanonis_protocol` for every call the backend
(:mod:`.nanonis`) sends, so a whole session can be rehearsed over real sockets before a
microscope is touched, and the tests exercise the real client code. It listens on a loopback
address only and serves one client at a time.

The emulated scanner's clock is the stream of set-points: each ``FolMe.XYPosSet`` that does
not wait for the end of its move is one sample period of the virtual AFM at the new
set-point (``ZCtrl.ZPosGet`` then reads that sample's height), so a rehearsal is
deterministic and runs as fast as the sockets allow; a path streamed through it gives the
same heights as :meth:`VirtualAFM.run` would. The period is the virtual AFM's T until the
client declares another with ``PiezoComp.ClockSet`` (the period, s, and the client's speedup,
both float64), this emulator's own call (:data:`~.nanonis_controller.EMULATOR_CLOCK_COMMAND`;
the backend sends it with ``emulator=True``), so that paths at another period (an image
streamed at one sample per pixel) run at theirs, as on the virtual AFM directly. A
set-point that waits (``Wait end of move`` = 1) moves at the Follow Me speed, and the
controller's own scan is computed at once; both then take their scanner time divided by the
speedup (1 until declared) on the wall clock before they answer or end, as a controller
would, so that the client's clock keeps up with the scanner's. With Z feedback off a
set-point pushes (the virtual AFM's ``z_feedback=False``) and Z stays where the feedback left
it. The controller's own scan runs :meth:`VirtualAFM.scan_image`; frames come back row 0
first, the first line scanned (scan direction up), both directions left to right. The drift
ramp (``Piezo.DriftCompSet``) adds its constant velocity to every set-point while it is on,
as the controller would.

Faults (:class:`Fault`) can be injected: a slow reply, a connection dropped, a malformed
reply, the error flag, each on the n-th call of a command.

The one module of :mod:`piezocomp.drivers` that imports the simulator; no backend
imports it.
"""

from __future__ import annotations

import ipaddress
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from piezocomp.drivers.nanonis_controller import EMULATOR_CLOCK_COMMAND
from piezocomp.drivers.nanonis_protocol import (
    HEADER_SIZE,
    decode_header,
    decode_values,
    encode_header,
    encode_reply,
)
from piezocomp.instrument import ScanImage
from piezocomp.virtual_afm import VirtualAFM

__all__ = ["FAULT_KINDS", "Fault", "NanonisEmulator"]

NM = 1e-9
"""Metres per nanometre."""

FAULT_KINDS = ("slow", "drop", "malformed", "error")
"""What can go wrong: a late reply, the connection closed, a reply that does not parse,
the controller's error flag."""

Z_RANGE_M = 5e-6
"""Z range the emulator states, m."""

POLL_S = 0.05
"""How often the server's loops look whether they were asked to stop, s."""


@dataclass(frozen=True)
class Fault:
    """One fault, injected once on the ``after + 1``-th call of ``command``.

    Attributes
    ----------
    kind : {"slow", "drop", "malformed", "error"}
        ``slow``: the call is served, its reply sent ``delay_s`` late; ``drop``: the
        connection is closed before the call is served; ``malformed``: the call is served
        and its reply cut short; ``error``: the call is refused with the error flag.
    command : str
        The command it hits (default ``FolMe.XYPosSet``, a streamed path's set-point).
    after : int
        Calls of ``command`` served normally before it.
    delay_s : float
        Lateness of a ``slow`` reply, s.
    """

    kind: str
    command: str = "FolMe.XYPosSet"
    after: int = 0
    delay_s: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            kinds = ", ".join(FAULT_KINDS)
            raise ValueError(f"fault kind must be one of {kinds}. Got {self.kind!r}.")
        if isinstance(self.after, bool) or not isinstance(self.after, int) or self.after < 0:
            raise ValueError(f"fault 'after' must be an integer >= 0. Got {self.after!r}.")
        if not (self.delay_s > 0 and np.isfinite(self.delay_s)):
            raise ValueError(f"fault delay_s must be > 0. Got {self.delay_s}.")

    @classmethod
    def parse(cls, text: str) -> Fault:
        """From ``KIND[@N][:COMMAND]``, e.g. ``drop@200`` or ``error@3:ZCtrl.OnOffSet``."""
        head, _, command = text.partition(":")
        kind, _, after = head.partition("@")
        try:
            n = int(after) if after else 0
        except ValueError:
            raise ValueError(
                f"a fault is KIND[@N][:COMMAND] (N an integer). Got {text!r}."
            ) from None
        return cls(kind, command or "FolMe.XYPosSet", n)


class _Refused(Exception):
    """A call the emulated controller refuses with its error flag."""


Handler = Callable[[list[Any]], tuple[Sequence[str], Sequence[Any]]]


class NanonisEmulator:
    """The Nanonis TCP interface served on loopback over a :class:`VirtualAFM`.

    Parameters
    ----------
    afm : VirtualAFM
        The instrument behind it (a grating one for a length-reference rehearsal).
    host : str
        A loopback address (127.0.0.1 by default); others are refused.
    port : int
        0 picks a free port (see :attr:`address`).
    faults : sequence of Fault
        Faults to inject, each once.

    Use as a context manager, or :meth:`start` (a thread) and :meth:`stop`.
    """

    def __init__(
        self,
        afm: VirtualAFM,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        faults: Sequence[Fault] = (),
    ) -> None:
        try:
            loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
        except ValueError:
            loopback = False
        if not loopback:
            raise ValueError(f"the emulator listens on a loopback address only. Got {host!r}.")
        self.afm = afm
        self._faults = list(faults)
        self._calls: Counter[str] = Counter()
        self.z_feedback = True
        self.drift_ramp_on = False
        self._ramp_m_s = (0.0, 0.0, 0.0)
        self._ramp_since_s = 0.0
        self._folme_speed_m_s = afm.max_speed_nm_per_s * NM
        self._height_nm = 0.0  # Z before the first sample (the feedback holds it somewhere)
        self._frame = (0.0, 0.0, 1e-6, 1e-6, 0.0)
        self._buffer: tuple[list[int], int, int] = ([30], 256, 256)
        self._line_time_s = 1.0
        self._image: ScanImage | None = None
        self.set_points = 0
        """``FolMe.XYPosSet`` calls served (a fault's refused or dropped call not counted)."""
        self.streamed_s = 0.0
        """Scanner time of the streamed set-points served, s (their periods summed)."""
        self._period_s = float(afm.sample_period_s)
        self._speedup = 1.0
        self._scan_ends = 0.0  # monotonic time at which the controller's scan is over
        self._server = socket.create_server((host, port))
        self._server.settimeout(POLL_S)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._handlers: dict[str, tuple[tuple[str, ...], Handler]] = {
            "Piezo.RangeGet": ((), self._range),
            "Piezo.SensGet": ((), self._sens),
            "Piezo.DriftCompGet": ((), self._drift_get),
            "Piezo.DriftCompSet": (("I", "f", "f", "f", "f"), self._drift_set),
            "ZCtrl.OnOffGet": ((), lambda v: (("I",), (int(self.z_feedback),))),
            "ZCtrl.OnOffSet": (("I",), self._z_set),
            "ZCtrl.ZPosGet": ((), lambda v: (("f",), (self._height_nm * NM,))),
            "FolMe.XYPosGet": (("I",), self._xy_get),
            "FolMe.XYPosSet": (("d", "d", "I"), self._xy_set),
            "FolMe.SpeedSet": (("f", "I"), self._speed_set),
            "FolMe.SpeedGet": ((), lambda v: (("f", "I"), (self._folme_speed_m_s, 1))),
            "FolMe.Stop": ((), lambda v: ((), ())),
            EMULATOR_CLOCK_COMMAND: (("d", "d"), self._clock_set),
            "Scan.FrameSet": (("f",) * 5, self._frame_set),
            "Scan.BufferGet": ((), lambda v: (("[i]", "i", "i"), self._buffer)),
            "Scan.BufferSet": (("[i]", "i", "i"), self._buffer_set),
            "Scan.SpeedSet": (("f", "f", "f", "f", "H", "f"), self._scan_speed),
            "Scan.Action": (("H", "I"), self._scan_action),
            "Scan.WaitEndOfScan": (("i",), self._wait_end_of_scan),
            "Scan.FrameDataGrab": (("I", "I"), self._frame_grab),
        }

    # ----------------------------------------------------------------- serving
    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` it listens on."""
        host, port = self._server.getsockname()[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        """``nanonis://HOST:PORT``, for ``--instrument``."""
        host, port = self.address
        return f"nanonis://{host}:{port}"

    def calls(self, command: str) -> int:
        """How many calls of ``command`` arrived."""
        return self._calls[command]

    def inject(self, fault: Fault) -> None:
        """Add a fault; its ``after`` counts from now."""
        self._faults.append(
            Fault(fault.kind, fault.command, fault.after + self._calls[fault.command],
                  fault.delay_s)
        )  # fmt: skip

    def warm_up(self) -> None:
        """Run the simulator once on a spare virtual AFM of the same configuration (a
        sample with Z feedback on and off, at another period, a small image), so that the
        first set-points of a session answer as fast as the rest: the compiled kernels are
        loaded before a client's timing depends on them. The served AFM is not touched."""
        spare = VirtualAFM(self.afm.config, sample_period_s=self.afm.sample_period_s)
        here = np.zeros((1, 2))
        spare.run(here)
        spare.run(here, sample_period_s=0.5 * spare.sample_period_s)
        spare.run(here, z_feedback=False)
        spare.scan_image((0.0, 0.0), 64.0, 16, 4.0)

    def start(self) -> NanonisEmulator:
        """Serve in a background thread."""
        self._thread = threading.Thread(target=self.serve, name="nanonis-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving (the current client is disconnected) and close the port."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._server.close()

    def __enter__(self) -> NanonisEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def serve(self) -> None:
        """Accept clients one after the other until :meth:`stop`."""
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                conn.settimeout(POLL_S)
                try:
                    self._serve_client(conn)
                except (ConnectionError, OSError):
                    pass  # the client went away: wait for the next

    def _read(self, conn: socket.socket, n: int) -> bytes | None:
        """``n`` bytes, or None if the client closed or the server is stopping."""
        buf = bytearray()
        while len(buf) < n:
            if self._stop.is_set():
                return None
            try:
                chunk = conn.recv(n - len(buf))
            except TimeoutError:
                continue
            if not chunk:
                return None
            buf += chunk
        return bytes(buf)

    def _serve_client(self, conn: socket.socket) -> None:
        while True:
            header = self._read(conn, HEADER_SIZE)
            if header is None:
                return
            try:
                name, size, respond = decode_header(header)
            except ValueError:
                return  # cannot find the next message: hang up, as the controller would
            body = self._read(conn, size)
            if body is None:
                return
            self._calls[name] += 1
            fault = self._fault_for(name)
            if fault is not None and fault.kind == "drop":
                return
            if fault is not None and fault.kind == "error":
                reply = encode_reply(name, error_status=1, error_text="emulated fault: error flag")
            else:
                reply = self._answer(name, body)
            if fault is not None and fault.kind == "slow":
                end = time.monotonic() + fault.delay_s
                while time.monotonic() < end and not self._stop.is_set():
                    time.sleep(min(POLL_S, max(0.0, end - time.monotonic())))
            if fault is not None and fault.kind == "malformed":
                reply = encode_header(name, 3, respond=False) + b"\x00\x01\x02"
            if respond:
                conn.sendall(reply)

    def _fault_for(self, name: str) -> Fault | None:
        for i, f in enumerate(self._faults):
            if f.command == name and self._calls[name] == f.after + 1:
                return self._faults.pop(i)
        return None

    def _answer(self, name: str, body: bytes) -> bytes:
        if name not in self._handlers:
            return encode_reply(name, error_status=1, error_text=f"unknown command {name}")
        codes, handler = self._handlers[name]
        try:
            values, end = decode_values(codes, body)
            if end != len(body):
                raise _Refused(f"{len(body) - end} bytes after the arguments")
            out_codes, out = handler(values)
        except (_Refused, ValueError) as exc:
            return encode_reply(name, error_status=1, error_text=str(exc))
        return encode_reply(name, out_codes, out)

    # ----------------------------------------------------------------- handlers
    def _range(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        r = self.afm.range_nm * NM
        return ("f", "f", "f"), (r, r, Z_RANGE_M)

    def _sens(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        s = self.afm.range_nm * NM / 20.0  # the range over +-10 V
        return ("f", "f", "f"), (s, s, Z_RANGE_M / 20.0)

    def _drift_get(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        vx, vy, vz = self._ramp_m_s
        return ("I", "f", "f", "f", "I", "I", "I", "f"), (
            int(self.drift_ramp_on), vx, vy, vz, 0, 0, 0, 0.1,
        )  # fmt: skip

    def _drift_set(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        on, vx, vy, vz, _ = v
        if on not in (0, 1, 2):
            raise _Refused(f"compensation on/off must be 0, 1 or 2. Got {on}")
        self._ramp_m_s = (float(vx), float(vy), float(vz))
        if on == 1 and not self.drift_ramp_on:
            self._ramp_since_s = self.afm.time_s
        if on:
            self.drift_ramp_on = on == 1
        return (), ()

    def _z_set(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        if v[0] not in (0, 1):
            raise _Refused(f"Z controller status must be 0 or 1. Got {v[0]}")
        self.z_feedback = bool(v[0])
        return (), ()

    def _ramp_nm(self) -> np.ndarray:
        if not self.drift_ramp_on:
            return np.zeros(2)
        dt = self.afm.time_s - self._ramp_since_s
        return np.array(self._ramp_m_s[:2]) / NM * dt

    def _xy_get(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        x, y = self.afm.command_nm
        return ("d", "d"), (x * NM, y * NM)

    def _xy_set(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        x, y, wait = float(v[0]) / NM, float(v[1]) / NM, v[2]
        target = np.array([x, y]) + self._ramp_nm()
        if wait:
            t0 = self.afm.time_s
            if not self.z_feedback:  # Z held where the feedback left it
                self.afm.push(float(target[0]), float(target[1]), self._folme_speed_m_s / NM)
            else:
                speed = self._folme_speed_m_s / NM
                rec = self.afm.move_to(float(target[0]), float(target[1]), speed)
                self._height_nm = float(rec.height_nm[-1])
            self._take(self.afm.time_s - t0)  # the move, on the wall clock
        else:
            T = None if self._period_s == self.afm.sample_period_s else self._period_s
            rec = self.afm.run(target[None, :], sample_period_s=T, z_feedback=self.z_feedback)
            if self.z_feedback:
                self._height_nm = float(rec.height_nm[-1])
            self.streamed_s += self._period_s
        self.set_points += 1
        return (), ()

    def _clock_set(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        period, speedup = float(v[0]), float(v[1])
        if not (np.isfinite(period) and period > 0 and np.isfinite(speedup) and speedup > 0):
            raise _Refused(f"the sample period and speedup must be > 0. Got {period}, {speedup}")
        self._period_s, self._speedup = period, speedup
        return (), ()

    def _take(self, scanner_s: float) -> None:
        """Let ``scanner_s`` of scanner time pass on the wall clock (divided by the speedup)."""
        self._sleep_until(time.monotonic() + scanner_s / self._speedup)

    def _sleep_until(self, end: float, until: float | None = None) -> bool:
        """Sleep until the monotonic time ``end`` (at most until ``until``, or until the
        server stops); False if cut short by ``until``."""
        stop = end if until is None else min(end, until)
        while time.monotonic() < stop and not self._stop.is_set():
            time.sleep(min(POLL_S, max(0.0, stop - time.monotonic())))
        return stop >= end

    def _speed_set(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        if not v[0] > 0:
            raise _Refused(f"speed must be > 0. Got {v[0]}")
        self._folme_speed_m_s = min(float(v[0]), self.afm.max_speed_nm_per_s * NM)
        return (), ()

    def _frame_set(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        self._frame = tuple(float(a) for a in v)  # type: ignore[assignment]
        return (), ()

    def _buffer_set(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        chans, pixels, lines = [int(c) for c in v[0]], int(v[1]), int(v[2])
        if pixels % 16 or pixels <= 0 or lines <= 0:
            raise _Refused(f"pixels must be a multiple of 16 and lines > 0. Got {pixels}, {lines}")
        self._buffer = (chans, pixels, lines)
        return (), ()

    def _scan_speed(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        if not (v[2] > 0 and v[3] > 0):
            raise _Refused("times per line must be > 0")
        self._line_time_s = float(v[2]) + float(v[3])
        return (), ()

    def _scan_action(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        action, up = v
        if action == 1:  # stop: the emulated scan ends now
            self._scan_ends = min(self._scan_ends, time.monotonic())
            return (), ()
        if action != 0 or up != 1:
            raise _Refused(f"the emulator scans start (0) upwards (1) only. Got {action}, {up}")
        cx, cy, w, h, angle = self._frame
        _, pixels, lines = self._buffer
        if angle != 0 or abs(w - h) > 1e-6 * w or pixels != lines:
            raise _Refused("the emulator scans square frames at angle 0 only")
        if not self.z_feedback:
            raise _Refused("Z feedback is off: no scan")
        t0 = self.afm.time_s
        self._image = self.afm.scan_image((cx / NM, cy / NM), w / NM, pixels, 1 / self._line_time_s)
        self._scan_ends = time.monotonic() + (self.afm.time_s - t0) / self._speedup
        return (), ()

    def _wait_end_of_scan(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        timeout_ms = int(v[0])  # -1: wait as long as the scan lasts
        until = None if timeout_ms < 0 else time.monotonic() + timeout_ms / 1e3
        ended = self._sleep_until(self._scan_ends, until)
        return ("I", "str"), (0 if ended else 1, "")

    def _frame_grab(self, v: list[Any]) -> tuple[Sequence[str], Sequence[Any]]:
        channel, forward = v
        if self._image is None:
            raise _Refused("no frame scanned yet")
        if channel not in self._buffer[0]:
            raise _Refused(f"channel {channel} is not acquired (buffer {self._buffer[0]})")
        data = self._image.forward_nm if forward else self._image.backward_nm
        return ("str", "[[f]]", "I"), ("Z (m)", np.asarray(data) * NM, 1)
