"""Checking pushes from images: where did each pushed particle go?

A push can fail in ways the planner cannot see while it pushes (Z feedback off, no image):
the particle stays where it was (held by the substrate: the tip rode over it), it leaves the
tip's path (rolled off, or the push started off-centre), or it leaves the image (picked up
by the tip, or pushed far away). The next image tells them apart. :func:`check_pushes`
compares the particles of the image the pushes were planned on with those of the image taken
after them:

- the image's frame may have moved between the two (drift, or the scanner's own error on an
  uncompensated instrument): the shift is the median displacement of the particles that
  were not pushed, each matched to its nearest neighbour within :data:`FRAME_SEARCH_NM`;
- every particle is then expected where it was, or where its push should have left it, and
  the particles of the new image are matched to those places (least total distance, none
  farther than ``check_nm``);
- a pushed particle found where it should be was **placed** (unless it lies nearer where it
  started, after a push longer than ``check_nm``: then it did not move); one found where it
  started is **stuck**; one not found at either place but explained by a particle the image
  did not expect, within :data:`OFF_PATH_NM` of the push's line, moved **off target**;
  otherwise it **vanished**. A push shorter than ``check_nm`` (a fine correction) cannot be
  told from one that did not move: it is placed, and the next pass corrects what is left.

What the planner does about a failure is recorded with it (:func:`with_action`), and the
failed pushes of each particle are counted as it is found from image to image
(:func:`count_failures`), so that a particle that keeps failing can be left alone. Nothing
here reads anything but the particles found in images.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from piezocomp._validation import check_finite_scalar

__all__ = [
    "FAILURES",
    "FRAME_SEARCH_NM",
    "OFF_PATH_NM",
    "PushCheck",
    "PushedParticle",
    "check_pushes",
    "count_failures",
    "frame_shift",
    "with_action",
]

FAILURES = ("stuck", "off_target", "vanished")
"""The ways a push is found to have failed, in the order reports list them."""

FRAME_SEARCH_NM = 60.0
"""How far a particle that was not pushed is looked for to measure the frame's shift."""

OFF_PATH_NM = 100.0
"""A particle the new image did not expect, within this of a failed push's line (from where
the particle was to where it should have gone), is taken for that push's particle."""


@dataclass(frozen=True)
class PushedParticle:
    """A particle pushed in a pass.

    Attributes
    ----------
    particle : int
        Its index among the particles of the image the pass planned on.
    target : int
        The target it was pushed to.
    to_nm : (float, float)
        Where the pass's pushes should have left it.
    """

    particle: int
    target: int
    to_nm: tuple[float, float]


@dataclass(frozen=True)
class PushCheck:
    """What the next image says of one pushed particle.

    Attributes
    ----------
    target : int
    kind : {"placed", "stuck", "off_target", "vanished"}
    from_nm, to_nm : (float, float)
        Where the particle was, and where it should have gone (the first image's frame).
    found_nm : (float, float) or None
        Where it is in the new image (None: vanished).
    action : str
        For a failure, what the planner did about it in the next pass: ``"pushed_again"``
        (the same particle), ``"another_particle"`` (another one assigned to the target), or
        ``"none"`` (no pass left, or nothing could be planned); empty until decided.
    """

    target: int
    kind: str
    from_nm: tuple[float, float]
    to_nm: tuple[float, float]
    found_nm: tuple[float, float] | None
    action: str = ""

    @property
    def failed(self) -> bool:
        """Whether the push failed (the particle is not where it should be)."""
        return self.kind != "placed"


def _pair(p: NDArray[np.float64]) -> tuple[float, float]:
    return (float(p[0]), float(p[1]))


def frame_shift(
    before_nm: NDArray[np.float64], after_nm: NDArray[np.float64], still: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """Median displacement, from ``before_nm`` to ``after_nm``, of the particles ``still``
    (not pushed) that are each other's nearest neighbour within :data:`FRAME_SEARCH_NM`;
    zero if none is."""
    b = before_nm[still]
    if b.shape[0] == 0 or after_nm.shape[0] == 0:
        return np.zeros(2)
    d = np.hypot(*(b[:, None, :] - after_nm[None, :, :]).transpose(2, 0, 1))
    j = np.argmin(d, axis=1)
    mutual = np.argmin(d, axis=0)[j] == np.arange(b.shape[0])
    ok = mutual & (d[np.arange(b.shape[0]), j] <= FRAME_SEARCH_NM)
    if not ok.any():
        return np.zeros(2)
    return np.asarray(np.median(after_nm[j[ok]] - b[ok], axis=0))


def check_pushes(
    before_nm: ArrayLike,
    pushed: Sequence[PushedParticle],
    after_nm: ArrayLike,
    *,
    check_nm: float = 5.0,
) -> tuple[tuple[PushCheck, ...], NDArray[np.float64]]:
    """Classify every pushed particle from the images before and after the pushes.

    Parameters
    ----------
    before_nm : array_like, shape (n, 2)
        Particles in the image the pushes were planned on.
    pushed : sequence of PushedParticle
    after_nm : array_like, shape (m, 2)
        Particles in the image taken after the pushes.
    check_nm : float
        A particle within this of where it should be (or of where it was) is found there.

    Returns
    -------
    checks : tuple of PushCheck
        One per pushed particle, in the order of ``pushed`` (positions in the first
        image's frame, ``found_nm`` in the new image's).
    shift_nm : ndarray, shape (2,)
        How far the new image's frame lies from the first's.
    """
    before = np.asarray(before_nm, dtype=float).reshape(-1, 2)
    after = np.asarray(after_nm, dtype=float).reshape(-1, 2)
    tol = check_finite_scalar("check_nm", check_nm)
    if tol <= 0:
        raise ValueError(f"check_nm must be > 0. Got {tol}.")
    expected = before.copy()
    still = np.ones(before.shape[0], bool)
    for p in pushed:
        if not 0 <= p.particle < before.shape[0]:
            raise ValueError(f"pushed particle {p.particle} is not one of the {len(before)}.")
        expected[p.particle] = p.to_nm
        still[p.particle] = False
    shift = frame_shift(before, after, still)
    exp, start = expected + shift, before + shift
    taken = np.zeros(after.shape[0], bool)
    match = np.full(before.shape[0], -1)
    if before.shape[0] and after.shape[0]:
        cost = np.hypot(*(exp[:, None, :] - after[None, :, :]).transpose(2, 0, 1))
        rows, cols = linear_sum_assignment(np.where(cost <= tol, cost, 1e9))
        ok = cost[rows, cols] <= tol
        match[rows[ok]] = cols[ok]
        taken[cols[ok]] = True
    kinds: dict[int, tuple[str, int]] = {}
    for p in pushed:
        i, j = p.particle, int(match[p.particle])
        if j >= 0:  # found where it should be; a push longer than check_nm can tell
            long = np.hypot(*(exp[i] - start[i])) > tol  # it from staying where it was
            nearer_start = np.hypot(*(after[j] - start[i])) < np.hypot(*(after[j] - exp[i]))
            kinds[i] = ("stuck" if long and nearer_start else "placed", j)
            continue
        free = np.flatnonzero(~taken)
        d = np.hypot(*(after[free] - start[i]).T) if free.size else np.zeros(0)
        if free.size and d.min() <= tol:
            j = int(free[np.argmin(d)])
            taken[j] = True
            kinds[i] = ("stuck", j)
    lost = [p for p in pushed if p.particle not in kinds]
    free = np.flatnonzero(~taken)
    if lost and free.size:  # particles the image did not expect, near the failed pushes
        cost = np.array([_to_segment(after[free], start[p.particle], exp[p.particle])
                         for p in lost])  # fmt: skip
        rows, cols = linear_sum_assignment(np.where(cost <= OFF_PATH_NM, cost, 1e9))
        for r, c in zip(rows, cols, strict=True):
            if cost[r, c] <= OFF_PATH_NM:
                kinds[lost[r].particle] = ("off_target", int(free[c]))
    checks = []
    for p in pushed:
        kind, j = kinds.get(p.particle, ("vanished", -1))
        checks.append(PushCheck(p.target, kind, _pair(before[p.particle]), p.to_nm,
                                None if j < 0 else _pair(after[j])))  # fmt: skip
    return tuple(checks), shift


def _to_segment(
    p: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Distance of points ``p`` (k, 2) from the segment ``a``-``b``."""
    ab = b - a
    L2 = float(ab @ ab)
    t = np.zeros(p.shape[0]) if L2 == 0 else np.clip((p - a) @ ab / L2, 0.0, 1.0)
    return np.asarray(np.hypot(*(p - (a + t[:, None] * ab)).T))


def with_action(
    check: PushCheck,
    positions_nm: NDArray[np.float64],
    assignment: NDArray[np.intp],
    pushes: Sequence[Any],
    check_nm: float,
) -> PushCheck:
    """``check`` with what the pass planned on ``positions_nm`` (its ``assignment`` of a
    particle to each target, its ``pushes``, each with a ``particle`` index) does about it,
    if it failed: the target's particle pushed again (the one the check found), another
    particle pushed to it, or nothing."""
    if not check.failed:
        return check
    i = int(assignment[check.target])
    if i < 0 or not any(p.particle == i for p in pushes):
        return replace(check, action="none")
    same = check.found_nm is not None and np.hypot(*(positions_nm[i] - check.found_nm)) <= check_nm
    return replace(check, action="pushed_again" if same else "another_particle")


def count_failures(
    tracked: Sequence[tuple[NDArray[np.float64], int]],
    checks: Sequence[PushCheck],
    shift_nm: NDArray[np.float64],
    check_nm: float,
) -> list[tuple[NDArray[np.float64], int]]:
    """Where the particles whose pushes failed are now, and how many of their pushes failed.

    ``tracked`` is in the frame of the image the ``checks``' pushes were planned on. A check
    pushed from a tracked place (within ``check_nm``) carries that particle's count: one more
    at the place it was found, if it failed there and was found (stuck, off target); dropped
    if it was placed or vanished. A failed check pushed from elsewhere starts a count of one.
    The places not pushed from move into the new image's frame (``shift_nm``)."""
    old = [(np.asarray(q, dtype=float), n) for q, n in tracked]
    used: set[int] = set()
    out: list[tuple[NDArray[np.float64], int]] = []
    for c in checks:
        frm = np.asarray(c.from_nm, dtype=float)
        k = next((k for k, (q, _) in enumerate(old)
                  if k not in used and np.hypot(*(q - frm)) <= check_nm), None)  # fmt: skip
        if k is not None:
            used.add(k)
        if c.failed and c.found_nm is not None:
            out.append((np.asarray(c.found_nm, dtype=float), 1 if k is None else old[k][1] + 1))
    return out + [(q + shift_nm, n) for k, (q, n) in enumerate(old) if k not in used]
