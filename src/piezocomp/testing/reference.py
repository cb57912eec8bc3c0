"""Plain-Python reference implementations (oracles) of every numba kernel.

Written from the paper's equations sample by sample, with no numpy vectorisation, so that
they are easy to check by eye against eqs (2), (4), (9)-(14), (19).
"""

from __future__ import annotations

import math


def play(u, r, z0=0.0):
    """Eq (4)."""
    out, z = [], z0
    for uk in u:
        z = max(uk - r, min(z, uk + r))
        out.append(z)
    return out


def asymmetry(h, d=(), g=()):
    """Eq (8'): ``S(h) = h + sum_l g_l q_{d_l}(h)``, one-sided dead zones."""
    out = h
    for dl, gl in zip(d, g, strict=True):
        out += gl * (max(h - dl, 0.0) if dl > 0 else min(h - dl, 0.0))
    return out


def asymmetry_inverse(v, d=(), g=()):
    """``S^{-1}(v)`` of eq (8') by bisection (not the closed form the kernels use)."""
    if not d:
        return v
    lo, hi = -1.0, 1.0
    while asymmetry(lo, d, g) > v:
        lo *= 2.0
    while asymmetry(hi, d, g) < v:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if asymmetry(mid, d, g) < v:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def forward(u, y0, a, r, w, tau, c, T, z0=None, x0=None, u_prev=0.0, beta=0.0, d=(), g=()):
    """Eq (14) with eq (2) creep (driven by u(k-1)) and eq (4) play operators; with
    ``beta != 0`` eq (2'): creep driven by ``u(k-1) + beta (a u(k-1) + sum w_j z_j(k-1))``;
    with dead zones ``d, g``, ``S(H)`` of eq (8') in place of ``H = a u + sum w_j z_j``."""
    p = [math.exp(-T / t) for t in tau]
    z = list(z0) if z0 is not None else [0.0] * len(r)
    x = list(x0) if x0 is not None else [0.0] * len(tau)
    y = []
    for uk in u:
        h_prev = a * u_prev + sum(wj * zj for wj, zj in zip(w, z, strict=True))
        s_prev = u_prev + beta * h_prev
        x = [p[i] * x[i] + (1 - p[i]) * s_prev for i in range(len(p))]
        z = [max(uk - r[j], min(z[j], uk + r[j])) for j in range(len(r))]
        h = a * uk + sum(wj * zj for wj, zj in zip(w, z, strict=True))
        y.append(y0 + asymmetry(h, d, g) + sum(ci * xi for ci, xi in zip(c, x, strict=True)))
        u_prev = uk
    return y


def inverse_parameters(a, r, w):
    """Eq (10): a_hat, r_hat, w_hat."""
    r_hat, w_hat = [], []
    for i in range(len(r)):
        phi = a * r[i] + sum(w[j] * (r[i] - r[j]) for j in range(i + 1))
        s_i = a + sum(w[: i + 1])
        s_prev = a + sum(w[:i])
        r_hat.append(phi)
        w_hat.append(-w[i] / (s_i * s_prev))
    return 1.0 / a, r_hat, w_hat


def inverse(yd, y0, a, r, w, tau, c, T, beta=0.0, d=(), g=()):
    """Eqs (9)-(13) from zero states: the command u for the desired extension yd; with
    ``beta != 0`` the creep is driven by ``u(k-1) + beta v(k-1)`` (eq 13'); with dead zones
    ``d, g``, ``v = S^{-1}(...)`` (eq 8'), found by bisection."""
    a_hat, r_hat, w_hat = inverse_parameters(a, r, w)
    p = [math.exp(-T / t) for t in tau]
    zh = [0.0] * len(r)
    x = [0.0] * len(tau)
    u_prev = 0.0
    v = 0.0
    u = []
    for ydk in yd:
        s_prev = u_prev + beta * v
        x = [p[i] * x[i] + (1 - p[i]) * s_prev for i in range(len(p))]
        v = asymmetry_inverse(ydk - y0 - sum(ci * xi for ci, xi in zip(c, x, strict=True)), d, g)
        zh = [max(v - r_hat[j], min(zh[j], v + r_hat[j])) for j in range(len(r))]
        uk = a_hat * v + sum(wj * zj for wj, zj in zip(w_hat, zh, strict=True))
        u.append(uk)
        u_prev = uk
    return u


def threshold_sensitivity(u, r, w, z0=0.0):
    """Eq (19) as read in NOTES.md: dy/dr for one play operator of weight w."""
    z, q, out = z0, 0.0, []
    for uk in u:
        if z >= uk + r:
            q = 1.0
        elif z <= uk - r:
            q = -1.0
        z = max(uk - r, min(z, uk + r))
        out.append(w * q)
    return out
