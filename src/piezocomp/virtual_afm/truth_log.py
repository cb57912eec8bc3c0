"""The log of true tip positions: where the tip really was at every recent sample.

:class:`TruthLog` keeps blocks of samples ``t0 + k dt`` (the instrument adds every block it
runs) up to :data:`TRUTH_LOG_SAMPLES` samples, and finds the true position of any logged
sample time (:meth:`TruthLog.positions_at`): the times of a Record or of an image's pixels,
through whatever instrument drove the simulator. Ground truth: for scoring, never for
compensation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["TRUTH_LOG_SAMPLES", "TruthLog"]

TRUTH_LOG_SAMPLES = 1 << 22
"""Samples of true tip position kept (the most recent; 64 MB): about 2 hours of images at
2 ms a pixel, 9 hours at 8 ms."""


class TruthLog:
    """The true positions of the most recent :data:`TRUTH_LOG_SAMPLES` samples."""

    def __init__(self) -> None:
        self._blocks: list[tuple[float, float, NDArray[np.float64]]] = []
        self._logged = 0

    def add(self, t0_s: float, dt_s: float, positions_nm: NDArray[np.float64]) -> None:
        """Keep the true positions (n, 2) of samples ``t0_s + k dt_s``."""
        if positions_nm.shape[0] == 0:
            return
        self._blocks.append((t0_s, dt_s, positions_nm))
        self._logged += positions_nm.shape[0]
        while self._logged - self._blocks[0][2].shape[0] >= TRUTH_LOG_SAMPLES:
            self._logged -= self._blocks.pop(0)[2].shape[0]

    def positions_at(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """True tip positions (sample frame, nm) at sample times ``t_s``, shape
        ``t_s.shape + (2,)``.

        Raises
        ------
        ValueError
            If a time is not that of a logged sample (before the log's
            :data:`TRUTH_LOG_SAMPLES` most recent samples, or between samples).
        """
        t = np.asarray(t_s, dtype=float)
        flat = t.ravel()
        out = np.full((flat.size, 2), np.nan)
        if self._blocks:
            starts = np.array([c[0] for c in self._blocks])
            found = np.searchsorted(starts, flat, side="right") - 1
            # a time computed another way may fall a rounding before its block's start
            for which in (found, found + 1):
                todo = np.isnan(out[:, 0]) & (which >= 0) & (which < len(self._blocks))
                for j in np.unique(which[todo]):
                    t0, dt, pos = self._blocks[int(j)]
                    sel = np.flatnonzero(todo & (which == j))
                    k = np.rint((flat[sel] - t0) / dt).astype(np.int64)
                    ok = (k >= 0) & (k < pos.shape[0])
                    near = np.abs(t0 + dt * np.clip(k, 0, None) - flat[sel])
                    ok &= near <= 1e-9 * (1.0 + abs(t0))
                    out[sel[ok]] = pos[k[ok]]
        missing = np.flatnonzero(np.isnan(out[:, 0]))
        if missing.size:
            raise ValueError(
                f"no true position logged at t = {flat[missing[0]]:.9g} s ({missing.size} of "
                f"{flat.size} times): not a sample time, or older than the log's "
                f"{TRUTH_LOG_SAMPLES} most recent samples."
            )
        return out.reshape(*t.shape, 2)
