"""A Nanonis (SPECS) controller as an :class:`~piezocomp.instrument.Instrument`, over TCP.

What it sends (framing in :mod:`.nanonis_protocol`; metres, volts and seconds on the wire,
nm and s everywhere else):

- at connection (:func:`.nanonis_controller.read_controller`): range, calibration, Z feedback
  (must be on), the drift ramp (switched off, or kept and reported), then ``FolMe.XYPosGet``
  (where the tip is) and ``FolMe.SpeedSet`` (Follow Me at the slew limit, so each set-point
  is reached within a sample period); to the emulator only, each path's sample period and
  the pacing's speedup (``PiezoComp.ClockSet``);
- a streamed path (:meth:`NanonisInstrument.run`, ``move_to``, ``wait``, ``push``): per sample,
  ``FolMe.XYPosSet`` (not waiting for the end of the move) then ``ZCtrl.ZPosGet`` (the
  topography), paced on a monotonic clock at the sample period;
- a push: ``ZCtrl.OnOffSet`` off, the path, ``ZCtrl.OnOffSet`` on, the last even when the path
  fails or is interrupted;
- an image: the controller's own scan (``Scan.FrameSet``, ``Scan.BufferGet``/``BufferSet``,
  ``Scan.SpeedSet``, ``Scan.Action``, ``Scan.WaitEndOfScan``, ``Scan.FrameDataGrab``) when it
  can scan the raster (x fast, pixels a multiple of 16), else the raster streamed as a path.

Safety. Every path is checked against range and slew before its first set-point is sent. A
timeout, a dropped connection, a malformed reply or the controller's error flag stops the
path at once: nothing more is sent (but ``FolMe.Stop`` and Z feedback on, when the
connection still answers), the tip stays at the last acknowledged set-point, and the error
says where that is in one line. Ctrl-C does the same, then lets the interrupt through.

Timing. The model assumes a sample every T; the client keeps it. Each record carries a
:class:`~piezocomp.instrument.SampleTiming` (when each set-point was really sent), the
session's :attr:`NanonisInstrument.timing_log` counts every path, and a path whose samples
strayed further than ``timing_tolerance`` x T from their slots raises :class:`TimingError`
(``timing="raise"``, the default: never silently used for identification) or is returned
flagged (``timing="flag"``; :mod:`.pacing`).

Imports only the core and its sibling modules (backends import only the core).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar
from piezocomp.drivers.nanonis_controller import (
    EMULATOR_CLOCK_COMMAND,
    NM,
    ControllerState,
    parse_address,
    read_controller,
)
from piezocomp.drivers.nanonis_protocol import (
    NanonisConnection,
    NanonisError,
    NanonisReplyError,
)
from piezocomp.drivers.pacing import TimingError, TimingLog
from piezocomp.instrument import (
    Raster,
    Record,
    SampleTiming,
    ScanCalibration,
    ScanImage,
    line_path,
)
from piezocomp.limits import CommandLimits

__all__ = [
    "ControllerState",
    "NanonisError",
    "NanonisInstrument",
    "NanonisReplyError",
    "TimingError",
    "parse_address",
]

SCAN_PIXEL_MULTIPLE = 16
"""Nanonis coerces pixels per line to a multiple of 16: other rasters are streamed."""

Z_SIGNAL_INDEX = 30
"""Index of ``Z (m)`` in Nanonis's default signal list (override with ``z_signal_index``)."""


class NanonisInstrument:
    """A Nanonis controller behind the :class:`~piezocomp.instrument.Instrument` interface.

    Parameters
    ----------
    connection : NanonisConnection
        An open connection (:meth:`connect` opens one from ``nanonis://HOST:PORT``).
    sample_period_s : float
        T: the period at which set-points are streamed and Z recorded, s.
    max_speed_nm_per_s : float
        Slew limit of each axis, nm/s (not readable from the controller; state it).
    range_nm : float, optional
        Travel to use, nm: at most the controller's (``Piezo.RangeGet``, the smaller of x
        and y); default the controller's. A smaller one keeps a first session small.
    timing_tolerance : float
        Largest distance of a sample from its slot, as a fraction of T (default 0.5).
    timing : {"raise", "flag"}
        A path beyond the tolerance raises :class:`TimingError`, or comes back flagged.
    speedup : float
        Pace the set-points this many times faster than T (the emulator only, whose clock
        is the set-point stream; 1 on a microscope). Times in records stay in instrument
        seconds.
    emulator : bool
        The server is ``piezocomp emulate`` (:mod:`.nanonis_emulator`): each path's sample
        period and the speedup are declared to it before the path (``PiezoComp.ClockSet``, a
        call only the emulator knows), so that its virtual scanner runs every path at the
        path's own period and its scans last as long as on the client's clock. Never set it
        for a controller, which runs in real time.
    drift_ramp : {"off", "keep"}
        Switch the controller's drift ramp off at connection (default), or keep it on and
        report it (:attr:`controller`).
    calibration_scan : ScanCalibration, optional
        The scan under which the scanner's calibration holds, if known.
    z_signal_index : int
        The controller's signal index of Z for its own scans (``Scan.FrameDataGrab``).
    controller_scan : bool
        Use the controller's scan for images it can scan (default True).
    """

    def __init__(
        self,
        connection: NanonisConnection,
        *,
        sample_period_s: float,
        max_speed_nm_per_s: float,
        range_nm: float | None = None,
        timing_tolerance: float = 0.5,
        timing: str = "raise",
        speedup: float = 1.0,
        emulator: bool = False,
        drift_ramp: str = "off",
        calibration_scan: ScanCalibration | None = None,
        z_signal_index: int = Z_SIGNAL_INDEX,
        controller_scan: bool = True,
    ) -> None:
        T = check_finite_scalar("sample_period_s", sample_period_s)
        vmax = check_finite_scalar("max_speed_nm_per_s", max_speed_nm_per_s)
        tol = check_finite_scalar("timing_tolerance", timing_tolerance)
        up = check_finite_scalar("speedup", speedup)
        for name, v in (("sample_period_s", T), ("max_speed_nm_per_s", vmax), ("speedup", up)):
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        if not 0 < tol <= 10:
            raise ValueError(f"timing_tolerance must be in (0, 10] sample periods. Got {tol}.")
        if drift_ramp not in ("off", "keep"):
            raise ValueError(f"drift_ramp must be 'off' or 'keep'. Got {drift_ramp!r}.")
        if up != 1 and not emulator:
            raise ValueError(
                "speedup paces the set-points faster than T, which only the emulator can "
                f"follow (emulator=True); on a controller it breaks the model. Got {up}."
            )
        self._conn = connection
        self._T, self._vmax, self._tol, self._speedup = T, vmax, tol, up
        self.timing_log = TimingLog(timing)
        """How far this session's streamed paths strayed from their slots
        (:class:`~piezocomp.drivers.pacing.TimingLog`)."""
        self._z_index = int(z_signal_index)
        self._controller_scan = bool(controller_scan)
        self.calibration_scan = calibration_scan
        self._emulator = bool(emulator)
        self._declared = float("nan")  # the sample period the emulator was last told
        self.controller = read_controller(self._call, drift_ramp)
        full = min(self.controller.range_nm)
        r = full if range_nm is None else check_finite_scalar("range_nm", range_nm)
        if not 0 < r <= full * (1 + 1e-6):
            raise ValueError(
                f"range_nm must be > 0 and at most the controller's range {full:.6g} nm. Got {r}."
            )
        self._range = r
        self._limits = CommandLimits.symmetric(r, vmax)
        x, y = self._call("FolMe.XYPosGet", ("I",), (1,), ("d", "d"))
        self._u = (x / NM, y / NM)
        half = 0.5 * r
        if abs(self._u[0]) > half or abs(self._u[1]) > half:
            raise ValueError(
                f"the tip is at ({self._u[0]:.6g}, {self._u[1]:.6g}) nm, outside the range "
                f"+-{half:g} nm this session may use; move it inside first (or widen range_nm)."
            )
        self._call("FolMe.SpeedSet", ("f", "I"), (vmax * NM, 1))
        self._declare(T)
        self._t0 = time.perf_counter()

    @classmethod
    def connect(cls, address: str, *, timeout_s: float = 2.0, **kwargs: Any) -> NanonisInstrument:
        """Connect to ``nanonis://HOST:PORT`` and read the controller (see the class)."""
        host, port = parse_address(address)
        conn = NanonisConnection(host, port, timeout_s=timeout_s)
        try:
            return cls(conn, **kwargs)
        except BaseException:
            conn.close("the instrument could not be set up")
            raise

    def close(self) -> None:
        """Close the connection (the controller keeps its state: Z feedback, position)."""
        self._conn.close()

    def __enter__(self) -> NanonisInstrument:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------- connection
    def _call(
        self,
        name: str,
        codes: tuple[str, ...] = (),
        values: tuple[Any, ...] = (),
        reply: tuple[str, ...] = (),
        timeout_s: float | None = None,
    ) -> list[Any]:
        out = self._conn.call(name, codes, values, reply, timeout_s=timeout_s)
        if not all(np.all(np.isfinite(v)) for v in out if not isinstance(v, str)):
            self._conn.close(f"a non-finite value in the reply to {name}")
            raise NanonisError(f"malformed reply to {name}: a non-finite value {out}")
        return out

    def _declare(self, period_s: float) -> None:
        """Tell the emulator the sample period of the set-points that follow and the
        speedup (once per change; nothing is sent to a controller)."""
        if self._emulator and period_s != self._declared:
            self._call(EMULATOR_CLOCK_COMMAND, ("d", "d"), (period_s, self._speedup))
            self._declared = period_s

    # ----------------------------------------------------------------- properties
    @property
    def address(self) -> str:
        """``nanonis://HOST:PORT``."""
        return f"nanonis://{self._conn.address}"

    @property
    def sample_period_s(self) -> float:
        """T, s."""
        return self._T

    @property
    def range_nm(self) -> float:
        """Travel of each axis this session uses, nm."""
        return self._range

    @property
    def max_speed_nm_per_s(self) -> float:
        """Slew limit of each axis, nm/s."""
        return self._vmax

    @property
    def limits(self) -> CommandLimits:
        """Range and slew limits of each axis' command."""
        return self._limits

    @property
    def command_nm(self) -> tuple[float, float]:
        """The last set-point the controller acknowledged, nominal nm."""
        return self._u

    @property
    def time_s(self) -> float:
        """Session time now, instrument seconds."""
        return (time.perf_counter() - self._t0) * self._speedup

    # ----------------------------------------------------------------- checks
    def _checked(self, command_nm: ArrayLike, dt: float) -> NDArray[np.float64]:
        u = as_finite_array("command_nm", command_nm, ndim=2)
        if u.shape[1] != 2:
            raise ValueError(f"command_nm must have shape (n, 2). Got {u.shape}.")
        for i, axis in enumerate("xy"):
            self._limits.check(
                u[:, i], dt, previous_nm=self._u[i], name=f"command {axis}", clip_hint=""
            )
        return u

    def _line(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> NDArray[np.float64]:
        x = check_finite_scalar("x_nm", x_nm)
        y = check_finite_scalar("y_nm", y_nm)
        v = check_finite_scalar("speed_nm_per_s", speed_nm_per_s)
        if not 0 < v <= self._vmax:
            raise ValueError(
                f"speed_nm_per_s must be > 0 and <= max_speed_nm_per_s = {self._vmax:g}. Got {v}."
            )
        half = 0.5 * self._range
        if abs(x) > half or abs(y) > half:
            raise ValueError(
                f"target ({x:.6g}, {y:.6g}) nm is outside the scanner range +-{half:g} nm; "
                "nothing was sent."
            )
        return line_path(np.asarray(self._u), np.array([x, y]), v, self._T)

    # ----------------------------------------------------------------- streaming
    def _stream(self, u: NDArray[np.float64], dt: float) -> Record:
        """Send the checked path ``u`` one set-point per ``dt``, Z read after each."""
        n = u.shape[0]
        sent = np.empty(n)
        height = np.empty(n)
        wall_dt = dt / self._speedup
        done = 0  # set-points the controller acknowledged
        unanswered: tuple[float, float] | None = None  # one sent, its reply not read
        try:
            self._declare(dt)
            start = time.perf_counter()
            for k in range(n):
                wait = start + k * wall_dt - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
                sent[k] = time.perf_counter()
                x, y = float(u[k, 0]), float(u[k, 1])
                unanswered = (x, y)
                self._call("FolMe.XYPosSet", ("d", "d", "I"), (x * NM, y * NM, 0))
                self._u, unanswered, done = (x, y), None, k + 1
                (z,) = self._call("ZCtrl.ZPosGet", reply=("f",))
                height[k] = z / NM
        except (NanonisError, KeyboardInterrupt) as exc:
            stopped = self._stop_quietly()
            x0, y0 = self._u
            where = (
                f"stopped after {done} of {n} set-points; the tip was left at the last "
                f"acknowledged set-point ({x0:.3f}, {y0:.3f}) nm"
            )
            if unanswered is not None and not isinstance(exc, NanonisReplyError):
                where += f" or the next, ({unanswered[0]:.3f}, {unanswered[1]:.3f}) nm"
            where += f"{stopped}; nothing more was sent"
            if isinstance(exc, KeyboardInterrupt):
                exc.add_note(f"nanonis: path {where}")
                raise
            raise type(exc)(f"{exc}: path {where}") from None
        t = (sent - self._t0) * self._speedup
        timing = SampleTiming(dt, t, self._tol * dt)
        return Record(t, u, height, timing)

    def _stop_quietly(self) -> str:
        """``FolMe.Stop`` if the connection still answers; a note for the message."""
        if self._conn.closed:
            return ""
        try:
            self._call("FolMe.Stop")
        except NanonisError:
            return " (FolMe.Stop was refused)"
        return ""

    # ----------------------------------------------------------------- Instrument API
    def run(
        self,
        command_nm: ArrayLike,
        *,
        sample_period_s: float | None = None,
        z_feedback: bool = True,
    ) -> Record:
        """Stream a command trajectory (n, 2), one set-point per sample period, reading Z
        after each; ``z_feedback=False`` runs it with Z feedback off (a push) and switches
        it on again afterwards, whatever happens.

        Raises
        ------
        ValueError
            A command outside the range or faster than the slew limit (nothing is sent).
        NanonisError
            The controller failed mid-path (the path stopped; see the module docstring).
        TimingError
            The path's timing broke the tolerance (``timing="raise"``).
        """
        dt = self._T
        if sample_period_s is not None:
            dt = check_finite_scalar("sample_period_s", sample_period_s)
        if dt <= 0:
            raise ValueError(f"sample_period_s must be > 0. Got {dt}.")
        return self._run(command_nm, dt, z_feedback, "a streamed path")

    def _run(self, command_nm: ArrayLike, dt: float, z_feedback: bool, operation: str) -> Record:
        """:meth:`run` of ``operation`` (named when its timing stops it)."""
        u = self._checked(command_nm, dt)
        if z_feedback:
            return self.timing_log.check(self._stream(u, dt), operation)
        self._call("ZCtrl.OnOffSet", ("I",), (0,))
        try:
            rec = self._stream(u, dt)
        except BaseException as exc:
            problem = self._z_on_quietly()
            if problem and isinstance(exc, KeyboardInterrupt):
                exc.add_note(f"nanonis: {problem}")
            elif problem:
                raise type(exc)(f"{exc}; {problem}") from None
            raise
        problem = self._z_on_quietly()
        if problem:
            raise NanonisError(f"the push ended but {problem}")
        return self.timing_log.check(rec, operation)

    def _z_on_quietly(self) -> str:
        """Z feedback on; '' if done, else what went wrong (for the message)."""
        try:
            self._call("ZCtrl.OnOffSet", ("I",), (1,))
        except NanonisError as exc:
            return (
                f"Z feedback could NOT be switched back on ({exc}): switch it on at the controller"
            )
        return ""

    def move_to(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Stream a straight line to ``(x_nm, y_nm)`` at ``speed_nm_per_s`` (Z feedback on)."""
        return self._run(self._line(x_nm, y_nm, speed_nm_per_s), self._T, True,
                         f"a move to ({x_nm:.6g}, {y_nm:.6g}) nm")  # fmt: skip

    def push(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Stream a straight line with Z feedback off (pushing); Z feedback on after it,
        even if it fails or is interrupted."""
        return self._run(self._line(x_nm, y_nm, speed_nm_per_s), self._T, False,
                         f"a push to ({x_nm:.6g}, {y_nm:.6g}) nm")  # fmt: skip

    def wait(self, duration_s: float) -> Record:
        """Hold the set-point for ``duration_s`` (whole samples), reading Z every T."""
        d = check_finite_scalar("duration_s", duration_s)
        if d < 0:
            raise ValueError(f"duration_s must be >= 0. Got {d}.")
        return self._run(np.tile(np.asarray(self._u, float), (round(d / self._T), 1)), self._T,
                         True, f"a wait of {d:.6g} s")  # fmt: skip

    def scan_image(
        self,
        center_nm: tuple[float, float],
        size_nm: float,
        pixels: int,
        line_rate_hz: float,
        *,
        fast_axis: str = "x",
    ) -> ScanImage:
        """A square raster image. The tip first streams to the first pixel at the scan
        speed; then the controller scans it (x fast, pixels a multiple of 16; the last step
        of the approach, one sample, is the controller's) or the raster is streamed as a
        path at one sample per pixel."""
        half = 0.5 * self._range
        cx = check_finite_scalar("center_nm[0]", center_nm[0])
        cy = check_finite_scalar("center_nm[1]", center_nm[1])
        size = check_finite_scalar("size_nm", size_nm)
        if max(abs(cx), abs(cy)) + 0.5 * abs(size) > half:
            raise ValueError(
                f"the image ({size:.6g} nm about ({cx:.6g}, {cy:.6g}) nm) reaches outside the "
                f"scanner range +-{half:g} nm; nothing was sent."
            )
        raster = Raster.square(center_nm, size_nm, pixels, line_rate_hz, fast_axis=fast_axis)
        speed = raster.speed_nm_per_s
        if speed > self._vmax:
            raise ValueError(
                f"scan speed 2 * size_nm * line_rate_hz = {speed:.6g} nm/s is above "
                f"max_speed_nm_per_s = {self._vmax:.6g}; lower line_rate_hz or size_nm."
            )
        what = f"an image of {size:.6g} nm at ({cx:.6g}, {cy:.6g}) nm"
        approach = line_path(np.asarray(self._u), raster.positions_nm[0], speed,
                             raster.sample_period_s)  # fmt: skip
        if self._controller_scan and fast_axis == "x" and pixels % SCAN_PIXEL_MULTIPLE == 0:
            # the controller takes the last step to the first pixel itself (one sample)
            if approach.shape[0] > 1:
                self._run(approach[:-1], raster.sample_period_s, True, f"the approach to {what}")
            return self._controller_image(raster, (cx, cy), size)
        self._run(approach, raster.sample_period_s, True, f"the approach to {what}")
        # the whole raster from its first pixel, where the approach ended (as the virtual AFM)
        rec = self._run(raster.positions_nm, raster.sample_period_s, True, what)
        return raster.image(rec.height_nm, float(rec.t_s[0]))

    def _controller_image(
        self, raster: Raster, center: tuple[float, float], size: float
    ) -> ScanImage:
        n = raster.x_nm.size
        line_time = 1.0 / raster.line_rate_hz
        self._call("Scan.FrameSet", ("f",) * 5, (center[0] * NM, center[1] * NM, size * NM,
                                                  size * NM, 0.0))  # fmt: skip
        channels, _, _ = self._call("Scan.BufferGet", reply=("[i]", "i", "i"))
        chans = [int(c) for c in channels]
        if self._z_index not in chans:
            chans.append(self._z_index)
        self._call("Scan.BufferSet", ("[i]", "i", "i"), (chans, n, n))
        v = raster.speed_nm_per_s * NM
        self._call("Scan.SpeedSet", ("f", "f", "f", "f", "H", "f"),
                   (v, v, line_time / 2, line_time / 2, 2, 1.0))  # fmt: skip
        t0 = self.time_s
        self._call("Scan.Action", ("H", "I"), (0, 1))
        budget = n * line_time * 1.5 + self._conn.timeout_s
        wait_ms = (round(budget * 1e3),)
        timeout = budget + self._conn.timeout_s
        timed_out, _ = self._call("Scan.WaitEndOfScan", ("i",), wait_ms, ("I", "str"), timeout)
        if timed_out:
            self._call("Scan.Action", ("H", "I"), (1, 1))
            raise NanonisError(f"the controller's scan did not end within {budget:.3g} s")
        traces = []
        for direction in (1, 0):
            _, data, _ = self._call("Scan.FrameDataGrab", ("I", "I"), (self._z_index, direction),
                                    ("str", "[[f]]", "I"))  # fmt: skip
            if data.shape != (n, n):
                self._conn.close("a frame of the wrong shape")
                raise NanonisError(f"the controller's frame is {data.shape}, not ({n}, {n})")
            traces.append(data / NM)
        x, y = self._call("FolMe.XYPosGet", ("I",), (1,), ("d", "d"))
        self._u = (x / NM, y / NM)
        return ScanImage(traces[0], traces[1], raster.x_nm, raster.y_nm, line_time, t0, "x")
