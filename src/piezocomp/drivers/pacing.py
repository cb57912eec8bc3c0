"""Set-points paced by the client: how far a session's paths strayed from the model's clock.

A backend that streams set-points over a network keeps the model's sample period T itself:
it paces them on a monotonic clock and time-stamps each one in the record
(:class:`~piezocomp.instrument.SampleTiming`). Every streamed record then goes through a
:class:`TimingLog`, which keeps the session's figures (paths, samples, the worst distance of
a sample from its slot, the paths beyond the tolerance) and raises :class:`TimingError` for a
path beyond the tolerance (``mode="raise"``: such a record is never used as if it were
uniform) or lets it through, flagged and counted (``mode="flag"``).

Imports only the core.
"""

from __future__ import annotations

from typing import Any

from piezocomp.instrument import Record, RunFailure

__all__ = ["TIMING_MODES", "TimingError", "TimingLog"]

TIMING_MODES = ("raise", "flag")
"""What happens to a path beyond the tolerance: it raises, or comes back flagged."""


class TimingError(ValueError, RunFailure):
    """A streamed path whose samples strayed beyond the tolerance from their slots; the
    path ran to its end, and the flagged record is ``record`` (found during a run: the
    command line exits 1)."""

    def __init__(self, message: str, record: Record) -> None:
        super().__init__(message)
        self.record = record


class TimingLog:
    """The timing of a session's streamed paths.

    Parameters
    ----------
    mode : {"raise", "flag"}
        A path beyond its tolerance raises :class:`TimingError` (after being counted), or
        is returned flagged.
    """

    def __init__(self, mode: str = "raise") -> None:
        if mode not in TIMING_MODES:
            raise ValueError(f"timing must be one of {TIMING_MODES}. Got {mode!r}.")
        self.mode = mode
        self.paths = 0
        """Streamed paths checked."""
        self.samples = 0
        """Their samples."""
        self.late_paths = 0
        """Paths with a sample beyond the tolerance."""
        self.late_samples = 0
        """Samples beyond the tolerance."""
        self.worst_s = 0.0
        """Largest distance of a sample from its slot, s."""
        self.worst_periods = 0.0
        """The same in sample periods of its path."""

    def check(self, record: Record, operation: str = "a streamed path") -> Record:
        """Count a streamed record; return it, or raise :class:`TimingError` (``"raise"``)
        if its timing broke the tolerance, naming the ``operation`` it stopped (``"a move to
        (10, 20) nm"``)."""
        timing = record.timing
        if timing is None:
            raise ValueError("a streamed record must carry its timing (Record.timing).")
        self.paths += 1
        self.samples += timing.sent_s.size
        worst = timing.max_deviation_s
        if worst > self.worst_s:
            self.worst_s = worst
        self.worst_periods = max(self.worst_periods, worst / timing.period_s)
        if timing.ok:
            return record
        self.late_paths += 1
        self.late_samples += timing.late_samples
        if self.mode == "raise":
            raise TimingError(
                f"stopped at {operation}: its timing broke the model's assumption "
                f"({timing.summary()}), and such a record is not to be used (slow the path, "
                "or lighten the machine; over the emulator, where a late set-point changes "
                "nothing it simulates, --timing flag counts it instead)",
                record,
            )
        return record

    def as_dict(self) -> dict[str, Any]:
        """The figures, JSON-ready."""
        return {
            "mode": self.mode,
            "paths": self.paths,
            "samples": self.samples,
            "late_paths": self.late_paths,
            "late_samples": self.late_samples,
            "worst_deviation_s": self.worst_s,
            "worst_deviation_periods": self.worst_periods,
        }

    def summary(self) -> str:
        """One line: the paths, the worst deviation and how many broke the tolerance."""
        verdict = (
            "every one within its tolerance"
            if self.late_paths == 0
            else f"{self.late_paths} beyond their tolerance ({self.late_samples} samples"
            + (", flagged and used)" if self.mode == "flag" else ")")
        )
        return (
            f"{self.paths} streamed paths, {self.samples} samples, worst {self.worst_s * 1e3:.3g} "
            f"ms ({self.worst_periods:.3g} periods) off their slot; {verdict}"
        )
