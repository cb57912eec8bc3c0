"""The per-sample loops of the scanner model, compiled with numba.

Private and unchecked: callers validate their inputs. One kernel per algorithm; the
batch forms are loops over the same per-sample update. State and parameters travel as
packed float arrays so that a streaming call of one sample stays cheap.

Packed layouts (``nh`` play operators, ``nc`` creep operators)::

    params = [y0, a, r_1..r_nh, w_1..w_nh, p_1..p_nc, c_1..c_nc, beta, d_1..d_nd, g_1..g_nd]
    state  = [z_1..z_nh, x_1..x_nc, u_prev]

``d, g`` are the dead zones of Kuhnen's asymmetry map ``S`` of eq (8') on the hysteresis
output, ``y = y0 + S(H) + sum c_i x_i``; ``nd`` follows from the length of ``params`` (``0``
when it ends at ``beta``: the very operations of the symmetric model, bit for bit). Only
:func:`forward` and :func:`inverse` read them; the sensitivity kernels hold for ``nd = 0``.

``beta`` is the creep coupling of eq (2'): the creep operators are driven by
``s(k-1) = u(k-1) + beta H(k-1)``, ``H(k) = a u(k) + sum_j w_j z_j(k)``; ``beta = 0`` runs the
very operations of the paper's eq (2) (bit for bit). ``forward_sensitivity`` reads the
layout without ``beta`` and holds only for ``beta = 0``; ``forward_sensitivity_coupled`` is
its form for eq (2'), with ``dy/dbeta`` as one more column.

For the inverse, ``params`` holds ``[y0, a_hat, r_hat.., w_hat.., p.., c.., beta, d_hat..,
g_hat..]`` (the dead zones of ``S^{-1}``), the play states are those of the inverse PI operator
(eq 9), fed with ``v = S^{-1}(y_d - y0 - sum c_i x_i)`` (eq 13), and the state carries one more
entry, ``v_prev = v(k-1)``, which equals ``H(k-1)`` of the command produced::

    inverse state = [z_hat_1..z_hat_nh, x_1..x_nc, u_prev, v_prev]
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def forward(u, nh, nc, params, state, y):  # pragma: no cover - compiled
    """Eq (14): ``y(k) = y0 + a u(k) + sum c_i x_i(k) + sum w_i z_i(k)``; updates ``state``.

    Creep by eq (2) or, with ``beta != 0``, eq (2') (driven by ``u(k-1) + beta H(k-1)``);
    with dead zones, ``S(H)`` of eq (8') in place of ``H = a u + sum w_i z_i``.
    """
    y0 = params[0]
    a = params[1]
    r = params[2 : 2 + nh]
    w = params[2 + nh : 2 + 2 * nh]
    p = params[2 + 2 * nh : 2 + 2 * nh + nc]
    c = params[2 + 2 * nh + nc : 2 + 2 * nh + 2 * nc]
    beta = params[2 + 2 * nh + 2 * nc]
    nd = (params.size - 3 - 2 * nh - 2 * nc) // 2
    d = params[3 + 2 * nh + 2 * nc : 3 + 2 * nh + 2 * nc + nd]
    g = params[3 + 2 * nh + 2 * nc + nd : 3 + 2 * nh + 2 * nc + 2 * nd]
    z = state[0:nh]
    x = state[nh : nh + nc]
    u_prev = state[nh + nc]
    h_prev = 0.0
    if beta != 0.0:  # H(k-1) from the state kept
        h_prev = a * u_prev
        for i in range(nh):
            h_prev += w[i] * z[i]
    for k in range(u.size):
        uk = u[k]
        acc = y0 + a * uk
        s_prev = u_prev
        if beta != 0.0:
            s_prev = u_prev + beta * h_prev
        for i in range(nc):  # eq (2), driven by u(k-1); eq (2'): by s(k-1)
            xi = p[i] * x[i] + (1.0 - p[i]) * s_prev
            x[i] = xi
            acc += c[i] * xi
        for i in range(nh):  # eq (4)
            zi = min(z[i], uk + r[i])
            zi = max(uk - r[i], zi)
            z[i] = zi
            acc += w[i] * zi
        if beta != 0.0 or nd > 0:
            h_prev = a * uk
            for i in range(nh):
                h_prev += w[i] * z[i]
            for i in range(nd):  # eq (8'): S(H) = H + sum g_l q_{d_l}(H)
                if d[i] > 0.0:
                    acc += g[i] * max(h_prev - d[i], 0.0)
                else:
                    acc += g[i] * min(h_prev - d[i], 0.0)
        y[k] = acc
        u_prev = uk
    state[nh + nc] = u_prev


@njit(cache=True, nogil=True)
def inverse(yd, nh, nc, params, state, u):  # pragma: no cover - compiled
    """Eqs (9)-(13): the command ``u`` that makes the model produce ``yd``; updates ``state``.

    With ``beta != 0`` the creep is driven by ``s(k-1) = u(k-1) + beta v(k-1)`` (eq 13'):
    ``v(k-1) = P[u](k-1) = H(k-1)``, so it is the drive of eq (2'), known at step ``k``. With
    dead zones, ``v = S^{-1}(y_d - y0 - sum c_i x_i)`` (eq 8'), ``S^{-1}`` of the same form.
    """
    y0 = params[0]
    ahat = params[1]
    rhat = params[2 : 2 + nh]
    what = params[2 + nh : 2 + 2 * nh]
    p = params[2 + 2 * nh : 2 + 2 * nh + nc]
    c = params[2 + 2 * nh + nc : 2 + 2 * nh + 2 * nc]
    beta = params[2 + 2 * nh + 2 * nc]
    nd = (params.size - 3 - 2 * nh - 2 * nc) // 2
    dhat = params[3 + 2 * nh + 2 * nc : 3 + 2 * nh + 2 * nc + nd]
    ghat = params[3 + 2 * nh + 2 * nc + nd : 3 + 2 * nh + 2 * nc + 2 * nd]
    zh = state[0:nh]
    x = state[nh : nh + nc]
    u_prev = state[nh + nc]
    v_prev = state[nh + nc + 1]
    for k in range(yd.size):
        v = yd[k] - y0  # eq (13) with the offset of eq (14)
        s_prev = u_prev
        if beta != 0.0:
            s_prev = u_prev + beta * v_prev
        for i in range(nc):
            xi = p[i] * x[i] + (1.0 - p[i]) * s_prev
            x[i] = xi
            v -= c[i] * xi
        if nd > 0:  # H = S^{-1}(y_d - y0 - sum c_i x_i)
            vs = v
            for i in range(nd):
                if dhat[i] > 0.0:
                    v += ghat[i] * max(vs - dhat[i], 0.0)
                else:
                    v += ghat[i] * min(vs - dhat[i], 0.0)
        uk = ahat * v
        for i in range(nh):  # eq (4) on v, thresholds r_hat
            zi = min(zh[i], v + rhat[i])
            zi = max(v - rhat[i], zi)
            zh[i] = zi
            uk += what[i] * zi
        u[k] = uk
        u_prev = uk
        v_prev = v
    state[nh + nc] = u_prev
    state[nh + nc + 1] = v_prev


@njit(cache=True, nogil=True)
def forward_sensitivity(u, nh, nc, params, state, sens, y, jac):  # pragma: no cover
    """Eq (14) and its gradient ``dy/dtheta`` in the order of eq (15).

    ``theta = [c_1..c_nc, p_1..p_nc, a, w_1..w_nh, r_1..r_nh, y0]``; ``sens`` holds the
    sensitivity states ``[dx_1/dp_1..dx_nc/dp_nc, dz_1/dr_1..dz_nh/dr_nh]`` (eq 19 and the
    creep-pole recursion of NOTES.md), updated in place like ``state``.
    """
    y0 = params[0]
    a = params[1]
    r = params[2 : 2 + nh]
    w = params[2 + nh : 2 + 2 * nh]
    p = params[2 + 2 * nh : 2 + 2 * nh + nc]
    c = params[2 + 2 * nh + nc : 2 + 2 * nh + 2 * nc]
    z = state[0:nh]
    x = state[nh : nh + nc]
    u_prev = state[nh + nc]
    s = sens[0:nc]
    q = sens[nc : nc + nh]
    for k in range(u.size):
        uk = u[k]
        acc = y0 + a * uk
        for i in range(nc):
            s[i] = x[i] - u_prev + p[i] * s[i]  # d x_i(k) / d p_i
            xi = p[i] * x[i] + (1.0 - p[i]) * u_prev
            x[i] = xi
            acc += c[i] * xi
            jac[k, i] = xi  # dy/dc_i
            jac[k, nc + i] = c[i] * s[i]  # dy/dp_i
        jac[k, 2 * nc] = uk  # dy/da
        for i in range(nh):
            zp = z[i]
            if zp >= uk + r[i]:  # clamped at u + r: dz/dr = +1
                zi = uk + r[i]
                q[i] = 1.0
            elif zp <= uk - r[i]:  # clamped at u - r: dz/dr = -1
                zi = uk - r[i]
                q[i] = -1.0
            else:
                zi = zp
            z[i] = zi
            acc += w[i] * zi
            jac[k, 2 * nc + 1 + i] = zi  # dy/dw_i
            jac[k, 2 * nc + 1 + nh + i] = w[i] * q[i]  # dy/dr_i, eq (19)
        jac[k, 2 * nc + 1 + 2 * nh] = 1.0  # dy/dy0
        y[k] = acc
        u_prev = uk
    state[nh + nc] = u_prev


@njit(cache=True, nogil=True)
def forward_sensitivity_coupled(
    u, nh, nc, params, state, sens, y, jac, thresholds
):  # pragma: no cover
    """Eq (14) with the creep of eq (2') and ``dy/dtheta`` for ``theta`` of eq (15) plus ``beta``.

    ``theta = [c_1..c_nc, p_1..p_nc, a, w_1..w_nh, r_1..r_nh, y0, beta]``. The creep drive
    ``s = u + beta H`` depends on ``a``, ``w``, ``r`` and ``beta``, so each creep state
    carries a sensitivity to each of them: ``sens`` holds
    ``[dx/dp (nc), dz/dr (nh), dx/da (nc), dx/dbeta (nc), dx_i/dw_j (nc*nh), dx_i/dr_j (nc*nh)]``
    (``dx_i/dw_j`` at ``3 nc + nh + i nh + j``), updated in place like ``state``. Each
    follows ``d x_i(k) = p_i d x_i(k-1) + (1 - p_i) d s(k-1)``, with ``ds/da = beta u``,
    ``ds/dw_j = beta z_j``, ``ds/dr_j = beta w_j dz_j/dr_j``, ``ds/dbeta = H`` (and
    ``x_i(k-1) - s(k-1)`` more for ``dx_i/dp_i``). Without ``thresholds`` the creep's
    sensitivity to the thresholds is not followed and their columns are NaN (for a
    refinement that holds them).
    """
    y0 = params[0]
    a = params[1]
    r = params[2 : 2 + nh]
    w = params[2 + nh : 2 + 2 * nh]
    p = params[2 + 2 * nh : 2 + 2 * nh + nc]
    c = params[2 + 2 * nh + nc : 2 + 2 * nh + 2 * nc]
    beta = params[2 + 2 * nh + 2 * nc]
    z = state[0:nh]
    x = state[nh : nh + nc]
    u_prev = state[nh + nc]
    sp = sens[0:nc]
    q = sens[nc : nc + nh]
    sa = sens[nc + nh : 2 * nc + nh]
    sb = sens[2 * nc + nh : 3 * nc + nh]
    sw = sens[3 * nc + nh : 3 * nc + nh + nc * nh]
    sr = sens[3 * nc + nh + nc * nh : 3 * nc + nh + 2 * nc * nh]
    h_prev = a * u_prev
    for j in range(nh):
        h_prev += w[j] * z[j]
    ja = 2 * nc
    jw = 2 * nc + 1
    jr = 2 * nc + 1 + nh
    jy0 = 2 * nc + 1 + 2 * nh
    jb = jy0 + 1
    z_prev = np.empty(nh)
    q_prev = np.empty(nh)
    dyw = np.empty(nh)
    dyr = np.empty(nh)
    for k in range(u.size):
        uk = u[k]
        s_prev = u_prev + beta * h_prev
        # the play operators first (eq 4), their step k-1 kept for the creep's drive
        h_k = a * uk
        for j in range(nh):
            zp = z[j]
            z_prev[j] = zp
            q_prev[j] = q[j]
            if zp >= uk + r[j]:
                zj = uk + r[j]
                q[j] = 1.0
            elif zp <= uk - r[j]:
                zj = uk - r[j]
                q[j] = -1.0
            else:
                zj = zp
            z[j] = zj
            h_k += w[j] * zj
            dyw[j] = zj
            dyr[j] = w[j] * q[j]
        acc = y0 + a * uk
        dya = uk
        dyb = 0.0
        for i in range(nc):  # the creep states and their sensitivities, from step k-1
            pi = p[i]
            gi = 1.0 - pi
            ci = c[i]
            sp[i] = x[i] - s_prev + pi * sp[i]
            xi = pi * x[i] + gi * s_prev
            x[i] = xi
            sa[i] = pi * sa[i] + gi * beta * u_prev
            sb[i] = pi * sb[i] + gi * h_prev
            base = i * nh
            for j in range(nh):
                v = pi * sw[base + j] + gi * beta * z_prev[j]
                sw[base + j] = v
                dyw[j] += ci * v
            if thresholds:
                for j in range(nh):
                    v = pi * sr[base + j] + gi * beta * w[j] * q_prev[j]
                    sr[base + j] = v
                    dyr[j] += ci * v
            acc += ci * xi
            dya += ci * sa[i]
            dyb += ci * sb[i]
            jac[k, i] = xi  # dy/dc_i
            jac[k, nc + i] = ci * sp[i]  # dy/dp_i
        jac[k, ja] = dya
        for j in range(nh):
            acc += w[j] * z[j]
            jac[k, jw + j] = dyw[j]
            jac[k, jr + j] = dyr[j] if thresholds else np.nan
        jac[k, jy0] = 1.0
        jac[k, jb] = dyb
        y[k] = acc
        u_prev = uk
        h_prev = h_k
    state[nh + nc] = u_prev


def sensitivity_size(nh: int, nc: int, coupled: bool) -> int:
    """Length of the ``sens`` array of :func:`forward_sensitivity` (``coupled``: of
    :func:`forward_sensitivity_coupled`)."""
    return 3 * nc + nh + 2 * nc * nh if coupled else nc + nh


@njit(cache=True, nogil=True)
def play_bank(u, r, z0, out):  # pragma: no cover - compiled
    """Eq (4) for a bank of play operators; ``out[k, i] = z_{r_i}(k)``; updates ``z0``."""
    nh = r.size
    for k in range(u.size):
        uk = u[k]
        for i in range(nh):
            zi = min(z0[i], uk + r[i])
            zi = max(uk - r[i], zi)
            z0[i] = zi
            out[k, i] = zi


@njit(cache=True, nogil=True)
def creep_bank(u, p, x0, u_prev, out):  # pragma: no cover - compiled
    """Eq (2) for a bank of creep operators; ``out[k, i] = x_i(k)``; updates ``x0``."""
    nc = p.size
    for k in range(u.size):
        for i in range(nc):
            x0[i] = p[i] * x0[i] + (1.0 - p[i]) * u_prev
            out[k, i] = x0[i]
        u_prev = u[k]
    return u_prev


def warm_up() -> None:
    """Compile (or load from cache) every kernel once."""
    u = np.zeros(2)
    params = np.array([0.0, 1.0, 1.0, 0.1, 0.5, 0.1, 0.0])
    state = np.zeros(3)
    forward(u, 1, 1, params, state, np.zeros(2))
    inverse(u, 1, 1, params, np.zeros(4), np.zeros(2))
    forward_sensitivity(u, 1, 1, params, state.copy(), np.zeros(2), np.zeros(2), np.zeros((2, 6)))
    forward_sensitivity_coupled(
        u, 1, 1, params, state.copy(), np.zeros(6), np.zeros(2), np.zeros((2, 7)), True
    )
    play_bank(u, np.array([1.0]), np.zeros(1), np.zeros((2, 1)))
    creep_bank(u, np.array([0.5]), np.zeros(1), 0.0, np.zeros((2, 1)))
