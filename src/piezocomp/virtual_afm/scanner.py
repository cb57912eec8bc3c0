"""The true 2-D scanner: what the tip really does for a command (hysteresis, creep, drift).

Per axis ``i`` (x, y), with ``h = range_nm / 2`` and the command ``u_i`` held over each
sample period (sample-and-hold):

    e_i(k) = h * (H_i[u_i / h](k) - H_rest) + C_i[u_i](k)

where ``H_rest`` is the hysteresis output at rest at command 0 (so that the scanner at
rest there is at true position 0), ``H_i`` is the normalised Preisach operator
(:mod:`piezocomp.virtual_afm.preisach`) and
``C_i`` the logarithmic creep bank (:mod:`piezocomp.virtual_afm.creep`). The true tip position
relative to the sample is then

    pos_x(k) = e_x(k) + d_x(k)
    pos_y(k) = e_y(k) + cross_coupling * e_x(k) + d_y(k)

with the thermal drift ``d(k) = d(k-1) + v T + sigma sqrt(T) n(k)`` (constant velocity
``v`` plus a random walk, ``n(k)`` standard normal drawn from the caller's Generator), and,
while the instrument warms up, an extra velocity ``w exp(-t / tau_w)`` integrated exactly
over each sample (``t``: time since the session started).
With drift off (``v = 0``, ``sigma = 0``) the drift term is exactly zero and no random
number is drawn.

:func:`simulate` is a pure function of ``(params, command, T, state, rng)`` returning the
positions and the new state, so batch == chunked streaming (to rounding of the creep sums).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import lfilter

from piezocomp._validation import as_finite_array, check_finite_scalar, readonly
from piezocomp.virtual_afm.config import AFMConfig
from piezocomp.virtual_afm.creep import CreepParams, CreepState, creep_run
from piezocomp.virtual_afm.preisach import PreisachParams, PreisachState, preisach_run

__all__ = ["ScannerParams", "ScannerState", "scanner_params_from_config", "simulate"]


FLICKER_TIME_CONSTANTS_S = (0.1, 1.0, 10.0, 100.0)
"""Time constants of the first-order processes whose sum is the 1/f positioning noise."""


@dataclass(frozen=True)
class ScannerParams:
    """Physics of the 2-D scanner.

    Parameters
    ----------
    range_nm : float
        Full travel of each axis, nm; commands lie in ``[-range_nm/2, range_nm/2]``.
    hysteresis : PreisachParams
        Normalised Preisach operator of both axes.
    creep : CreepParams
        Creep bank of both axes.
    drift_velocity_nm_per_s : tuple of float
        Constant drift velocity (x, y), nm/s.
    drift_random_walk_nm_per_sqrt_s : float
        Random-walk intensity of the drift, nm/sqrt(s), per axis.
    cross_coupling : float
        Fraction of the x extension that appears in y.
    drift_warmup_nm_per_s : tuple of float
        Extra drift velocity (x, y) at the start of the session (an instrument warming up),
        decaying as ``exp(-t / drift_warmup_time_s)``.
    drift_warmup_time_s : float
        Time constant of that decay, s.
    position_noise_nm : float
        White lateral positioning noise of each axis, nm rms per sample (DAC and
        high-voltage amplifier noise seen through the piezo's sensitivity).
    position_flicker_nm : float
        1/f lateral positioning noise of each axis, nm rms: the sum of first-order processes
        with the time constants :data:`FLICKER_TIME_CONSTANTS_S`, of equal variance, whose
        spectrum falls as 1/f between about 2 mHz and 2 Hz.
    creep_domain_fraction : float
        Fraction ``f`` of the creep that is the slow relaxation of the domains the
        hysteresis switched, in [0, 1]: the creep modes are driven by
        ``(1 - f) u + f y_h / kappa`` instead of the command ``u``, with ``y_h`` the
        hysteresis operator's extension and ``kappa`` its mean slope over the range. A
        small step after a reversal switches few domains and creeps little; a large one, or
        one that continues the last direction, creeps more: the creep is no longer a linear
        filter of the command.
    """

    range_nm: float
    hysteresis: PreisachParams
    creep: CreepParams
    drift_velocity_nm_per_s: tuple[float, float] = (0.0, 0.0)
    drift_random_walk_nm_per_sqrt_s: float = 0.0
    cross_coupling: float = 0.0
    drift_warmup_nm_per_s: tuple[float, float] = (0.0, 0.0)
    drift_warmup_time_s: float = 900.0
    position_noise_nm: float = 0.0
    position_flicker_nm: float = 0.0
    creep_domain_fraction: float = 0.0
    domain_creep: CreepParams | None = None
    rest_output: float = field(init=False, repr=False)
    """Normalised hysteresis output at rest at command 0 (demagnetised); subtracted so
    that the scanner at rest at command 0 is at true position 0."""
    hysteresis_slope: float = field(init=False, repr=False)
    """``kappa``: the hysteresis operator's mean slope over the range (nm of extension per
    nm of command between the major loop's ends)."""

    def __post_init__(self) -> None:
        st = PreisachState.demagnetised(self.hysteresis, 0.0)
        v0, _ = preisach_run(self.hysteresis, [0.0], st)
        object.__setattr__(self, "rest_output", float(v0[0]))
        ends, _ = preisach_run(self.hysteresis, [1.0, -1.0, 1.0], st)
        object.__setattr__(self, "hysteresis_slope", float(0.5 * (ends[2] - ends[1])))
        r = check_finite_scalar("range_nm", self.range_nm)
        if r <= 0:
            raise ValueError(f"range_nm must be > 0. Got {r}.")
        v = tuple(
            check_finite_scalar("drift_velocity_nm_per_s", c) for c in self.drift_velocity_nm_per_s
        )
        if len(v) != 2:
            raise ValueError(f"drift_velocity_nm_per_s must have 2 entries. Got {len(v)}.")
        rw = check_finite_scalar(
            "drift_random_walk_nm_per_sqrt_s", self.drift_random_walk_nm_per_sqrt_s
        )
        if rw < 0:
            raise ValueError(f"drift_random_walk_nm_per_sqrt_s must be >= 0. Got {rw}.")
        object.__setattr__(self, "range_nm", r)
        object.__setattr__(self, "drift_velocity_nm_per_s", v)
        object.__setattr__(self, "drift_random_walk_nm_per_sqrt_s", rw)
        object.__setattr__(
            self, "cross_coupling", check_finite_scalar("cross_coupling", self.cross_coupling)
        )
        w = tuple(
            check_finite_scalar("drift_warmup_nm_per_s", c) for c in self.drift_warmup_nm_per_s
        )
        if len(w) != 2:
            raise ValueError(f"drift_warmup_nm_per_s must have 2 entries. Got {len(w)}.")
        tw = check_finite_scalar("drift_warmup_time_s", self.drift_warmup_time_s)
        if tw <= 0:
            raise ValueError(f"drift_warmup_time_s must be > 0. Got {tw}.")
        object.__setattr__(self, "drift_warmup_nm_per_s", w)
        object.__setattr__(self, "drift_warmup_time_s", tw)
        for name in ("position_noise_nm", "position_flicker_nm"):
            val = check_finite_scalar(name, getattr(self, name))
            if val < 0:
                raise ValueError(f"{name} must be >= 0. Got {val}.")
            object.__setattr__(self, name, val)
        f = check_finite_scalar("creep_domain_fraction", self.creep_domain_fraction)
        if not 0 <= f <= 1:
            raise ValueError(f"creep_domain_fraction must be in [0, 1]. Got {f}.")
        object.__setattr__(self, "creep_domain_fraction", f)

    def creep_drive(self, u_nm: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
        """What the creep modes relax towards: ``(1 - f) u + f h (v - v_rest) / kappa`` for
        commands ``u_nm`` and normalised hysteresis outputs ``v`` (``(1 - f) u`` alone when
        the domains relax through a bank of their own, :attr:`domain_creep`)."""
        u = np.asarray(u_nm, dtype=float)
        f = self.creep_domain_fraction
        if f == 0.0:
            return u
        if self.domain_creep is not None:
            return np.asarray((1.0 - f) * u)
        return np.asarray((1.0 - f) * u + f * self.domain_drive(v))

    def domain_drive(self, v: ArrayLike) -> NDArray[np.float64]:
        """``h (v - v_rest) / kappa``: the hysteresis extension in command units."""
        y_h = self.half_range_nm * (np.asarray(v, dtype=float) - self.rest_output)
        return np.asarray(y_h / self.hysteresis_slope)

    @property
    def half_range_nm(self) -> float:
        """Half the travel, nm."""
        return 0.5 * self.range_nm

    @property
    def drift_on(self) -> bool:
        """True when the drift term can be non-zero."""
        return (
            any(v != 0.0 for v in self.drift_velocity_nm_per_s)
            or any(v != 0.0 for v in self.drift_warmup_nm_per_s)
            or self.drift_random_walk_nm_per_sqrt_s > 0.0
        )

    @property
    def noise_on(self) -> bool:
        """True when the lateral positioning noise is on."""
        return self.position_noise_nm > 0.0 or self.position_flicker_nm > 0.0


@dataclass(frozen=True)
class ScannerState:
    """State of the 2-D scanner: memories of both axes, creep modes, drift offset (nm), the
    time since the session started (s; it sets the warm-up drift) and the 1/f noise's
    processes (nm, shape ``(len(FLICKER_TIME_CONSTANTS_S), 2)``)."""

    hysteresis: tuple[PreisachState, PreisachState]
    creep: tuple[CreepState, CreepState]
    drift_nm: NDArray[np.float64]
    position_nm: NDArray[np.float64]
    elapsed_s: float = 0.0
    flicker_nm: NDArray[np.float64] | None = None
    domain_creep: tuple[CreepState, CreepState] | None = None
    """The domains' own creep modes (:attr:`ScannerParams.domain_creep`), if any."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "drift_nm", readonly(self.drift_nm))
        object.__setattr__(self, "position_nm", readonly(self.position_nm))
        flick = self.flicker_nm
        if flick is None:
            flick = np.zeros((len(FLICKER_TIME_CONSTANTS_S), 2))
        object.__setattr__(self, "flicker_nm", readonly(np.asarray(flick, dtype=float)))

    @classmethod
    def initial(
        cls, params: ScannerParams, start_nm: tuple[float, float] = (0.0, 0.0)
    ) -> ScannerState:
        """Scanner at rest at the command ``start_nm``: hysteresis memory demagnetised
        (decaying cycles ending there), creep settled, no drift offset."""
        h = params.half_range_nm
        hy = []
        cr = []
        dc: list[CreepState] = []
        e = []
        for u0 in start_nm:
            u0 = check_finite_scalar("start_nm", u0)
            if abs(u0) > h:
                raise ValueError(f"start_nm must lie within +-{h} nm. Got {u0}.")
            st = PreisachState.demagnetised(params.hysteresis, u0 / h)
            v, st = preisach_run(params.hysteresis, [u0 / h], st)
            hy.append(st)
            s0 = float(params.creep_drive(u0, v[0]))
            cs = CreepState.steady(params.creep, s0)
            cr.append(cs)
            e.append(h * (v[0] - params.rest_output) + params.creep.reference_gain * s0)
            if params.domain_creep is not None:
                d0 = params.creep_domain_fraction * float(params.domain_drive(v[0]))
                dc.append(CreepState.steady(params.domain_creep, d0))
                e[-1] += params.domain_creep.reference_gain * d0
        pos = np.array([e[0], e[1] + params.cross_coupling * e[0]])
        domain = (dc[0], dc[1]) if dc else None
        return cls((hy[0], hy[1]), (cr[0], cr[1]), np.zeros(2), pos, domain_creep=domain)


def simulate(
    params: ScannerParams,
    command_nm: ArrayLike,
    sample_period_s: float,
    state: ScannerState,
    rng: np.random.Generator | None = None,
    drift_out: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], ScannerState]:
    """True tip positions for a held command trajectory.

    Parameters
    ----------
    params : ScannerParams
    command_nm : array_like, shape (n, 2)
        Command of x and y at each sample, nominal nm, within the range.
    sample_period_s : float
        Hold time of each command sample, s.
    state : ScannerState
        State before the first sample (not modified).
    rng : numpy.random.Generator, optional
        Source of the drift random walk and the positioning noise; required only when
        either is on.
    drift_out : ndarray, shape (n, 2), optional
        Filled with the drift offset at each sample (included in ``positions_nm``): what a
        scorer subtracts to compare a model with the scanner's own extension.

    Returns
    -------
    positions_nm : ndarray, shape (n, 2)
        True tip position relative to the sample at each sample, nm.
    state : ScannerState
        State after the last sample.
    """
    u = as_finite_array("command_nm", command_nm, ndim=2)
    if u.shape[1] != 2:
        raise ValueError(f"command_nm must have shape (n, 2). Got {u.shape}.")
    T = check_finite_scalar("sample_period_s", sample_period_s)
    if T <= 0:
        raise ValueError(f"sample_period_s must be > 0. Got {T}.")
    h = params.half_range_nm
    n = u.shape[0]
    e = np.empty((n, 2))
    hy, cr, dc = [], [], []
    for i in range(2):
        ui = np.ascontiguousarray(u[:, i])
        v, hs = preisach_run(params.hysteresis, ui / h, state.hysteresis[i])
        c, cs = creep_run(params.creep, params.creep_drive(ui, v), T, state.creep[i])
        if params.domain_creep is not None:  # the domains' own, slower modes
            if state.domain_creep is None:
                raise ValueError("the state has no domain creep modes; the parameters do.")
            d = params.creep_domain_fraction * params.domain_drive(v)
            c2, ds = creep_run(params.domain_creep, d, T, state.domain_creep[i])
            c = c + c2
            dc.append(ds)
        e[:, i] = h * (v - params.rest_output) + c
        hy.append(hs)
        cr.append(cs)
    pos = e.copy()
    pos[:, 1] += params.cross_coupling * e[:, 0]
    # every random number of a sample is drawn in one row, so that a run in pieces draws
    # the same numbers as the run in one call
    sigma = params.drift_random_walk_nm_per_sqrt_s if params.drift_on else 0.0
    n_walk = 2 if sigma > 0 else 0
    n_noise = 2 * (1 + len(FLICKER_TIME_CONSTANTS_S)) if params.noise_on else 0
    draws = np.zeros((n, 0))
    if n and n_walk + n_noise:
        if rng is None:
            raise ValueError("rng is required when the drift random walk or the noise is on.")
        draws = rng.standard_normal((n, n_walk + n_noise))
    flicker_end = np.array(state.flicker_nm)
    if n_noise and n:
        noise, flicker_end = _positioning_noise(params, T, flicker_end, draws[:, n_walk:])
        pos += noise
    drift_end = np.array(state.drift_nm)
    if params.drift_on and n:
        steps = np.tile(np.asarray(params.drift_velocity_nm_per_s) * T, (n, 1))
        if any(v != 0.0 for v in params.drift_warmup_nm_per_s):  # exact over each hold
            tau = params.drift_warmup_time_s
            t0 = state.elapsed_s + T * np.arange(n)
            decay = tau * (np.exp(-t0 / tau) - np.exp(-(t0 + T) / tau))
            steps += np.outer(decay, params.drift_warmup_nm_per_s)
        if n_walk:
            steps += sigma * np.sqrt(T) * draws[:, :2]
        d = state.drift_nm + np.cumsum(steps, axis=0)
        pos += d
        drift_end = d[-1]
        if drift_out is not None:
            drift_out[:] = d
    elif drift_out is not None:
        drift_out[:] = drift_end
    last = pos[-1] if n else state.position_nm
    return pos, ScannerState(
        (hy[0], hy[1]),
        (cr[0], cr[1]),
        drift_end,
        last,
        state.elapsed_s + n * T,
        flicker_end,
        (dc[0], dc[1]) if dc else None,
    )


def _positioning_noise(
    params: ScannerParams, T: float, flicker: NDArray[np.float64], w: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """White plus 1/f noise of both axes from standard normal draws ``w`` (one row a sample:
    the white noise's two, then two per 1/f process), and the 1/f processes' states after
    them: ``x(k) = a x(k-1) + sqrt(1 - a^2) s w(k)``, ``a = exp(-T / tau)``, each of variance
    ``s^2 = position_flicker_nm^2 / len(FLICKER_TIME_CONSTANTS_S)``."""
    noise = params.position_noise_nm * w[:, :2]
    end = flicker.copy()
    if params.position_flicker_nm > 0:
        s = params.position_flicker_nm / math.sqrt(len(FLICKER_TIME_CONSTANTS_S))
        for j, tau in enumerate(FLICKER_TIME_CONSTANTS_S):
            a = math.exp(-T / tau)
            wj = s * math.sqrt(1.0 - a * a) * w[:, 2 + 2 * j : 4 + 2 * j]
            x, _ = lfilter([1.0], [1.0, -a], wj, axis=0, zi=a * flicker[j][None, :])
            noise = noise + x
            end[j] = x[-1]
    return noise, end


def scanner_params_from_config(config: AFMConfig) -> ScannerParams:
    """Build the scanner physics from the ``[scanner]`` keys (solving the Preisach density
    and the creep weights so that the keys are what a measurement finds)."""
    s = config.scanner
    hyst = PreisachParams.from_targets(
        s.hysteresis,
        s.hysteresis_small,
        s.hysteresis_small_span,
        s.hysteresis_asymmetry,
        s.hysteresis_saturation,
    )
    creep = CreepParams.logarithmic(
        s.creep, s.creep_tau_min_s, s.creep_tau_max_s, s.creep_modes_per_decade,
        s.creep_reference_time_s,
    )  # fmt: skip
    domain = None
    if s.creep_domain_tau_min_s > 0 and s.creep_domain_fraction > 0:
        slow = creep.tau_s >= s.creep_domain_tau_min_s
        if not slow.any():
            raise ValueError(
                f"scanner.creep_domain_tau_min_s = {s.creep_domain_tau_min_s:g} s leaves no "
                f"creep mode (the slowest is {creep.tau_s.max():g} s)."
            )
        tau = creep.tau_s[slow]
        key = np.exp(-0.1 / creep.tau_s) - np.exp(-100.0 / creep.tau_s)  # 0.1 s to 100 s
        scale = float(np.sum(creep.weights * key) / np.sum(creep.weights[slow] * key[slow]))
        domain = CreepParams(tau, creep.weights[slow] * scale, creep.reference_time_s)
    ang = math.radians(s.drift_direction_deg)
    v = (s.drift_nm_per_s * math.cos(ang), s.drift_nm_per_s * math.sin(ang))
    w = (s.drift_warmup_nm_per_s * math.cos(ang), s.drift_warmup_nm_per_s * math.sin(ang))
    return ScannerParams(
        s.range_nm, hyst, creep, v, s.drift_random_walk_nm_per_sqrt_s, s.cross_coupling,
        w, s.drift_warmup_time_s, s.position_noise_nm, s.position_flicker_nm,
        s.creep_domain_fraction, domain,
    )  # fmt: skip
