"""The virtual AFM: implements :class:`piezocomp.instrument.Instrument` on simulated physics.

Every command passes :class:`piezocomp.limits.CommandLimits` (range and slew): a command
outside them is refused with an error and nothing happens. The scanner physics is
:mod:`piezocomp.virtual_afm.scanner`, the sample and tip :mod:`piezocomp.virtual_afm.sample`.

The ground truth (true tip positions, true particle positions) is behind
:attr:`VirtualAFM.truth`, a :class:`~piezocomp.virtual_afm.ground_truth.GroundTruth`
object. It exists for tests, calibration and evaluation only: compensation and
identification code must never use it (a real instrument has no such door).

Randomness: one :class:`numpy.random.SeedSequence` from ``sample.seed`` is split into
independent streams for the particles, the roughness, the height noise and the drift, so
the run is deterministic for a seed, and switching drift on does not change the sample.
Pushing draws from the seed and the particles (:mod:`piezocomp.virtual_afm.pushing`). A push
lasts while Z feedback is off, over one call or several: it ends when the feedback is back
on (:mod:`piezocomp.virtual_afm.worked_sample`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar
from piezocomp.instrument import Raster, Record, ScanCalibration, ScanImage
from piezocomp.limits import CommandLimits
from piezocomp.virtual_afm.config import AFMConfig, load_config
from piezocomp.virtual_afm.grating import Grating, grating_topography
from piezocomp.virtual_afm.ground_truth import GroundTruth
from piezocomp.virtual_afm.sample import Particles, Substrate, topography
from piezocomp.virtual_afm.scanner import (
    ScannerState,
    scanner_params_from_config,
    simulate,
)
from piezocomp.virtual_afm.truth_log import TRUTH_LOG_SAMPLES
from piezocomp.virtual_afm.worked_sample import WorkedSample, initial_particles

__all__ = ["TRUTH_LOG_SAMPLES", "VirtualAFM"]


PROGRESS_LINES = 64
"""Lines of an image simulated between two progress reports."""

MAX_SAMPLES = 20_000_000
"""Most samples one call may run (about 1 GB of working memory): a larger request is
refused before anything is built."""


def _check_budget(n: int, what: str) -> None:
    if n > MAX_SAMPLES:
        raise ValueError(
            f"{what} needs {n:.3g} samples, more than the {MAX_SAMPLES:.0e} one call may run; "
            "nothing was sent: split it, or lower the size or the rate."
        )


class VirtualAFM:
    """Simulated AFM with a piezo tube scanner (hysteresis, creep, drift) over a sample of
    spherical particles, imaged in tapping mode.

    Parameters
    ----------
    config : AFMConfig, preset name, TOML path or mapping
        Scanner and sample configuration (see :mod:`piezocomp.virtual_afm.config`).
    sample_period_s : float
        Sample period of :meth:`run`, :meth:`move_to`, :meth:`push` and :meth:`wait`, s.
    particles : Particles or array_like (n, 2) / (n, 3), optional
        Explicit particles (x, y[, diameter]) overriding the configuration's.
    start_nm : tuple of float
        Command at which the scanner starts, at rest (demagnetised memory, settled creep).
    seed : int, optional
        Overrides ``sample.seed``.
    grating : Grating, optional
        A calibration grating as the sample instead of the particles (the same scanner, tip,
        substrate roughness and noise): the length reference of a lateral calibration
        (:mod:`piezocomp.virtual_afm.grating`). Nothing can be pushed on it.
    calibration_scan : ScanCalibration, optional
        The lab's calibration record of the scanner, stated to the software as a real
        controller states it (:attr:`calibration_scan`); none by default.
    """

    def __init__(
        self,
        config: AFMConfig | str | os.PathLike[str] | Mapping[str, Any] = "cpr5",
        *,
        sample_period_s: float = 0.008,
        particles: Particles | ArrayLike | None = None,
        start_nm: tuple[float, float] = (0.0, 0.0),
        seed: int | None = None,
        grating: Grating | None = None,
        calibration_scan: ScanCalibration | None = None,
    ) -> None:
        if calibration_scan is not None and not isinstance(calibration_scan, ScanCalibration):
            raise TypeError(
                "calibration_scan must be a ScanCalibration or None. Got "
                f"{type(calibration_scan).__name__}."
            )
        self._calibration_scan = calibration_scan
        if grating is not None and not isinstance(grating, Grating):
            raise TypeError(f"grating must be a Grating or None. Got {type(grating).__name__}.")
        if grating is not None and particles is not None:
            raise ValueError("give either particles or a grating as the sample, not both.")
        cfg = load_config(config)
        if seed is not None:
            cfg = cfg.with_seed(seed)
        T = check_finite_scalar("sample_period_s", sample_period_s)
        if T <= 0:
            raise ValueError(f"sample_period_s must be > 0. Got {T}.")
        self._config = cfg
        self._T = T
        self._params = scanner_params_from_config(cfg)
        self._limits = CommandLimits.symmetric(cfg.scanner.range_nm, cfg.scanner.max_speed_nm_per_s)
        s = cfg.sample
        ss_particles, ss_rough, ss_noise, ss_drift = np.random.SeedSequence(s.seed).spawn(4)
        self._rng_noise = np.random.default_rng(ss_noise)
        self._rng_drift = np.random.default_rng(ss_drift)
        self._drift_blocks: list[NDArray[np.float64]] = []
        self._substrate = (
            Substrate.random(np.random.default_rng(ss_rough), s.roughness_nm)
            if s.roughness_nm > 0
            else Substrate.flat()
        )
        self._grating = grating
        self._work = WorkedSample(
            s,
            Particles(np.zeros((0, 2)), np.zeros(0))
            if grating is not None
            else initial_particles(s, particles, np.random.default_rng(ss_particles)),
        )
        for v in start_nm:
            check_finite_scalar("start_nm", v)
        self._limits.check(np.asarray(start_nm[:1], float), T, name="start_nm x")
        self._limits.check(np.asarray(start_nm[1:], float), T, name="start_nm y")
        self._u = (float(start_nm[0]), float(start_nm[1]))
        self._state = ScannerState.initial(self._params, self._u)
        self._t = 0.0
        self.truth = GroundTruth(self._params, self._substrate, self._work, lambda: self._state)

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_preset(cls, name: str = "cpr5", **kwargs: Any) -> VirtualAFM:
        """A virtual AFM from a named preset (``cpr5``, ``gentle``, ``harsh``, ...)."""
        from piezocomp.virtual_afm.config import list_presets

        if name not in list_presets():
            raise ValueError(f"unknown preset '{name}'. Known: {', '.join(list_presets())}.")
        return cls(name, **kwargs)

    @classmethod
    def from_config(
        cls, config: AFMConfig | str | os.PathLike[str] | Mapping[str, Any], **kwargs: Any
    ) -> VirtualAFM:
        """A virtual AFM from a TOML file path, a mapping or an :class:`AFMConfig`."""
        return cls(config, **kwargs)

    # ----------------------------------------------------------------- properties
    @property
    def config(self) -> AFMConfig:
        """The configuration in use."""
        return self._config

    @property
    def sample_period_s(self) -> float:
        """Sample period of run/move/push/wait, s."""
        return self._T

    @property
    def range_nm(self) -> float:
        """Full travel of each axis, nm."""
        return self._config.scanner.range_nm

    @property
    def max_speed_nm_per_s(self) -> float:
        """Largest command speed of one axis, nm/s."""
        return self._config.scanner.max_speed_nm_per_s

    @property
    def calibration_scan(self) -> ScanCalibration | None:
        """The calibration record this instrument was given (``calibration_scan=``), as a
        lab states it to a real controller; ``None``: none. The virtual lab measures it on a
        grating through the instrument interface
        (:func:`piezocomp.experiments.virtual_identification.calibration_record`); the
        scanner's physics alone gives the exact speed
        (:func:`piezocomp.virtual_afm.calibration.calibration_speed`, for diagnosis)."""
        return self._calibration_scan

    @property
    def grating(self) -> Grating | None:
        """The calibration grating mounted instead of particles, if any."""
        return self._grating

    @property
    def limits(self) -> CommandLimits:
        """Range and slew limits of each axis' command."""
        return self._limits

    @property
    def command_nm(self) -> tuple[float, float]:
        """Command applied now to (x, y), nominal nm."""
        return self._u

    @property
    def time_s(self) -> float:
        """Session time, s (time of the next sample)."""
        return self._t

    # ----------------------------------------------------------------- internals
    def _checked(self, command_nm: ArrayLike, dt: float) -> NDArray[np.float64]:
        u = as_finite_array("command_nm", command_nm, ndim=2)
        if u.shape[1] != 2:
            raise ValueError(f"command_nm must have shape (n, 2). Got {u.shape}.")
        for i, axis in enumerate("xy"):  # the virtual AFM never clips: no clip hint
            self._limits.check(
                u[:, i], dt, previous_nm=self._u[i], name=f"command {axis}", clip_hint=""
            )
        return u

    def _advance(
        self, u: NDArray[np.float64], dt: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Run the scanner over checked commands; return (times, true positions). The drift
        offsets of those samples are kept in ``self._drift_blocks``."""
        drift = np.empty((u.shape[0], 2))
        pos, self._state = simulate(
            self._params, u, dt, self._state, self._rng_drift, drift_out=drift
        )
        self._drift_blocks.append(drift)
        t = self._t + dt * np.arange(u.shape[0], dtype=np.float64)
        self.truth.log(self._t, dt, pos)
        self._t += dt * u.shape[0]
        if u.shape[0]:
            self._u = (float(u[-1, 0]), float(u[-1, 1]))
        return t, pos

    def _heights(self, pos: NDArray[np.float64]) -> NDArray[np.float64]:
        s = self._config.sample
        noise = (
            s.height_noise_nm * self._rng_noise.standard_normal(pos.shape[0])
            if s.height_noise_nm > 0
            else np.zeros(pos.shape[0])
        )
        if self._grating is not None:
            return grating_topography(pos, self._grating, self._work.tip, self._substrate, noise)
        return topography(pos, self._work.surface, self._work.tip, self._substrate, noise)

    def _line(
        self, x_nm: float, y_nm: float, speed_nm_per_s: float, dt: float
    ) -> NDArray[np.float64]:
        """Straight-line command from the current command to (x, y) at ``speed``."""
        x = check_finite_scalar("x_nm", x_nm)
        y = check_finite_scalar("y_nm", y_nm)
        v = check_finite_scalar("speed_nm_per_s", speed_nm_per_s)
        if v <= 0:
            raise ValueError(f"speed_nm_per_s must be > 0. Got {v}.")
        if v > self.max_speed_nm_per_s:
            raise ValueError(
                f"speed_nm_per_s must be <= max_speed_nm_per_s = {self.max_speed_nm_per_s}. "
                f"Got {v}."
            )
        half = 0.5 * self.range_nm
        if abs(x) > half or abs(y) > half:  # checked before any sample is built
            raise ValueError(
                f"target ({x:.6g}, {y:.6g}) nm is outside the scanner range +-{half:g} nm; "
                "nothing was sent."
            )
        x0, y0 = self._u
        dist = math.hypot(x - x0, y - y0)
        n = max(1, math.ceil(dist / (v * dt) - 1e-9))
        _check_budget(n, f"a line of {dist:.6g} nm at {v:.6g} nm/s")
        f = np.arange(1, n + 1) / n
        return np.column_stack([x0 + (x - x0) * f, y0 + (y - y0) * f])

    # ----------------------------------------------------------------- Instrument API
    def run(
        self,
        command_nm: ArrayLike,
        *,
        sample_period_s: float | None = None,
        z_feedback: bool = True,
    ) -> Record:
        """Apply a command trajectory (n, 2), one row per sample period, recording at every
        sample.

        Parameters
        ----------
        command_nm : array_like, shape (n, 2)
            Commands of x and y, nominal nm.
        sample_period_s : float, optional
            Period of these samples, s (default :attr:`sample_period_s`); any period > 0.
        z_feedback : bool
            True: topography is recorded. False: Z feedback off, the tip's apex
            ``push_height_nm`` above the substrate pushes every particle in its way along
            the true path (see :meth:`push`); the height channel is NaN.

        Raises
        ------
        ValueError
            If any sample is outside the range or steps faster than the slew limit
            (nothing is applied then), or if pushing over a grating.
        """
        dt = self._T if sample_period_s is None else self._period(sample_period_s)
        u = self._checked(command_nm, dt)
        _check_budget(u.shape[0], "the trajectory")
        if not z_feedback:
            return self._push_run(u, dt)
        self._work.lift()
        self._drift_blocks = []
        t, pos = self._advance(u, dt)
        h = self._heights(pos)
        self._truth_of_last(pos)
        return Record(t, u, h)

    def _truth_of_last(self, pos: NDArray[np.float64]) -> None:
        """Keep the last command sequence's true positions and drift offsets."""
        self.truth.last_record_positions_nm = pos
        blocks = self._drift_blocks
        self.truth.last_record_drift_nm = np.vstack(blocks) if blocks else np.zeros((0, 2))
        self._drift_blocks = []

    def _period(self, sample_period_s: float) -> float:
        dt = check_finite_scalar("sample_period_s", sample_period_s)
        if dt <= 0:
            raise ValueError(f"sample_period_s must be > 0. Got {dt}.")
        return dt

    def _push_run(self, u: NDArray[np.float64], dt: float) -> Record:
        if self._grating is not None:
            raise ValueError(
                "push needs Z feedback off, which a grating sample does not allow (the tip "
                "would run into its lines); mount particles to push."
            )
        start = np.asarray(self._state.position_nm, float)
        self._drift_blocks = []
        t, pos = self._advance(u, dt)
        self._work.push(np.vstack([start, pos]))
        self._truth_of_last(pos)
        return Record(t, u, np.full(u.shape[0], np.nan))

    def move_to(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Move the command along a straight line to ``(x_nm, y_nm)`` at ``speed_nm_per_s``
        (Z feedback on, recording)."""
        return self.run(self._line(x_nm, y_nm, speed_nm_per_s, self._T))

    def wait(self, duration_s: float) -> Record:
        """Hold the command for ``duration_s`` (rounded to whole samples) while recording."""
        d = check_finite_scalar("duration_s", duration_s)
        if d < 0:
            raise ValueError(f"duration_s must be >= 0. Got {d}.")
        n = round(d / self._T)
        return self.run(np.tile(np.asarray(self._u, float), (n, 1)))

    def push(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Move in a straight line to ``(x_nm, y_nm)`` with Z feedback off: the tip, its apex
        ``push_height_nm`` above the substrate, pushes every particle in its way
        (:mod:`piezocomp.virtual_afm.pushing`: a push may fail). The height channel is NaN
        (no topography while pushing)."""
        return self.run(self._line(x_nm, y_nm, speed_nm_per_s, self._T), z_feedback=False)

    def scan_image(
        self,
        center_nm: tuple[float, float],
        size_nm: float,
        pixels: int,
        line_rate_hz: float,
        *,
        fast_axis: str = "x",
        progress: Callable[[float], None] | None = None,
    ) -> ScanImage:
        """Acquire a square raster image: fast axis ``fast_axis`` (forward then backward),
        the other axis slow and ascending, one height sample per pixel. ``progress``, if
        given, is called with the fraction of the image done after every block of lines.

        The tip first moves (at the fast-scan speed) to the first pixel; each line takes
        ``1 / line_rate_hz`` seconds (forward + backward) and the slow axis steps one pixel
        at the end of each line. Pixel ``i`` is at command
        ``center - size/2 + (i + 1/2) size/pixels``. A y-fast image (scan angle 90 degrees)
        is what the y axis' identification line is chosen from: its forward and backward
        traces are y traces.

        Returns
        -------
        ScanImage
            Forward and backward heights (ny, nx), both stored in ascending order of the
            fast axis (left to right, or bottom to top for ``fast_axis="y"``).
        """
        half = 0.5 * self.range_nm
        cx = check_finite_scalar("center_nm[0]", center_nm[0])
        cy = check_finite_scalar("center_nm[1]", center_nm[1])
        size = check_finite_scalar("size_nm", size_nm)
        if max(abs(cx), abs(cy)) + 0.5 * abs(size) > half:  # before any sample is built
            raise ValueError(
                f"the image ({size:.6g} nm about ({cx:.6g}, {cy:.6g}) nm) reaches outside the "
                f"scanner range +-{half:g} nm; nothing was sent."
            )
        raster = Raster.square(center_nm, size_nm, pixels, line_rate_hz, fast_axis=fast_axis)
        n, dt, speed = raster.x_nm.size, raster.sample_period_s, raster.speed_nm_per_s
        if speed > self.max_speed_nm_per_s:
            raise ValueError(
                f"scan speed 2 * size_nm * line_rate_hz = {speed:.6g} nm/s is "
                f"above max_speed_nm_per_s = {self.max_speed_nm_per_s:.6g}; "
                "lower line_rate_hz or size_nm."
            )
        path = raster.positions_nm
        approach = self._line(path[0, 0], path[0, 1], speed, dt)
        self._work.lift()
        u = self._checked(np.vstack([approach, path]), dt)
        t0 = self._t + dt * approach.shape[0]
        self._drift_blocks = []
        # in blocks of lines (batch == chunked: the same positions)
        step = 2 * n * PROGRESS_LINES
        parts: list[NDArray[np.float64]] = []
        for a in range(0, u.shape[0], step):
            _, p_blk = self._advance(u[a : a + step], dt)
            parts.append(p_blk)
            if progress is not None:
                progress(min(1.0, (a + step) / u.shape[0]))
        pos = np.vstack(parts)
        image = raster.image(self._heights(pos[approach.shape[0] :]), t0)
        p = pos[approach.shape[0] :].reshape(n, 2, n, 2)  # (slow, direction, fast, xy)
        pf, pb = p[:, 0].copy(), p[:, 1, ::-1].copy()
        if fast_axis == "y":  # (x, y) -> (ny, nx)
            pf, pb = pf.transpose(1, 0, 2).copy(), pb.transpose(1, 0, 2).copy()
        self._truth_of_last(pos)
        self.truth.last_image_positions_nm = (pf, pb)
        return image
