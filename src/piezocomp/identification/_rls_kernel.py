"""The compiled loops of the sensorless recursive estimator, eqs (16)-(20), and of the height
profile ``h(y)`` it reads (the loop stage's
:class:`~piezocomp.identification.loop.profile.HeightProfile` evaluates it here too).

Private and unchecked: :mod:`piezocomp.identification.estimation.rls` validates every input.

Layouts (``nc`` creep, ``nh`` play operators)::

    theta = [c_1..c_nc, p_1..p_nc, a, w_1..w_nh, r_1..r_nh, y0]      eq (15)
    state = [z_1..z_nh, x_1..x_nc, u_prev]                           (model.ModelState.packed)
    sens  = [dx_1/dp_1..dx_nc/dp_nc, dz_1/dr_1..dz_nh/dr_nh]
    htab  = (start, step, values[n], slopes[n])                       profile.HeightProfile

With the creep coupling of eq (2') ``theta`` has ``beta`` last (``ThetaLayout(coupled=True)``)
and ``sens`` is the layout of :func:`~piezocomp.operators._kernels.forward_sensitivity_coupled`
(``[dx/dp, dz/dr, dx/da, dx/dbeta, dx_i/dw_j, dx_i/dr_j]``), whose recursion
:func:`coupled_step` follows with the current estimates; the length of ``theta`` tells which.

The recursion works on the scaled vector ``phi = theta / scale`` (``P`` is the covariance of
``phi``), which is the paper's RLS (20) with ``P(0) = p0 I`` in units where every parameter
is of order one. Only the free parameters ``theta[free]`` (an index array) adapt, and ``P``
is their covariance, ``(free.size, free.size)``: a held parameter's regressor entry is zero,
so its rows and columns of a full ``P`` would never move from ``p0 I`` (the recursion on the
free block alone is the same estimator at a fraction of the cost).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def hermite(y, start, step, values, slopes):  # pragma: no cover - compiled
    """Cubic Hermite ``h(y)`` and ``h'(y)`` on a uniform table (slope 0 outside)."""
    n = values.size
    t_all = (y - start) / step
    if t_all < 0.0:
        return values[0], 0.0
    if t_all > n - 1:
        return values[n - 1], 0.0
    i = int(np.floor(t_all))
    if i > n - 2:
        i = n - 2
    t = t_all - i
    p0 = values[i]
    p1 = values[i + 1]
    m0 = slopes[i] * step
    m1 = slopes[i + 1] * step
    t2 = t * t
    t3 = t2 * t
    h = (
        (2 * t3 - 3 * t2 + 1) * p0
        + (t3 - 2 * t2 + t) * m0
        + (-2 * t3 + 3 * t2) * p1
        + (t3 - t2) * m1
    )
    dh = (
        (6 * t2 - 6 * t) * p0
        + (3 * t2 - 4 * t + 1) * m0
        + (-6 * t2 + 6 * t) * p1
        + (3 * t2 - 2 * t) * m1
    ) / step
    return h, dh


@njit(cache=True, nogil=True)
def hermite_array(y, start, step, values, slopes, h_out, dh_out):  # pragma: no cover
    """:func:`hermite` at every sample of a 1-D ``y``."""
    for k in range(y.size):
        h_out[k], dh_out[k] = hermite(y[k], start, step, values, slopes)


@njit(cache=True, nogil=True)
def project(theta, nc, nh, lower, upper, min_gap):  # pragma: no cover - compiled
    """Project ``theta`` onto the feasible set, in place.

    Box ``lower <= theta <= upper`` on every entry (``c >= 0``, ``0 < p < 1``, ``a > 0``,
    ``w > 0``), then the thresholds onto ``r_1 >= lower``, ``r_{j+1} - r_j >= min_gap``,
    ``r_nh <= upper`` (a forward then a backward pass; exact when the box admits it).
    """
    for j in range(theta.size):
        if theta[j] < lower[j]:
            theta[j] = lower[j]
        elif theta[j] > upper[j]:
            theta[j] = upper[j]
    r0 = 2 * nc + 1 + nh
    for j in range(1, nh):
        if theta[r0 + j] < theta[r0 + j - 1] + min_gap:
            theta[r0 + j] = theta[r0 + j - 1] + min_gap
    for j in range(nh - 2, -1, -1):
        if theta[r0 + j] > theta[r0 + j + 1] - min_gap:
            theta[r0 + j] = theta[r0 + j + 1] - min_gap


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "nsz", "arcp"})
def flush(P, f, v):  # pragma: no cover - compiled
    """``P <- P - f v v'``, in place (the rank-one update of eq 20)."""
    for a in range(v.size):
        fa = f * v[a]
        for b in range(v.size):
            P[a, b] -= fa * v[b]


@njit(cache=True, nogil=True)
def apply_prior(theta, P, free, scale, prior, nc, nh, lower, upper, min_gap):  # pragma: no cover
    """Pseudo-measurements ``0 = prior[i] . theta`` (a smoothness prior), one RLS update
    (20) each with ``alpha = 1``, on the free parameters; then the projection."""
    nf = free.size
    psi = np.zeros(nf)
    ppsi = np.zeros(nf)
    for i in range(prior.shape[0]):
        e = 0.0
        for j in range(theta.size):
            e -= prior[i, j] * theta[j]
        for j in range(nf):
            psi[j] = prior[i, free[j]] * scale[free[j]]
        spp = 0.0
        for a in range(nf):
            acc = 0.0
            for b in range(nf):
                acc += P[a, b] * psi[b]
            ppsi[a] = acc
            spp += psi[a] * acc
        if spp <= 0.0:
            continue
        den = 1.0 + spp
        for j in range(nf):
            theta[free[j]] += scale[free[j]] * ppsi[j] * e / den
        flush(P, 1.0 / den, ppsi)
    project(theta, nc, nh, lower, upper, min_gap)


@njit(cache=True, nogil=True)
def coupled_step(uk, u_prev, theta, nc, nh, z, x, sens, grad, z_prev, q_prev):  # pragma: no cover
    """One step of the predictor (14) with the creep of eq (2') and its gradient ``grad``
    over the coupled ``theta``; updates ``z``, ``x`` and ``sens``; returns ``y_hat(k)``.

    The drive ``s(k-1) = u(k-1) + beta H(k-1)`` is formed with the current estimates from the
    state kept (``H(k-1) = a u(k-1) + sum_j w_j z_j(k-1)``); each creep state carries its
    sensitivity to ``a``, ``w``, ``r`` and ``beta`` through the drive, as in
    :func:`~piezocomp.operators._kernels.forward_sensitivity_coupled`.
    """
    ia = 2 * nc
    iw = 2 * nc + 1
    ir = 2 * nc + 1 + nh
    iy0 = 2 * nc + 2 * nh + 1
    a = theta[ia]
    beta = theta[iy0 + 1]
    sp = sens[0:nc]
    q = sens[nc : nc + nh]
    sa = sens[nc + nh : 2 * nc + nh]
    sb = sens[2 * nc + nh : 3 * nc + nh]
    sw = sens[3 * nc + nh : 3 * nc + nh + nc * nh]
    sr = sens[3 * nc + nh + nc * nh : 3 * nc + nh + 2 * nc * nh]
    h_prev = a * u_prev
    for j in range(nh):
        h_prev += theta[iw + j] * z[j]
    s_prev = u_prev + beta * h_prev
    acc = theta[iy0] + a * uk
    for j in range(nh):  # the plays first (eq 4), their step k-1 kept for the creep's drive
        rj = theta[ir + j]
        zp = z[j]
        z_prev[j] = zp
        q_prev[j] = q[j]
        if zp >= uk + rj:
            zj = uk + rj
            q[j] = 1.0
        elif zp <= uk - rj:
            zj = uk - rj
            q[j] = -1.0
        else:
            zj = zp
        z[j] = zj
        acc += theta[iw + j] * zj
        grad[iw + j] = zj
        grad[ir + j] = theta[iw + j] * q[j]
    grad[ia] = uk
    grad[iy0 + 1] = 0.0
    for i in range(nc):
        pi = theta[nc + i]
        gi = 1.0 - pi
        ci = theta[i]
        sp[i] = x[i] - s_prev + pi * sp[i]
        xi = pi * x[i] + gi * s_prev
        x[i] = xi
        sa[i] = pi * sa[i] + gi * beta * u_prev
        sb[i] = pi * sb[i] + gi * h_prev
        acc += ci * xi
        grad[i] = xi
        grad[nc + i] = ci * sp[i]
        grad[ia] += ci * sa[i]
        grad[iy0 + 1] += ci * sb[i]
        base = i * nh
        for j in range(nh):
            v = pi * sw[base + j] + gi * beta * z_prev[j]
            sw[base + j] = v
            grad[iw + j] += ci * v
            v = pi * sr[base + j] + gi * beta * theta[iw + j] * q_prev[j]
            sr[base + j] = v
            grad[ir + j] += ci * v
    grad[iy0] = 1.0
    return acc


# Reassociation lets the compiler vectorise the products with P (about twice as fast); no
# finite-math assumption (NaN and inf keep their meaning).
@njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "nsz", "arcp"})
def rls_run(
    u,
    zm,
    nc,
    nh,
    theta,
    P,
    state,
    sens,
    hstart,
    hstep,
    hval,
    hslope,
    scale,
    free,
    lower,
    upper,
    min_gap,
    p0,
    k0,
    min_eig,
    eig_every,
    paper_alpha,
    clip,
    prior,
    shift,
    eps_out,
    yhat_out,
    theta_out,
    reset_out,
):  # pragma: no cover - compiled
    """Run eqs (16)-(20) over a record; ``theta``, ``P``, ``state``, ``sens`` updated in place.

    For each sample ``k``: the predictor (14) runs one step with the current estimates
    ``theta(k-1)`` (state and sensitivities carried from the previous step), giving
    ``y_hat(k)`` and ``dy_hat/dtheta`` (creep poles by ``dx/dp = x(k-1) - u(k-1) + p dx/dp``,
    thresholds by eq (19),
    :mod:`~piezocomp.identification.estimation.rls`); then ``eps = z_m - h(y_hat)`` (17),
    ``psi = h'(y_hat) dy_hat/dtheta`` (18) and the update (20) with
    ``alpha = psi' P psi / psi' psi`` (``paper_alpha``; else ``alpha = 1``); then the projection
    onto the feasible set; then covariance resetting ``P = p0 I`` every ``k0`` samples
    (``k0 > 0``) and whenever the smallest eigenvalue of ``P`` (checked every ``eig_every``
    samples) falls below ``min_eig``. ``h`` is evaluated at ``y_hat(k) + shift[k]``: the
    sample's known drift along the line (zeros without one).

    With ``theta`` of the coupled layout (``beta`` last), the predictor is :func:`coupled_step`
    (eq 2'); ``sens`` then has its layout.

    Returns the number of covariance resets.
    """
    n_theta = theta.size
    coupled = n_theta == 2 * nc + 2 * nh + 3
    z_prev = np.zeros(nh)
    q_prev = np.zeros(nh)
    z = state[0:nh]
    x = state[nh : nh + nc]
    u_prev = state[nh + nc]
    s = sens[0:nc]
    q = sens[nc : nc + nh]
    nf = free.size
    grad = np.zeros(n_theta)
    psi = np.zeros(nf)
    ppsi = np.zeros(nf)
    # The rank-one update of P (20) is applied lazily, in the same sweep over P as the next
    # product P psi (one pass over P per sample instead of two): P - f v v' is pending.
    vpend = np.zeros(nf)
    fpend = 0.0
    pending = False
    ia = 2 * nc
    iw = 2 * nc + 1
    ir = 2 * nc + 1 + nh
    iy0 = 2 * nc + 2 * nh + 1
    n_resets = 0
    since_reset = 0
    for k in range(u.size):
        uk = u[k]
        # ---- predictor (14) with theta(k-1), and dy_hat/dtheta
        if coupled:
            yhat = coupled_step(uk, u_prev, theta, nc, nh, z, x, sens, grad, z_prev, q_prev)
        else:
            acc = theta[iy0] + theta[ia] * uk
            for i in range(nc):
                pi = theta[nc + i]
                ci = theta[i]
                s[i] = x[i] - u_prev + pi * s[i]
                xi = pi * x[i] + (1.0 - pi) * u_prev
                x[i] = xi
                acc += ci * xi
                grad[i] = xi
                grad[nc + i] = ci * s[i]
            grad[ia] = uk
            for j in range(nh):
                rj = theta[ir + j]
                zp = z[j]
                if zp >= uk + rj:
                    zj = uk + rj
                    q[j] = 1.0
                elif zp <= uk - rj:
                    zj = uk - rj
                    q[j] = -1.0
                else:
                    zj = zp
                z[j] = zj
                acc += theta[iw + j] * zj
                grad[iw + j] = zj
                grad[ir + j] = theta[iw + j] * q[j]
            grad[iy0] = 1.0
            yhat = acc
        u_prev = uk
        hv, hd = hermite(yhat + shift[k], hstart, hstep, hval, hslope)
        eps = zm[k] - hv  # eq (17)
        eps_out[k] = eps
        yhat_out[k] = yhat
        # ---- regressor (18), scaled
        pp = 0.0
        for j in range(nf):
            pj = hd * grad[free[j]] * scale[free[j]]
            psi[j] = pj
            pp += pj * pj
        if pp > 0.0:
            spp = 0.0
            if pending:  # P <- P - f v v' (the last update) while forming P psi
                for a in range(nf):
                    fa = fpend * vpend[a]
                    acc2 = 0.0
                    for b in range(nf):
                        pab = P[a, b] - fa * vpend[b]
                        P[a, b] = pab
                        acc2 += pab * psi[b]
                    ppsi[a] = acc2
                    spp += psi[a] * acc2
                pending = False
            else:
                for a in range(nf):
                    acc2 = 0.0
                    for b in range(nf):
                        acc2 += P[a, b] * psi[b]
                    ppsi[a] = acc2
                    spp += psi[a] * acc2
            alpha = spp / pp if paper_alpha else 1.0
            den = 1.0 + alpha * spp
            e_used = eps  # Huber: an error beyond +-clip counts as +-clip (clip > 0)
            if clip > 0.0:
                e_used = min(max(eps, -clip), clip)
            g = alpha * e_used / den
            for j in range(nf):
                theta[free[j]] += scale[free[j]] * g * ppsi[j]
            fpend = alpha / den  # P(k) = P(k-1) - fpend ppsi ppsi', applied with the next
            for j in range(nf):
                vpend[j] = ppsi[j]
            pending = True
            project(theta, nc, nh, lower, upper, min_gap)
        # ---- covariance resetting
        since_reset += 1
        reset = False
        if k0 > 0 and since_reset >= k0:
            reset = True
        elif min_eig > 0.0 and eig_every > 0 and nf > 0 and (k + 1) % eig_every == 0:
            if pending:
                flush(P, fpend, vpend)
                pending = False
            for a in range(nf):  # keep P symmetric against rounding
                for b in range(a + 1, nf):
                    m = 0.5 * (P[a, b] + P[b, a])
                    P[a, b] = m
                    P[b, a] = m
            if np.linalg.eigvalsh(P)[0] < min_eig:
                reset = True
        if reset:
            pending = False  # P starts afresh
            for a in range(nf):
                for b in range(nf):
                    P[a, b] = 0.0
                P[a, a] = p0
            n_resets += 1
            since_reset = 0
            reset_out[k] = True
            if prior.shape[0] > 0:
                apply_prior(theta, P, free, scale, prior, nc, nh, lower, upper, min_gap)
        for j in range(n_theta):
            theta_out[k, j] = theta[j]
    if pending:
        flush(P, fpend, vpend)
    state[nh + nc] = u_prev
    return n_resets
