"""Thermal drift: a Kalman filter of the drift displacement measured on landmarks.

The paper's compensator runs inside a drift-compensated AFM (the same authors' earlier work,
IEEE T-ASE 3(3), 2006: Kalman filtering of drift measured on landmarks). Each axis' drift
``d(t)`` is tracked independently with the state ``[d, v]`` (displacement and velocity), or
``[d, v, a]`` with the acceleration of a warming-up instrument:

- the displacement has a white-noise velocity on top of the state's (a random walk of
  intensity ``position_nm_per_sqrt_s``: the drift's own random walk);
- the highest derivative is itself a random walk (``rate_noise``: nm/s per sqrt(s) for the
  velocity, nm/s^2 per sqrt(s) for the acceleration), so the filter follows a drift rate that
  changes.

The continuous model is discretised exactly for any interval (measurements come at irregular
times). Everything exists twice, as in filterpy: pure functions (:func:`predict`,
:func:`update`) on a :class:`DriftEstimate`, and the stateful :class:`DriftFilter`. The
noise can be estimated from a recorded run by maximum likelihood over the innovations
(:func:`fit_noise`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.drift import _kernels
from piezocomp.drift.landmarks import LandmarkSettings, Sighting

__all__ = [
    "MIN_MEASUREMENT_NM",
    "DriftEstimate",
    "DriftFilter",
    "DriftNoise",
    "DriftSettings",
    "Measurement",
    "NoiseFit",
    "fit_noise",
    "initial_acceleration_var",
    "log_likelihood",
    "predict",
    "update",
]


@dataclass(frozen=True)
class DriftNoise:
    """The drift model's noise, the same for both axes.

    The defaults are a generic prior, set for no instrument in particular (and equal to
    none of the virtual AFM's presets): tracking starts from them and learns the drift's
    own noise from its measurements (:mod:`piezocomp.drift.noise_learning`). 0.05 nm/sqrt(s)
    is on the cautious side for an ambient AFM after warm-up (a filter that expects more
    random walk than there is measures more often, never less accurately).

    Parameters
    ----------
    position_nm_per_sqrt_s : float
        Random walk of the displacement itself (white velocity noise), nm/sqrt(s).
    rate_noise : float
        Random walk of the highest derivative of the state: of the velocity (order 2),
        nm/s/sqrt(s), or of the acceleration (order 3), nm/s^2/sqrt(s).
    measurement_nm : float
        Standard deviation of one landmark measurement, nm: the registration's own error
        and the positioning error of the scanner at the landmark (about 0.5 nm through the
        creep-and-hysteresis compensator on ``cpr5``).
    order : {2, 3}
        ``[d, v]``, or ``[d, v, a]`` for a drift rate that changes steadily (warm-up).
    initial_velocity_nm_per_s : float
        Prior standard deviation of the drift velocity when tracking starts.
    """

    position_nm_per_sqrt_s: float = 0.05
    rate_noise: float = 1e-6
    measurement_nm: float = 0.5
    order: int = 3
    initial_velocity_nm_per_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ("position_nm_per_sqrt_s", "rate_noise", "measurement_nm",
                     "initial_velocity_nm_per_s"):  # fmt: skip
            v = check_finite_scalar(name, getattr(self, name))
            if v < 0:
                raise ValueError(f"{name} must be >= 0. Got {v}.")
            object.__setattr__(self, name, v)
        if self.order not in (2, 3):
            raise ValueError(f"order must be 2 or 3. Got {self.order!r}.")
        if self.measurement_nm <= 0:
            raise ValueError(f"measurement_nm must be > 0. Got {self.measurement_nm}.")

    def transition(self, dt_s: float) -> NDArray[np.float64]:
        """``F`` of the state over ``dt_s``."""
        if self.order == 2:
            return np.array([[1.0, dt_s], [0.0, 1.0]])
        return np.array([[1.0, dt_s, 0.5 * dt_s * dt_s], [0.0, 1.0, dt_s], [0.0, 0.0, 1.0]])

    def process(self, dt_s: float) -> NDArray[np.float64]:
        """``Q`` over ``dt_s``: the exact discretisation of the continuous white noises."""
        t = float(dt_s)
        q = np.zeros((self.order, self.order))
        q[0, 0] = self.position_nm_per_sqrt_s**2 * t
        r = self.rate_noise**2
        if self.order == 2:
            q += r * np.array([[t**3 / 3, t**2 / 2], [t**2 / 2, t]])
        else:
            q += r * np.array(
                [
                    [t**5 / 20, t**4 / 8, t**3 / 6],
                    [t**4 / 8, t**3 / 3, t**2 / 2],
                    [t**3 / 6, t**2 / 2, t],
                ]
            )
        return q


@dataclass(frozen=True)
class DriftEstimate:
    """The drift of both axes at one time: mean and covariance of each axis' state.

    Attributes
    ----------
    t_s : float
        Session time of the estimate, s.
    mean : ndarray, shape (2, order)
        ``[d, v(, a)]`` of x and y (nm, nm/s, nm/s^2), relative to the reference.
    cov : ndarray, shape (2, order, order)
        Their covariances.
    """

    t_s: float
    mean: NDArray[np.float64]
    cov: NDArray[np.float64]

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_s", check_finite_scalar("t_s", self.t_s))
        m = readonly(as_finite_array("mean", self.mean, ndim=2))
        c = readonly(as_finite_array("cov", self.cov, ndim=3))
        if m.shape[0] != 2 or c.shape != (2, m.shape[1], m.shape[1]):
            raise ValueError(f"mean must be (2, k) and cov (2, k, k). Got {m.shape}, {c.shape}.")
        object.__setattr__(self, "mean", m)
        object.__setattr__(self, "cov", c)

    @classmethod
    def start(cls, t_s: float, noise: DriftNoise) -> DriftEstimate:
        """Tracking starts at ``t_s``: the drift is zero then by definition (the landmarks'
        reference), its velocity unknown within ``noise.initial_velocity_nm_per_s``."""
        k = noise.order
        cov = np.zeros((2, k, k))
        cov[:, 1, 1] = noise.initial_velocity_nm_per_s**2
        if k == 3:
            cov[:, 2, 2] = initial_acceleration_var(noise)
        return cls(t_s, np.zeros((2, k)), cov)

    def with_order(self, noise: DriftNoise) -> DriftEstimate:
        """The estimate in ``noise``'s order: ``[d, v]`` of a ``[d, v, a]`` estimate is its
        marginal (the acceleration dropped); ``[d, v]`` gains an acceleration of zero mean
        and the prior's variance, uncorrelated."""
        k, have = noise.order, self.mean.shape[1]
        if k == have:
            return self
        if k < have:
            return DriftEstimate(self.t_s, self.mean[:, :k], self.cov[:, :k, :k])
        mean = np.zeros((2, k))
        mean[:, :have] = self.mean
        cov = np.zeros((2, k, k))
        cov[:, :have, :have] = self.cov
        cov[:, 2, 2] = initial_acceleration_var(noise)
        return DriftEstimate(self.t_s, mean, cov)

    @property
    def displacement_nm(self) -> NDArray[np.float64]:
        """``(dx, dy)``, nm."""
        return np.asarray(self.mean[:, 0])

    @property
    def std_nm(self) -> NDArray[np.float64]:
        """Standard deviation of the displacement of each axis, nm."""
        return np.sqrt(np.asarray(self.cov[:, 0, 0]))


def initial_acceleration_var(noise: DriftNoise) -> float:
    """The prior variance of the drift's acceleration (order 3) when tracking starts: the
    initial velocity's spread reached over ten minutes, (nm/s^2)^2."""
    return (noise.initial_velocity_nm_per_s / 600.0) ** 2


def predict(estimate: DriftEstimate, t_s: float, noise: DriftNoise) -> DriftEstimate:
    """The estimate carried forward (or held) to time ``t_s``."""
    dt = check_finite_scalar("t_s", t_s) - estimate.t_s
    if dt < -1e-9:
        raise ValueError(f"t_s = {t_s} is before the estimate's time {estimate.t_s}.")
    dt = max(dt, 0.0)
    F, Q = noise.transition(dt), noise.process(dt)
    mean = estimate.mean @ F.T
    cov = np.einsum("ij,ajk,lk->ail", F, estimate.cov, F) + Q
    return DriftEstimate(float(t_s), mean, cov)


def update(
    estimate: DriftEstimate, z_nm: ArrayLike, sigma_nm: ArrayLike | None, noise: DriftNoise
) -> tuple[DriftEstimate, NDArray[np.float64], NDArray[np.float64]]:
    """A measured displacement ``z_nm`` (x, y) at the estimate's time.

    Returns
    -------
    estimate : DriftEstimate
    innovation : ndarray, shape (2,)
        ``z - d_predicted``, nm.
    innovation_var : ndarray, shape (2,)
        Its predicted variance, nm^2.
    """
    z = as_finite_array("z_nm", z_nm).reshape(2)
    r = (
        np.full(2, noise.measurement_nm)
        if sigma_nm is None
        else as_finite_array("sigma_nm", sigma_nm).reshape(2)
    )
    mean = np.array(estimate.mean)
    cov = np.array(estimate.cov)
    innov = z - mean[:, 0]
    s = cov[:, 0, 0] + r**2
    for a in range(2):
        gain = cov[a, :, 0] / s[a]
        mean[a] += gain * innov[a]
        cov[a] -= np.outer(gain, cov[a, 0, :])
        cov[a] = 0.5 * (cov[a] + cov[a].T)
    return DriftEstimate(estimate.t_s, mean, cov), innov, s


class DriftFilter:
    """A stateful drift filter: :func:`predict` and :func:`update` on one estimate.

    Parameters
    ----------
    noise : DriftNoise
    estimate : DriftEstimate
        Where tracking stands (e.g. :meth:`DriftEstimate.start`).
    """

    def __init__(self, noise: DriftNoise, estimate: DriftEstimate) -> None:
        if estimate.mean.shape[1] != noise.order:
            raise ValueError(
                f"the estimate has {estimate.mean.shape[1]} states; the noise model {noise.order}."
            )
        self.noise = noise
        self.estimate = estimate
        self.innovations: list[tuple[float, NDArray[np.float64], NDArray[np.float64]]] = []
        """``(t, innovation, variance)`` of every update, for diagnostics and tuning."""

    def at(self, t_s: float) -> DriftEstimate:
        """The prediction at ``t_s`` (no change to the filter)."""
        return predict(self.estimate, t_s, self.noise)

    def measure(self, t_s: float, z_nm: ArrayLike, sigma_nm: ArrayLike | None = None) -> None:
        """Take a measurement at ``t_s``."""
        est, innov, var = update(self.at(t_s), z_nm, sigma_nm, self.noise)
        self.estimate = est
        self.innovations.append((float(t_s), innov, var))


def log_likelihood(
    t_s: ArrayLike, z_nm: ArrayLike, noise: DriftNoise, sigma_nm: ArrayLike | None = None
) -> float:
    """Log-likelihood of measured displacements ``z_nm`` (n, 2) at times ``t_s`` under
    ``noise``, from the filter's innovations (the first measurement, the reference, is
    taken as the start). The filter runs compiled
    (:func:`piezocomp.drift._kernels.log_likelihood_run`): :func:`predict` and
    :func:`update` step for step, summed in its own order (about 1e-14 relative)."""
    t = as_finite_array("t_s", t_s, ndim=1)
    z = as_finite_array("z_nm", z_nm, ndim=2)
    if z.shape != (t.size, 2) or t.size < 2:
        raise ValueError(f"need at least 2 measurements (n, 2). Got {z.shape} for {t.size} times.")
    sig = None if sigma_nm is None else as_finite_array("sigma_nm", sigma_nm, ndim=2)
    if sig is not None and sig.shape != z.shape:
        raise ValueError(f"sigma_nm must have the shape of z_nm {z.shape}. Got {sig.shape}.")
    if np.any(np.diff(t) < -1e-9):
        k = int(np.argmax(np.diff(t) < -1e-9))
        raise ValueError(f"t_s = {t[k + 1]} is before the estimate's time {t[k]}.")
    # the filter's arithmetic compiled (a noise fit runs it thousands of times)
    total = float(
        _kernels.log_likelihood_run(
            t, z, np.zeros_like(z) if sig is None else sig, sig is not None,
            noise.position_nm_per_sqrt_s, noise.rate_noise, noise.measurement_nm,
            noise.order, noise.initial_velocity_nm_per_s,
        )
    )  # fmt: skip
    if not math.isfinite(total):
        raise ValueError(f"the log-likelihood is not finite ({total}) under {noise}.")
    return total


MIN_MEASUREMENT_NM = 0.02
"""The smallest measurement noise :func:`fit_noise` returns: below it a short series cannot
tell the measurement's noise from the drift's own random walk, and a filter that trusts
each measurement exactly would follow every registration error."""


@dataclass(frozen=True)
class NoiseFit:
    """What :func:`fit_noise` found: the noise and the log-likelihood it reaches."""

    noise: DriftNoise
    log_likelihood: float
    n_measurements: int
    start: DriftNoise = field(repr=False, default_factory=DriftNoise)


def fit_noise(
    t_s: ArrayLike,
    z_nm: ArrayLike,
    start: DriftNoise | None = None,
    sigma_nm: ArrayLike | None = None,
) -> NoiseFit:
    """The noise that makes a recorded series of drift measurements most likely.

    Maximises :func:`log_likelihood` over the logarithms of ``position_nm_per_sqrt_s``,
    ``rate_noise`` and ``measurement_nm`` above :data:`MIN_MEASUREMENT_NM` (Nelder-Mead;
    ``order`` and the prior are kept from ``start``). Needs a few tens of measurements to
    say much. With ``sigma_nm`` (n, 2), each measurement's known standard deviation (the
    first row, the reference's, unused), the measurement noise is not fitted: only the
    drift's own noise, the part of the series' scatter those deviations do not explain.
    """
    s0 = DriftNoise() if start is None else start
    known = sigma_nm is not None
    x0 = np.log([
        max(s0.position_nm_per_sqrt_s, 1e-6), max(s0.rate_noise, 1e-6),
        max(s0.measurement_nm - MIN_MEASUREMENT_NM, 1e-6),
    ][: 2 if known else 3])  # fmt: skip

    def noise_of(x: NDArray[np.float64]) -> DriftNoise:
        p, r = float(math.exp(x[0])), float(math.exp(x[1]))
        m = s0.measurement_nm if known else MIN_MEASUREMENT_NM + float(math.exp(x[2]))
        return replace(s0, position_nm_per_sqrt_s=p, rate_noise=r, measurement_nm=m)

    def cost(x: NDArray[np.float64]) -> float:
        return -log_likelihood(t_s, z_nm, noise_of(x), sigma_nm)

    res = minimize(cost, x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-4,
                                                           "maxiter": 600})  # fmt: skip
    return NoiseFit(noise_of(res.x), -float(res.fun), int(np.asarray(t_s).size), s0)


@dataclass(frozen=True)
class DriftSettings:
    """How drift is tracked.

    Parameters
    ----------
    tolerance_nm : float
        Measure before a motion whenever the predicted standard deviation of the drift
        would exceed this by its end.
    max_interval_s : float
        Measure at least this often.
    image_tolerance_nm : float
        An image is interrupted between two lines to measure when the drift's predicted
        standard deviation would exceed this by the end of the next line. A measurement in
        mid-image costs the image's continuity (the tip's excursion to the landmarks and
        back leaves the scanner's compensation residual), so this is larger than
        ``tolerance_nm``: short images are measured before, long ones also during.
    gate_sigma : float
        A landmark whose drift differs from the others' (or, alone, from the prediction)
        by more than this many standard deviations has moved: it is replaced.
    noise : DriftNoise
        The drift model (:func:`piezocomp.drift.filter.fit_noise` estimates it from a run).
    landmarks : LandmarkSettings
    overview_pixels, overview_line_rate_hz : int, float
        The overview image landmarks are chosen from, when none is given.
    overview_trace : {"mean", "forward", "backward"}
        The overview's trace particles are found in: ``"mean"`` when the traces coincide
        (a compensated scanner); one trace on a scanner whose hysteresis shows every
        particle twice in the mean, its traces tens of nanometres apart.
    measure_scanner_error : bool
        Measure the wrapped scanner's own error at the landmarks when tracking starts, and
        size the windows, the search, the measurement noise and the tolerances from it
        (:mod:`piezocomp.drift.scanner_error`): for a scanner without creep-and-hysteresis
        compensation.
    learn_noise_after, learn_noise_every : int
        Re-estimate the drift's noise from the session's own measurements after this many
        drift measurements, then after every ``learn_noise_every`` more
        (:mod:`piezocomp.drift.noise_learning`); 0: keep ``noise`` as given.
    learn_given_sigma : bool
        Learn the drift's noise with each measurement's standard deviation as the filter
        took it (the sighting noise learnt, :attr:`learn_measurement_noise`), so that the
        drift's noise is the scatter that deviation does not explain; else the fit finds a
        measurement noise of its own, which the filter does not use.
    learn_order : bool
        With the noise, learn the drift's order from the session's measurements (a steady
        rate or one that changes: :func:`piezocomp.drift.noise_learning.relearn`); else
        keep ``noise.order``.
    learn_measurement_noise : bool
        Take the measurement noise of a landmark from the session's own sightings: the
        spread of the landmarks of each measurement about their mean, pooled, the prior
        ``noise.measurement_nm`` counted as a few observations
        (:class:`~piezocomp.drift.noise_learning.SightingSpread`). Through a
        creep-and-hysteresis compensator only (with ``measure_scanner_error`` the scanner's
        measured error sets it).
    """

    tolerance_nm: float = 0.5
    max_interval_s: float = 300.0
    image_tolerance_nm: float = 1.0
    gate_sigma: float = 6.0
    noise: DriftNoise = field(default_factory=DriftNoise)
    landmarks: LandmarkSettings = field(default_factory=LandmarkSettings)
    overview_pixels: int = 192
    overview_line_rate_hz: float = 1.0
    overview_trace: str = "mean"
    measure_scanner_error: bool = False
    learn_noise_after: int = 8
    learn_noise_every: int = 4
    learn_given_sigma: bool = True
    learn_order: bool = True
    learn_measurement_noise: bool = True

    @classmethod
    def uncompensated(cls) -> DriftSettings:
        """Settings for a scanner driven without creep-and-hysteresis compensation.

        Its images of one place disagree by the scanner's own error there (the creep and
        hysteresis of the moves that led there, different at every approach): tens of
        nanometres between the overview and a landmark window, several to tens between two
        windows on ``cpr5``. So the overview's particles are read on the forward trace
        alone, a landmark is first looked for in a 384 nm window, and the scanner's error
        at the landmarks is measured when tracking starts and with every sighting: it sizes
        the windows (which double while they miss), the filter's measurement noise, its gate
        (3 standard deviations) and the tolerances
        (:func:`piezocomp.drift.scanner_error.sized`). Three landmarks; measured at least
        every 120 s. The drift model has no acceleration state (order 2: sightings this
        noisy cannot tell a changing rate) and expects 0.1 nm/s or less (after warm-up).
        """
        return cls(
            noise=DriftNoise(order=2, initial_velocity_nm_per_s=0.1), overview_trace="forward",
            measure_scanner_error=True,
            landmarks=LandmarkSettings(search_nm=384.0, count=3), max_interval_s=120.0,
            gate_sigma=3.0, learn_measurement_noise=False,  # the measured error sets it
        )  # fmt: skip

    def __post_init__(self) -> None:
        for name in ("tolerance_nm", "max_interval_s", "image_tolerance_nm", "gate_sigma",
                     "overview_line_rate_hz"):  # fmt: skip
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        if self.image_tolerance_nm < self.tolerance_nm:
            raise ValueError(
                f"image_tolerance_nm must be >= tolerance_nm ({self.tolerance_nm:g}). "
                f"Got {self.image_tolerance_nm:g}."
            )
        if self.overview_trace not in ("mean", "forward", "backward"):
            raise ValueError(
                "overview_trace must be 'mean', 'forward' or 'backward'. "
                f"Got {self.overview_trace!r}."
            )
        for name in ("measure_scanner_error", "learn_given_sigma", "learn_order",
                     "learn_measurement_noise"):  # fmt: skip
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False. Got {getattr(self, name)!r}.")
        for name, low in (("learn_noise_after", 0), ("learn_noise_every", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"{name} must be an integer >= {low}. Got {v!r}.")
        if (
            isinstance(self.overview_pixels, bool)
            or not isinstance(self.overview_pixels, int)
            or (self.overview_pixels < 16)
        ):
            raise ValueError(
                f"overview_pixels must be an integer >= 16. Got {self.overview_pixels!r}."
            )


@dataclass(frozen=True)
class Measurement:
    """One drift measurement: every landmark sighted, and what was kept.

    Attributes
    ----------
    t_s : float
        Its time (the mean of the sightings'), s.
    drift_nm : ndarray, shape (2,) or None
        The drift taken into the estimate (``None``: no landmark trusted).
    sightings : tuple of Sighting
    replaced : tuple of int
        Landmarks found bad and replaced.
    duration_s : float
        Time spent measuring (moves and images), s.
    area : str
        Empty for the landmarks; else the area of the work whose image was the one
        sighting (:meth:`~piezocomp.drift.compensated.DriftCompensatedInstrument.scan_area`).
    sigma_nm : ndarray, shape (2,) or None
        The standard deviation the drift was taken into the estimate with (``None`` when
        none was taken, or not recorded).
    """

    t_s: float
    drift_nm: NDArray[np.float64] | None
    sightings: tuple[Sighting, ...] = field(repr=False)
    replaced: tuple[int, ...]
    duration_s: float
    area: str = ""
    sigma_nm: NDArray[np.float64] | None = None
