"""Pushing particles with the tip (Z feedback off): friction, and pushes that fail.

Geometry (all nm). With Z feedback off the tip's apex is ``z_push`` above the substrate; a
particle whose centre comes closer to the tip axis than the contact distance at that
height (:meth:`piezocomp.tip.TipGeometry.contact_distance`) is in contact. A contact moves
the particle as in quasi-static pushing of a disc with Coulomb friction between tip and
particle (Mason 1986): while the tip's motion lies within the friction cone (half-angle
``atan(mu)``) about the contact normal the particle is carried along with the tip; outside
it, it slides around the tip, kept at the contact distance along the line from the tip to
its centre. Particles do not push each other.

Real pushing is not that tidy. Each particle has its own friction coefficient ``mu`` (drawn
per sample about ``tip_friction``, log-normal), and each *engagement* (a contact from its
first touch until the tip leaves the particle) can fail in one of three ways that the AFM
manipulation literature reports (see ``docs/virtual_afm.md`` for the sources and the rates):

- **stuck**: the particle is held by the substrate and does not move; the tip rides over it;
- **rolls off**: the particle leaves the tip within its first :data:`ROLL_RELEASE_NM` of
  travel, jumping sideways off the tip's path (one to two contact distances from its axis);
- **picked up**: the particle sticks to the tip and leaves the surface; when the push ends
  (the tip lifts, Z feedback back on) it is dropped near the tip's last position with
  probability ``drop_fraction``, and otherwise carried away for good.

Randomness is counter-based: an engagement's draws are a hash of the sample's key, the
particle and the engagement's number (:func:`piezocomp.virtual_afm._kernels.uniform`), and
everything else lives in :class:`PushState`, passed in and returned. So a push made in
pieces is the push made in one call, and a sample pushed twice the same way fails the same
way.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._validation import as_finite_array, check_finite_scalar
from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm import _kernels as K
from piezocomp.virtual_afm.config import SampleConfig
from piezocomp.virtual_afm.sample import Particles

__all__ = [
    "ROLL_RELEASE_NM",
    "STEP_NM",
    "PushCounts",
    "PushParams",
    "PushState",
    "end_push",
    "push",
    "push_particles",
]

ROLL_RELEASE_NM = 50.0
"""A particle that rolls off leaves the tip after a travel drawn uniformly in
``[0, ROLL_RELEASE_NM)``: a push shorter than that may end before it does."""

STEP_NM = 0.25
"""Longest advance of the tip between two evaluations of the contacts."""


def _frozen(a: ArrayLike, dtype: Any) -> NDArray[Any]:
    out = np.array(a, dtype=dtype, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class PushParams:
    """How the particles of one sample respond to pushing.

    Attributes
    ----------
    friction : ndarray, shape (n,)
        Tip-particle Coulomb friction coefficient of each particle (>= 0).
    stuck_rate, roll_rate, pickup_rate : float
        Probability that an engagement leaves the particle where it is, lets it roll off,
        or picks it up (each in [0, 1], their sum <= 1).
    drop_fraction : float
        Probability that a picked-up particle is dropped when the push ends (else it is
        lost from the surface).
    key : int
        Key of the engagements' draws (0 to 2**64 - 1): the sample's.
    z_offset_nm : ndarray, shape (n,), optional
        How far above the push height as set each particle meets the apex (the substrate's
        height under it against the plane the setting refers to); zeros when not given.
    """

    friction: NDArray[np.float64]
    stuck_rate: float = 0.0
    roll_rate: float = 0.0
    pickup_rate: float = 0.0
    drop_fraction: float = 0.0
    key: int = 0
    z_offset_nm: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        mu = as_finite_array("friction", self.friction, ndim=1)
        if mu.size and mu.min() < 0:
            raise ValueError(f"friction must be >= 0. Got {mu.min()}.")
        object.__setattr__(self, "friction", _frozen(mu, np.float64))
        for name in ("stuck_rate", "roll_rate", "pickup_rate", "drop_fraction"):
            v = check_finite_scalar(name, getattr(self, name))
            if not 0 <= v <= 1:
                raise ValueError(f"{name} must be in [0, 1]. Got {v}.")
            object.__setattr__(self, name, v)
        total = self.stuck_rate + self.roll_rate + self.pickup_rate
        if total > 1 + 1e-12:
            raise ValueError(f"stuck_rate + roll_rate + pickup_rate must be <= 1. Got {total:g}.")
        if isinstance(self.key, bool) or not isinstance(self.key, int | np.integer):
            raise TypeError(f"key must be an integer. Got {self.key!r}.")
        if not 0 <= int(self.key) < 1 << 64:
            raise ValueError(f"key must be in [0, 2**64). Got {self.key}.")
        object.__setattr__(self, "key", int(self.key))
        dz = np.zeros(mu.size) if self.z_offset_nm is None else self.z_offset_nm
        dz = as_finite_array("z_offset_nm", dz, ndim=1)
        if dz.shape != mu.shape:
            raise ValueError(
                f"z_offset_nm must have one value per particle ({mu.size}). Got {dz.size}."
            )
        object.__setattr__(self, "z_offset_nm", _frozen(dz, np.float64))

    def z_push_nm(self, z_set_nm: float) -> NDArray[np.float64]:
        """The apex height each particle meets when the push height is set to
        ``z_set_nm`` (never below the substrate)."""
        assert self.z_offset_nm is not None  # set by __post_init__
        return np.maximum(z_set_nm + self.z_offset_nm, 0.0)

    @classmethod
    def uniform(cls, n: int, friction: float = 0.0) -> PushParams:
        """``n`` particles of friction ``friction`` whose pushes never fail."""
        return cls(np.full(int(n), check_finite_scalar("friction", friction)))

    @classmethod
    def from_config(cls, sample: SampleConfig, particles: Particles) -> PushParams:
        """The pushing of ``particles`` on the sample of ``sample`` (its seed, friction and
        failure rates): the frictions are drawn log-normal with median ``tip_friction`` and
        log standard deviation ``tip_friction_spread``, the push height's offsets uniformly
        within ``+-push_height_spread_nm`` (a stream of their own: the other draws do not
        move); every draw depends on the seed and on the particles (a sample is its seed and
        its particles)."""
        digest = zlib.crc32(np.ascontiguousarray(particles.xy_nm).tobytes())
        digest = zlib.crc32(np.ascontiguousarray(particles.diameter_nm).tobytes(), digest)
        ss = np.random.SeedSequence([sample.seed, 0x9054, digest])
        key = int(ss.generate_state(1, np.uint64)[0])
        rng = np.random.default_rng(np.random.SeedSequence([sample.seed, 0xF41C, digest]))
        n = len(particles)
        mu = sample.tip_friction * np.exp(sample.tip_friction_spread * rng.standard_normal(n))
        dz = np.zeros(n)
        if sample.push_height_spread_nm > 0:
            rz = np.random.default_rng(np.random.SeedSequence([sample.seed, 0x2E16, digest]))
            dz = sample.push_height_spread_nm * rz.uniform(-1.0, 1.0, n)
        return cls(mu, sample.push_stuck_rate, sample.push_roll_rate, sample.push_pickup_rate,
                   sample.push_drop_fraction, key, dz)  # fmt: skip


@dataclass(frozen=True)
class PushCounts:
    """What pushing did so far: engagements begun and how many failed, by kind."""

    engagements: int = 0
    stuck: int = 0
    rolled_off: int = 0
    picked_up: int = 0
    dropped: int = 0
    lost: int = 0

    def __add__(self, other: PushCounts) -> PushCounts:
        return PushCounts(*(a + b for a, b in zip(self.as_tuple(), other.as_tuple(),
                                                   strict=True)))  # fmt: skip

    def as_tuple(self) -> tuple[int, ...]:
        """The counts in the order of the fields."""
        return (self.engagements, self.stuck, self.rolled_off, self.picked_up, self.dropped,
                self.lost)  # fmt: skip


@dataclass(frozen=True)
class PushState:
    """Where pushing stands: which particles are on the surface, which the tip touches, the
    number and fate of every particle's engagements, and the particles on the tip.

    Attributes
    ----------
    on_surface, touching : ndarray of bool, shape (n,)
    engagements : ndarray of int, shape (n,)
        Engagements begun with each particle (the counter of its draws).
    fate : ndarray of int8, shape (n,)
        The fate of each particle's last engagement (the kernel's ``FATE_*``).
    travel_nm : ndarray, shape (n,)
        Distance each particle travelled in its last engagement.
    held : tuple of int
        Particles on the tip now (picked up during the push under way).
    tip_nm : (float, float)
        The tip's last position while pushing (where held particles are dropped).
    counts : PushCounts
        Totals since the state was made.
    """

    on_surface: NDArray[np.bool_]
    touching: NDArray[np.bool_]
    engagements: NDArray[np.int64]
    fate: NDArray[np.int8]
    travel_nm: NDArray[np.float64]
    held: tuple[int, ...] = ()
    tip_nm: tuple[float, float] = (0.0, 0.0)
    counts: PushCounts = field(default_factory=PushCounts)

    def __post_init__(self) -> None:
        n = np.asarray(self.on_surface).shape
        for name, dtype in (("on_surface", np.bool_), ("touching", np.bool_),
                            ("engagements", np.int64), ("fate", np.int8),
                            ("travel_nm", np.float64)):  # fmt: skip
            a = _frozen(getattr(self, name), dtype)
            if a.shape != n or a.ndim != 1:
                raise ValueError(f"{name} must have shape {n}. Got {a.shape}.")
            object.__setattr__(self, name, a)

    @classmethod
    def initial(cls, n: int) -> PushState:
        """Nothing pushed yet: ``n`` particles on the surface."""
        return cls(np.ones(n, bool), np.zeros(n, bool), np.zeros(n, np.int64),
                   np.zeros(n, np.int8), np.zeros(n))  # fmt: skip

    @property
    def pushing(self) -> bool:
        """Whether a push is under way (the tip touches a particle or holds one)."""
        return bool(self.touching.any()) or bool(self.held)


def push(
    path_nm: ArrayLike,
    particles: Particles,
    tip: TipGeometry,
    params: PushParams,
    state: PushState,
    z_push_nm: float = 0.0,
) -> tuple[Particles, PushState, int]:
    """Push along the true tip path ``path_nm`` (m, 2; Z feedback off, apex set at
    ``z_push_nm``, met by each particle at ``params.z_push_nm(z_push_nm)``).

    Returns
    -------
    particles : Particles
        Every particle after the push (those off the surface keep their last position:
        read ``state.on_surface``). The input is not modified.
    state : PushState
    n_contacts : int
        Sub-steps x particles at which the tip touched a particle.
    """
    path = np.ascontiguousarray(as_finite_array("path_nm", path_nm, ndim=2))
    if path.shape[1] != 2:
        raise ValueError(f"path_nm must have shape (m, 2). Got {path.shape}.")
    z = check_finite_scalar("z_push_nm", z_push_nm)
    n = len(particles)
    if params.friction.shape != (n,) or state.on_surface.shape != (n,):
        raise ValueError(
            f"params and state must describe the {n} particles. Got "
            f"{params.friction.shape[0]} and {state.on_surface.shape[0]}."
        )
    R = 0.5 * np.asarray(particles.diameter_nm)
    z_met = params.z_push_nm(z)
    if z < 0 or (R.size and np.any(z_met >= 2 * R)):
        met = f" (met at {z_met.min():.3g} to {z_met.max():.3g} nm)" if z_met.size else ""
        raise ValueError(
            f"z_push_nm must be in [0, smallest particle height) at every particle. Got {z}{met}."
        )
    if path.shape[0] == 0:
        return particles, state, 0
    tip_end = (float(path[-1, 0]), float(path[-1, 1]))
    if path.shape[0] < 2 or n == 0:
        return particles, replace(state, tip_nm=tip_end), 0
    xy = np.array(particles.xy_nm)
    contact = tip.contact_distance(R, z_met)
    lo = path.min(axis=0) - contact.max() - 1.0
    hi = path.max(axis=0) + contact.max() + 1.0
    # only particles within reach of the path can move; the others' contact ends
    near = np.flatnonzero(np.all((xy >= lo) & (xy <= hi), axis=1) & state.on_surface)
    touching = np.array(state.touching)
    touching[np.setdiff1d(np.arange(n), near)] = False
    mu = params.friction[near]
    cos_f = np.where(mu > 0, 1.0 / np.sqrt(1.0 + mu * mu), 2.0)
    px, py = np.ascontiguousarray(xy[near, 0]), np.ascontiguousarray(xy[near, 1])
    on = np.array(state.on_surface[near])
    tc = np.array(touching[near])
    eng = np.array(state.engagements[near])
    fate = np.array(state.fate[near])
    travel = np.array(state.travel_nm[near])
    counts = np.zeros(4, np.int64)
    n_contacts = K.push_run(
        path, px, py, np.ascontiguousarray(contact[near]), STEP_NM, cos_f,
        near.astype(np.int64), np.uint64(params.key), params.stuck_rate, params.roll_rate,
        params.pickup_rate, ROLL_RELEASE_NM, on, tc, eng, fate, travel, counts,
    )  # fmt: skip
    xy[near, 0], xy[near, 1] = px, py
    on_surface = np.array(state.on_surface)
    picked = near[state.on_surface[near] & ~on]
    on_surface[near] = on
    touching[near] = tc
    new = PushState(
        on_surface, touching, _put(state.engagements, near, eng), _put(state.fate, near, fate),
        _put(state.travel_nm, near, travel), state.held + tuple(int(i) for i in picked),
        tip_end, state.counts + PushCounts(*(int(c) for c in counts)),
    )  # fmt: skip
    return Particles(xy, particles.diameter_nm), new, int(n_contacts)


def _put(a: NDArray[Any], idx: NDArray[np.intp], values: NDArray[Any]) -> NDArray[Any]:
    out = np.array(a)
    out[idx] = values
    return out


def end_push(
    particles: Particles, tip: TipGeometry, params: PushParams, state: PushState, z_push_nm: float
) -> tuple[Particles, PushState]:
    """The tip lifts (Z feedback back on): no particle is touched any more, and each one the
    tip holds is dropped near its last position (within a contact distance, with
    probability ``params.drop_fraction``: the engagement's slot-4 draw) or lost."""
    if not state.pushing:
        return particles, state
    xy = np.array(particles.xy_nm)
    on_surface = np.array(state.on_surface)
    dropped = lost = 0
    for i in state.held:
        e = int(state.engagements[i]) - 1
        if K.uniform(np.uint64(params.key), i, e, 4) < params.drop_fraction:
            z_i = float(params.z_push_nm(z_push_nm)[i])
            c = float(tip.contact_distance(0.5 * float(particles.diameter_nm[i]), z_i))
            ang = 2.0 * math.pi * K.uniform(np.uint64(params.key), i, e, 5)
            r = c * K.uniform(np.uint64(params.key), i, e, 6)
            xy[i] = (state.tip_nm[0] + r * math.cos(ang), state.tip_nm[1] + r * math.sin(ang))
            on_surface[i] = True
            dropped += 1
        else:
            lost += 1
    new = replace(
        state, on_surface=on_surface, touching=np.zeros_like(state.touching), held=(),
        counts=state.counts + PushCounts(dropped=dropped, lost=lost),
    )  # fmt: skip
    return Particles(xy, particles.diameter_nm), new


def push_particles(
    path_nm: ArrayLike,
    particles: Particles,
    tip: TipGeometry,
    z_push_nm: float = 0.0,
    friction: float = 0.0,
) -> tuple[Particles, int]:
    """One push that never fails, every particle of friction ``friction`` (the tidy model:
    :func:`push` with :meth:`PushParams.uniform`).

    Returns
    -------
    particles : Particles
        Particles after the push (the input is not modified).
    n_contacts : int
        Sub-steps x particles at which the tip touched a particle.
    """
    mu = check_finite_scalar("friction", friction)
    if mu < 0:
        raise ValueError(f"friction must be >= 0. Got {mu}.")
    n = len(particles)
    out, _, n_contacts = push(path_nm, particles, tip, PushParams.uniform(n, mu),
                              PushState.initial(n), z_push_nm)  # fmt: skip
    return out, n_contacts
