"""Rate-independent hysteresis of one scanner axis: a Preisach operator with a smooth density.

The operator is evaluated exactly, not on a grid of hysterons. With relays of output 0/1
switching up at ``alpha`` and down at ``beta <= alpha`` (normalised input ``x`` in
``[-1, 1]``), write ``c = (alpha + beta)/2`` (centre) and ``r = (alpha - beta)/2``
(half-width). The density is

    mu(r, c) = r**p * (1 + s*c + q*c**2),     0 <= r,  |c| <= 1 - r,

so that its Everett function (the weight of the triangle ``beta <= beta' <= alpha' <= alpha``)
has the closed form, with ``w = (alpha - beta)/2`` and ``m = (alpha + beta)/2``,

    E(alpha, beta) = K w**(p+2) [1 + s m + q m**2 + 2 q w**2 / ((p+3)(p+4))],

``K`` making ``E(1, -1) = 1``. The state is the stack of alternating dominant extrema
(Mayergoyz's memory); an input beyond a stored extremum wipes it out. The fraction of
relays up is ``P = sum of Everett increments``, and the axis output (normalised) is

    v = a x + b (2 P - 1),      a + b = 1,

a reversible (linear) part plus the hysteretic part, with ``v = +-1`` at ``x = +-1``.

The exponent ``p`` sets how hysteresis grows with amplitude: the relays that switch on a
centred cycle of amplitude ``A`` have ``r <= A``, so the loop width relative to its
height grows like ``A**(p+1)``. ``p`` and ``b`` are solved (:meth:`PreisachParams.from_targets`)
so that a full-range cycle and a small centred cycle show the requested hysteresis exactly.
A Prandtl-Ishlinskii operator is the special case of a density independent of ``c``
(``s = q = 0``) with finitely many ``r``: a finite PI can only approximate this operator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from piezocomp._validation import as_finite_1d, check_finite_scalar, readonly
from piezocomp.virtual_afm import _kernels as K

__all__ = [
    "PreisachParams",
    "PreisachState",
    "everett",
    "loop_hysteresis",
    "preisach_run",
]

_GRID = np.linspace(-1.0, 1.0, 8001)


def _norm(p: float, q: float) -> float:
    return 1.0 / (1.0 + 2.0 * q / ((p + 3.0) * (p + 4.0)))


def everett(
    alpha: ArrayLike, beta: ArrayLike, p: float, s: float = 0.0, q: float = 0.0
) -> NDArray[np.float64]:
    """Everett function of the density ``r**p (1 + s c + q c**2)``, normalised to ``E(1, -1) = 1``.

    Parameters
    ----------
    alpha, beta : array_like
        Up and down switching inputs (normalised, ``beta <= alpha``; 0 where ``beta >= alpha``).
    p, s, q : float
        Density exponent in the half-width, asymmetry and curvature in the centre.

    Returns
    -------
    ndarray
        ``E(alpha, beta)``: weight of the relays with ``beta <= beta' <= alpha' <= alpha``.
    """
    a = np.asarray(alpha, dtype=float)
    b = np.asarray(beta, dtype=float)
    w = np.maximum(0.5 * (a - b), 0.0)
    m = 0.5 * (a + b)
    return (
        _norm(p, q)
        * w ** (p + 2.0)
        * (1.0 + s * m + q * m * m + 2.0 * q * w * w / ((p + 3.0) * (p + 4.0)))
    )


def _cycle_ratio(p: float, s: float, q: float, b: float, amplitude: float) -> float:
    """Hysteresis of a steady centred cycle of amplitude ``amplitude``: max divergence of
    the branches over the output span (exact, from the Everett function)."""
    A = amplitude
    x = _GRID * A
    e_full = float(everett(A, -A, p, s, q))
    div = e_full - everett(A, x, p, s, q) - everett(x, -A, p, s, q)  # P_desc - P_asc
    a = 1.0 - b
    return float(2.0 * b * div.max() / (2.0 * a * A + 2.0 * b * e_full))


@dataclass(frozen=True)
class PreisachParams:
    """Parameters of the normalised Preisach operator (input and output in [-1, 1]).

    Parameters
    ----------
    p : float
        Exponent of the density in the relay half-width, ``> -1``.
    s : float
        Asymmetry of the density in the relay centre (0: symmetric loops).
    q : float
        Curvature of the density in the relay centre (< 0: fewer relays near the ends).
    b : float
        Weight of the hysteretic part, in ``[0, 1)``; the reversible part is ``a = 1 - b``.
    """

    p: float
    s: float = 0.0
    q: float = 0.0
    b: float = 0.0

    def __post_init__(self) -> None:
        p = check_finite_scalar("p", self.p)
        s = check_finite_scalar("s", self.s)
        q = check_finite_scalar("q", self.q)
        b = check_finite_scalar("b", self.b)
        if p <= -1.0:
            raise ValueError(f"p must be > -1 (integrable density). Got {p}.")
        if not 0.0 <= b < 1.0:
            raise ValueError(f"b must be in [0, 1) (the reversible part must stay > 0). Got {b}.")
        c = np.linspace(-1.0, 1.0, 201)
        if np.min(1.0 + s * c + q * c * c) <= 0.0:
            raise ValueError(
                f"the density factor 1 + s c + q c^2 must stay > 0 on [-1, 1]. Got s={s}, q={q}."
            )
        for name, v in (("p", p), ("s", s), ("q", q), ("b", b)):
            object.__setattr__(self, name, v)

    @property
    def a(self) -> float:
        """Weight of the reversible (linear) part."""
        return 1.0 - self.b

    @property
    def norm(self) -> float:
        """Constant making ``E(1, -1) = 1``."""
        return _norm(self.p, self.q)

    def cycle_hysteresis(self, amplitude: float = 1.0) -> float:
        """Hysteresis (max branch divergence / output span) of a steady cycle ``+-amplitude``."""
        A = check_finite_scalar("amplitude", amplitude)
        if not 0.0 < A <= 1.0:
            raise ValueError(f"amplitude must be in (0, 1]. Got {A}.")
        return _cycle_ratio(self.p, self.s, self.q, self.b, A)

    @classmethod
    def from_targets(
        cls,
        hysteresis: float,
        hysteresis_small: float,
        small_span: float = 0.1,
        asymmetry: float = 0.0,
        saturation: float = 0.0,
    ) -> PreisachParams:
        """Solve ``p`` and ``b`` so that cycles show the requested hysteresis exactly.

        Parameters
        ----------
        hysteresis : float
            Max branch divergence / range on a full-range cycle.
        hysteresis_small : float
            Max branch divergence / output span on a centred cycle of peak-to-peak span
            ``small_span`` (fraction of the range). Must be below ``hysteresis``.
        small_span : float
            Peak-to-peak span of the small cycle, / range, in (0, 1).
        asymmetry, saturation : float
            ``s`` and ``-q`` of the density.

        Returns
        -------
        PreisachParams
        """
        H = float(hysteresis)
        h = float(hysteresis_small)
        s, q = float(asymmetry), -float(saturation)
        if H == 0.0:
            return cls(p=0.0, s=s, q=q, b=0.0)
        if not 0.0 < h < H:
            raise ValueError(
                "hysteresis_small must be > 0 and < hysteresis when hysteresis > 0. "
                f"Got hysteresis_small={h}, hysteresis={H}."
            )
        A = 0.5 * float(small_span)

        def b_of(p: float) -> float:
            x = _GRID
            d1 = 1.0 - everett(1.0, x, p, s, q) - everett(x, -1.0, p, s, q)
            return H / float(d1.max())

        def f(p: float) -> float:
            b = b_of(p)
            return _cycle_ratio(p, s, q, min(b, 0.999999), A) - h

        # b(p) falls as p grows; the small-cycle ratio rises then falls: solve on the
        # falling side, where the reversible part keeps at least 10 % of the slope.
        hi = 12.0
        lo = -0.999 if b_of(-0.999) <= 0.9 else float(brentq(lambda p: b_of(p) - 0.9, -0.999, hi))
        grid = np.linspace(lo, min(lo + 3.0, hi), 61)
        vals = np.array([f(p) for p in grid])
        lo = float(grid[int(np.argmax(vals))])
        flo, fhi = f(lo), f(hi)
        if flo < 0 or fhi > 0:
            raise ValueError(
                f"no smooth Preisach density gives hysteresis={H} and hysteresis_small={h} "
                f"on a span of {small_span} of the range (reachable: {h + fhi:.4g} to "
                f"{h + flo:.4g}). Change hysteresis_small."
            )
        p = float(brentq(f, lo, hi, xtol=1e-12, rtol=1e-12))
        b = b_of(p)
        if b >= 1.0:
            raise ValueError(
                f"hysteresis={H} needs a hysteretic weight b={b:.4g} >= 1 (no reversible part)."
            )
        return cls(p=p, s=s, q=q, b=b)


@dataclass(frozen=True)
class PreisachState:
    """Memory of the operator: the stack of alternating dominant extrema.

    Attributes
    ----------
    stack : ndarray
        ``stack[0] = -1`` (negative saturation), then maxima at odd and minima at even
        indices, each maximum below the previous one, each minimum above the previous one.
    cum : ndarray
        Relay weight closed by ``stack[:i+1]`` (prefix sums of Everett increments).
    last : float
        The last input.
    """

    stack: NDArray[np.float64]
    cum: NDArray[np.float64]
    last: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "stack", readonly(self.stack))
        object.__setattr__(self, "cum", readonly(self.cum))
        if self.stack.ndim != 1 or self.stack.size < 1 or self.cum.shape != self.stack.shape:
            raise ValueError("stack and cum must be 1-D arrays of the same, non-zero size.")
        object.__setattr__(self, "last", float(self.last))

    @classmethod
    def negative_saturation(cls) -> PreisachState:
        """All relays down, input at -1."""
        return cls(np.array([-1.0]), np.array([0.0]), -1.0)

    @classmethod
    def demagnetised(
        cls, params: PreisachParams, x0: float = 0.0, decay: float = 0.8
    ) -> PreisachState:
        """State left by an alternating input of decaying amplitude ending at ``x0``
        (as after a few large cycles that shrink to the starting point)."""
        x0 = check_finite_scalar("x0", x0)
        if not -1.0 <= x0 <= 1.0:
            raise ValueError(f"x0 must be in [-1, 1]. Got {x0}.")
        amps = (1.0 + abs(x0)) * decay ** np.arange(80)
        signs = np.where(np.arange(80) % 2 == 0, 1.0, -1.0)
        seq = np.clip(x0 + signs * amps, -1.0, 1.0)
        seq = np.append(seq, x0)
        _, state = preisach_run(params, seq, cls.negative_saturation())
        return state


def preisach_run(
    params: PreisachParams, x: ArrayLike, state: PreisachState
) -> tuple[NDArray[np.float64], PreisachState]:
    """Run the operator: ``(v, new_state)`` for the normalised input ``x`` in [-1, 1].

    Parameters
    ----------
    params : PreisachParams
    x : array_like, shape (n,)
        Normalised input (values within 1e-9 outside [-1, 1] are clipped: rounding).
    state : PreisachState
        Memory before the first sample (not modified).

    Returns
    -------
    v : ndarray, shape (n,)
        Normalised output ``a x + b (2 P - 1)``.
    state : PreisachState
        Memory after the last sample.
    """
    u = as_finite_1d("x", x)
    if u.size and (u.min() < -1.0 - 1e-9 or u.max() > 1.0 + 1e-9):
        raise ValueError(f"x must lie in [-1, 1]. Got values in [{u.min()}, {u.max()}].")
    u = np.clip(u, -1.0, 1.0)
    n0 = state.stack.size
    stack = np.empty(n0 + u.size + 1)
    cum = np.empty_like(stack)
    stack[:n0] = state.stack
    cum[:n0] = state.cum
    out = np.empty(u.size)
    top, last = K.preisach_run(
        u, stack, cum, n0 - 1, state.last, params.p, params.s, params.q, params.norm, out
    )
    v = params.a * u + params.b * (2.0 * out - 1.0)
    return v, PreisachState(stack[: top + 1].copy(), cum[: top + 1].copy(), last)


def loop_hysteresis(x: ArrayLike, v: ArrayLike, n_bins: int = 400) -> float:
    """Measured hysteresis of one closed cycle: max divergence of the rising and falling
    branches (interpolated on a common input grid) over the output span.

    Parameters
    ----------
    x, v : array_like, shape (n,)
        Input and output of ONE cycle: rising from its minimum to its maximum, then falling
        back (or the reverse).
    n_bins : int
        Number of common input points.
    """
    xs = as_finite_1d("x", x)
    vs = as_finite_1d("v", v)
    rising_first = xs[0] - xs.min() < xs.max() - xs[0]
    k = int(np.argmax(xs)) if rising_first else int(np.argmin(xs))
    b1x, b1v = xs[: k + 1], vs[: k + 1]
    b2x, b2v = xs[k:][::-1], vs[k:][::-1]
    lo = max(b1x.min(), b2x.min())
    hi = min(b1x.max(), b2x.max())
    g = np.linspace(lo, hi, n_bins)
    o1 = np.argsort(b1x, kind="stable")
    o2 = np.argsort(b2x, kind="stable")
    d = np.abs(np.interp(g, b1x[o1], b1v[o1]) - np.interp(g, b2x[o2], b2v[o2]))
    return float(d.max() / (vs.max() - vs.min()))
