"""The sample as the tip works on it: particles, the tip that pushes them, and how far along.

:class:`WorkedSample` holds what pushing changes during a session: the particles (on the
surface, on the tip, or lost), the tip (its apex radius drawn per sample seed, since the
software does not know it, and growing with every push as it wears) and the pushing state
(:mod:`piezocomp.virtual_afm.pushing`). A push lasts while Z feedback is off, over any
number of :meth:`WorkedSample.push` calls; :meth:`WorkedSample.lift` ends it when the
feedback comes back on: particles held by the tip are dropped or lost, and the tip has worn.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from piezocomp._validation import as_finite_array
from piezocomp.tip import TipGeometry
from piezocomp.virtual_afm.config import SampleConfig
from piezocomp.virtual_afm.pushing import PushParams, PushState, end_push, push
from piezocomp.virtual_afm.sample import Particles

__all__ = ["WorkedSample", "drawn_tip", "drawn_tip_radius", "initial_particles"]


def initial_particles(
    sample: SampleConfig, particles: Particles | ArrayLike | None, rng: np.random.Generator
) -> Particles:
    """The particles a session starts with: ``particles`` as given (``Particles``, or rows
    ``(x, y)`` or ``(x, y, diameter)``), else the configuration's ``particle_positions_nm``,
    else random ones drawn from ``rng`` (``particles_per_um2`` in ``+-area_half_width_nm``)."""
    s = sample
    if isinstance(particles, Particles):
        return particles
    if particles is None and s.particle_positions_nm:
        rows = s.particle_positions_nm
        xy = np.array([r[:2] for r in rows], float)
        d = np.array([r[2] if len(r) == 3 else s.particle_diameter_nm for r in rows], float)
        return Particles(xy, d)
    if particles is not None:
        a = as_finite_array("particles", particles, ndim=2)
        if a.shape[1] not in (2, 3):
            raise ValueError(f"particles must have shape (n, 2) or (n, 3). Got {a.shape}.")
        d = a[:, 2] if a.shape[1] == 3 else np.full(a.shape[0], s.particle_diameter_nm)
        return Particles(a[:, :2], d)
    return Particles.random(
        rng, s.particles_per_um2, s.area_half_width_nm, s.particle_diameter_nm,
        s.particle_diameter_std_nm,
    )  # fmt: skip


def drawn_tip_radius(sample: SampleConfig) -> float:
    """The tip's apex radius of this sample seed, nm: uniform within ``tip_radius_nm * (1 +-
    tip_radius_spread)``, from a stream of its own (the other draws do not move)."""
    if sample.tip_radius_spread == 0:
        return sample.tip_radius_nm
    rng = np.random.default_rng(np.random.SeedSequence([sample.seed, 0x7197]))
    return float(sample.tip_radius_nm * (1.0 + sample.tip_radius_spread * rng.uniform(-1, 1)))


def drawn_tip(sample: SampleConfig) -> TipGeometry:
    """The tip of this sample seed: its apex radius (:func:`drawn_tip_radius`) and its cone
    half-angle, uniform within ``tip_half_angle_deg +- tip_half_angle_spread_deg`` from a
    stream of its own."""
    angle = sample.tip_half_angle_deg
    if sample.tip_half_angle_spread_deg > 0:
        rng = np.random.default_rng(np.random.SeedSequence([sample.seed, 0x7198]))
        angle += sample.tip_half_angle_spread_deg * float(rng.uniform(-1, 1))
    return TipGeometry(drawn_tip_radius(sample), angle)


class WorkedSample:
    """The particles of ``sample`` and the tip pushing them (all lengths nm).

    Parameters
    ----------
    sample : SampleConfig
        The tip, the friction, the failure rates and the seed.
    particles : Particles
        Every particle at the start.
    """

    def __init__(self, sample: SampleConfig, particles: Particles) -> None:
        self._config = sample
        self._tip = drawn_tip(sample)
        self._particles = particles
        self._surface = particles
        self._params = PushParams.from_config(sample, particles)
        self._state = PushState.initial(len(particles))
        self._pushing = False

    @property
    def tip(self) -> TipGeometry:
        """The tip now."""
        return self._tip

    @property
    def particles(self) -> Particles:
        """Every particle of the sample (those off the surface where they left it)."""
        return self._particles

    @property
    def surface(self) -> Particles:
        """The particles on the surface now."""
        return self._surface

    @property
    def push_params(self) -> PushParams:
        """Every particle's friction, the failure rates and the draws' key."""
        return self._params

    @property
    def push_state(self) -> PushState:
        """Where pushing stands."""
        return self._state

    @property
    def pushing(self) -> bool:
        """Whether a push is under way (Z feedback off since the last :meth:`lift`)."""
        return self._pushing

    def push(self, path_nm: ArrayLike) -> int:
        """Push along the true tip path ``path_nm`` (m, 2), its first row where the tip was
        before; the push goes on until :meth:`lift`. Returns the number of contacts."""
        self._particles, self._state, n = push(
            path_nm, self._particles, self._tip, self._params, self._state,
            self._config.push_height_nm,
        )  # fmt: skip
        self._pushing = True
        self._on_surface_changed()
        return n

    def lift(self) -> None:
        """Z feedback back on: the push under way ends (held particles dropped or lost),
        and the tip has worn by it (``tip_blunting_nm_per_push``). Nothing when no push is
        under way."""
        if not self._pushing:
            return
        s = self._config
        self._particles, self._state = end_push(
            self._particles, self._tip, self._params, self._state, s.push_height_nm
        )
        self._pushing = False
        self._on_surface_changed()
        if s.tip_blunting_nm_per_push > 0:
            self._tip = TipGeometry(
                self._tip.radius_nm + s.tip_blunting_nm_per_push, self._tip.half_angle_deg
            )

    def _on_surface_changed(self) -> None:
        on = self._state.on_surface
        p = self._particles
        # a new object only when needed: topography keeps the cell list of the last one
        if on.all():
            self._surface = p
        elif self._surface.xy_nm.shape[0] != int(on.sum()) or not np.array_equal(
            self._surface.xy_nm, p.xy_nm[on]
        ):
            self._surface = Particles(p.xy_nm[on], p.diameter_nm[on])
