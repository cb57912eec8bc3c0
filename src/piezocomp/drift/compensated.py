"""Drift compensation: an instrument whose positions stay fixed to the sample.

:class:`DriftCompensatedInstrument` wraps any :class:`~piezocomp.instrument.Instrument` (the
raw one, or a :class:`~piezocomp.positioning.CompensatedInstrument`: the two compensators
compose by wrapping) and is itself an ``Instrument``. Its positions are the sample's: every
position asked for is offset by the drift predicted for the moment of that sample
(:mod:`piezocomp.drift.filter`) before it reaches the wrapped instrument, so a move, an image, a
push or a wait lands where it should on the drifting sample.

The drift is measured on landmarks (:mod:`piezocomp.drift.landmarks`): chosen automatically from an
overview image when tracking starts, imaged as templates, then imaged again whenever the
predicted uncertainty of the drift would exceed ``tolerance_nm`` by the end of the next
motion, or ``max_interval_s`` has passed. A landmark that vanished, matches badly or moved
(it disagrees with the others beyond ``gate_sigma`` standard deviations) is replaced by a new
one, templated where the estimate says it is, never trusted. Time spent measuring is counted:
:attr:`DriftCompensatedInstrument.overhead_fraction`.

Around a scanner without creep-and-hysteresis compensation
(:meth:`DriftSettings.uncompensated`) every landmark sighting also carries the scanner's own
error; it is measured when tracking starts and with every sighting after
(:mod:`piezocomp.drift.scanner_error`), and sizes the windows (which grow while they miss),
the measurement noise and the tolerances. Tracking that cannot go on raises
:class:`TrackingLost`.

The whole tracking state (the estimate, the landmarks' templates, the counters, the scanner
error measured) is saved atomically (:meth:`DriftCompensatedInstrument.save`,
:mod:`piezocomp.drift.state_file`) and restored (:meth:`DriftCompensatedInstrument.load`),
so a long manipulation survives a restart.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, replace

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
from piezocomp.drift.landmarks import (
    Landmark,
    Sighting,
    choose_landmarks,
    take_template,
)
from piezocomp.drift.landmarks import sight as sight_landmark
from piezocomp.drift.noise_learning import adopt, relearn
from piezocomp.drift.scanner_error import (
    ScannerError,
    approach_points,
    calibrate,
    grown_window_nm,
    sized,
)
from piezocomp.drift.state_file import (
    landmarks_from,
    landmarks_to,
    read_state,
    scanner_error_from,
    scanner_error_to,
    settings_from,
    write_state,
)
from piezocomp.imaging.features import FoundParticles, find_particles
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
        self._landmarks: list[Landmark] = []
        self._particles: FoundParticles | None = None
        self._avoid = np.zeros((0, 2))
        self._avoid_radius = 100.0
        self._retired: list[NDArray[np.float64]] = []
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
        self.learnt_noise: list[tuple[int, DriftNoise]] = []
        """Every re-estimation of the drift's noise: how many measurements it used, and the
        noise then taken (:mod:`piezocomp.drift.noise_learning`)."""

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
        return tuple(self._landmarks)

    @property
    def estimate(self) -> DriftEstimate:
        """The drift estimate after the last measurement."""
        return self._require().estimate

    @property
    def noise(self) -> DriftNoise:
        """The drift noise the filter runs with now (the prior until it is learnt)."""
        return self._require().noise

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
        self._particles = find_particles(img, trace=s.overview_trace)
        self._avoid = np.asarray(avoid_nm, dtype=float).reshape(-1, 2)
        self._avoid_radius = float(avoid_radius_nm)
        centre = (float(np.mean(img.x_nm)), float(np.mean(img.y_nm)))
        picks = choose_landmarks(self._particles, s.landmarks, avoid_nm=self._avoid,
                                 avoid_radius_nm=self._avoid_radius, near_nm=centre)  # fmt: skip
        if not picks:
            raise ValueError(
                "no particle of the overview is fit to be a landmark (alone within "
                f"{s.landmarks.clearance_nm:g} nm, away from the points to avoid): image a "
                "larger area."
            )
        landmarks = [lm for c in picks if (lm := take_template(self._inner, c, s.landmarks))]
        if not landmarks:
            raise TrackingLost(
                "no landmark could be imaged where the overview shows one: image the "
                "overview slower, or with the creep-and-hysteresis compensator."
            )
        t0 = float(np.mean([lm.t_s for lm in landmarks]))
        self._landmarks = landmarks
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
            rounds = calibrate(self._inner, self._landmarks, self.settings, points)
            error = ScannerError.from_rounds(rounds)
            if error is not None:
                self.scanner_error = error
                for sightings in rounds:
                    seen = [g for g in sightings if g.drift_nm is not None]
                    if seen:
                        z = np.mean([np.asarray(g.drift_nm) for g in seen], axis=0)
                        f.measure(float(np.mean([g.t_s for g in seen])), z,
                                  np.full(2, np.max(error.sigma_nm)))  # fmt: skip
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
        """Size the settings from the scanner error measured so far (only the window
        before there is one); whether the landmark window grew (its templates must then
        be taken again)."""
        base, err = self._base, self.scanner_error
        w = grown_window_nm(self.settings, base.landmarks.window_nm, err, missed)
        grew = w > self.settings.landmarks.window_nm
        if err is None:
            ls = self.settings.landmarks
            self.settings = replace(self.settings, landmarks=replace(
                ls, window_nm=w, search_nm=max(ls.search_nm or 0.0, 2.0 * w)))  # fmt: skip
        else:
            self.settings = sized(base, err, w)
            self._require().noise = self.settings.noise
        return grew

    def _retake_all(self) -> None:
        """Take every landmark's template again with the settings now in force, where the
        estimate says it is (a landmark not found is dropped)."""
        f = self._require()
        for i in reversed(range(len(self._landmarks))):
            lm = self._landmarks[i]
            here = lm.center_nm - (self.drift_nm(self._next_time()) - lm.offset_nm)
            new = take_template(self._inner, here, self.settings.landmarks)
            if new is None:
                self._retired.append(np.asarray(lm.center_nm + lm.offset_nm))
                del self._landmarks[i]
                continue
            at = f.at(new.t_s)
            self._landmarks[i] = replace(new, offset_nm=at.displacement_nm,
                                         offset_var_nm2=at.cov[:, 0, 0])  # fmt: skip
        self._reacquire()  # as many as before

    # ------------------------------------------------------------------ measuring
    def measure(self) -> Measurement:
        """Sight every landmark now, update the estimate and replace bad landmarks."""
        f = self._require()
        s = self.settings
        t_begin = self._now
        if not self._landmarks:
            self._reacquire()
        sightings = [
            sight_landmark(self._inner, lm, f.at(self._next_time()).displacement_nm, s.landmarks)
            for lm in self._landmarks
        ]
        good = self._trusted(sightings)
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
            r2 = s.noise.measurement_nm**2 / (1 if shared else len(good)) + np.mean(
                [sightings[i].var_nm2 for i in good], axis=0
            )
            f.measure(t, z, np.sqrt(r2))
            drift = np.asarray(z)
        replaced = tuple(i for i in range(len(sightings)) if i not in good)
        if retake:  # every landmark again, in the grown window
            self._retake_all()
        for i in () if retake else reversed(replaced):  # from the end: no index shifts
            self._replace(i)
        self._now = self._next_time()
        duration = self._now - t_begin
        self._measuring_s += duration
        self._last_measurement = t
        m = Measurement(t, drift, tuple(sightings), replaced, duration)
        self.measurements.append(m)
        self._learn_noise()
        return m

    def _learn_noise(self) -> None:
        """Re-estimate the drift's noise from the measurements so far, when due
        (:attr:`DriftSettings.learn_noise_after`, :mod:`piezocomp.drift.noise_learning`)."""
        s, f = self.settings, self._require()
        new = relearn(self.measurements, self._t_start, f.noise, s.learn_noise_after,
                      s.learn_noise_every)  # fmt: skip
        if new is not None:
            f.noise = new
            self.settings = replace(s, noise=adopt(s.noise, new))
            self._base = replace(self._base, noise=adopt(self._base.noise, new))
            self.learnt_noise.append((sum(m.drift_nm is not None for m in self.measurements), new))

    def _trusted(self, sightings: list[Sighting]) -> list[int]:
        """Indices of the sightings to trust: seen, and consistent with one another (or, for
        a single one, with the prediction)."""
        f = self._require()
        s = self.settings
        seen = [i for i, g in enumerate(sightings) if g.drift_nm is not None]
        if not seen:
            return []
        sig_m = s.noise.measurement_nm
        if len(seen) >= 2:
            zs = np.array([sightings[i].drift_nm for i in seen])
            med = np.median(zs, axis=0)
            spread = [np.max(np.abs(sightings[i].drift_nm - med)) for i in seen]
            return [i for i, d in zip(seen, spread, strict=True) if d <= s.gate_sigma * sig_m]
        g = sightings[seen[0]]
        pred = f.at(g.t_s)
        std = np.sqrt(pred.cov[:, 0, 0] + sig_m**2 + g.var_nm2)
        miss = np.abs(np.asarray(g.drift_nm) - pred.displacement_nm)
        return [seen[0]] if np.all(miss <= s.gate_sigma * std) else []

    def _reacquire(self) -> None:
        """New landmarks up to ``count`` (when every one was lost, or fewer are left),
        templated where the estimate says the overview's particles now are."""
        s = self.settings
        f = self._require()
        avoid = np.vstack([self._avoid.reshape(-1, 2), *self._retired])
        taken = [lm.center_nm + lm.offset_nm for lm in self._landmarks]
        need = s.landmarks.count - len(taken)
        picks = [] if self._particles is None or need <= 0 else choose_landmarks(
            self._particles, s.landmarks, count=need, avoid_nm=avoid,
            avoid_radius_nm=max(self._avoid_radius, s.landmarks.clearance_nm), taken_nm=taken,
        )  # fmt: skip
        for c in picks:
            lm = take_template(self._inner, c - self.drift_nm(self._next_time()), s.landmarks)
            if lm is not None:
                at = f.at(lm.t_s)
                self._landmarks.append(replace(lm, offset_nm=at.displacement_nm,
                                               offset_var_nm2=at.cov[:, 0, 0]))  # fmt: skip
        if not self._landmarks:
            raise TrackingLost(
                "drift tracking lost every landmark and found no new one among the overview's "
                "particles: start again with a new overview."
            )

    def _replace(self, index: int) -> None:
        """Replace landmark ``index`` by a new one templated where the estimate says it is
        (the next fit particle of the overview; the landmark is dropped if none is left)."""
        old = self._landmarks[index]
        self._retired.append(np.asarray(old.center_nm + old.offset_nm))
        if self._particles is None:
            del self._landmarks[index]
            return
        s = self.settings
        f = self._require()
        taken = [lm.center_nm + lm.offset_nm for j, lm in enumerate(self._landmarks) if j != index]
        avoid = np.vstack([self._avoid.reshape(-1, 2), *self._retired])
        for _ in range(3):
            picks = choose_landmarks(
                self._particles, s.landmarks, count=1, avoid_nm=avoid,
                avoid_radius_nm=max(self._avoid_radius, s.landmarks.clearance_nm),
                near_nm=tuple(old.center_nm), taken_nm=taken,
            )  # fmt: skip
            if not picks:
                break
            # the particle, at c in the overview, now shows at c - drift
            lm = take_template(self._inner, picks[0] - self.drift_nm(self._next_time()),
                               s.landmarks)  # fmt: skip
            if lm is not None:
                at = f.at(lm.t_s)
                self._landmarks[index] = replace(lm, offset_nm=at.displacement_nm,
                                                 offset_var_nm2=at.cov[:, 0, 0])  # fmt: skip
                return
            avoid = np.vstack([avoid, picks[0]])
            self._retired.append(np.asarray(picks[0]))
        del self._landmarks[index]

    def _due(self, duration_s: float, tolerance_nm: float | None = None) -> bool:
        f = self._require()
        end = self._now + duration_s
        if end - self._last_measurement > self.settings.max_interval_s:
            return True
        tol = self.settings.tolerance_nm if tolerance_nm is None else tolerance_nm
        return bool(np.max(f.at(end).std_nm) > tol)

    def _worth_measuring(self, duration_s: float) -> bool:
        """Whether to interrupt an image to measure: the drift will be due
        (``image_tolerance_nm`` or ``max_interval_s``) by the end of the next line, and the
        last measurement did bring its uncertainty below that tolerance (with noisy
        measurements another one would not, and every line would be interrupted)."""
        s = self.settings
        if not self._due(duration_s, s.image_tolerance_nm):
            return False
        overdue = self._now + duration_s - self._last_measurement > s.max_interval_s
        return overdue or bool(np.max(self._require().estimate.std_nm) < s.image_tolerance_nm)

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
        """Hold the tip over one point of the sample for ``duration_s``."""
        d = check_finite_scalar("duration_s", duration_s)
        if d < 0:
            raise ValueError(f"duration_s must be >= 0. Got {d}.")
        here = np.asarray(self.command_nm)
        n = round(d / self.sample_period_s)
        if self._due(d):
            self.measure()
            self._go_to(here, self.settings.landmarks.speed_nm_per_s)
        return self._send(np.tile(here, (n, 1)), self.sample_period_s, True)

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
        raster = Raster.square(center_nm, size_nm, pixels, line_rate_hz, fast_axis=fast_axis)
        path, T = raster.positions_nm, raster.sample_period_s
        per_line = path.shape[0] // pixels
        speed = min(raster.speed_nm_per_s, self.max_speed_nm_per_s)
        heights, starts = [], []
        if self._due(path.shape[0] * T):  # measured before rather than during the image
            self.measure()
        for j in range(pixels):
            line = path[j * per_line : (j + 1) * per_line]
            measured = j > 0 and self._worth_measuring(line.shape[0] * T)
            if measured:
                self.measure()
            if j == 0 or measured:  # to the image's start, or back to the line's
                self._go_to(line[0], speed)
            rec = self._send(line, T, True)
            heights.append(rec.height_nm)
            starts.append(float(rec.t_s[0]))
        gaps = np.diff(starts) > per_line * T * (1 + 1e-6)
        return raster.image(np.concatenate(heights), starts[0],
                            np.asarray(starts) if gaps.any() else None)  # fmt: skip

    # ------------------------------------------------------------------ internals
    def _require(self) -> DriftFilter:
        if self._filter is None:
            raise RuntimeError("drift tracking has not started: call start() first.")
        return self._filter

    def _next_time(self) -> float:
        """Time of the wrapped instrument's next sample (its ``time_s``), s."""
        t = getattr(self._inner, "time_s", None)
        if t is None:
            raise TypeError(
                "drift compensation needs the wrapped instrument's clock: a time_s property "
                "(session time of its next sample)."
            )
        return float(t)

    def _line(self, x_nm: float, y_nm: float, speed: float, *, z_feedback: bool) -> Record:
        x = check_finite_scalar("x_nm", x_nm)
        y = check_finite_scalar("y_nm", y_nm)
        v = check_finite_scalar("speed_nm_per_s", speed)
        if not 0 < v <= self.max_speed_nm_per_s:
            raise ValueError(
                f"speed_nm_per_s must be in (0, {self.max_speed_nm_per_s:g}]. Got {v}."
            )
        T = self.sample_period_s
        end = np.array([x, y])
        path = line_path(np.asarray(self.command_nm), end, v, T)
        if self._due(path.shape[0] * T):
            self.measure()
            path = line_path(np.asarray(self.command_nm), end, v, T)
        return self._send(path, T, z_feedback)

    def _go_to(self, p: NDArray[np.float64], speed: float) -> None:
        """Move (Z feedback on) to sample position ``p``, drift-corrected."""
        T = self.sample_period_s
        self._send(line_path(np.asarray(self.command_nm), p, speed, T), T, True)

    def _send(self, p: NDArray[np.float64], dt: float, z_feedback: bool) -> Record:
        f = self._require()
        t = self._next_time() + dt * np.arange(p.shape[0])
        est = f.estimate
        # the predicted drift at every sample: the mean of the state carried forward
        k = est.mean.shape[1]
        tau = t - est.t_s
        basis = np.column_stack([tau**j / math.factorial(j) for j in range(k)])
        drift = basis @ est.mean.T
        period = None if dt == self.sample_period_s else dt
        rec = self._inner.run(p - drift, sample_period_s=period, z_feedback=z_feedback)
        self._now = self._next_time()
        return Record(rec.t_s, p, rec.height_nm, rec.timing)

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the tracking state (estimate, landmarks and their templates, counters, the
        scanner error measured) atomically to ``path`` (``.npz``)."""
        f = self._require()
        lms, arrays = landmarks_to(self._landmarks)
        meta = {
            "settings": self.settings,
            "base_settings": asdict(self._base),
            "scanner_error": scanner_error_to(self.scanner_error),
            "t_start_s": self._t_start,
            "avoid_radius_nm": self._avoid_radius,
            "measuring_s": self._measuring_s,
            "last_measurement_s": self._last_measurement,
            "estimate_t_s": f.estimate.t_s,
            "landmarks": lms,
        }
        arrays.update({
            "mean": f.estimate.mean, "cov": f.estimate.cov, "avoid": self._avoid,
            "retired": np.asarray(self._retired, dtype=float).reshape(-1, 2),
        })  # fmt: skip
        if self._particles is not None:
            arrays["particles"] = self._particles.positions_nm
            arrays["particle_heights"] = self._particles.heights_nm
        write_state(path, meta, arrays)

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], instrument: Instrument
    ) -> DriftCompensatedInstrument:
        """Resume tracking from a saved state, on ``instrument`` (the same wrapped
        instrument, still in its session: its clock goes on)."""
        meta, data = read_state(path)
        settings = meta["settings"]
        self = cls(instrument, settings)
        if meta.get("base_settings") is not None:
            self._base = settings_from(meta["base_settings"])
        self.scanner_error = scanner_error_from(meta.get("scanner_error"))
        est = DriftEstimate(meta["estimate_t_s"], data["mean"], data["cov"])
        self._filter = DriftFilter(settings.noise, est)
        self._avoid = data["avoid"].reshape(-1, 2)
        self._avoid_radius = float(meta.get("avoid_radius_nm", 100.0))
        self._retired = [np.asarray(r) for r in data.get("retired", np.zeros((0, 2)))]
        if "particles" in data:
            self._particles = FoundParticles(data["particles"], data["particle_heights"])
        self._landmarks = landmarks_from(meta["landmarks"], data)
        self._t_start = meta["t_start_s"]
        self._measuring_s = meta["measuring_s"]
        self._last_measurement = meta["last_measurement_s"]
        self._now = self._next_time()
        return self
