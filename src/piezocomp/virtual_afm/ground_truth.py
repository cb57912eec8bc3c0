"""The virtual AFM's ground truth: where the tip and the particles really are.

:class:`GroundTruth` is behind :attr:`piezocomp.virtual_afm.VirtualAFM.truth`. It exists for
tests, calibration and evaluation only: compensation and identification code must never use
it (a real instrument has no such door).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm.pushing import PushParams, PushState
from piezocomp.virtual_afm.sample import Particles, Substrate
from piezocomp.virtual_afm.scanner import ScannerParams, ScannerState
from piezocomp.virtual_afm.truth_log import TruthLog
from piezocomp.virtual_afm.worked_sample import WorkedSample

__all__ = ["GroundTruth"]


class GroundTruth:
    """The simulator's ground truth. NOT for compensation or identification code.

    Use it in tests, calibration scripts and evaluations to know where the tip and the
    particles really are. Obtain it as ``afm.truth``.
    """

    def __init__(
        self,
        params: ScannerParams,
        substrate: Substrate,
        work: WorkedSample,
        state: Callable[[], ScannerState],
    ) -> None:
        """``state`` returns the instrument's scanner state now (it changes with every
        sample); the other parts stay the same objects for the instrument's life."""
        self._params = params
        self._substrate = substrate
        self._work = work
        self._state = state
        self._log = TruthLog()
        self.last_record_positions_nm: NDArray[np.float64] = np.zeros((0, 2))
        """True tip positions (n, 2) of every sample of the last command sequence: the last
        :class:`Record` returned, or, after
        :meth:`~piezocomp.virtual_afm.VirtualAFM.scan_image`, the image's samples (approach
        to the first pixel included)."""
        self.last_record_drift_nm: NDArray[np.float64] = np.zeros((0, 2))
        """The drift offset (n, 2) included in each of :attr:`last_record_positions_nm`:
        subtracted, the scanner's own extension (with its noise), which a scanner model
        predicts."""
        self.last_image_positions_nm: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        """True tip positions (ny, nx, 2) of the last image's forward and backward pixels
        (backward stored left to right like :class:`ScanImage`)."""

    @property
    def last_record_extension_nm(self) -> NDArray[np.float64]:
        """The scanner's own extension (n, 2) over the last command sequence:
        :attr:`last_record_positions_nm` less :attr:`last_record_drift_nm` (what a scanner
        model predicts; the sample's drift is not the scanner's)."""
        return np.asarray(self.last_record_positions_nm - self.last_record_drift_nm)

    def log(self, t0_s: float, dt_s: float, positions_nm: NDArray[np.float64]) -> None:
        """Keep the true positions of samples ``t0 + k dt`` (called by the instrument)."""
        self._log.add(t0_s, dt_s, positions_nm)

    def positions_at(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """True tip positions (sample frame, nm) at sample times ``t_s``, shape
        ``t_s.shape + (2,)``: the times of a :class:`~piezocomp.instrument.Record` or of an
        image's pixels (:meth:`~piezocomp.instrument.ScanImage.pixel_times_s`), through any
        instrument that drives this one (a compensated one included). See
        :meth:`~piezocomp.virtual_afm.truth_log.TruthLog.positions_at`."""
        return self._log.positions_at(t_s)

    def tip_position_nm(self) -> tuple[float, float]:
        """True tip position now, sample frame, nm."""
        p = self._state().position_nm
        return float(p[0]), float(p[1])

    def particles(self) -> Particles:
        """True particles on the surface now (positions in the sample frame and diameters,
        nm): not those on the tip or lost."""
        return self._work.surface

    @property
    def push_params(self) -> PushParams:
        """Every particle's friction and the pushes' failure rates (every particle, in the
        order the sample was made)."""
        return self._work.push_params

    @property
    def push_state(self) -> PushState:
        """Where pushing stands: which particles are on the surface, their engagements, and
        ``counts``, the engagements so far and how many failed, by kind."""
        return self._work.push_state

    @property
    def scanner_params(self) -> ScannerParams:
        """The scanner physics in use."""
        return self._params

    @property
    def scanner_state(self) -> ScannerState:
        """The scanner state now (hysteresis memory, creep modes, drift offset)."""
        return self._state()

    @property
    def tip(self) -> TipGeometry:
        """Tip geometry now."""
        return self._work.tip

    @property
    def substrate(self) -> Substrate:
        """Substrate roughness."""
        return self._substrate
