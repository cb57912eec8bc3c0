"""The cost of the batch refinement: residuals and Jacobian of the height prediction error
(17) over every record, with the smoothness rows and the per-record drift paths.

:class:`RefineCost` is what :func:`~piezocomp.identification.estimation.batch.refine` hands to
:func:`scipy.optimize.least_squares`. The Jacobian is the regressor of eq (18), ``h'(y_hat + d)
dy_hat/dtheta``, chained into the optimiser's coordinates
(:class:`~piezocomp.identification.estimation.reparametrisation.Reparametrisation`); a record's
drift ``d`` (a shift of ``h``'s argument) is a fixed path plus, if given, a basis whose coefficients
are estimated with the model, penalised by their second differences and anchored at zero."""

from __future__ import annotations

import math
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp.identification.estimation.parameters import simulate_with_gradient
from piezocomp.identification.estimation.reparametrisation import Reparametrisation
from piezocomp.model import ModelState, simulate

__all__ = ["CostRecord", "OutputMap", "RefineCost", "checked_basis"]


@runtime_checkable
class OutputMap(Protocol):
    """The measured output as a function of the extension, ``z_m = h(y)`` (eq 14, 16).

    ``derivative(y)`` is ``h'(y)``, which enters the regressor of eq (18). Both take and
    return arrays of the shape of ``y``.
    """

    def __call__(self, y: NDArray[np.float64], /) -> NDArray[np.float64]: ...

    def derivative(self, y: NDArray[np.float64], /) -> NDArray[np.float64]: ...


def checked_basis(
    basis: ArrayLike | None, n_sim: int, output: OutputMap | None, where: str
) -> NDArray[np.float64] | None:
    """A record's drift basis, checked and cut to its simulated samples."""
    if basis is None:
        return None
    b = np.asarray(basis, dtype=float)
    if b.ndim != 2 or b.shape[0] < n_sim or b.shape[1] < 1 or not np.all(np.isfinite(b)):
        raise ValueError(
            f"{where}drift_basis must be a finite (n, m) array, one row per command sample. "
            f"Got shape {b.shape}."
        )
    if output is None:
        raise ValueError(f"{where}drift_basis needs an output map (a drift of h's argument).")
    return b[:n_sim]


CostRecord = tuple[
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.bool_],
    ModelState,
    OutputMap | None,
    NDArray[np.float64],
    float | None,
]
"""One record of :func:`~piezocomp.identification.estimation.batch.refine`: command, target,
residual selection, state, output map, shift, and the held command its creep rests on
(``None``: the state's creep as given)."""


class RefineCost:
    """The residuals of :func:`~piezocomp.identification.estimation.batch.refine` over every record
    (and the smoothness rows) and their Jacobian in the optimiser's coordinates, computed once per
    point; ``history`` holds the cost of every evaluation."""

    def __init__(
        self,
        rep: Reparametrisation,
        records: list[CostRecord],
        T: float,
        smooth: NDArray[np.float64] | None,
        bases: list[NDArray[np.float64] | None] | None = None,
        drift_smoothing: float = 0.0,
        drift_anchor: float = 0.0,
    ) -> None:
        self.rep, self.records, self.T, self.smooth = rep, records, T, smooth
        self.smooth_x = None if smooth is None else rep.chain(smooth)  # its d/dx
        self.history: list[float] = []
        self.cache: dict[str, Any] = {}
        self.bases = bases or [None] * len(records)
        # each record's drift coefficients follow the model's, in the records' order
        self.n_model = rep.x0.size
        sizes = [0 if b is None else b.shape[1] for b in self.bases]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(int) + self.n_model
        self.n_drift = int(sum(sizes))
        self.drift_rows = self._drift_rows(drift_smoothing, drift_anchor)
        self.n_penalty_rows = (0 if smooth is None else smooth.shape[0]) + (
            0 if self.drift_rows is None else self.drift_rows.shape[0]
        )

    def _drift_rows(self, weight: float, anchor: float) -> NDArray[np.float64] | None:
        """Second differences of each record's coefficients weighted by ``weight``, and the
        coefficients themselves by ``anchor``, times the heights' mean information about one
        coefficient at the start (rows over the whole parameter vector)."""
        if self.n_drift == 0 or (weight <= 0 and anchor <= 0):
            return None
        rows = []
        x0 = np.concatenate([self.rep.x0, np.zeros(self.n_drift)])
        m = self.rep.model(self.rep.x0)
        for i, ((u_r, _, sel_r, st_r, out_r, sh_r, rest_r), b) in enumerate(
            zip(self.records, self.bases, strict=True)
        ):
            if b is None or b.shape[1] < 2:
                continue
            if rest_r is not None:
                st_r = st_r.with_creep_at_rest(m, rest_r)
            y, _ = simulate(m, u_r, self.T, st_r)
            assert out_r is not None
            hd = np.asarray(out_r.derivative((y + sh_r)[sel_r]), dtype=float)
            info = float(np.mean(np.sum((hd[:, None] * b[sel_r]) ** 2, axis=0)))
            # the knots' second differences, a first knot held at 0 before the basis' own
            d2 = np.diff(np.eye(b.shape[1] + 1), 2, axis=0)[:, 1:] * math.sqrt(weight * info)
            if anchor > 0:
                d2 = np.vstack([d2, np.eye(b.shape[1]) * math.sqrt(anchor * info)])
            block = np.zeros((d2.shape[0], x0.size))
            block[:, self.offsets[i] : self.offsets[i + 1]] = d2
            rows.append(block)
        return np.vstack(rows) if rows else None

    def drift_coefficients(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """Each record's drift coefficients (empty tuple without bases)."""
        if self.n_drift == 0:
            return ()
        return tuple(
            np.array(x[self.offsets[i] : self.offsets[i + 1]]) for i in range(len(self.records))
        )

    def evaluate(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        key = x.tobytes()
        if self.cache.get("key") != key:
            xm = x[: self.n_model]
            m = self.rep.model(xm)
            res, jacs = [], []
            for i, (u_r, target_r, sel_r, st_r, out_r, shift_r, rest_r) in enumerate(self.records):
                y, jac_theta, _ = simulate_with_gradient(
                    m, u_r, self.T, st_r, coupled=self.rep.layout.coupled,
                    thresholds=self.rep.thresholds_free, creep_rest_nm=rest_r,
                )  # fmt: skip
                b = self.bases[i]
                if b is not None:
                    shift_r = shift_r + b @ x[self.offsets[i] : self.offsets[i + 1]]
                y, jac = (y + shift_r)[sel_r], self.rep.chain(jac_theta, sel_r)  # d/dx
                if self.n_drift:
                    full = np.zeros((jac.shape[0], x.size))
                    full[:, : self.n_model] = jac
                    if b is not None:
                        full[:, self.offsets[i] : self.offsets[i + 1]] = b[sel_r]
                    jac = full
                if out_r is None:
                    pred = y
                else:
                    pred = np.asarray(out_r(y), dtype=float)
                    jac = jac * np.asarray(out_r.derivative(y), dtype=float)[:, None]
                res.append(pred - target_r)
                jacs.append(jac)
            if self.smooth is not None and self.smooth_x is not None:
                res.append(self.smooth @ self.rep.theta(xm))
                sx = self.smooth_x
                if self.n_drift:
                    sx = np.hstack([sx, np.zeros((sx.shape[0], self.n_drift))])
                jacs.append(sx)
            if self.drift_rows is not None:
                res.append(self.drift_rows @ x)
                jacs.append(self.drift_rows)
            self.cache.update(
                key=key,
                res=res[0] if len(res) == 1 else np.concatenate(res),
                jac=jacs[0] if len(jacs) == 1 else np.vstack(jacs),
            )
        return self.cache["res"], self.cache["jac"]

    def fun(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        res = self.evaluate(x)[0]
        self.history.append(0.5 * float(res @ res))
        return res

    def jac(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.evaluate(x)[1]
