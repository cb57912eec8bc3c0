"""The instrument interface: what identification, experiments and manipulation may ask of an AFM.

A real driver (e.g. Nanonis over TCP) and the virtual AFM (:mod:`piezocomp.virtual_afm`) both
implement :class:`Instrument`. Commands are nominal nanometres per axis, in the scanner
frame centred on 0 (``[-range_nm/2, +range_nm/2]``); heights come back in nm with
timestamps in s. Nothing here exposes the true tip position: a simulator's ground truth
lives behind its own, separately named door and compensation code never uses it.

The compensated instrument (:class:`piezocomp.positioning.compensated.CompensatedInstrument`) is an
:class:`Instrument` too, whose positions are true nanometres instead of nominal ones: code
written against this interface runs unchanged on either.

Signal convention: time is the first axis; ``(n, 2)`` arrays hold ``x`` then ``y``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly

__all__ = [
    "Instrument",
    "Raster",
    "Record",
    "RunFailure",
    "RunValueError",
    "SampleTiming",
    "ScanCalibration",
    "ScanImage",
    "line_path",
]


class RunFailure(Exception):
    """Mixed into an error found while a run was under way (a path whose timing broke the
    model's assumption, a record the estimation cannot use), not in how the run was asked
    for: the command line exits 1 for it, 2 being a usage error."""


class RunValueError(ValueError, RunFailure):
    """A ``ValueError`` found while a run was under way (the command line exits 1)."""


@dataclass(frozen=True)
class ScanCalibration:
    """The scan under which a scanner's nominal sensitivity holds (its calibration record).

    A lateral calibration on a grating of known pitch sets the nominal sensitivity so that
    a steady triangular scan over ``span_nm`` at ``speed_nm_per_s`` is as wide as
    commanded: the calibration condition of Section IV of the paper. Creep makes the width
    of a steady scan depend on its speed, so the condition holds at this speed only; the
    sensorless identification runs its calibration cycles there. An instrument may state
    it as an optional ``calibration_scan`` attribute (``None`` or absent: not known).

    Parameters
    ----------
    span_nm : float
        Command span of the calibration scan, nm (> 0).
    speed_nm_per_s : float
        Its ramp speed, nm/s (> 0): twice the span times the line rate.
    """

    span_nm: float
    speed_nm_per_s: float

    def __post_init__(self) -> None:
        for name in ("span_nm", "speed_nm_per_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or check_finite_scalar(name, v) <= 0:
                raise ValueError(f"{name} must be a finite number > 0. Got {v!r}.")
            object.__setattr__(self, name, float(v))


@dataclass(frozen=True)
class SampleTiming:
    """When the samples of a streamed path were really sent, against the model's schedule.

    The scanner model assumes a sample every ``period_s``: sample ``k`` at
    ``sent_s[0] + k period_s``. An instrument whose set-points are paced by a client (over
    TCP) states here how far it kept to that; a record whose timing broke ``tolerance_s``
    must not be used for identification as if it had not.

    Attributes
    ----------
    period_s : float
        The sample period the path was meant to run at, s.
    sent_s : ndarray, shape (n,)
        Session time at which each sample's set-point was sent, s (a monotonic clock).
    tolerance_s : float
        Largest lateness or earliness of a sample against its slot that the model's
        assumption tolerates, s.
    """

    period_s: float
    sent_s: NDArray[np.float64]
    tolerance_s: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "sent_s", readonly(as_finite_array("sent_s", self.sent_s, 1)))
        for name in ("period_s", "tolerance_s"):
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
            object.__setattr__(self, name, v)

    @property
    def deviation_s(self) -> NDArray[np.float64]:
        """Each sample's time minus its slot ``sent_s[0] + k period_s``, s (> 0: late)."""
        k = np.arange(self.sent_s.size, dtype=np.float64)
        return np.asarray(self.sent_s - (self.sent_s[0] + k * self.period_s)) if k.size else k

    @property
    def max_deviation_s(self) -> float:
        """Largest ``|deviation_s|``, s (0 for an empty path)."""
        d = self.deviation_s
        return float(np.max(np.abs(d))) if d.size else 0.0

    @property
    def late_samples(self) -> int:
        """Samples further than ``tolerance_s`` from their slot."""
        return int(np.count_nonzero(np.abs(self.deviation_s) > self.tolerance_s))

    @property
    def ok(self) -> bool:
        """Whether every sample kept within ``tolerance_s`` of its slot."""
        return self.late_samples == 0

    def summary(self) -> str:
        """One line: the period, the worst deviation and the verdict."""
        verdict = "within" if self.ok else f"{self.late_samples} samples beyond"
        return (
            f"{self.sent_s.size} samples at T = {self.period_s:g} s, worst "
            f"{self.max_deviation_s * 1e3:.3g} ms off their slot ({verdict} the "
            f"{self.tolerance_s * 1e3:.3g} ms tolerance)"
        )


@dataclass(frozen=True)
class Record:
    """Samples recorded while the instrument ran a command trajectory.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
        Time of each sample, s, from the start of the session.
    command_nm : ndarray, shape (n, 2)
        Command applied on x and y during each sample (nominal nm), after any clipping.
    height_nm : ndarray, shape (n,)
        Measured topography (Z feedback on) or, during a push with Z feedback off, the
        instrument's height channel as it is (may be all NaN if the instrument has none).
    timing : SampleTiming, optional
        When each sample was really sent, for an instrument whose samples are paced by a
        client (``None``: the instrument's own clock keeps the period exactly).
    """

    t_s: NDArray[np.float64]
    command_nm: NDArray[np.float64]
    height_nm: NDArray[np.float64]
    timing: SampleTiming | None = None

    def __post_init__(self) -> None:
        t = readonly(self.t_s)
        c = readonly(self.command_nm)
        h = readonly(self.height_nm)
        if t.ndim != 1 or c.shape != (t.size, 2) or h.shape != t.shape:
            raise ValueError(
                "Record needs t_s (n,), command_nm (n, 2) and height_nm (n,). "
                f"Got {t.shape}, {c.shape}, {h.shape}."
            )
        if self.timing is not None and self.timing.sent_s.shape != t.shape:
            raise ValueError(
                f"Record.timing must time every sample ({t.size}). Got {self.timing.sent_s.size}."
            )
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "command_nm", c)
        object.__setattr__(self, "height_nm", h)

    def __len__(self) -> int:
        return int(self.t_s.size)

    @classmethod
    def joined(cls, records: Sequence[Record]) -> Record:
        """One record of several run one after the other (their samples in order; the
        gaps between them stay in ``t_s``, and in ``timing`` when every one is timed)."""
        if not records:
            raise ValueError("Record.joined needs at least one record.")
        timings = [r.timing for r in records]
        timing = None
        if all(tm is not None for tm in timings):
            first = timings[0]
            assert first is not None
            timing = SampleTiming(first.period_s,
                                  np.concatenate([tm.sent_s for tm in timings if tm]),
                                  first.tolerance_s)  # fmt: skip
        return cls(np.concatenate([r.t_s for r in records]),
                   np.concatenate([r.command_nm for r in records]),
                   np.concatenate([r.height_nm for r in records]), timing)  # fmt: skip


@dataclass(frozen=True)
class ScanImage:
    """A raster image, forward (trace) and backward (retrace).

    Attributes
    ----------
    forward_nm, backward_nm : ndarray, shape (ny, nx)
        Heights, nm. Row ``j`` is the line at slow-axis command ``y_nm[j]``; column ``i``
        is fast-axis command ``x_nm[i]`` for BOTH traces (the backward trace is stored
        in the same left-to-right order as the forward one).
    x_nm : ndarray, shape (nx,)
        Position of each column along x, nm, in the instrument's frame (nominal command for
        a raw instrument, true nm for a compensated one).
    y_nm : ndarray, shape (ny,)
        Position of each row along y, nm, likewise.
    line_time_s : float
        Duration of one line (forward + backward), s.
    t_start_s : float
        Session time at which the image's first pixel was sampled, s.
    fast_axis : {"x", "y"}
        The axis scanned forward and backward; the other steps once per line.
    line_start_s : ndarray, shape (lines,), optional
        Session time at which each line started, when the lines were not scanned back to
        back (e.g. drift measured between them); ``None``: ``t_start_s + j line_time_s``.
    """

    forward_nm: NDArray[np.float64]
    backward_nm: NDArray[np.float64]
    x_nm: NDArray[np.float64]
    y_nm: NDArray[np.float64]
    line_time_s: float
    t_start_s: float = 0.0
    fast_axis: str = "x"
    line_start_s: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        for name in ("forward_nm", "backward_nm", "x_nm", "y_nm"):
            object.__setattr__(self, name, readonly(getattr(self, name)))
        shape = (self.y_nm.size, self.x_nm.size)
        if self.forward_nm.shape != shape or self.backward_nm.shape != shape:
            raise ValueError(
                f"ScanImage traces must have shape (ny, nx) = {shape}. "
                f"Got {self.forward_nm.shape} and {self.backward_nm.shape}."
            )
        if self.fast_axis not in ("x", "y"):
            raise ValueError(f"fast_axis must be 'x' or 'y'. Got {self.fast_axis!r}.")
        if self.line_start_s is not None:
            starts = readonly(as_finite_array("line_start_s", self.line_start_s, ndim=1))
            lines = self.y_nm.size if self.fast_axis == "x" else self.x_nm.size
            if (
                starts.size != lines
                or np.any(np.diff(starts) < self.line_time_s * (1 - 1e-9))
                or abs(float(starts[0]) - float(self.t_start_s)) > 1e-9 * max(1.0, abs(starts[0]))
            ):
                raise ValueError(
                    f"line_start_s must hold {lines} start times at least line_time_s apart, "
                    f"the first t_start_s ({self.t_start_s:g} s). Got {starts.size} from "
                    f"{float(starts[0]) if starts.size else float('nan'):g} s."
                )
            object.__setattr__(self, "line_start_s", starts)

    @property
    def pixel_period_s(self) -> float:
        """Time between two pixels of a line, s (a line is forward then backward)."""
        n = self.x_nm.size if self.fast_axis == "x" else self.y_nm.size
        return float(self.line_time_s) / (2.0 * n)

    def pixel_times_s(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Session time at which each pixel was sampled, s: ``(forward, backward)``, each
        shaped like the traces (the backward trace stored in the forward one's order).

        Line ``j`` starts at ``t_start_s + j line_time_s`` (or ``line_start_s[j]``); pixel
        ``i`` of its forward pass follows ``i`` pixel periods later, and the backward pass
        returns over the same pixels in reverse order.
        """
        fast = self.x_nm.size if self.fast_axis == "x" else self.y_nm.size
        slow = self.y_nm.size if self.fast_axis == "x" else self.x_nm.size
        dt = self.pixel_period_s
        starts = (
            self.t_start_s + self.line_time_s * np.arange(slow, dtype=np.float64)
            if self.line_start_s is None
            else np.asarray(self.line_start_s, dtype=np.float64)
        )
        line0 = starts[:, None]
        i = np.arange(fast)[None, :]
        fwd, bwd = line0 + i * dt, line0 + (2 * fast - 1 - i) * dt
        if self.fast_axis == "y":
            fwd, bwd = fwd.T.copy(), bwd.T.copy()
        return fwd, bwd

    @property
    def pixel_nm(self) -> float:
        """Nominal pixel size along the fast axis, nm."""
        return float(abs(self.x_nm[1] - self.x_nm[0])) if self.x_nm.size > 1 else float("nan")


@dataclass(frozen=True)
class Raster:
    """The samples of a square raster image, in the order they are scanned.

    Line ``j`` is forward then backward along the fast axis, one sample per pixel, the slow
    axis stepping one pixel per line; pixel ``i`` is at
    ``center - size/2 + (i + 1/2) size/pixels``. Every instrument scans this way, so an
    image built from a trajectory (a compensated or drift-corrected one) has the layout and
    the pixel times (:meth:`ScanImage.pixel_times_s`) of one the instrument scanned itself.

    Attributes
    ----------
    positions_nm : ndarray, shape (2 pixels^2, 2)
        The samples' positions (x, y).
    x_nm, y_nm : ndarray, shape (pixels,)
        The pixel grid.
    sample_period_s : float
        Time between two pixels: ``1 / (2 pixels line_rate_hz)``.
    line_rate_hz : float
    fast_axis : {"x", "y"}
    """

    positions_nm: NDArray[np.float64]
    x_nm: NDArray[np.float64]
    y_nm: NDArray[np.float64]
    sample_period_s: float
    line_rate_hz: float
    fast_axis: str

    @classmethod
    def square(
        cls,
        center_nm: tuple[float, float],
        size_nm: float,
        pixels: int,
        line_rate_hz: float,
        *,
        fast_axis: str = "x",
    ) -> Raster:
        """The raster of an image; arguments checked, as :meth:`Instrument.scan_image`
        takes them."""
        if fast_axis not in ("x", "y"):
            raise ValueError(f"fast_axis must be 'x' or 'y'. Got {fast_axis!r}.")
        cx = check_finite_scalar("center_nm[0]", center_nm[0])
        cy = check_finite_scalar("center_nm[1]", center_nm[1])
        size = check_finite_scalar("size_nm", size_nm)
        rate = check_finite_scalar("line_rate_hz", line_rate_hz)
        if isinstance(pixels, bool) or not isinstance(pixels, int | np.integer) or pixels < 2:
            raise ValueError(f"pixels must be an integer >= 2. Got {pixels!r}.")
        if size <= 0 or rate <= 0:
            raise ValueError(f"size_nm and line_rate_hz must be > 0. Got {size}, {rate}.")
        n = int(pixels)
        if 2 * n * n > MAX_RASTER_SAMPLES:
            raise ValueError(
                f"an image of {n} x {n} pixels needs {2 * n * n:.3g} samples, more than "
                f"{MAX_RASTER_SAMPLES:.0e}: lower pixels."
            )
        xs = cx - size / 2 + (np.arange(n) + 0.5) * size / n
        ys = cy - size / 2 + (np.arange(n) + 0.5) * size / n
        fast, slow = (xs, ys) if fast_axis == "x" else (ys, xs)
        f = np.tile(np.concatenate([fast, fast[::-1]]), n)
        s = np.repeat(slow, 2 * n)
        pos = np.column_stack([f, s] if fast_axis == "x" else [s, f])
        return cls(pos, xs, ys, 1.0 / (2.0 * n * rate), rate, fast_axis)

    @property
    def speed_nm_per_s(self) -> float:
        """Speed of the fast axis, nm/s (``2 size line_rate``)."""
        pitch = abs(float(self.x_nm[1] - self.x_nm[0]))
        return pitch / self.sample_period_s

    def image(
        self,
        height_nm: NDArray[np.float64],
        t_start_s: float,
        line_start_s: NDArray[np.float64] | None = None,
    ) -> ScanImage:
        """The image of the heights recorded along the raster (one per sample), its lines
        started at ``line_start_s`` if they were not scanned back to back."""
        n = self.x_nm.size
        h = np.asarray(height_nm, dtype=float).reshape(n, 2, n)
        fwd, bwd = h[:, 0, :], h[:, 1, ::-1]
        if self.fast_axis == "y":
            fwd, bwd = fwd.T.copy(), bwd.T.copy()
        return ScanImage(
            fwd, bwd, self.x_nm, self.y_nm, line_time_s=1.0 / self.line_rate_hz,
            t_start_s=float(t_start_s), fast_axis=self.fast_axis, line_start_s=line_start_s,
        )  # fmt: skip


MAX_RASTER_SAMPLES = 20_000_000
"""Most samples an image may take (about 1 GB of working memory)."""


@runtime_checkable
class Instrument(Protocol):
    """What the rest of piezocomp needs from an AFM.

    Implementations must check every command against :attr:`limits` (range and slew,
    see :class:`piezocomp.limits.CommandLimits`) before sending anything.

    Optional: a ``calibration_scan`` attribute (:class:`ScanCalibration` or ``None``), the
    scan under which the scanner's nominal sensitivity holds; the sensorless
    identification runs its calibration cycles at its speed.
    """

    @property
    def sample_period_s(self) -> float:
        """Period at which commands are applied and heights recorded, s."""
        ...

    @property
    def range_nm(self) -> float:
        """Full travel of each lateral axis, nm (commands lie in ``[-range/2, range/2]``)."""
        ...

    @property
    def max_speed_nm_per_s(self) -> float:
        """Largest allowed command speed of one axis, nm/s."""
        ...

    @property
    def command_nm(self) -> tuple[float, float]:
        """Command currently applied to (x, y), nominal nm."""
        ...

    def run(
        self,
        command_nm: NDArray[np.float64],
        *,
        sample_period_s: float | None = None,
        z_feedback: bool = True,
    ) -> Record:
        """Apply a command trajectory (shape (n, 2), one row per sample period) while
        recording at every sample.

        ``sample_period_s`` runs the trajectory at another period than
        :attr:`sample_period_s` (an instrument that cannot refuses it with ``ValueError``
        before anything moves). ``z_feedback=False`` runs it with Z feedback off, the tip
        lowered to push what lies in its way (the height channel then reads as the
        instrument has it, possibly NaN)."""
        ...

    def move_to(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Move the command along a straight line to ``(x_nm, y_nm)`` at the given speed."""
        ...

    def scan_image(
        self,
        center_nm: tuple[float, float],
        size_nm: float,
        pixels: int,
        line_rate_hz: float,
        *,
        fast_axis: str = "x",
    ) -> ScanImage:
        """Acquire a square raster image: fast axis ``fast_axis`` (forward then backward
        along it), the other axis slow, ascending. The arrays are (ny, nx) whichever axis is
        fast; with ``fast_axis="y"`` each column is one line (forward: y ascending)."""
        ...

    def push(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Move in a straight line to ``(x_nm, y_nm)`` with Z feedback off (pushing)."""
        ...

    def wait(self, duration_s: float) -> Record:
        """Hold the command still for ``duration_s`` while recording."""
        ...


def line_path(
    p0: NDArray[np.float64], p1: NDArray[np.float64], speed_nm_per_s: float, dt_s: float
) -> NDArray[np.float64]:
    """Samples (n, 2) of a straight line from ``p0`` (excluded) to ``p1`` at a speed, one
    per ``dt_s``; at least one."""
    a, b = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    n = max(1, math.ceil(float(np.hypot(*(b - a))) / (speed_nm_per_s * dt_s) - 1e-9))
    return np.asarray(a + (b - a) * (np.arange(1, n + 1)[:, None] / n))
