"""The inverse model, eqs (8)-(13), and the feedforward compensator built on it.

Given a desired extension ``y_d(k)``, the compensator computes the command ``u(k)``:

1. creep states from the previous command, eq (2): ``x_i(k) = p_i x_i(k-1) + (1-p_i) u(k-1)``;
2. ``v(k) = y_d(k) - y0 - sum c_i x_i(k)`` (eq 13, with the offset of eq 14);
3. ``u(k) = P^{-1}[v](k) = a_hat v(k) + sum w_hat_i z_{r_hat_i}[v](k)`` (eqs 9-11).

With a creep coupling ``beta`` (eq 2'), step 1 is driven by ``s(k-1) = u(k-1) + beta v(k-1)``
(eq 13'): ``v(k-1) = P[u](k-1)`` is exactly the hysteresis output ``H(k-1)`` of eq (2') of the
command produced at step ``k-1``, so the drive is known before ``u(k)`` is computed and the
recursion stays exact. Before the first sample ``v(-1) = H(-1) = a u(-1) + sum w_j z_j(-1)``
from the plant state (:meth:`~piezocomp.model.ScannerModel.hysteresis_output`).

With the asymmetry map of eq (8') (Kuhnen's modified PI, ``y = y0 + S(H) + creep``), step 2
becomes ``v(k) = S^{-1}(y_d(k) - y0 - sum c_i x_i(k))``; ``S^{-1}`` is again a superposition of
one-sided dead zones, in closed form (:func:`~piezocomp.operators.dead_zone.inverse_dead_zones`),
and ``v`` is still ``H``, so the creep drive of eq (13') is unchanged.

With the plant in the state the compensator believes it is in, ``forward(inverse(y_d))``
reproduces ``y_d`` to rounding.

State correspondence
--------------------
The compensator's state is expressed as the plant state it predicts (a
:class:`~piezocomp.model.ModelState`). Inside, the inverse play states are

``z_hat_i = (a + sum_{j<=i} w_j) z_i + sum_{j>i} w_j z_j``,

which holds exactly for every play state reachable from a history of inputs (for those,
``|u - z_i| <= r_i`` and ``|z_i - z_j| <= |r_i - r_j|``): on such states the right-hand side
moves exactly as a play operator of threshold ``r_hat_i = phi(r_i)`` driven by
``v = P[u]`` does. The map is upper triangular with a positive diagonal, so it is inverted
exactly by back substitution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar, readonly
from piezocomp.limits import CommandLimits, LimitReport
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.operators import _kernels
from piezocomp.operators.dead_zone import inverse_dead_zones

__all__ = [
    "CompensationResult",
    "Compensator",
    "InversePI",
    "compensate",
    "inverse_play_state",
    "plant_play_state",
]


@dataclass(frozen=True)
class InversePI:
    """Parameters of the inverse Prandtl-Ishlinskii operator, eqs (9)-(10).

    Attributes
    ----------
    gain : float
        ``a_hat = 1 / a``.
    thresholds_nm : ndarray
        ``r_hat_i = phi(r_i)`` (nm of extension), strictly increasing.
    weights : ndarray
        ``w_hat_i = -w_i / ((a + sum_{j<=i} w_j)(a + sum_{j<i} w_j))`` (negative).
    """

    gain: float
    thresholds_nm: NDArray[np.float64]
    weights: NDArray[np.float64]

    @classmethod
    def from_model(cls, model: ScannerModel) -> InversePI:
        """Eq (10) from the forward parameters ``a``, ``w_i``, ``r_i``."""
        a = model.gain
        w = np.asarray(model.weights)
        r = np.asarray(model.thresholds_nm)
        cum = a + np.cumsum(w)  # a + sum_{j<=i} w_j
        cum_prev = np.concatenate(([a], cum[:-1]))  # a + sum_{j<i} w_j
        rhat = model.loading_curve(r)
        what = -w / (cum * cum_prev)
        return cls(1.0 / a, readonly(rhat), readonly(what))

    def packed(self, model: ScannerModel, sample_period_s: float) -> NDArray[np.float64]:
        """``[y0, a_hat, r_hat.., w_hat.., p.., c.., beta, d_hat.., g_hat..]`` for the inverse
        kernel (``d_hat, g_hat``: the dead zones of ``S^{-1}``, eq 8', none for a symmetric
        model)."""
        d_hat, g_hat = inverse_dead_zones(model.dead_zones_nm, model.dead_zone_gains)
        return np.concatenate(
            (
                [model.offset_nm, self.gain],
                self.thresholds_nm,
                self.weights,
                model.creep_poles(sample_period_s),
                model.creep_gains,
                [model.creep_coupling],
                d_hat,
                g_hat,
            )
        )


def inverse_play_state(model: ScannerModel, play_nm: ArrayLike) -> NDArray[np.float64]:
    """Inverse-PI play states matching forward play states (see the module notes)."""
    z = np.asarray(play_nm, dtype=float)
    w = np.asarray(model.weights)
    diag = model.gain + np.cumsum(w)
    tail = np.concatenate((np.cumsum((w * z)[::-1])[::-1][1:], [0.0]))  # sum_{j>i} w_j z_j
    return np.asarray(diag * z + tail)


def plant_play_state(model: ScannerModel, inverse_play_nm: ArrayLike) -> NDArray[np.float64]:
    """Forward play states from inverse-PI play states (back substitution)."""
    zh = np.asarray(inverse_play_nm, dtype=float)
    w = np.asarray(model.weights)
    diag = model.gain + np.cumsum(w)
    z = np.empty_like(zh)
    tail = 0.0
    for i in range(zh.size - 1, -1, -1):
        z[i] = (zh[i] - tail) / diag[i]
        tail += w[i] * z[i]
    return z


def _to_kernel_state(model: ScannerModel, state: ModelState) -> NDArray[np.float64]:
    """``[z_hat.., x.., u_prev, v_prev]``, ``v_prev = H(k-1)`` of the state (eq 13')."""
    state.check_for(model)
    v_prev = model.hysteresis_output(state)
    return np.concatenate(
        (inverse_play_state(model, state.play_nm), state.creep_nm, [state.u_prev_nm, v_prev])
    )


def _from_kernel_state(model: ScannerModel, packed: NDArray[np.float64]) -> ModelState:
    nh, nc = model.n_play, model.n_creep
    return ModelState(
        plant_play_state(model, packed[:nh]), packed[nh : nh + nc].copy(), float(packed[nh + nc])
    )


@dataclass(frozen=True)
class CompensationResult:
    """Output of :func:`compensate`.

    Attributes
    ----------
    command_nm : ndarray
        The command to send, nominal nm (clipped if clipping was asked for).
    state : ModelState
        Predicted plant state after the last sample (after clipping, if any).
    report : LimitReport
        Samples clipped to the command limits (empty unless ``clip=True``).
    """

    command_nm: NDArray[np.float64]
    state: ModelState
    report: LimitReport = field(default_factory=LimitReport)


def compensate(
    model: ScannerModel,
    y_desired_nm: ArrayLike,
    sample_period_s: float,
    state: ModelState | None = None,
    *,
    limits: CommandLimits | None = None,
    clip: bool = False,
) -> CompensationResult:
    """Command that drives the model along ``y_desired_nm`` (eqs 9-13).

    Parameters
    ----------
    model : ScannerModel
        Identified forward model.
    y_desired_nm : array_like, shape (n,)
        Desired extension, nm (finite).
    sample_period_s : float
        Sample period ``T``, s.
    state : ModelState, optional
        Plant state before the first sample, as predicted; zeros by default.
    limits : CommandLimits, optional
        Range and slew limits of the command. A trajectory that breaks them raises
        ``ValueError`` (nothing to send) unless ``clip`` is true.
    clip : bool
        Clip to ``limits`` and report every clipped sample; the returned state then follows
        the clipped command (the plant will not reach ``y_d`` on those samples).

    Returns
    -------
    CompensationResult
    """
    yd = as_finite_1d("y_desired_nm", y_desired_nm)
    T = check_finite_scalar("sample_period_s", sample_period_s)
    st = model.initial_state() if state is None else state
    packed_state = _to_kernel_state(model, st)
    u = np.empty(yd.size)
    params = InversePI.from_model(model).packed(model, T)
    _kernels.inverse(yd, model.n_play, model.n_creep, params, packed_state, u)
    if limits is None:
        return CompensationResult(u, _from_kernel_state(model, packed_state))
    u_sent, report = limits.check(u, T, previous_nm=st.u_prev_nm, clip=clip, name="command")
    if report.n_clipped == 0:
        return CompensationResult(u, _from_kernel_state(model, packed_state), report)
    _, end_state = simulate(model, u_sent, T, st)  # the plant follows what is sent
    return CompensationResult(u_sent, end_state, report)


class Compensator:
    """Streaming feedforward compensator for one axis (eqs 9-13).

    Parameters
    ----------
    model : ScannerModel
        Identified forward model.
    sample_period_s : float
        Sample period ``T``, s.
    state : ModelState, optional
        Predicted plant state at the start; zeros by default.
    limits : CommandLimits, optional
        Command range and slew limits, checked before anything is returned.
    clip : bool
        With ``limits``: clip instead of refusing; clipped samples are listed in
        :attr:`clipped_samples`.

    Notes
    -----
    ``step`` keeps the state in the kernel's packed form so that one sample costs a few
    microseconds; :attr:`state` converts it to a :class:`ModelState` on demand.
    """

    def __init__(
        self,
        model: ScannerModel,
        sample_period_s: float,
        state: ModelState | None = None,
        *,
        limits: CommandLimits | None = None,
        clip: bool = False,
    ) -> None:
        if not isinstance(model, ScannerModel):
            raise TypeError(f"model must be a ScannerModel. Got {type(model).__name__}.")
        self._model = model
        self._T = check_finite_scalar("sample_period_s", sample_period_s)
        if self._T <= 0:
            raise ValueError(f"sample_period_s must be > 0. Got {self._T}.")
        self._params = InversePI.from_model(model).packed(model, self._T)
        self._nh, self._nc = model.n_play, model.n_creep
        self._limits = limits
        self._clip = bool(clip)
        self._one_in = np.zeros(1)
        self._one_out = np.zeros(1)
        self._index = 0
        self.clipped_samples: list[tuple[int, float, float]] = []
        self.reset(state)

    @property
    def model(self) -> ScannerModel:
        """The forward model being inverted."""
        return self._model

    @property
    def sample_period_s(self) -> float:
        """Sample period ``T``, s."""
        return self._T

    @property
    def state(self) -> ModelState:
        """Predicted plant state after the last sample."""
        return _from_kernel_state(self._model, self._packed)

    def reset(self, state: ModelState | None = None) -> None:
        """Restart from ``state`` (zeros by default) and clear the clipping log."""
        st = self._model.initial_state() if state is None else state
        self._packed = _to_kernel_state(self._model, st)
        self._index = 0
        self.clipped_samples = []

    def step(self, y_desired_nm: float) -> float:
        """Command for one desired sample."""
        yd = float(y_desired_nm)
        if not math.isfinite(yd):
            raise ValueError(f"y_desired_nm must be finite. Got {yd} at sample {self._index}.")
        if self._limits is None:
            self._one_in[0] = yd
            _kernels.inverse(
                self._one_in, self._nh, self._nc, self._params, self._packed, self._one_out
            )
            self._index += 1
            return float(self._one_out[0])
        u = self.run(np.array([yd]))
        return float(u[0])

    def run(self, y_desired_nm: ArrayLike) -> NDArray[np.float64]:
        """Commands for a block of desired samples (continues the stream).

        Refuses the whole block (state unchanged) if it breaks the limits and clipping is off.
        """
        before = self.state
        result = compensate(
            self._model, y_desired_nm, self._T, before, limits=self._limits, clip=self._clip
        )
        if result.report.n_clipped:
            requested = compensate(self._model, y_desired_nm, self._T, before).command_nm
            idx = np.union1d(result.report.range_clipped, result.report.slew_clipped)
            self.clipped_samples.extend(
                (self._index + int(i), float(requested[i]), float(result.command_nm[i]))
                for i in idx
            )
        self._packed = _to_kernel_state(self._model, result.state)
        self._index += result.command_nm.size
        return result.command_nm
