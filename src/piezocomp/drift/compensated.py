"""Drift compensation: an instrument whose positions stay fixed to the sample.

:class:`DriftCompensatedInstrument` wraps any :class:`~piezocomp.instrument.Instrument` (the
raw one, or a :class:`~piezocomp.positioning.CompensatedInstrument`: the two compensators
compose by wrapping) and is itself an ``Instrument``. Every position asked for is offset by
the drift predicted for the moment of that sample (:mod:`.filter`), so a move, an image, a
push or a wait lands where it should on the drifting sample.

The drift is measured on landmarks chosen in an overview when tracking starts
(:mod:`.landmarks`, :mod:`.landmark_set`), whenever :mod:`.schedule` says so; a landmark
that vanished, matches badly or disagrees with the others is replaced, never trusted.
Around a scanner without creep-and-hysteresis compensation
(:meth:`DriftSettings.uncompensated`) the scanner's own error at the landmarks is measured
too and sizes the windows, noise and tolerances (:mod:`.scanner_error`). Tracking that
cannot go on raises :class:`TrackingLost`. Time spent measuring is counted
(:attr:`DriftCompensatedInstrument.overhead_fraction`); the whole tracking state is saved
atomically and restored (:mod:`.state_file`), so a long manipulation survives a restart.
"""

from __future__ import annotations

import math
import os
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar
from piezocomp.drift.filter import (
    DriftEstimate,
    DriftFilter,
    DriftNoise,
    DriftSettings,
    Measurement,
)
from piezocomp.drift.landmark_set import LandmarkSet, clock, trusted
from piezocomp.drift.landmarks import Landmark, registered
from piezocomp.drift.noise_learning import SightingSpread, adopt, relearn
from piezocomp.drift.scanner_error import (
    ScannerError,
    approach_points,
    calibrate,
    resized,
    round_drifts,
)
from piezocomp.drift.schedule import WAIT_STEP_S, due, worth_measuring
from piezocomp.drift.state_file import TrackingState, load_tracking, save_tracking
from piezocomp.imaging.features import find_particles
from piezocomp.instrument import Instrument, Raster, Record, ScanImage, line_path

__all__ = ["DriftCompensatedInstrument", "DriftSettings", "Measurement", "TrackingLost"]


class TrackingLost(RuntimeError):
    """Drift tracking cannot measure: no landmark could be imaged, or every one was lost
    and none could be found again."""


class DriftCompensatedInstrument:
    """An :class:`~piezocomp.instrument.Instrument` whose positions stay fixed to the
    drifting sample.

    Parameters
    ----------
    instrument : Instrument
        The wrapped instrument (raw or compensated for creep and hysteresis).
    settings : DriftSettings, optional

    Notes
    -----
    Call :meth:`start` first: it chooses the landmarks, takes their templates and sets the
    drift's reference (zero) to that moment. The wrapped instrument must tell its clock
    (``time_s``, the session time of its next sample), as the virtual AFM and the
    compensated instrument do: the drift is predicted for the time of every sample.
    """

    def __init__(self, instrument: Instrument, settings: DriftSettings | None = None) -> None:
        if not isinstance(instrument, Instrument):
            raise TypeError(
                f"instrument must implement Instrument. Got {type(instrument).__name__}."
            )
        self._inner = instrument
        self._next_time()  # refuse an instrument without a clock now, not later
        self.settings = DriftSettings() if settings is None else settings
        self._filter: DriftFilter | None = None
        self._set = LandmarkSet()
        self._now = math.nan
        self._t_start = math.nan
        self._measuring_s = 0.0
        self._last_measurement = math.nan
        self.measurements: list[Measurement] = []
        """Every measurement taken, in order."""
        self.scanner_error: ScannerError | None = None
        """The wrapped scanner's error at the landmarks, when measured
        (:attr:`DriftSettings.measure_scanner_error`)."""
        self._base = self.settings  # the settings before sizing from the scanner's error
        self._prior = self.settings.noise  # the drift model learning starts from
        self.learnt_noise: list[tuple[int, DriftNoise]] = []
        """Every re-estimation of the drift's noise: how many measurements it used, and the
        noise then taken (:mod:`piezocomp.drift.noise_learning`)."""
        self.sighting_spread: SightingSpread | None = None
        """The landmarks' pooled spread the measurement noise is learnt from
        (:attr:`DriftSettings.learn_measurement_noise`; ``None``: none yet)."""

    # ------------------------------------------------------------------ properties
    @property
    def inner(self) -> Instrument:
        """The wrapped instrument."""
        return self._inner

    @property
    def sample_period_s(self) -> float:
        """The wrapped instrument's sample period, s."""
        return float(self._inner.sample_period_s)

    @property
    def range_nm(self) -> float:
        """The wrapped instrument's travel, nm."""
        return float(self._inner.range_nm)

    @property
    def max_speed_nm_per_s(self) -> float:
        """The wrapped instrument's speed limit, nm/s."""
        return float(self._inner.max_speed_nm_per_s)

    @property
    def command_nm(self) -> tuple[float, float]:
        """Where the tip is on the sample now (the wrapped instrument's position plus the
        predicted drift)."""
        d = self.drift_nm()
        c = self._inner.command_nm
        return (float(c[0] + d[0]), float(c[1] + d[1]))

    @property
    def landmarks(self) -> tuple[Landmark, ...]:
        """The landmarks in use."""
        return tuple(self._set.landmarks)

    @property
    def areas(self) -> dict[str, Landmark]:
        """The references of the areas imaged with :meth:`scan_area`, by name (a copy)."""
        return dict(self._set.areas)

    @property
    def measuring_s(self) -> float:
        """Time spent measuring drift since :meth:`start`, s."""
        return self._measuring_s

    @property
    def estimate(self) -> DriftEstimate:
        """The drift estimate after the last measurement."""
        return self._require().estimate

    @property
    def noise(self) -> DriftNoise:
        """The drift noise the filter runs with now (the prior until it is learnt; its
        ``measurement_nm`` stays the prior: :attr:`measurement_sigma_nm` is the one in use)."""
        return self._require().noise

    @property
    def measurement_sigma_nm(self) -> float:
        """The standard deviation of one landmark sighting in use, nm: learnt from the
        session's sightings (:attr:`sighting_spread`), else the settings' prior."""
        s, spread = self.settings, self.sighting_spread
        if spread is not None and s.learn_measurement_noise and self.scanner_error is None:
            return spread.sigma_nm
        return s.noise.measurement_nm

    @property
    def time_s(self) -> float:
        """Session time of the next sample, s."""
        return self._now

    @property
    def overhead_fraction(self) -> float:
        """Fraction of the time since :meth:`start` spent measuring drift."""
        total = self._now - self._t_start
        return float(self._measuring_s / total) if total > 0 else 0.0

    def drift_nm(self, t_s: float | None = None) -> NDArray[np.float64]:
        """The predicted drift at ``t_s`` (default: now), nm."""
        f = self._require()
        return f.at(self._now if t_s is None else t_s).displacement_nm

    # ------------------------------------------------------------------ start
    def start(
        self,
        *,
        overview: ScanImage | None = None,
        center_nm: tuple[float, float] = (0.0, 0.0),
        size_nm: float = 1000.0,
        avoid_nm: ArrayLike = (),
        avoid_radius_nm: float = 100.0,
    ) -> None:
        """Choose landmarks, take their templates, and set the drift's reference.

        Parameters
        ----------
        overview : ScanImage, optional
            An image the wrapped instrument just took; else one of ``center_nm +- size_nm/2``
            is taken.
        avoid_nm, avoid_radius_nm
            Points landmarks keep away from: particles about to be pushed, their targets.

        Raises
        ------
        ValueError
            If the overview holds no particle fit to be a landmark.
        """
        s = self.settings
        img = overview
        if img is None:
            img = self._inner.scan_image(center_nm, size_nm, s.overview_pixels,
                                         s.overview_line_rate_hz)  # fmt: skip
        centre = (float(np.mean(img.x_nm)), float(np.mean(img.y_nm)))
        self._set = LandmarkSet.chosen(
            self._inner, find_particles(img, trace=s.overview_trace), s.landmarks, centre,
            np.asarray(avoid_nm, dtype=float).reshape(-1, 2), float(avoid_radius_nm),
        )  # fmt: skip
        if not self._set.landmarks:
            raise TrackingLost(
                "no landmark could be imaged where the overview shows one: image the "
                "overview slower, or with the creep-and-hysteresis compensator."
            )
        t0 = float(np.mean([lm.t_s for lm in self._set.landmarks]))
        self._filter = DriftFilter(s.noise, DriftEstimate.start(t0, s.noise))
        self._now = self._next_time()
        self._t_start = t0
        self._last_measurement = t0
        if s.measure_scanner_error:
            self._base = s
            self._reacquire()  # as many as asked for, where some were not found
            self._calibrate(approach_points(centre, float(np.ptp(img.x_nm))))

    def _calibrate(self, points: NDArray[np.float64]) -> None:
        """Measure the scanner's error at the landmarks from ``points``
        (:mod:`piezocomp.drift.scanner_error`), size the settings from it and take the
        sightings as drift measurements; while windows miss their landmarks, grow them and
        measure again."""
        t_begin = self._now
        f = self._require()
        while True:
            rounds = calibrate(self._inner, self._set.landmarks, self.settings, points)
            error = ScannerError.from_rounds(rounds)
            if error is not None:
                self.scanner_error = error
                for t, z in round_drifts(rounds):
                    f.measure(t, z, np.full(2, np.max(error.sigma_nm)))
            missed = error is None or any(g.drift_nm is None for r in rounds for g in r)
            if not self._size(missed=missed):
                break
            self._retake_all()  # and measure again in the grown windows
        if self.scanner_error is None:
            raise TrackingLost(
                "no landmark was found again after the tip came from the overview's corners, "
                f"even in {self.settings.landmarks.window_nm:g} nm windows: the scanner's own "
                "error is larger than drift tracking on it can measure."
            )
        self._now = self._next_time()
        self._measuring_s += self._now - t_begin
        self._last_measurement = f.estimate.t_s

    def _size(self, *, missed: bool) -> bool:
        """Size the settings from the scanner error measured so far
        (:func:`~piezocomp.drift.scanner_error.resized`); whether the landmark window grew."""
        self.settings, grew = resized(self.settings, self._base, self.scanner_error, missed)
        if self.scanner_error is not None:
            self._require().noise = self.settings.noise
        return grew

    def _retake_all(self) -> None:
        """Take every landmark's template again with the settings now in force, where the
        estimate says it is (a landmark not found is dropped), and reacquire up to the count."""
        if not self._set.retake_all(self._inner, self.settings, self._require().at):
            self._lost()

    # ------------------------------------------------------------------ measuring
    def measure(self) -> Measurement:
        """Sight every landmark now, update the estimate and replace bad landmarks."""
        f = self._require()
        s = self.settings
        t_begin = self._now
        if not self._set.landmarks:
            self._reacquire()
        sightings = self._set.sight_all(self._inner, s.landmarks, f.at)
        good = trusted(sightings, f.at, s)
        drift = None
        t = float(np.mean([g.t_s for g in sightings]))
        retake = False
        if self.scanner_error is not None:  # measuring the scanner's error as we go
            pred = f.at(t)
            self.scanner_error = self.scanner_error.with_innovations(
                [np.asarray(sightings[i].drift_nm) - pred.displacement_nm for i in good],
                pred.cov[:, 0, 0],
            )
            retake = self._size(missed=any(g.drift_nm is None for g in sightings))
            s = self.settings
        if good:
            z = np.mean([np.asarray(sightings[i].drift_nm) for i in good], axis=0)
            # an uncompensated scanner's error is largely the same at every landmark (the
            # creep of where the tip has been): averaging them does not reduce it
            shared = self.scanner_error is not None
            if s.learn_measurement_noise and not shared:
                spread = self.sighting_spread or SightingSpread.prior(s.noise.measurement_nm)
                self.sighting_spread = spread.with_measurement(
                    [np.asarray(sightings[i].drift_nm) for i in good]
                )
            sigma = self.measurement_sigma_nm
            r2 = sigma**2 / (1 if shared else len(good)) + np.mean(
                [sightings[i].var_nm2 for i in good], axis=0
            )
            sig = np.sqrt(r2)
            f.measure(t, z, sig)
            drift = np.asarray(z)
        replaced = tuple(i for i in range(len(sightings)) if i not in good)
        if retake:  # every landmark again, in the grown window
            self._retake_all()
        for i in () if retake else reversed(replaced):  # from the end: no index shifts
            self._set.replace(i, self._inner, s, f.at)
        self._now = self._next_time()
        duration = self._now - t_begin
        self._measuring_s += duration
        self._last_measurement = t
        m = Measurement(t, drift, tuple(sightings), replaced, duration,
                        sigma_nm=None if drift is None else sig)  # fmt: skip
        self.measurements.append(m)
        self._learn_noise()
        return m

    def _learn_noise(self) -> None:
        """Re-estimate the drift's noise from the measurements so far, when due
        (:attr:`DriftSettings.learn_noise_after`, :mod:`piezocomp.drift.noise_learning`)."""
        s, f = self.settings, self._require()
        new = relearn(self.measurements, self._t_start, f.noise, s.learn_noise_after,
                      s.learn_noise_every, prior=self._prior if s.learn_order else None,
                      given_sigma=s.learn_given_sigma)  # fmt: skip
        if new is not None:
            f.estimate = f.estimate.with_order(new)
            f.noise = new
            self.settings = replace(s, noise=adopt(s.noise, new))
            self._base = replace(self._base, noise=adopt(self._base.noise, new))
            self.learnt_noise.append((sum(m.drift_nm is not None for m in self.measurements), new))

    def _reacquire(self) -> None:
        """New landmarks up to ``count`` (when every one was lost, or fewer are left),
        templated where the estimate says the overview's particles now are."""
        if not self._set.reacquire(self._inner, self.settings, self._require().at):
            self._lost()

    @staticmethod
    def _lost() -> None:
        raise TrackingLost(
            "drift tracking lost every landmark and found no new one among the overview's "
            "particles: start again with a new overview."
        )

    def _due(self, duration_s: float) -> bool:
        """Whether to measure before a motion of ``duration_s`` (:func:`.schedule.due`)."""
        return due(self._require(), self.settings, self._now + duration_s, self._last_measurement)

    def _worth_measuring(self, duration_s: float) -> bool:
        """Whether to measure before the next ``duration_s`` of an image or a wait
        (:func:`.schedule.worth_measuring`)."""
        return worth_measuring(self._require(), self.settings, self._now + duration_s,
                               self._last_measurement)  # fmt: skip

    # ------------------------------------------------------------------ Instrument API
    def run(
        self,
        command_nm: ArrayLike,
        *,
        sample_period_s: float | None = None,
        z_feedback: bool = True,
    ) -> Record:
        """Follow a trajectory of sample positions (n, 2), one row per sample."""
        p = as_finite_array("positions", command_nm, ndim=2)
        if p.shape[1] != 2:
            raise ValueError(f"positions must have shape (n, 2). Got {p.shape}.")
        dt = self.sample_period_s if sample_period_s is None else float(sample_period_s)
        if self._due(p.shape[0] * dt):
            self.measure()
            self._go_to(p[0], self.settings.landmarks.speed_nm_per_s)
        return self._send(p, dt, z_feedback)

    def move_to(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Move along a straight line on the sample to ``(x_nm, y_nm)``."""
        return self._line(x_nm, y_nm, speed_nm_per_s, z_feedback=True)

    def push(self, x_nm: float, y_nm: float, speed_nm_per_s: float) -> Record:
        """Push along a straight line on the sample to ``(x_nm, y_nm)``, Z feedback off."""
        return self._line(x_nm, y_nm, speed_nm_per_s, z_feedback=False)

    def wait(self, duration_s: float) -> Record:
        """Hold the tip over one point of the sample for ``duration_s``.

        The drift is measured first if it will be due by the end; a long wait is held in
        pieces of :data:`~piezocomp.drift.schedule.WAIT_STEP_S`, measured between them as an
        image is between its lines (the record holds the wait's samples only, the gaps in
        ``t_s``)."""
        d = check_finite_scalar("duration_s", duration_s)
        if d < 0:
            raise ValueError(f"duration_s must be >= 0. Got {d}.")
        here = np.asarray(self.command_nm)
        T = self.sample_period_s
        n = round(d / T)
        step = max(1, round(WAIT_STEP_S / T))
        pieces = []
        for k in range(0, max(n, 1), step):
            m = min(step, n - k)
            if self._due(d) if k == 0 else self._worth_measuring(m * T):
                self.measure()
                self._go_to(here, self.settings.landmarks.speed_nm_per_s)
            pieces.append(self._send(np.tile(here, (m, 1)), T, True))
        return pieces[0] if len(pieces) == 1 else Record.joined(pieces)

    def scan_image(
        self,
        center_nm: tuple[float, float],
        size_nm: float,
        pixels: int,
        line_rate_hz: float,
        *,
        fast_axis: str = "x",
    ) -> ScanImage:
        """An image whose pixels are fixed to the sample: each pixel's position is offset by
        the drift predicted for its moment. The drift is measured first if it will be due
        before the image ends (:attr:`DriftSettings.tolerance_nm`); an image of minutes may
        still outlast that, so between lines it is measured again when the uncertainty
        would pass :attr:`DriftSettings.image_tolerance_nm` (or ``max_interval_s`` has
        passed), and the lines' start times go with the image."""
        return self._scan(center_nm, size_nm, pixels, line_rate_hz, fast_axis)[0]

    def scan_area(
        self,
        name: str,
        center_nm: tuple[float, float],
        size_nm: float,
        pixels: int,
        line_rate_hz: float,
        *,
        fast_axis: str = "x",
    ) -> ScanImage:
        """An image of an area the work leaves as it is (:meth:`scan_image`), taken as a
        drift sighting that costs no time.

        The first image of the area ``name`` is its reference. Each later one, of the same
        raster, is registered against it as a landmark's window is against its template
        (:func:`~piezocomp.drift.landmarks.registered`) and measures the drift: the shift
        between the two is what the drift predicted for their pixels missed (the
        reference's own miss, unknown, counted as the variance of its prediction). The
        image was work to be done anyway, so the sighting adds nothing to the time spent
        measuring, and the landmarks are due later. Two limits: the reference's miss is the
        same in every later sighting of the area, though each is taken as independent of
        the others; and each sighting carries the scanner's error at that area into the
        estimate, which the next motion, elsewhere, inherits. A reference stays for the
        session (an area that changed for good is refused at every visit: image it under
        a new name).

        It is trusted as a lone landmark is: registered with a match error below
        ``max_match_error`` and within ``gate_sigma`` of the prediction; otherwise (the
        area changed: a particle pushed or picked up, the tip changed) it is recorded in
        :attr:`measurements` with its reason and left out. An image during which the drift
        was measured is not a sighting (nor a reference: the next image is): its pixels
        were not placed by one prediction. Only for areas nothing changes between two
        visits: an area being worked on (pushed, written) is imaged with
        :meth:`scan_image`.

        Raises
        ------
        ValueError
            If ``name`` was imaged before with another raster.
        """
        ref = self._set.areas.get(name)
        if ref is not None:  # refused before imaging
            raster = Raster.square(center_nm, size_nm, pixels, line_rate_hz, fast_axis=fast_axis)
            tpl = ref.template
            if not (
                np.array_equal(tpl.x_nm, raster.x_nm) and np.array_equal(tpl.y_nm, raster.y_nm)
                and math.isclose(tpl.line_time_s, 1.0 / raster.line_rate_hz)
                and tpl.fast_axis == raster.fast_axis
            ):  # fmt: skip
                side = float(tpl.x_nm[-1] - tpl.x_nm[0]) * tpl.x_nm.size / (tpl.x_nm.size - 1)
                raise ValueError(
                    f"area {name!r} was first imaged centred at ({np.mean(tpl.x_nm):.1f}, "
                    f"{np.mean(tpl.y_nm):.1f}) nm, {side:g} nm, {tpl.x_nm.size} pixels, "
                    f"{1.0 / tpl.line_time_s:g} lines/s, fast axis {tpl.fast_axis}: its "
                    "later images must have the same raster."
                )
        img, applied, clean = self._scan(center_nm, size_nm, pixels, line_rate_hz, fast_axis)
        f, s = self._require(), self.settings
        t = float(np.mean(np.concatenate([p.ravel() for p in img.pixel_times_s()])))
        if not clean:
            return img
        if ref is None:
            c = np.asarray(center_nm, dtype=float)
            self._set.areas[name] = Landmark(c, img, t, applied, f.at(t).cov[:, 0, 0])
            return img
        g = registered(t, applied, ref, img, img, s.landmarks)
        good = trusted([g], f.at, s)
        drift = sig = None
        if good:
            sig = np.sqrt(self.measurement_sigma_nm**2 + g.var_nm2)
            f.measure(t, np.asarray(g.drift_nm), sig)
            drift = np.asarray(g.drift_nm)
            self._last_measurement = t
        elif not g.reason:
            g = replace(g, reason="the area's drift disagrees with the prediction")
        self.measurements.append(Measurement(t, drift, (g,), (), 0.0, name, sig))
        self._learn_noise()
        return img

    def _scan(
        self, center_nm: tuple[float, float], size_nm: float, pixels: int,
        line_rate_hz: float, fast_axis: str,
    ) -> tuple[ScanImage, NDArray[np.float64], bool]:  # fmt: skip
        """:meth:`scan_image`'s image, the mean drift its pixels were placed with, and
        whether no measurement came between its lines."""
        raster = Raster.square(center_nm, size_nm, pixels, line_rate_hz, fast_axis=fast_axis)
        path, T = raster.positions_nm, raster.sample_period_s
        per_line = path.shape[0] // pixels
        speed = min(raster.speed_nm_per_s, self.max_speed_nm_per_s)
        heights, starts = [], []
        applied: list[NDArray[np.float64]] = []
        if self._due(path.shape[0] * T):  # measured before rather than during the image
            self.measure()
        clean = True
        for j in range(pixels):
            line = path[j * per_line : (j + 1) * per_line]
            measured = j > 0 and self._worth_measuring(line.shape[0] * T)
            if measured:
                self.measure()
                clean = False
            if j == 0 or measured:  # to the image's start, or back to the line's
                self._go_to(line[0], speed)
            rec = self._send(line, T, True, applied)
            heights.append(rec.height_nm)
            starts.append(float(rec.t_s[0]))
        gaps = np.diff(starts) > per_line * T * (1 + 1e-6)
        img = raster.image(np.concatenate(heights), starts[0],
                           np.asarray(starts) if gaps.any() else None)  # fmt: skip
        return img, np.mean(np.concatenate(applied), axis=0), clean

    # ------------------------------------------------------------------ internals
    def _require(self) -> DriftFilter:
        if self._filter is None:
            raise RuntimeError("drift tracking has not started: call start() first.")
        return self._filter

    def _next_time(self) -> float:
        """Time of the wrapped instrument's next sample (its ``time_s``), s."""
        return clock(self._inner)

    def _line(self, x_nm: float, y_nm: float, speed: float, *, z_feedback: bool) -> Record:
        x = check_finite_scalar("x_nm", x_nm)
        y = check_finite_scalar("y_nm", y_nm)
        v = check_finite_scalar("speed_nm_per_s", speed)
        if not 0 < v <= self.max_speed_nm_per_s:
            raise ValueError(
                f"speed_nm_per_s must be in (0, {self.max_speed_nm_per_s:g}]. Got {v}."
            )
        T = self.sample_period_s
        start, end = np.asarray(self.command_nm), np.array([x, y])
        path = line_path(start, end, v, T)
        if self._due(path.shape[0] * T):
            self.measure()  # the tip is at a landmark now
            if z_feedback:  # a move goes on from there
                path = line_path(np.asarray(self.command_nm), end, v, T)
            else:  # a push starts where it was asked to, never from the landmark
                self._go_to(start, self.settings.landmarks.speed_nm_per_s)
        return self._send(path, T, z_feedback)

    def _go_to(self, p: NDArray[np.float64], speed: float) -> None:
        """Move (Z feedback on) to sample position ``p``, drift-corrected."""
        T = self.sample_period_s
        self._send(line_path(np.asarray(self.command_nm), p, speed, T), T, True)

    def _send(
        self, p: NDArray[np.float64], dt: float, z_feedback: bool,
        applied: list[NDArray[np.float64]] | None = None,
    ) -> Record:  # fmt: skip
        """Send sample positions ``p`` to the wrapped instrument, each offset by the drift
        predicted for its moment (appended to ``applied`` when given)."""
        f = self._require()
        t = self._next_time() + dt * np.arange(p.shape[0])
        est = f.estimate
        # the predicted drift at every sample: the mean of the state carried forward
        k = est.mean.shape[1]
        tau = t - est.t_s
        basis = np.column_stack([tau**j / math.factorial(j) for j in range(k)])
        drift = basis @ est.mean.T
        if applied is not None:
            applied.append(drift)
        period = None if dt == self.sample_period_s else dt
        rec = self._inner.run(p - drift, sample_period_s=period, z_feedback=z_feedback)
        self._now = self._next_time()
        return Record(rec.t_s, p, rec.height_nm, rec.timing)

    # ------------------------------------------------------------------ persistence
    def state(self) -> TrackingState:
        """The whole tracking state now (:mod:`piezocomp.drift.state_file`)."""
        return TrackingState(self.settings, self._base, self.scanner_error,
                             self._require().estimate, self._set, self._t_start,
                             self._measuring_s, self._last_measurement,
                             self.sighting_spread, self._prior)  # fmt: skip

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the tracking state (estimate, landmarks and their templates, counters, the
        scanner error measured) atomically to ``path`` (``.npz``)."""
        save_tracking(path, self.state())

    @classmethod
    def resume(cls, state: TrackingState, instrument: Instrument) -> DriftCompensatedInstrument:
        """Go on tracking from ``state`` on ``instrument`` (the same wrapped instrument, still
        in its session: its clock goes on)."""
        self = cls(instrument, state.settings)
        self._base = state.base_settings
        self.scanner_error = state.scanner_error
        self._filter = DriftFilter(state.settings.noise, state.estimate)
        self._set = state.landmarks
        self._t_start = state.t_start_s
        self._measuring_s = state.measuring_s
        self._last_measurement = state.last_measurement_s
        self.sighting_spread = state.sighting_spread
        if state.prior_noise is not None:
            self._prior = state.prior_noise
        self._now = self._next_time()
        return self

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], instrument: Instrument
    ) -> DriftCompensatedInstrument:
        """Resume tracking from a state saved in ``path``, on ``instrument`` (the same
        wrapped instrument, still in its session: its clock goes on)."""
        return cls.resume(load_tracking(path), instrument)
