"""Choice of the orders ``N_H`` and ``N_c`` of a model fitted to a sensor record: every
candidate fitted by the linear stage of :func:`~piezocomp.sensor.fit.fit_sensor`, scored on
the held-out end of the samples given, and the smallest within a tolerance of the best kept
(:func:`~piezocomp.identification.estimation.orders.select_orders`).
"""

from __future__ import annotations

from collections.abc import Iterable

from numpy.typing import ArrayLike

from piezocomp._validation import as_finite_1d
from piezocomp.identification.estimation.orders import (
    DEFAULT_N_CREEP,
    DEFAULT_N_PLAY,
    OrderSelection,
    select_orders,
)
from piezocomp.sensor.fit import (
    DEFAULT_MIN_TIME_CONSTANT_S,
    InitialState,
    SensorFit,
    fit_sensor,
)
from piezocomp.sensor.record import split_record

__all__ = ["select_sensor_orders"]


def select_sensor_orders(
    u_nm: ArrayLike,
    y_nm: ArrayLike,
    sample_period_s: float,
    *,
    n_play_candidates: Iterable[int] = DEFAULT_N_PLAY,
    n_creep_candidates: Iterable[int] = DEFAULT_N_CREEP,
    inner_validation_fraction: float = 0.25,
    warmup_samples: int = 0,
    initial_state: InitialState | float = "auto",
    tolerance: float = 0.02,
    min_time_constant_s: float | None = DEFAULT_MIN_TIME_CONSTANT_S,
) -> OrderSelection:
    """Orders for :func:`~piezocomp.sensor.fit.fit_sensor` from ``(u, y)``.

    Pass only the samples you fit on: the last ``inner_validation_fraction`` of them is
    held out to score the candidates, so a final validation on a later part of the record
    stays independent of the choice. Each candidate is fitted by the linear
    (non-negative least-squares) stage with placed thresholds and time constants (fast and
    convex).
    Errors are rms in nm; ``fitted`` is the chosen candidate's :class:`SensorFit`.
    ``warmup_samples``, ``initial_state`` and ``min_time_constant_s`` are passed to
    :func:`~piezocomp.sensor.fit.fit_sensor`.

    Excitation warnings of the individual candidates are not suppressed.
    """
    u = as_finite_1d("u_nm", u_nm)
    y = as_finite_1d("y_nm", y_nm)
    split = split_record(u.size, inner_validation_fraction, None, warmup_samples)
    if split >= u.size:
        raise ValueError("inner_validation_fraction must leave samples to score on (> 0).")

    def fit_fn(nh: int, nc: int) -> tuple[SensorFit, float]:
        f = fit_sensor(
            u,
            y,
            sample_period_s,
            n_play=nh,
            n_creep=nc,
            split_index=split,
            warmup_samples=warmup_samples,
            initial_state=initial_state,
            refine=False,
            min_time_constant_s=min_time_constant_s,
            reference_orders=None,
            n_dead_zones=0,
        )
        return f, f.fit_errors.rms_nm

    def score_fn(f: SensorFit) -> float:
        if f.validation_errors is None:  # pragma: no cover - split < n above
            raise RuntimeError("no held-out samples to score on.")
        return f.validation_errors.rms_nm

    pairs = [(nh, nc) for nh in n_play_candidates for nc in n_creep_candidates]
    return select_orders(pairs, fit_fn, score_fn, tolerance=tolerance)
