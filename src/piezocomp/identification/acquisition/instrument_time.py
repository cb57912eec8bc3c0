"""The instrument time an identification takes, stage by stage.

A user with a shared microscope needs to know how long the identification keeps it, and
which part of that time buys what. :class:`InstrumentClock` stands in for the instrument
(every call is passed on unchanged) and reads the session clock from what each call returns
(a record's sample times, an image's line times): the time from the end of the previous
call's output to the end of this one's goes to the stage under way, so that what a call
does before its output starts (the approach to an image's first line) is counted, and on a
real instrument so is the computing between calls, during which the instrument waits.
Only the very first call's lead-in, before its output starts, has no earlier output to be
reckoned from and is left out.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.instrument import Instrument, Record, ScanImage

__all__ = ["InstrumentClock", "with_total"]


def with_total(stages: dict[str, float]) -> dict[str, float]:
    """``stages`` (s) and their ``total``: ``summary.json``'s ``instrument_s`` of an axis."""
    return {**stages, "total": float(sum(stages.values()))}


class InstrumentClock:
    """An instrument that counts the time of what it runs, by stage.

    Parameters
    ----------
    instrument : Instrument
        The instrument every call goes to (its other attributes, such as an optional
        ``calibration_scan``, are read through).

    Attributes
    ----------
    seconds : dict of str to float
        Instrument time of each stage, s, in the order the stages first ran; time outside
        any :meth:`stage` goes to ``"other"``.
    """

    def __init__(self, instrument: Instrument) -> None:
        self._instrument = instrument
        self._stage = "other"
        self._end_s: float | None = None
        self.seconds: dict[str, float] = {}

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Count the calls made inside the block as stage ``name`` (stages may nest: the
        inner one counts)."""
        outer, self._stage = self._stage, name
        try:
            yield
        finally:
            self._stage = outer

    @property
    def total_s(self) -> float:
        """Instrument time of every stage together, s."""
        return float(sum(self.seconds.values()))

    def _add(self, start_s: float, end_s: float) -> None:
        """An output that ran from ``start_s`` to ``end_s`` on the session clock."""
        begin = start_s if self._end_s is None else min(self._end_s, start_s)
        self._end_s = end_s
        self.seconds[self._stage] = self.seconds.get(self._stage, 0.0) + (end_s - begin)

    def _record(self, rec: Record, period_s: float | None = None) -> Record:
        T = float(self._instrument.sample_period_s) if period_s is None else float(period_s)
        if len(rec):
            self._add(float(rec.t_s[0]), float(rec.t_s[-1]) + T)
        return rec

    # ---------------------------------------------------------------- the interface
    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):  # not the instrument's (and no recursion before __init__)
            raise AttributeError(name)
        return getattr(self._instrument, name)

    @property
    def sample_period_s(self) -> float:
        return float(self._instrument.sample_period_s)

    @property
    def range_nm(self) -> float:
        return float(self._instrument.range_nm)

    @property
    def max_speed_nm_per_s(self) -> float:
        return float(self._instrument.max_speed_nm_per_s)

    @property
    def command_nm(self) -> tuple[float, float]:
        return self._instrument.command_nm

    def run(
        self,
        command_nm: NDArray[np.float64],
        *,
        sample_period_s: float | None = None,
        z_feedback: bool = True,
    ) -> Record:
        options: dict[str, Any] = {}  # passed on as given: a backend may take neither
        if sample_period_s is not None:
            options["sample_period_s"] = sample_period_s
        if not z_feedback:
            options["z_feedback"] = z_feedback
        return self._record(self._instrument.run(command_nm, **options), sample_period_s)

    def move_to(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        return self._record(self._instrument.move_to(x_nm, y_nm, speed_nm_per_s))

    def push(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        return self._record(self._instrument.push(x_nm, y_nm, speed_nm_per_s))

    def wait(self, duration_s: float) -> Record:
        return self._record(self._instrument.wait(duration_s))

    def scan_image(
        self,
        center_nm: tuple[float, float],
        size_nm: float,
        pixels: int,
        line_rate_hz: float,
        *,
        fast_axis: str = "x",
    ) -> ScanImage:
        options = {} if fast_axis == "x" else {"fast_axis": fast_axis}
        image = self._instrument.scan_image(center_nm, size_nm, pixels, line_rate_hz, **options)
        starts = image.line_start_s
        lines = image.forward_nm.shape[0 if fast_axis == "x" else 1]
        line_s = float(image.line_time_s)
        last = image.t_start_s + (lines - 1) * line_s if starts is None else float(starts[-1])
        self._add(float(image.t_start_s), float(last) + line_s)
        return image
