"""Automatic assembly: particles pushed into a pattern with no user in the loop (Fig. 10).

:func:`assemble` is what the paper's Fig. 10 demonstrates: one image of the area, particles
found in it (:func:`~piezocomp.imaging.features.find_particles`), one assigned to each target
(:func:`scipy.optimize.linear_sum_assignment`, least total travel), and every particle pushed
to its target along a straight line through its centre with Z feedback off; no image between
pushes. The whole is done in passes: the first places the particles coarsely, the next find
them again and correct what is left (the paper's two passes, coarse then fine).

Pushes fail: a particle stays put, leaves the tip's path or leaves the surface. Each pass's
image checks the pass before (:mod:`~piezocomp.positioning.push_check`): a particle that did
not move, moved off target or vanished is a failed push, which the next pass recovers by
pushing it again or another particle to its target (one whose pushes failed
``max_attempts`` times is left alone). A pass that found a failure, or pushed for one,
earns one more pass, up to ``recovery_passes``.

The tip stops short of the target by the contact distance (:func:`contact_distance`, from
the tip's shape and the particle's height in the image), and starts ``approach_nm`` behind
contact. A push is planned only if its tip path keeps clear of every other particle (their
contact distance plus ``clearance_nm``) and the particle's own path does not run into
another; otherwise it goes around in two legs (an L through a corner), or waits until pushes
planned before it have cleared the way. The order follows the paper by
default: the next push is the one whose start lies farthest from the tip, to make the tip
travel between pushes (``order="nearest"`` does the opposite, for throughput), except that a
push which would wall in a target still to be filled (no way left to it past the particles
already placed), or take the only way a target ready now has, gives way to the next in the
order that does not: enclosed sites are filled first, which matters for a blunt tip, whose
contact distance is large.

It runs on any :class:`~piezocomp.instrument.Instrument`: on a raw instrument the lengths
are nominal and the pushes miss; on a :class:`~piezocomp.positioning.CompensatedInstrument`
every position is true.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from piezocomp._validation import as_finite_array, check_finite_scalar
from piezocomp.imaging.features import FoundParticles, find_particles
from piezocomp.imaging.tip_estimate import estimate_tip_radius
from piezocomp.instrument import Instrument, ScanImage
from piezocomp.positioning import push_check as pc
from piezocomp.tip import TipGeometry

__all__ = [
    "STAGING_NM",
    "AssemblyResult",
    "AssemblySettings",
    "PassResult",
    "Push",
    "assemble",
    "contact_distance",
    "match_targets",
    "plan_pushes",
]


@dataclass(frozen=True)
class AssemblySettings:
    """How :func:`assemble` images, plans and pushes.

    Parameters
    ----------
    passes : int
        Image-plan-push passes (the paper's 2: coarse, then fine).
    push_speed_nm_per_s, move_speed_nm_per_s : float
        Speed of a push (Z feedback off) and of the moves between pushes (Z feedback on).
    tip_radius_nm : float or None
        The tip's apex radius; ``None`` (the default): estimated from every pass's image
        (:func:`~piezocomp.imaging.tip_estimate.estimate_tip_radius`), so that a tip that
        blunts as it works is followed. With :func:`plan_pushes` alone it must be given.
    tip_half_angle_deg, push_height_nm : float
        The tip's cone half-angle (its datasheet's) and its apex's height above the substrate
        while pushing: with the radius they set the contact distance
        (:func:`contact_distance`).
    approach_nm : float
        A push starts this far behind contact.
    clearance_nm : float
        Extra room kept between the tip (or a pushed particle) and every other particle.
    tolerance_nm : float
        A particle within this of its target is not pushed again.
    order : {"farthest", "nearest"}
        Next push: the one starting farthest from the tip (the paper) or nearest.
    image_pixels, image_line_rate_hz : int, float
        The images of the area (before every pass and after the last).
    min_height_nm : float
        Smallest particle height counted in the images.
    check_nm : float
        A pushed particle found farther than this from where its push should have left it
        failed (:func:`~piezocomp.positioning.push_check.check_pushes`).
    recovery_passes : int
        Most passes added to ``passes`` to recover failed pushes.
    max_attempts : int
        A particle whose pushes failed this many times (it stayed put, or went off target
        again) is left alone: another one takes its target.
    """

    passes: int = 2
    push_speed_nm_per_s: float = 200.0
    move_speed_nm_per_s: float = 1000.0
    tip_radius_nm: float | None = None
    tip_half_angle_deg: float = 20.0
    push_height_nm: float = 1.0
    approach_nm: float = 10.0
    clearance_nm: float = 3.0
    tolerance_nm: float = 0.5
    order: str = "farthest"
    image_pixels: int = 256
    image_line_rate_hz: float = 1.0
    min_height_nm: float = 5.0
    check_nm: float = 5.0
    recovery_passes: int = 2
    max_attempts: int = 2

    def __post_init__(self) -> None:
        for name in ("push_speed_nm_per_s", "move_speed_nm_per_s", "tip_radius_nm",
                     "tip_half_angle_deg", "image_line_rate_hz", "min_height_nm",
                     "check_nm"):  # fmt: skip
            if name == "tip_radius_nm" and self.tip_radius_nm is None:
                continue
            v = check_finite_scalar(name, getattr(self, name))
            if v <= 0:
                raise ValueError(f"{name} must be > 0. Got {v}.")
        for name in ("push_height_nm", "approach_nm", "clearance_nm", "tolerance_nm"):
            v = check_finite_scalar(name, getattr(self, name))
            if v < 0:
                raise ValueError(f"{name} must be >= 0. Got {v}.")
        for name, low in (("passes", 1), ("image_pixels", 16), ("recovery_passes", 0),
                          ("max_attempts", 1)):  # fmt: skip
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"{name} must be an integer >= {low}. Got {v!r}.")
        if self.order not in ("farthest", "nearest"):
            raise ValueError(f"order must be 'farthest' or 'nearest'. Got {self.order!r}.")


@dataclass(frozen=True)
class Push:
    """One push: the tip goes down at ``start_nm`` and stops at ``end_nm``.

    Attributes
    ----------
    particle : int
        Index of the pushed particle in the pass's list of found particles.
    start_nm, end_nm : tuple of float
        Tip positions, nm (instrument frame).
    to_nm : tuple of float
        Where the particle should end.
    """

    particle: int
    start_nm: tuple[float, float]
    end_nm: tuple[float, float]
    to_nm: tuple[float, float]


@dataclass(frozen=True)
class PassResult:
    """One pass: what the image showed, the plan and what could not be planned.

    Attributes
    ----------
    found : FoundParticles
        Particles in the pass's image.
    assignment : ndarray of int, shape (m,)
        Found particle assigned to each target (-1: none).
    pushes : tuple of Push
        In the order executed.
    blocked : tuple of int
        Targets whose particle could not be pushed (no clear path).
    tip_radius_nm : float
        The tip's apex radius the plan used (estimated from the pass's image, or given).
    checks : tuple of PushCheck
        What the next image showed of each particle the pass pushed, and what was done about
        each failure.
    """

    found: FoundParticles
    assignment: NDArray[np.intp]
    pushes: tuple[Push, ...]
    blocked: tuple[int, ...]
    tip_radius_nm: float = float("nan")
    checks: tuple[pc.PushCheck, ...] = ()


@dataclass(frozen=True)
class AssemblyResult:
    """What :func:`assemble` did and where the particles ended, as the last image shows.

    Attributes
    ----------
    targets_nm : ndarray, shape (m, 2)
    passes : tuple of PassResult
    final : FoundParticles
        Particles in the last image.
    final_positions_nm : ndarray, shape (m, 2)
        The particle matched to each target in the last image (NaN: none within reach).
    images : tuple of ScanImage
        Every image taken (one per pass, then the last).
    """

    targets_nm: NDArray[np.float64]
    passes: tuple[PassResult, ...]
    final: FoundParticles
    final_positions_nm: NDArray[np.float64]
    images: tuple[ScanImage, ...] = field(repr=False)

    @property
    def errors_nm(self) -> NDArray[np.float64]:
        """Distance of each target's particle from it in the last image, nm (NaN: none)."""
        return np.asarray(np.hypot(*(self.final_positions_nm - self.targets_nm).T))

    @property
    def max_error_nm(self) -> float:
        """The largest of :attr:`errors_nm` (NaN if a target has no particle)."""
        e = self.errors_nm
        return float(np.max(e)) if e.size else 0.0

    @property
    def n_pushes(self) -> int:
        """Pushes made over all passes."""
        return sum(len(p.pushes) for p in self.passes)

    @property
    def failed_pushes(self) -> tuple[pc.PushCheck, ...]:
        """Every push the images showed had failed, in order."""
        return tuple(c for p in self.passes for c in p.checks if c.failed)

    @property
    def failures(self) -> dict[str, int]:
        """Failed pushes by kind (``"stuck"``, ``"off_target"``, ``"vanished"``)."""
        return {k: sum(c.kind == k for c in self.failed_pushes) for k in pc.FAILURES}

    @property
    def recoveries(self) -> dict[str, int]:
        """What was done about the failed pushes: ``"pushed_again"``, ``"another_particle"``,
        ``"none"``."""
        acts = ("pushed_again", "another_particle", "none")
        return {a: sum(c.action == a for c in self.failed_pushes) for a in acts}


def contact_distance(
    diameter_nm: ArrayLike, tip_radius_nm: float, tip_half_angle_deg: float, push_height_nm: float
) -> Any:
    """Lateral distance between the tip's axis and a particle's centre at first contact, for
    a sphere on the substrate and a sphere-ended cone whose apex is ``push_height_nm`` above
    it (:meth:`piezocomp.tip.TipGeometry.contact_distance`: the particle meets the
    apex sphere or, low down, the cone's flank)."""
    R = 0.5 * np.asarray(diameter_nm, dtype=float)
    return TipGeometry(float(tip_radius_nm), float(tip_half_angle_deg)).contact_distance(
        R, float(push_height_nm)
    )


def _segment_distance(
    p: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]
) -> Any:
    """Distance of points ``p`` (k, 2) from the segment ``a``-``b``."""
    ab = b - a
    L2 = float(ab @ ab)
    t = np.zeros(p.shape[0]) if L2 == 0 else np.clip((p - a) @ ab / L2, 0.0, 1.0)
    return np.hypot(*(p - (a + t[:, None] * ab)).T)


STAGING_NM = 80.0
"""How far from its target a way may stage a particle, on one of the target's four sides,
before its last push into the target (a site whose straight and L-shaped ways run into
particles already placed, such as a cell's corner reached from outside the cell)."""


def _legs(
    p: NDArray[np.float64], t: NDArray[np.float64], within: NDArray[np.float64] | None = None
) -> list[list[NDArray[np.float64]]]:
    """Ways from ``p`` to ``t``: straight, then the two L-shapes (x first, y first), then by
    a staging point :data:`STAGING_NM` from ``t`` on each of its four sides (reached straight
    or by an L), shortest first; a staging point outside ``within`` (``[[x0, x1], [y0,
    y1]]``, the area the pushes may use) is not tried."""

    def ells(a: NDArray[np.float64], b: NDArray[np.float64]) -> list[list[NDArray[np.float64]]]:
        out = [[b]]
        for corner in (np.array([b[0], a[1]]), np.array([a[0], b[1]])):
            if np.hypot(*(corner - a)) > 1e-9 and np.hypot(*(b - corner)) > 1e-9:
                out.append([corner, b])
        return out

    ways = ells(p, t)
    staged = []
    for side in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)):
        stage = t + STAGING_NM * np.asarray(side)
        inside = within is None or bool(np.all((within[:, 0] <= stage) & (stage <= within[:, 1])))
        if inside and np.hypot(*(stage - p)) > 1e-9:
            staged += [[*way, t] for way in ells(p, stage)]

    def length(way: list[NDArray[np.float64]]) -> float:
        pts = [p, *way]
        return float(sum(np.hypot(*(b - a)) for a, b in itertools.pairwise(pts)))

    return ways + sorted(staged, key=length)


def plan_pushes(
    particles_nm: ArrayLike,
    diameters_nm: ArrayLike,
    targets_nm: ArrayLike,
    assignment: ArrayLike,
    settings: AssemblySettings,
    *,
    tip_nm: tuple[float, float] = (0.0, 0.0),
    within_nm: tuple[tuple[float, float], tuple[float, float]] | None = None,
) -> tuple[tuple[Push, ...], tuple[int, ...]]:
    """Pushes that bring each assigned particle to its target, in the order of
    ``settings.order``, each clear of every other particle where it then is.

    Parameters
    ----------
    particles_nm : array_like, shape (n, 2)
        Particle centres now.
    diameters_nm : array_like, shape (n,)
        Their diameters (an image's apex heights).
    targets_nm : array_like, shape (m, 2)
    assignment : array_like of int, shape (m,)
        Particle for each target (-1: none). Particles already within ``tolerance_nm``
        are left where they are.
    settings : AssemblySettings
    tip_nm : (float, float)
        Where the tip is before the first push.
    within_nm : ((float, float), (float, float)), optional
        ``((x0, x1), (y0, y1))``: the area the pushes may use (the imaged one, whose
        particles are known); a staging point outside it is not tried (default: anywhere).

    Returns
    -------
    pushes : tuple of Push
    blocked : tuple of int
        Targets left out for want of a clear path.
    """
    pos = as_finite_array("particles_nm", particles_nm, ndim=2).copy()
    dia = as_finite_array("diameters_nm", diameters_nm, ndim=1)
    tgt = as_finite_array("targets_nm", targets_nm, ndim=2)
    asg = np.asarray(assignment, dtype=np.intp)
    s = settings
    if s.tip_radius_nm is None:
        raise ValueError(
            "plan_pushes needs settings.tip_radius_nm: estimate it from an image "
            "(piezocomp.imaging.tip_estimate.estimate_tip_radius) or give it."
        )
    contact = contact_distance(dia, s.tip_radius_nm, s.tip_half_angle_deg, s.push_height_nm)
    todo = [
        j for j in range(tgt.shape[0])
        if asg[j] >= 0 and np.hypot(*(pos[asg[j]] - tgt[j])) > s.tolerance_nm
    ]  # fmt: skip
    tip = np.asarray(tip_nm, dtype=float)
    within = None if within_nm is None else as_finite_array("within_nm", within_nm, ndim=2)
    if within is not None and (within.shape != (2, 2) or not np.all(within[:, 0] < within[:, 1])):
        raise ValueError(
            f"within_nm must be ((x0, x1), (y0, y1)) with x0 < x1 and y0 < y1. Got {within_nm}."
        )
    pushes: list[Push] = []

    def clear(
        i: int, a: NDArray[np.float64], b: NDArray[np.float64], moving: frozenset[int] = frozenset()
    ) -> list[Push] | None:
        """The push of particle ``i`` from ``a`` to ``b``, or None if a particle other than
        those of ``moving`` (still to be pushed, so not counted) is in the way."""
        d = (b - a) / max(float(np.hypot(*(b - a))), 1e-12)
        start = a - (contact[i] + s.approach_nm) * d
        end = b - contact[i] * d
        others = np.arange(pos.shape[0]) != i
        if moving:
            others[list(moving)] = False
        tip_room = _segment_distance(pos[others], start, end) - contact[others]
        body_room = _segment_distance(pos[others], a, b) - 0.5 * (dia[others] + dia[i])
        if others.any() and min(tip_room.min(), body_room.min()) < s.clearance_nm:
            return None
        return [Push(i, (float(start[0]), float(start[1])), (float(end[0]), float(end[1])),
                     (float(b[0]), float(b[1])))]  # fmt: skip

    def way(j: int, moving: frozenset[int] = frozenset()) -> list[Push] | None:
        i = int(asg[j])
        for legs in _legs(pos[i], tgt[j], within):
            plan: list[Push] = []
            a = pos[i].copy()
            saved = pos[i].copy()
            for b in legs:
                leg = clear(i, a, b, moving)
                if leg is None:
                    break
                plan += leg
                a = b
                pos[i] = b  # the next leg starts where this one put the particle
            pos[i] = saved
            if len(plan) == len(legs):
                return plan
        return None

    def closed(j: int, rest: list[int]) -> bool:
        """Whether target ``j`` can no longer be reached: no way clear of the particles that
        will not move again (those placed, those left where they are), the particles of
        ``rest`` not counted since they move before the end."""
        return way(j, frozenset(int(asg[q]) for q in rest)) is None

    def closes(j: int, ready: list[int]) -> bool:
        """Whether placing target ``j``'s particle now closes another target: one ready
        (``ready``: a way clear of every particle where it now is) that no way would reach
        any more, or one still open that could no longer be reached at all."""
        rest = [q for q in todo if q != j]
        i, saved = int(asg[j]), pos[int(asg[j])].copy()
        before = [q for q in rest if q not in ready and not closed(q, todo)]
        pos[i] = tgt[j]
        shut = any(way(q) is None for q in ready if q != j) or any(closed(q, rest) for q in before)
        pos[i] = saved
        return shut

    while todo:
        ready = [(j, w) for j in todo if (w := way(j)) is not None]
        if not ready:
            break
        dist = [float(np.hypot(*(np.asarray(w[0].start_nm) - tip))) for _, w in ready]
        sign = -1.0 if s.order == "farthest" else 1.0
        rank = sorted(range(len(ready)), key=lambda r: (sign * dist[r], r))
        # the order's choice, unless it would wall in a target another choice leaves open
        # (fill the enclosed sites first)
        now = [q for q, _ in ready]
        k = next((r for r in rank if not closes(ready[r][0], now)), rank[0])
        j, w = ready[k]
        pushes += w
        pos[asg[j]] = tgt[j]
        tip = np.asarray(w[-1].end_nm)
        todo.remove(j)
    return tuple(pushes), tuple(todo)


def match_targets(
    particles_nm: ArrayLike, targets_nm: ArrayLike, *, max_distance_nm: float = math.inf
) -> NDArray[np.intp]:
    """Particle for each target, one each, least total distance
    (:func:`scipy.optimize.linear_sum_assignment`); -1 where none is within
    ``max_distance_nm`` (or there are fewer particles than targets)."""
    p = np.asarray(particles_nm, dtype=float).reshape(-1, 2)
    t = as_finite_array("targets_nm", targets_nm, ndim=2)
    out = np.full(t.shape[0], -1, dtype=np.intp)
    if p.shape[0] == 0 or t.shape[0] == 0:
        return out
    cost = np.hypot(*(t[:, None, :] - p[None, :, :]).transpose(2, 0, 1))
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] <= max_distance_nm
    out[rows[ok]] = cols[ok]
    return out


def assemble(
    instrument: Instrument,
    targets_nm: ArrayLike,
    *,
    center_nm: tuple[float, float],
    size_nm: float,
    settings: AssemblySettings | None = None,
) -> AssemblyResult:
    """Push particles of the square area ``center_nm +- size_nm / 2`` onto ``targets_nm``.

    Every pass images the area, finds the particles, assigns one to each target (least
    total travel), plans the pushes (:func:`plan_pushes`) and makes them, with no image
    in between; a last image shows where they ended. Each image also checks the pushes of
    the pass before it (:func:`~piezocomp.positioning.push_check.check_pushes`); failed
    pushes are recovered in the next pass, and earn passes beyond ``settings.passes`` (at
    most ``settings.recovery_passes``). The result says how many pushes failed, how, and
    what was done about each (:attr:`AssemblyResult.failures`,
    :attr:`AssemblyResult.recoveries`).

    Raises
    ------
    ValueError
        If a target lies outside the area, or the first image holds fewer particles than
        targets.
    """
    s = AssemblySettings() if settings is None else settings
    tgt = as_finite_array("targets_nm", targets_nm, ndim=2)
    if tgt.shape[1] != 2:
        raise ValueError(f"targets_nm must have shape (m, 2). Got {tgt.shape}.")
    c = np.array([check_finite_scalar("center_nm", v) for v in center_nm])
    size = check_finite_scalar("size_nm", size_nm)
    if size <= 0:
        raise ValueError(f"size_nm must be > 0. Got {size}.")
    if np.any(np.abs(tgt - c) > 0.5 * size):
        raise ValueError("every target must lie inside the area center_nm +- size_nm / 2.")
    h = 0.5 * size
    area = ((float(c[0] - h), float(c[0] + h)), (float(c[1] - h), float(c[1] + h)))

    def image() -> tuple[ScanImage, FoundParticles]:
        img = instrument.scan_image((float(c[0]), float(c[1])), size, s.image_pixels,
                                    s.image_line_rate_hz)  # fmt: skip
        return img, find_particles(img, trace="mean", min_height_nm=s.min_height_nm)

    images: list[ScanImage] = []
    passes: list[PassResult] = []
    img, found = image()
    if len(found) < tgt.shape[0]:
        raise ValueError(
            f"the image holds {len(found)} particles, fewer than the {tgt.shape[0]} targets."
        )
    failing: list[tuple[NDArray[np.float64], int]] = []  # particles whose pushes failed
    extra = 0
    while True:
        images.append(img)
        pos = found.positions_nm
        asg = _assign(pos, tgt, [q for q, n in failing if n >= s.max_attempts], s.check_nm)
        radius = s.tip_radius_nm
        if radius is None:  # learnt from the image, as the tip blunts
            try:
                radius = estimate_tip_radius(
                    img, found, half_angle_deg=s.tip_half_angle_deg, trace="mean"
                ).radius_nm
            except ValueError:  # no particle left to measure it on: the last estimate
                if not passes:
                    raise
                radius = passes[-1].tip_radius_nm
        pushes, blocked = plan_pushes(
            pos, found.heights_nm, tgt, asg, replace(s, tip_radius_nm=radius),
            tip_nm=instrument.command_nm, within_nm=area,
        )  # fmt: skip
        recovering = False
        if passes:  # what this pass does about the last one's failures
            ch = tuple(pc.with_action(k, pos, asg, pushes, s.check_nm) for k in passes[-1].checks)
            passes[-1] = replace(passes[-1], checks=ch)
            recovering = any(k.action in ("pushed_again", "another_particle") for k in ch)
        for p in pushes:
            instrument.move_to(*p.start_nm, s.move_speed_nm_per_s)
            instrument.push(*p.end_nm, s.push_speed_nm_per_s)
        before = found
        img, found = image()
        moved = {p.particle for p in pushes}
        pushed = [pc.PushedParticle(int(asg[j]), j, (float(tgt[j, 0]), float(tgt[j, 1])))
                  for j in range(tgt.shape[0]) if asg[j] in moved]  # fmt: skip
        done, shift = pc.check_pushes(pos, pushed, found.positions_nm, check_nm=s.check_nm)
        passes.append(PassResult(before, asg, pushes, blocked, radius, done))
        failed = [c for c in done if c.failed]
        failing = pc.count_failures(failing, done, shift, s.check_nm)
        if len(passes) >= s.passes:
            if not (failed or recovering) or extra >= s.recovery_passes:
                break
            extra += 1
    ch = tuple(replace(k, action="none") if k.failed else k for k in passes[-1].checks)
    passes[-1] = replace(passes[-1], checks=ch)
    images.append(img)
    final = match_targets(found.positions_nm, tgt, max_distance_nm=0.25 * size)
    pos = np.full(tgt.shape, np.nan)
    pos[final >= 0] = found.positions_nm[final[final >= 0]]
    return AssemblyResult(tgt, tuple(passes), found, pos, tuple(images))


def _assign(
    positions_nm: NDArray[np.float64],
    targets_nm: NDArray[np.float64],
    left_nm: list[NDArray[np.float64]],
    check_nm: float,
) -> NDArray[np.intp]:
    """:func:`match_targets` among the particles farther than ``check_nm`` from every place
    of ``left_nm`` (particles whose pushes failed too often), as indices of all of them."""
    idx = [i for i, p in enumerate(positions_nm)
           if all(np.hypot(*(p - q)) > check_nm for q in left_nm)]  # fmt: skip
    sub = match_targets(positions_nm[idx].reshape(-1, 2), targets_nm)
    return np.array([idx[k] if k >= 0 else -1 for k in sub], dtype=np.intp)
