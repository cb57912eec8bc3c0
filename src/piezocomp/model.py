"""The scanner model of one axis, eq (14), and its 2-D pair.

``y(k) = y0 + a u(k) + sum_i c_i x_i(k) + sum_j w_j z_{r_j}(k)``

with creep states ``x_i`` (eq 2, poles ``p_i = exp(-T / tau_i)``) and play outputs ``z_{r_j}``
(eq 4). The extended family couples the creep to the hysteresis: the creep operators are
driven by ``s(k-1) = u(k-1) + beta H(k-1)`` instead of ``u(k-1)``, eq (2'), where
``H(k) = a u(k) + sum_j w_j z_{r_j}(k)`` is the rate-independent output of eq (8) without the
offset; ``beta = 0`` (the default) is the paper's model exactly. Kuhnen's modified PI adds a
static asymmetry map on that output, ``y = y0 + S(H) + sum_i c_i x_i`` with
``S(h) = h + sum_l g_l q_{d_l}(h)`` a superposition of one-sided dead zones, eq (8')
(:mod:`piezocomp.operators.dead_zone`); no dead zones (the default) is the symmetric model
exactly.

Parameters are frozen (:class:`ScannerModel`); the state is a separate small object
(:class:`ModelState`) passed in and returned, so batch, chunked and per-sample simulation
agree exactly.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_1d, check_finite_scalar, readonly
from piezocomp.operators import _kernels
from piezocomp.operators.creep import creep_poles
from piezocomp.operators.dead_zone import check_dead_zones, dead_zone_map
from piezocomp.operators.play import check_thresholds

__all__ = ["ModelState", "ScannerModel", "ScannerModel2D", "simulate"]


def _empty() -> NDArray[np.float64]:
    return readonly(np.zeros(0))


def _fields_equal(a: Any, b: Any) -> bool:
    """Exact equality of two dataclass instances of the same type (arrays by value)."""
    if type(a) is not type(b):
        return NotImplemented
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)


@dataclass(frozen=True, eq=False)
class ScannerModel:
    """Parameters of the creep + Prandtl-Ishlinskii model of one axis, eq (14).

    Parameters
    ----------
    offset_nm : float
        ``y0``, extension at zero command, nm.
    gain : float
        ``a`` (> 0), the weight of the input term (``w_0`` of eq 8).
    thresholds_nm : array_like, shape (N_H,)
        Play thresholds ``0 < r_1 < ... < r_NH``, nm of command.
    weights : array_like, shape (N_H,)
        Play weights ``w_j > 0``; with ``a > 0`` they make the loading curve (8) strictly
        increasing, so the model is invertible (eq 10).
    creep_time_constants_s : array_like, shape (N_c,)
        ``tau_i = 1 / lambda_i > 0`` of the creep operators (1), s.
    creep_gains : array_like, shape (N_c,)
        ``c_i >= 0``.
    creep_coupling : float
        ``beta >= 0`` (dimensionless), the creep coupling of eq (2'): the creep operators
        are driven by ``s(k-1) = u(k-1) + beta H(k-1)``, ``H`` the hysteresis output
        ``a u + sum_j w_j z_{r_j}``. ``0`` (default): the paper's eq (2), driven by ``u``.
    domain_nm : (float, float), optional
        The command interval ``(lo, hi)`` over which the model was identified: where its
        thresholds and weights were informed. Outside it the model extrapolates; the
        compensated instrument refuses commands outside it unless told otherwise. ``None``:
        not stated.
    range_nm : float, optional
        Full travel of the scanner axis the model describes (commands lie in
        ``[-range_nm/2, range_nm/2]``). ``None``: not stated.
    dead_zones_nm : array_like, shape (N_d,)
        Thresholds ``d_l`` (nm of the hysteresis output ``H``, non-zero, strictly
        increasing) of the asymmetry map ``S`` of eq (8'). Empty (default): ``S`` is the
        identity, the symmetric model.
    dead_zone_gains : array_like, shape (N_d,)
        Gains ``g_l`` (of either sign) of those dead zones; every slope of ``S`` must be
        positive, so that the model stays invertible.

    Notes
    -----
    The discrete poles are computed from the time constants for the sample period used, so
    one model serves any sample rate (:meth:`creep_poles`).
    """

    offset_nm: float = 0.0
    gain: float = 1.0
    thresholds_nm: NDArray[np.float64] = field(default_factory=_empty)
    weights: NDArray[np.float64] = field(default_factory=_empty)
    creep_time_constants_s: NDArray[np.float64] = field(default_factory=_empty)
    creep_gains: NDArray[np.float64] = field(default_factory=_empty)
    domain_nm: tuple[float, float] | None = None
    range_nm: float | None = None
    creep_coupling: float = 0.0
    dead_zones_nm: NDArray[np.float64] = field(default_factory=_empty)
    dead_zone_gains: NDArray[np.float64] = field(default_factory=_empty)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        dz, dg = check_dead_zones(self.dead_zones_nm, self.dead_zone_gains)
        set_(self, "dead_zones_nm", readonly(dz))
        set_(self, "dead_zone_gains", readonly(dg))
        if self.domain_nm is not None:
            d = as_finite_1d("domain_nm", self.domain_nm)
            if d.size != 2 or not d[0] < d[1]:
                raise ValueError(f"domain_nm must be two numbers lo < hi. Got {self.domain_nm!r}.")
            set_(self, "domain_nm", (float(d[0]), float(d[1])))
        if self.range_nm is not None:
            rng = check_finite_scalar("range_nm", self.range_nm)
            if rng <= 0:
                raise ValueError(f"range_nm must be > 0. Got {rng}.")
            set_(self, "range_nm", rng)
            if self.domain_nm is not None and max(map(abs, self.domain_nm)) > rng / 2:
                raise ValueError(
                    f"domain_nm {self.domain_nm} must lie within the range +-{rng / 2:g} nm."
                )
        set_(self, "offset_nm", check_finite_scalar("offset_nm", self.offset_nm))
        beta = check_finite_scalar("creep_coupling", self.creep_coupling)
        if beta < 0:
            raise ValueError(f"creep_coupling must be >= 0. Got {beta}.")
        set_(self, "creep_coupling", beta + 0.0)  # -0.0 -> 0.0
        a = check_finite_scalar("gain", self.gain)
        if a <= 0:
            raise ValueError(f"gain must be > 0 for the model to be invertible. Got {a}.")
        set_(self, "gain", a)
        r = check_thresholds("thresholds_nm", self.thresholds_nm)
        w = as_finite_1d("weights", self.weights)
        if w.shape != r.shape:
            raise ValueError(f"weights must have one entry per threshold ({r.size}). Got {w.size}.")
        if np.any(w <= 0):
            i = int(np.flatnonzero(w <= 0)[0])
            raise ValueError(
                f"weights must be > 0 for the model to be invertible. Got weights[{i}] = {w[i]}."
            )
        tau = as_finite_1d("creep_time_constants_s", self.creep_time_constants_s)
        if np.any(tau <= 0):
            i = int(np.flatnonzero(tau <= 0)[0])
            raise ValueError(
                f"creep_time_constants_s must be > 0. Got creep_time_constants_s[{i}] = {tau[i]}."
            )
        c = as_finite_1d("creep_gains", self.creep_gains)
        if c.shape != tau.shape:
            raise ValueError(
                f"creep_gains must have one entry per time constant ({tau.size}). Got {c.size}."
            )
        if np.any(c < 0):
            i = int(np.flatnonzero(c < 0)[0])
            raise ValueError(f"creep_gains must be >= 0. Got creep_gains[{i}] = {c[i]}.")
        for name, arr in (
            ("thresholds_nm", r),
            ("weights", w),
            ("creep_time_constants_s", tau),
            ("creep_gains", c),
        ):
            set_(self, name, readonly(arr))

    __eq__ = _fields_equal
    __hash__ = None  # type: ignore[assignment]

    # ------------------------------------------------------------------ shape
    @property
    def n_play(self) -> int:
        """``N_H``, the number of play operators."""
        return int(self.thresholds_nm.size)

    @property
    def n_creep(self) -> int:
        """``N_c``, the number of creep operators."""
        return int(self.creep_time_constants_s.size)

    @property
    def n_dead_zones(self) -> int:
        """``N_d``, the number of dead zones of the asymmetry map (eq 8'); 0: symmetric."""
        return int(self.dead_zones_nm.size)

    def asymmetry_map(self, h_nm: ArrayLike) -> NDArray[np.float64]:
        """``S(h)`` of eq (8'), the extension's rate-independent part for a hysteresis
        output ``h`` (the identity without dead zones)."""
        return dead_zone_map(h_nm, self.dead_zones_nm, self.dead_zone_gains)

    def require_symmetric(self, what: str) -> None:
        """Refuse (``ValueError``) a model with dead zones (eq 8') in ``what``, an estimator
        or a computation that knows only the symmetric model."""
        if self.n_dead_zones:
            raise ValueError(
                f"{what} handles only the symmetric model (no dead zones, eq 8'); this model "
                f"has {self.n_dead_zones}."
            )

    @property
    def static_gain(self) -> float:
        """``a + sum c_i (1 + beta a)``: the slope of a small slow command (play operators
        still) once creep has settled; ``a + sum c_i`` for the paper's model. With dead zones
        (eq 8') it holds where ``S`` has slope 1, between the innermost thresholds; beyond
        them ``a`` is multiplied by the slope of ``S`` there."""
        return float(self.gain + self.creep_gains.sum() * (1.0 + self.creep_coupling * self.gain))

    def creep_poles(self, sample_period_s: float) -> NDArray[np.float64]:
        """Discrete creep poles ``p_i = exp(-T / tau_i)`` for sample period ``T`` (eq 2)."""
        return creep_poles(self.creep_time_constants_s, sample_period_s)

    def packed(self, sample_period_s: float) -> NDArray[np.float64]:
        """Parameters in the kernels' packed layout ``[y0, a, r.., w.., p.., c.., beta, d..,
        g..]`` (``d, g``: the dead zones of eq 8', absent for the symmetric model)."""
        return np.concatenate(
            (
                [self.offset_nm, self.gain],
                self.thresholds_nm,
                self.weights,
                self.creep_poles(sample_period_s),
                self.creep_gains,
                [self.creep_coupling],
                self.dead_zones_nm,
                self.dead_zone_gains,
            )
        )

    def hysteresis_output(self, state: ModelState) -> float:
        """``H(k-1) = a u(k-1) + sum_j w_j z_{r_j}(k-1)`` of a state (eq 8 without ``y0``)."""
        state.check_for(self)
        return float(self.gain * state.u_prev_nm + np.dot(self.weights, state.play_nm))

    def require_uncoupled(self, what: str) -> None:
        """Refuse (``ValueError``) a model with ``creep_coupling != 0`` in ``what``, an
        estimator that knows only the paper's eq (2)."""
        if self.creep_coupling != 0.0:
            raise ValueError(
                f"{what} handles only the paper's model (creep_coupling = 0); this model has "
                f"creep_coupling = {self.creep_coupling:g}."
            )

    def loading_curve(self, r_nm: ArrayLike) -> NDArray[np.float64]:
        """Initial loading curve ``phi(r) = sum_{j: r_j <= r} w_j (r - r_j)``, eq (8).

        ``w_0 = a`` and ``r_0 = 0``; defined for ``r >= 0``. It is the curve of the
        hysteresis output ``H``, before the asymmetry map of eq (8') (:meth:`asymmetry_map`).
        """
        r = np.asarray(r_nm, dtype=float)
        if np.any(r < 0):
            raise ValueError("loading_curve is defined for r >= 0.")
        out = self.gain * r
        for rj, wj in zip(self.thresholds_nm, self.weights, strict=True):
            out = out + wj * np.maximum(r - rj, 0.0)
        return out

    # ------------------------------------------------------------------ simulation
    def initial_state(self) -> ModelState:
        """All operator states zero (the start of the initial loading curve)."""
        return ModelState.zeros(self)

    def simulate(
        self,
        u_nm: ArrayLike,
        sample_period_s: float,
        state: ModelState | None = None,
    ) -> tuple[NDArray[np.float64], ModelState]:
        """Extension ``y`` for command ``u``, eq (14). See :func:`simulate`."""
        return simulate(self, u_nm, sample_period_s, state)

    @property
    def file_version(self) -> int:
        """The lowest model-file version that holds this model: 3 with dead zones (eq 8'),
        else 2."""
        return 3 if self.n_dead_zones else 2

    def to_dict(self) -> dict[str, Any]:
        """The model as the body of a model file of :attr:`file_version` (see
        :mod:`piezocomp.io.model_files`): the creep coupling is ``creep.coupling``, the dead
        zones of eq (8') ``asymmetry.dead_zones`` and ``asymmetry.gains`` (version 3 only)."""
        extra: dict[str, Any] = {}
        if self.n_dead_zones:
            extra["asymmetry"] = {
                "dead_zones": self.dead_zones_nm.tolist(),
                "gains": self.dead_zone_gains.tolist(),
            }
        if self.domain_nm is not None:
            extra["domain_nm"] = list(self.domain_nm)
        if self.range_nm is not None:
            extra["range_nm"] = self.range_nm
        return {
            "offset": self.offset_nm,
            "gain": self.gain,
            "play": {
                "thresholds": self.thresholds_nm.tolist(),
                "weights": self.weights.tolist(),
            },
            "creep": {
                "time_constants_s": self.creep_time_constants_s.tolist(),
                "gains": self.creep_gains.tolist(),
                "coupling": self.creep_coupling,
            },
            **extra,
        }

    @classmethod
    def from_dict(
        cls, body: Mapping[str, Any], where: str = "model", version: int = 2
    ) -> ScannerModel:
        """Build from the body of a model file of ``version`` 1, 2 or 3; unknown or missing
        keys are refused (``domain_nm`` and ``range_nm`` are optional, and in version 3
        ``asymmetry``). Versions 2 and 3 state the creep coupling as ``creep.coupling``;
        version 1 has none and means the paper's model (``beta = 0``). Version 3 may hold
        the dead zones of eq (8') as ``asymmetry``; without it the model is symmetric."""
        if version not in (1, 2, 3):
            raise ValueError(f"{where}: model body version must be 1, 2 or 3. Got {version!r}.")
        optional = OPTIONAL_KEYS | ({"asymmetry"} if version == 3 else set())
        _check_keys(body, {"offset", "gain", "play", "creep"}, where, frozenset(optional))
        play = body["play"]
        creep = body["creep"]
        _check_keys(play, {"thresholds", "weights"}, f"{where}.play")
        creep_keys = {"time_constants_s", "gains"} | ({"coupling"} if version >= 2 else set())
        _check_keys(creep, creep_keys, f"{where}.creep")
        asym = body.get("asymmetry", {"dead_zones": [], "gains": []})
        _check_keys(asym, {"dead_zones", "gains"}, f"{where}.asymmetry")
        try:
            return cls(
                offset_nm=body["offset"],
                gain=body["gain"],
                thresholds_nm=play["thresholds"],
                weights=play["weights"],
                creep_time_constants_s=creep["time_constants_s"],
                creep_gains=creep["gains"],
                domain_nm=body.get("domain_nm"),
                range_nm=body.get("range_nm"),
                creep_coupling=creep.get("coupling", 0.0),
                dead_zones_nm=asym["dead_zones"],
                dead_zone_gains=asym["gains"],
            )
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None


OPTIONAL_KEYS = frozenset({"domain_nm", "range_nm"})
"""Keys a model body may hold besides ``offset``, ``gain``, ``play`` and ``creep``."""


def _check_keys(
    body: Any, expected: set[str], where: str, optional: frozenset[str] = frozenset()
) -> None:
    if not isinstance(body, Mapping):
        raise ValueError(f"{where} must be an object. Got {type(body).__name__}.")
    unknown = sorted(set(body) - expected - optional)
    if unknown:
        raise ValueError(f"{where} has unknown key(s) {unknown}; expected {sorted(expected)}.")
    missing = sorted(expected - set(body))
    if missing:
        raise ValueError(f"{where} is missing key(s) {missing}.")


@dataclass(frozen=True, eq=False)
class ModelState:
    """State of the model of one axis between two samples.

    Attributes
    ----------
    play_nm : ndarray, shape (N_H,)
        Play outputs ``z_{r_j}(k-1)``.
    creep_nm : ndarray, shape (N_c,)
        Creep states ``x_i(k-1)``.
    u_prev_nm : float
        Last command ``u(k-1)``, which drives the creep update of eq (2). With a creep
        coupling (eq 2') the drive ``s(k-1) = u(k-1) + beta H(k-1)`` is a function of
        ``u_prev_nm`` and ``play_nm`` (:meth:`ScannerModel.hysteresis_output`), so the
        state holds no more.
    """

    play_nm: NDArray[np.float64]
    creep_nm: NDArray[np.float64]
    u_prev_nm: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "play_nm", readonly(as_finite_1d("play_nm", self.play_nm)))
        object.__setattr__(self, "creep_nm", readonly(as_finite_1d("creep_nm", self.creep_nm)))
        object.__setattr__(self, "u_prev_nm", check_finite_scalar("u_prev_nm", self.u_prev_nm))

    __eq__ = _fields_equal
    __hash__ = None  # type: ignore[assignment]

    @classmethod
    def zeros(cls, model: ScannerModel) -> ModelState:
        """All states zero, ``u(-1) = 0``."""
        return cls(np.zeros(model.n_play), np.zeros(model.n_creep), 0.0)

    @classmethod
    def at_rest(cls, model: ScannerModel, u_nm: float) -> ModelState:
        """Held at command ``u_nm`` for ever, play operators centred on it.

        The creep states have settled on their drive: ``u`` for the paper's model,
        ``s = u + beta (a + sum_j w_j) u`` with a creep coupling (eq 2').
        """
        u = check_finite_scalar("u_nm", u_nm)
        s = u
        if model.creep_coupling != 0.0:
            s = u + model.creep_coupling * (model.gain + float(model.weights.sum())) * u
        return cls(np.full(model.n_play, u), np.full(model.n_creep, s), u)

    def with_creep_at_rest(self, model: ScannerModel, u_rest_nm: float) -> ModelState:
        """This state with its creep states settled on a command held at ``u_rest_nm``
        (:meth:`at_rest`'s: with a creep coupling, eq 2', they depend on the parameters)."""
        creep = ModelState.at_rest(model, u_rest_nm).creep_nm
        return ModelState(self.play_nm, creep, self.u_prev_nm)

    def packed(self) -> NDArray[np.float64]:
        """``[z.., x.., u_prev]`` (a fresh writable array)."""
        return np.concatenate((self.play_nm, self.creep_nm, [self.u_prev_nm]))

    @classmethod
    def from_packed(cls, packed: NDArray[np.float64], n_play: int, n_creep: int) -> ModelState:
        """Inverse of :meth:`packed`."""
        return cls(packed[:n_play].copy(), packed[n_play : n_play + n_creep].copy(), packed[-1])

    def check_for(self, model: ScannerModel) -> None:
        """Refuse a state whose shape does not fit ``model``."""
        if self.play_nm.size != model.n_play or self.creep_nm.size != model.n_creep:
            raise ValueError(
                f"state has {self.play_nm.size} play and {self.creep_nm.size} creep states; "
                f"the model has {model.n_play} and {model.n_creep}."
            )


def simulate(
    model: ScannerModel,
    u_nm: ArrayLike,
    sample_period_s: float,
    state: ModelState | None = None,
) -> tuple[NDArray[np.float64], ModelState]:
    """Run the forward model (14) on a command trajectory.

    Parameters
    ----------
    model : ScannerModel
        Parameters.
    u_nm : array_like, shape (n,)
        Command samples, nominal nm (finite).
    sample_period_s : float
        Sample period ``T``, s.
    state : ModelState, optional
        State before the first sample; :meth:`ModelState.zeros` by default.

    Returns
    -------
    y : ndarray, shape (n,)
        Extension, nm.
    state : ModelState
        State after the last sample; passing it to the next call continues the stream
        exactly (batch == chunked == per-sample).
    """
    u = as_finite_1d("u_nm", u_nm)
    st = model.initial_state() if state is None else state
    st.check_for(model)
    packed = st.packed()
    y = np.empty(u.size)
    _kernels.forward(u, model.n_play, model.n_creep, model.packed(sample_period_s), packed, y)
    return y, ModelState.from_packed(packed, model.n_play, model.n_creep)


@dataclass(frozen=True)
class ScannerModel2D:
    """Independent models of the x and y axes (the paper neglects x-y coupling, Sec. V)."""

    x: ScannerModel
    y: ScannerModel

    def __post_init__(self) -> None:
        for name in ("x", "y"):
            if not isinstance(getattr(self, name), ScannerModel):
                raise TypeError(
                    f"{name} must be a ScannerModel. Got {type(getattr(self, name)).__name__}."
                )

    def __getitem__(self, axis: str) -> ScannerModel:
        if axis not in ("x", "y"):
            raise KeyError(f"axis must be 'x' or 'y'. Got {axis!r}.")
        return self.x if axis == "x" else self.y
