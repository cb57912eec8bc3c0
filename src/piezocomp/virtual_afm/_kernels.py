"""Numba kernels of the virtual AFM (private: no input checks; callers check everything).

One kernel per algorithm:

- :func:`preisach_run`: the Preisach operator through its Everett function and the stack
  of dominant extrema (wiping-out property).
- :func:`creep_run`: a bank of first-order modes driven by the held command.
- :func:`heights_at`: tapping-mode topography (tip-dilated spheres on a rough plane).
- :func:`push_run`: particles pushed by the tip along its path (Z feedback off), with the
  counter-based draws of their fates (:func:`uniform`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def everett(alpha, beta, p, s, q, norm):  # pragma: no cover - compiled
    """Everett function of the density ``r**p (1 + s c + q c**2)`` (see preisach.py)."""
    w = 0.5 * (alpha - beta)
    if w <= 0.0:
        return 0.0
    m = 0.5 * (alpha + beta)
    return (
        norm
        * w ** (p + 2.0)
        * (1.0 + s * m + q * m * m + 2.0 * q * w * w / ((p + 3.0) * (p + 4.0)))
    )


@njit(cache=True)
def preisach_run(x, stack, cum, top, last, p, s, q, norm, out):  # pragma: no cover - compiled
    """Run the Preisach operator over the normalised input ``x`` (in [-1, 1]).

    ``stack[0..top]`` holds alternating dominant extrema, ``stack[0] = -1`` (a minimum);
    even indices are minima, odd maxima. ``cum[i]`` is the relay area closed by
    ``stack[0..i]``. ``last`` is the previous input. ``out`` receives the fraction of
    relays switched up (0..1). Returns the new ``(top, last)``; ``stack`` and ``cum`` are
    updated in place and must have room for ``top + 1 + x.size`` entries.
    """
    for k in range(x.size):
        xk = x[k]
        if top % 2 == 0:  # rising from the minimum stack[top]
            if xk < last:  # reversal: last is a new maximum
                top += 1
                stack[top] = last
                cum[top] = cum[top - 1] + everett(last, stack[top - 1], p, s, q, norm)
                while top >= 3 and xk <= stack[top - 1]:
                    top -= 2
            else:
                while top >= 2 and xk >= stack[top - 1]:
                    top -= 2
        else:  # falling from the maximum stack[top]
            if xk > last:  # reversal: last is a new minimum
                top += 1
                stack[top] = last
                cum[top] = cum[top - 1] - everett(stack[top - 1], last, p, s, q, norm)
                while top >= 2 and xk >= stack[top - 1]:
                    top -= 2
            else:
                while top >= 3 and xk <= stack[top - 1]:
                    top -= 2
        if top % 2 == 0:
            out[k] = cum[top] + everett(xk, stack[top], p, s, q, norm)
        else:
            out[k] = cum[top] - everett(stack[top], xk, p, s, q, norm)
        last = xk
    return top, last


@njit(cache=True)
def creep_run(u, u_prev, poles, weights, state, out):  # pragma: no cover - compiled
    """Bank of first-order modes ``x_j(k) = p_j x_j(k-1) + (1 - p_j) u(k-1)``.

    ``out[k] = sum_j w_j (x_j(k) - u(k))``; ``state`` (the ``x_j``) is updated in place.
    Returns the last input (the ``u(k-1)`` of the next call).
    """
    nm = poles.size
    for k in range(u.size):
        acc = 0.0
        for j in range(nm):
            state[j] = poles[j] * state[j] + (1.0 - poles[j]) * u_prev
            acc += weights[j] * (state[j] - u[k])
        out[k] = acc
        u_prev = u[k]
    return u_prev


@njit(cache=True)
def _particle_height(d2, radius, tip_r, sin_t, cos_t, tan_t):  # pragma: no cover - compiled
    """Apex height of a sphere-ended cone touching a sphere (radius ``radius``) resting on
    the plane, at squared lateral distance ``d2`` between the tip axis and the sphere centre.
    Returns -1 when the tip does not reach the sphere above the plane."""
    rr = radius + tip_r
    d = math.sqrt(d2)
    if d <= rr * cos_t:
        return radius + math.sqrt(rr * rr - d2) - tip_r
    return radius + rr / sin_t - tip_r - d / tan_t


@njit(cache=True)
def heights_at(
    pos,
    px,
    py,
    pr,
    cell_start,
    cell_count,
    grid_x0,
    grid_y0,
    cell,
    ncx,
    ncy,
    tip_r,
    sin_t,
    cos_t,
    tan_t,
    rough_kx,
    rough_ky,
    rough_ph,
    rough_amp,
    noise,
    out,
):  # pragma: no cover - compiled
    """Topography at the true tip positions ``pos`` (n, 2): max over the tip-dilated
    particles found in the neighbouring cells and the plane, plus roughness and noise.
    Particles are sorted by cell; ``cell_start``/``cell_count`` index them (row-major,
    ``ncx`` columns)."""
    nr = rough_kx.size
    for k in range(pos.shape[0]):
        x = pos[k, 0]
        y = pos[k, 1]
        h = 0.0
        cx = math.floor((x - grid_x0) / cell)
        cy = math.floor((y - grid_y0) / cell)
        for iy in range(cy - 1, cy + 2):
            if iy < 0 or iy >= ncy:
                continue
            for ix in range(cx - 1, cx + 2):
                if ix < 0 or ix >= ncx:
                    continue
                c = iy * ncx + ix
                for m in range(cell_start[c], cell_start[c] + cell_count[c]):
                    dx = x - px[m]
                    dy = y - py[m]
                    hp = _particle_height(dx * dx + dy * dy, pr[m], tip_r, sin_t, cos_t, tan_t)
                    if hp > h:
                        h = hp
        r = 0.0
        for j in range(nr):
            r += rough_amp[j] * math.cos(rough_kx[j] * x + rough_ky[j] * y + rough_ph[j])
        out[k] = h + r + noise[k]


_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True)
def _mix(z):  # pragma: no cover - compiled
    """The splitmix64 finaliser: a 64-bit integer to a well-mixed one."""
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


@njit(cache=True)
def uniform(key, particle, engagement, slot):  # pragma: no cover - compiled
    """A uniform number in [0, 1) that depends only on its four integer arguments (the
    sample's key, the particle, which of its engagements with the tip, which draw of that
    engagement): counter-based, so a run in pieces draws what the run in one call draws."""
    z = _mix(np.uint64(key) + _GOLDEN * (np.uint64(particle) + np.uint64(1)))
    z = _mix(z + _GOLDEN * (np.uint64(engagement) + np.uint64(1)))
    z = _mix(z + _GOLDEN * (np.uint64(slot) + np.uint64(1)))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


FATE_CARRIED = 0
FATE_STUCK = 1
FATE_ROLLS = 2
FATE_PICKED = 3
FATE_RELEASED = 4


@njit(cache=True)
def push_run(
    pos,
    px,
    py,
    contact,
    step_nm,
    cos_friction,
    ids,
    key,
    stuck_rate,
    roll_rate,
    pickup_rate,
    release_nm,
    on_surface,
    touching,
    engagements,
    fate,
    travel,
    counts,
):  # pragma: no cover - compiled
    """Move the particles (``px``, ``py`` in place) out of the tip's way along the true
    path ``pos`` (n, 2), subdivided so that the tip advances at most ``step_nm`` per
    sub-step.

    A particle on the surface closer than ``contact`` to the tip axis is in contact. The
    first sub-step of a contact (an *engagement*: ``touching`` was False) numbers it
    (``engagements``) and draws its fate (:func:`uniform` of ``key``, ``ids[m]``, the
    engagement and slot 0): stuck with probability ``stuck_rate`` (it does not move: the tip
    rides over it), rolling off with ``roll_rate``, picked up by the tip with
    ``pickup_rate`` (``on_surface`` set False), else carried. A carried or rolling particle
    is carried along by the sub-step if the tip moves within its friction cone about the
    contact normal (the cosine of the angle between the motion and the line from the tip to
    the particle's centre is at least ``cos_friction[m]``; > 1: never), else it slides
    around the tip; either way it is then put back at distance ``contact`` along the line
    from the tip to its centre. A rolling particle leaves the tip once it has travelled
    ``release_nm`` times the engagement's slot-1 draw: it jumps sideways off the tip's path
    to between one and two contact distances from the tip's axis (slot 2 the side when
    hit dead centre, slot 3 the distance). ``travel`` holds each engagement's distance
    travelled; ``fate`` its fate; ``counts`` (4,) adds up engagements, stuck, rolled off and
    picked up. Returns the number of contacts (sub-steps x particles in contact)."""
    n_contacts = 0
    npart = px.size
    p_stuck = stuck_rate
    p_roll = stuck_rate + roll_rate
    p_pick = stuck_rate + roll_rate + pickup_rate
    for k in range(1, pos.shape[0]):
        x0 = pos[k - 1, 0]
        y0 = pos[k - 1, 1]
        ddx = pos[k, 0] - x0
        ddy = pos[k, 1] - y0
        seg = math.sqrt(ddx * ddx + ddy * ddy)
        nsub = max(1, math.ceil(seg / step_nm))
        sx = ddx / nsub
        sy = ddy / nsub
        for i in range(1, nsub + 1):
            tx = x0 + ddx * i / nsub
            ty = y0 + ddy * i / nsub
            for m in range(npart):
                if not on_surface[m]:
                    continue
                ex = px[m] - tx
                ey = py[m] - ty
                d2 = ex * ex + ey * ey
                c = contact[m]
                if d2 >= c * c:
                    touching[m] = False
                    continue
                n_contacts += 1
                if not touching[m]:  # a new engagement: its fate
                    touching[m] = True
                    u = uniform(key, ids[m], engagements[m], 0)
                    engagements[m] += 1
                    counts[0] += 1
                    travel[m] = 0.0
                    if u < p_stuck:
                        fate[m] = FATE_STUCK
                        counts[1] += 1
                    elif u < p_roll:
                        fate[m] = FATE_ROLLS
                        counts[2] += 1
                    elif u < p_pick:
                        fate[m] = FATE_PICKED
                        counts[3] += 1
                    else:
                        fate[m] = FATE_CARRIED
                f = fate[m]
                if f == FATE_STUCK or f == FATE_RELEASED:
                    continue  # the tip passes over it, or it has left the tip
                if f == FATE_PICKED:
                    on_surface[m] = False  # on the tip: off the surface until dropped
                    touching[m] = False
                    continue
                ox = px[m]
                oy = py[m]
                if seg > 0:  # within the friction cone: carried by the sub-step
                    nx = px[m] - (tx - sx)
                    ny = py[m] - (ty - sy)
                    nn = math.sqrt(nx * nx + ny * ny)
                    if nn > 1e-12 and (nx * ddx + ny * ddy) / (nn * seg) >= cos_friction[m]:
                        px[m] += sx  # then kept at the contact distance below
                        py[m] += sy
                        ex = px[m] - tx
                        ey = py[m] - ty
                        d2 = ex * ex + ey * ey
                d = math.sqrt(d2)
                if d < 1e-12:  # dead centre: push along the motion
                    ex = ddx
                    ey = ddy
                    d = seg if seg > 0 else 1.0
                    if seg <= 0:
                        ex = 1.0
                        ey = 0.0
                px[m] = tx + ex / d * c
                py[m] = ty + ey / d * c
                travel[m] += math.sqrt((px[m] - ox) ** 2 + (py[m] - oy) ** 2)
                e = engagements[m] - 1
                if (
                    f == FATE_ROLLS
                    and seg > 0
                    and travel[m] >= release_nm * uniform(key, ids[m], e, 1)
                ):  # it rolls off the tip, sideways off the path
                    ux = ddx / seg
                    uy = ddy / seg
                    side = ux * (py[m] - ty) - uy * (px[m] - tx)
                    if abs(side) < 1e-9:
                        side = 1.0 if uniform(key, ids[m], e, 2) < 0.5 else -1.0
                    side = 1.0 if side > 0 else -1.0
                    off = c * (1.0 + uniform(key, ids[m], e, 3))
                    px[m] = tx - uy * side * off
                    py[m] = ty + ux * side * off
                    fate[m] = FATE_RELEASED
    return n_contacts
