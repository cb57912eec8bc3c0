"""The topography along the identification line as a function of the extension, ``h(y)``.

Section IV: once the steady loop's ascending branch ``f_a`` is known (eqs 21-23), the
forward trace's heights ``z_m(u)`` re-indexed by ``y = f_a(u)`` give ``h(y)``, the output map
of eq (14). Its derivative ``h'(y)`` enters the regressor (18), so ``h`` is smoothed (a
penalised cubic smoothing spline, smoothing chosen by generalised cross-validation, over the
average of the steady forward traces), never differenced from raw samples.

The fitted spline is tabulated on a uniform grid of values and slopes; ``h`` is the cubic
Hermite interpolant of that table (C1, with an exact analytic derivative), the same function
in Python and in the compiled RLS kernel. Outside the table ``h`` is continued by its end
values (slope 0: no information there).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import make_smoothing_spline

from piezocomp._validation import as_finite_1d, as_finite_array, check_finite_scalar, readonly
from piezocomp.identification import _rls_kernel
from piezocomp.identification.loop.symmetric import SymmetricLoop

__all__ = ["HeightProfile", "hermite_eval", "spline_penalty"]


def spline_penalty(spline: Any, x: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    """The penalty ``lam`` of a cubic smoothing spline, from the spline itself.

    :func:`scipy.interpolate.make_smoothing_spline` minimises
    ``sum (y_i - f(x_i))^2 + lam int f''^2`` and, with ``lam=None``, chooses ``lam`` by
    generalised cross-validation without returning it. The minimiser's residuals are
    proportional to the jumps of its third derivative ``f3`` at the data points,
    ``y_i - f(x_i) = lam (f3(x_i+) - f3(x_i-))`` (the natural cubic spline's optimality
    condition), so ``lam`` is their least-squares ratio; refitting with it reproduces the
    spline to rounding. NaN for an interpolating spline (no residuals).
    """
    d3 = spline.derivative(3)
    eps = 1e-9 * max(1.0, float(np.max(np.abs(x))))
    jump = d3(x + eps) - d3(x - eps)
    res = y - spline(x)
    jj = float(jump @ jump)
    lam = float(res @ jump) / jj if jj > 0 else float("nan")
    return lam if lam > 0 else float("nan")


def hermite_eval(
    y: NDArray[np.float64],
    start: float,
    step: float,
    values: NDArray[np.float64],
    slopes: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Cubic Hermite interpolation on a uniform table, and its derivative (any shape of ``y``).

    Outside ``[start, start + (n - 1) step]`` the end value is continued with slope 0. The
    same compiled function (:func:`piezocomp.identification._rls_kernel.hermite`) serves the
    RLS kernel, so Python and kernel see one ``h``.
    """
    yy = np.ascontiguousarray(y, dtype=np.float64)
    flat = yy.reshape(-1)
    h = np.empty_like(flat)
    dh = np.empty_like(flat)
    _rls_kernel.hermite_array(
        flat,
        float(start),
        float(step),
        np.ascontiguousarray(values, dtype=np.float64),
        np.ascontiguousarray(slopes, dtype=np.float64),
        h,
        dh,
    )
    return h.reshape(yy.shape), dh.reshape(yy.shape)


@dataclass(frozen=True)
class HeightProfile:
    """``h(y)`` on a uniform table of values and slopes (cubic Hermite, C1).

    Parameters
    ----------
    start_nm : float
        ``y`` of the first table entry (nm).
    step_nm : float
        Table spacing (nm, > 0).
    values_nm : array_like, shape (n,)
        ``h`` at ``start + i step`` (nm), ``n >= 2``.
    slopes : array_like, shape (n,)
        ``h'`` there (dimensionless).
    noise_nm : float, optional
        Estimated noise standard deviation of one height sample (nm), for information.
    penalty : float, optional
        Penalty ``lam`` of the smoothing spline the table came from (:meth:`from_samples`),
        to smooth other samples of the same heights alike (NaN if unknown).
    """

    start_nm: float
    step_nm: float
    values_nm: NDArray[np.float64]
    slopes: NDArray[np.float64]
    noise_nm: float = float("nan")
    penalty: float = float("nan")

    def __post_init__(self) -> None:
        object.__setattr__(self, "start_nm", check_finite_scalar("start_nm", self.start_nm))
        step = check_finite_scalar("step_nm", self.step_nm)
        if step <= 0:
            raise ValueError(f"step_nm must be > 0. Got {step}.")
        object.__setattr__(self, "step_nm", step)
        v = as_finite_1d("values_nm", self.values_nm)
        s = as_finite_1d("slopes", self.slopes)
        if v.size < 2 or s.shape != v.shape:
            raise ValueError(
                f"values_nm and slopes must have the same length >= 2. Got {v.size}, {s.size}."
            )
        object.__setattr__(self, "values_nm", readonly(v))
        object.__setattr__(self, "slopes", readonly(s))
        object.__setattr__(self, "noise_nm", float(self.noise_nm))
        object.__setattr__(self, "penalty", float(self.penalty))

    @property
    def y_range_nm(self) -> tuple[float, float]:
        """``(first, last)`` ``y`` of the table (nm)."""
        return self.start_nm, self.start_nm + (self.values_nm.size - 1) * self.step_nm

    def __call__(self, y_nm: ArrayLike) -> Any:
        """``h(y)`` (nm)."""
        y = as_finite_array("y_nm", y_nm)
        h, _ = hermite_eval(
            np.atleast_1d(y), self.start_nm, self.step_nm, self.values_nm, self.slopes
        )
        return h.reshape(y.shape) if y.ndim else float(h[0])

    def derivative(self, y_nm: ArrayLike) -> Any:
        """``h'(y)`` (dimensionless), the exact derivative of :meth:`__call__`."""
        y = as_finite_array("y_nm", y_nm)
        _, d = hermite_eval(
            np.atleast_1d(y), self.start_nm, self.step_nm, self.values_nm, self.slopes
        )
        return d.reshape(y.shape) if y.ndim else float(d[0])

    def scaled(self, factor: float) -> HeightProfile:
        """``factor * h(y)``: the same profile in other units of height (e.g. a record's
        residuals weighted by ``factor`` in a joint fit)."""
        f = check_finite_scalar("factor", factor)
        return HeightProfile(
            self.start_nm, self.step_nm, f * self.values_nm, f * self.slopes,
            abs(f) * self.noise_nm, self.penalty,
        )  # fmt: skip

    def table(self) -> tuple[float, float, NDArray[np.float64], NDArray[np.float64]]:
        """``(start, step, values, slopes)`` as contiguous arrays for the compiled kernels."""
        return (
            self.start_nm,
            self.step_nm,
            np.ascontiguousarray(self.values_nm),
            np.ascontiguousarray(self.slopes),
        )

    # ------------------------------------------------------------------ fitting
    @classmethod
    def from_samples(
        cls,
        y_nm: ArrayLike,
        height_nm: ArrayLike,
        *,
        lam: float | None = None,
        step_nm: float | None = None,
        noise_nm: float = float("nan"),
    ) -> HeightProfile:
        """Smooth heights sampled at increasing positions ``y`` and tabulate them.

        Parameters
        ----------
        y_nm : array_like, shape (n,)
            Strictly increasing positions (nm).
        height_nm : array_like, shape (n,)
            Heights there (nm).
        lam : float, optional
            Penalty of the smoothing spline (:func:`scipy.interpolate.make_smoothing_spline`);
            default chosen by generalised cross-validation. Either way it is stored as
            :attr:`penalty` (:func:`spline_penalty`).
        step_nm : float, optional
            Table spacing; default a quarter of the mean sample spacing.
        noise_nm : float, optional
            Noise estimate to store with the profile.
        """
        y = as_finite_1d("y_nm", y_nm)
        z = as_finite_1d("height_nm", height_nm)
        if y.shape != z.shape or y.size < 5:
            raise ValueError(
                f"y_nm and height_nm must have the same length >= 5. Got {y.size}, {z.size}."
            )
        if np.any(np.diff(y) <= 0):
            raise ValueError("y_nm must be strictly increasing.")
        if lam is not None and not (np.isfinite(lam) and lam >= 0):
            raise ValueError(f"lam must be a finite number >= 0. Got {lam!r}.")
        spline = make_smoothing_spline(y, z, lam=lam)
        penalty = spline_penalty(spline, y, z) if lam is None else float(lam)
        step = float(np.mean(np.diff(y))) / 4 if step_nm is None else float(step_nm)
        if not step > 0:
            raise ValueError(f"step_nm must be > 0. Got {step}.")
        n = int(np.floor((y[-1] - y[0]) / step)) + 1
        grid = y[0] + step * np.arange(n)
        return cls(y[0], step, spline(grid), spline.derivative()(grid), noise_nm, penalty)

    @classmethod
    def from_loop(
        cls,
        loop: SymmetricLoop,
        u_forward_nm: ArrayLike,
        heights_nm: ArrayLike,
        *,
        lam: float | None = None,
        step_nm: float | None = None,
    ) -> HeightProfile:
        """``h(y)`` from the forward traces of steady cycles, re-indexed by ``y = f_a(u)``.

        Parameters
        ----------
        loop : SymmetricLoop
            The steady loop (eqs 21-23).
        u_forward_nm : array_like, shape (m,)
            Command of the forward (ascending) trace, strictly increasing (nm).
        heights_nm : array_like, shape (m,) or (n_cycles, m)
            Heights of one or several steady forward traces on that command grid (nm);
            several are averaged (their spread gives the noise estimate).
        lam, step_nm
            As in :meth:`from_samples`.
        """
        u = as_finite_1d("u_forward_nm", u_forward_nm)
        y = np.asarray(loop.ascending(u), dtype=float)
        return cls.from_positions(y, heights_nm, lam=lam, step_nm=step_nm)

    @classmethod
    def from_positions(
        cls,
        y_nm: ArrayLike,
        heights_nm: ArrayLike,
        *,
        lam: float | None = None,
        step_nm: float | None = None,
    ) -> HeightProfile:
        """``h(y)`` from steady forward traces whose positions ``y`` are known.

        The positions come from the loop (:meth:`from_loop`, ``y = f_a(u)``) or from a model's
        prediction of the same steady cycles (the model's own frame, see
        :func:`~piezocomp.identification.estimation.chain.model_profile`).

        Parameters
        ----------
        y_nm : array_like, shape (m,)
            Position of each sample of the forward trace, strictly increasing (nm).
        heights_nm : array_like, shape (m,) or (n_cycles, m)
            Heights of one or several steady forward traces at those positions (nm); several
            are averaged (their spread gives the noise estimate).
        lam, step_nm
            As in :meth:`from_samples`.
        """
        y = as_finite_1d("y_nm", y_nm)
        z = np.atleast_2d(as_finite_array("heights_nm", heights_nm))
        if z.ndim != 2 or z.shape[1] != y.size:
            raise ValueError(
                f"heights_nm must have shape (m,) or (n_cycles, m) with m = {y.size}. "
                f"Got {z.shape}."
            )
        if np.any(np.diff(y) <= 0):
            k = int(np.argmax(np.diff(y) <= 0))
            raise ValueError(
                "the positions of a forward trace must be strictly increasing; "
                f"y_nm[{k + 1}] = {y[k + 1]:.6g} follows y_nm[{k}] = {y[k]:.6g}."
            )
        noise = float(np.sqrt(np.mean(np.var(z, axis=0, ddof=1)))) if z.shape[0] > 1 else np.nan
        return cls.from_samples(y, z.mean(axis=0), lam=lam, step_nm=step_nm, noise_nm=noise)
