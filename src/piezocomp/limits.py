"""Command limits of a scanner axis: travel range and slew rate.

Every command trajectory sent to an instrument passes :meth:`CommandLimits.check` first.
A trajectory that breaks a limit is refused before anything is sent, unless the caller
asks for clipping, in which case every clipped sample is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar

__all__ = ["CommandLimits", "LimitReport"]


@dataclass(frozen=True)
class LimitReport:
    """What :meth:`CommandLimits.check` changed when clipping.

    Attributes
    ----------
    range_clipped : ndarray of int
        Sample indices clipped to the travel range.
    slew_clipped : ndarray of int
        Sample indices whose step was limited to the slew rate.
    """

    range_clipped: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, np.intp))
    slew_clipped: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, np.intp))

    @property
    def n_clipped(self) -> int:
        """Number of distinct samples changed."""
        return int(np.union1d(self.range_clipped, self.slew_clipped).size)


@dataclass(frozen=True)
class CommandLimits:
    """Travel range and slew limit of one axis, in nominal nm of command.

    Parameters
    ----------
    min_nm, max_nm : float
        Allowed command interval (inclusive); infinite bounds mean no range limit.
    max_slew_nm_per_s : float, optional
        Largest allowed ``|u(k) - u(k-1)| / T``; ``inf`` means no slew limit.
    """

    min_nm: float
    max_nm: float
    max_slew_nm_per_s: float = float("inf")

    def __post_init__(self) -> None:
        lo, hi = float(self.min_nm), float(self.max_nm)
        if np.isnan(lo) or np.isnan(hi) or not lo < hi:
            raise ValueError(f"min_nm must be < max_nm. Got min_nm={lo}, max_nm={hi}.")
        s = float(self.max_slew_nm_per_s)
        if not (s > 0) or np.isnan(s):
            raise ValueError(f"max_slew_nm_per_s must be > 0. Got {self.max_slew_nm_per_s}.")
        object.__setattr__(self, "min_nm", lo)
        object.__setattr__(self, "max_nm", hi)
        object.__setattr__(self, "max_slew_nm_per_s", s)

    @classmethod
    def symmetric(cls, range_nm: float, max_slew_nm_per_s: float = float("inf")) -> CommandLimits:
        """Limits ``[-range_nm/2, +range_nm/2]`` for a scanner of full travel ``range_nm``."""
        r = check_finite_scalar("range_nm", range_nm)
        if r <= 0:
            raise ValueError(f"range_nm must be > 0. Got {r}.")
        return cls(-r / 2, r / 2, max_slew_nm_per_s)

    def check(
        self,
        command_nm: ArrayLike,
        sample_period_s: float,
        *,
        previous_nm: float | None = None,
        clip: bool = False,
        name: str = "command",
        clip_hint: str = "Pass clip=True to clip.",
    ) -> tuple[NDArray[np.float64], LimitReport]:
        """Check (or clip) a command trajectory against the limits.

        Parameters
        ----------
        command_nm : array_like, shape (n,)
            Command samples, nominal nm.
        sample_period_s : float
            Sample period T, s.
        previous_nm : float, optional
            Command in force before the first sample (its step is checked too).
        clip : bool
            False: refuse a trajectory that breaks a limit (ValueError naming the first
            offending sample). True: clip and report every clipped sample.
        name : str
            Name used in error messages.
        clip_hint : str
            How the caller can clip, added to a refusal (a command line names its flag).

        Returns
        -------
        command : ndarray
            The command (a clipped copy when ``clip``).
        report : LimitReport
            Indices of the clipped samples (empty when nothing was clipped).
        """
        u = as_finite_1d(name, command_nm)
        T = check_finite_scalar("sample_period_s", sample_period_s)
        if T <= 0:
            raise ValueError(f"sample_period_s must be > 0. Got {T}.")
        max_step = self.max_slew_nm_per_s * T
        out_of_range = np.flatnonzero((u < self.min_nm) | (u > self.max_nm))
        steps = np.diff(u, prepend=u[0] if previous_nm is None else float(previous_nm))
        too_fast = np.flatnonzero(np.abs(steps) > max_step * (1 + 1e-12))
        tail = f" {clip_hint}" if clip_hint else ""
        if not clip:
            if out_of_range.size:
                k = int(out_of_range[0])
                raise ValueError(
                    f"{name}[{k}] = {u[k]:.6g} nm is outside the scanner range "
                    f"[{self.min_nm:.6g}, {self.max_nm:.6g}] nm ({out_of_range.size} samples "
                    f"outside); nothing was sent.{tail}"
                )
            if too_fast.size:
                k = int(too_fast[0])
                raise ValueError(
                    f"{name} step at sample {k} is {steps[k]:.6g} nm in {T:.6g} s "
                    f"({abs(steps[k]) / T:.6g} nm/s), above the slew limit "
                    f"{self.max_slew_nm_per_s:.6g} nm/s ({too_fast.size} samples too fast); "
                    f"nothing was sent.{tail}"
                )
            return u, LimitReport()
        if out_of_range.size == 0 and too_fast.size == 0:
            return u, LimitReport()
        clipped = np.clip(u, self.min_nm, self.max_nm)
        if np.isfinite(max_step):
            prev = clipped[0] if previous_nm is None else float(previous_nm)
            slew_idx = []
            for k in range(clipped.size):
                d = clipped[k] - prev
                if abs(d) > max_step:
                    clipped[k] = prev + np.sign(d) * max_step
                    slew_idx.append(k)
                prev = clipped[k]
            slew = np.asarray(slew_idx, dtype=np.intp)
        else:
            slew = np.zeros(0, np.intp)
        return clipped, LimitReport(out_of_range.astype(np.intp), slew)
