"""A record with a position sensor: its fitted and held-out parts, and error figures.

The sensor-based fit (:mod:`~piezocomp.sensor.fit`) and the order selection
(:mod:`~piezocomp.sensor.orders`) split a record of ``(u, y)`` in time
(:func:`split_record`: the first part fitted, the rest held out, a warm-up left out of
both) and score a prediction on each part (:func:`error_figures`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import check_finite_scalar

__all__ = ["ErrorFigures", "error_figures", "split_record"]


@dataclass(frozen=True)
class ErrorFigures:
    """Prediction errors over a set of samples (``predicted - measured``).

    Attributes
    ----------
    rms_nm, max_nm : float
        Root mean square and largest absolute error, nm.
    rms_percent_of_range : float
        ``100 rms / output range``; the range is that of the measured output over the
        record after the warm-up (the same for the fit and the validation figures).
    n_samples : int
    """

    rms_nm: float
    max_nm: float
    rms_percent_of_range: float
    n_samples: int

    def as_dict(self) -> dict[str, float | int]:
        """Plain ``dict`` (for JSON summaries)."""
        return {
            "rms_nm": self.rms_nm,
            "max_nm": self.max_nm,
            "rms_percent_of_range": self.rms_percent_of_range,
            "n_samples": self.n_samples,
        }


def error_figures(
    predicted: NDArray[np.float64], measured: NDArray[np.float64], output_range_nm: float
) -> ErrorFigures:
    """:class:`ErrorFigures` of ``predicted - measured``."""
    e = np.asarray(predicted, dtype=float) - np.asarray(measured, dtype=float)
    if e.size == 0:
        raise ValueError("no samples to compute errors on.")
    rms = float(np.sqrt(np.mean(e**2)))
    return ErrorFigures(
        rms_nm=rms,
        max_nm=float(np.max(np.abs(e))),
        rms_percent_of_range=100.0 * rms / output_range_nm if output_range_nm > 0 else np.inf,
        n_samples=int(e.size),
    )


def split_record(
    n: int,
    validation_fraction: float = 0.25,
    split_index: int | None = None,
    warmup_samples: int = 0,
) -> int:
    """Index of the first held-out sample (``split_index`` wins over the fraction)."""
    if isinstance(warmup_samples, bool) or int(warmup_samples) != warmup_samples:
        raise TypeError(f"warmup_samples must be an integer. Got {warmup_samples!r}.")
    if warmup_samples < 0:
        raise ValueError(f"warmup_samples must be >= 0. Got {warmup_samples}.")
    if split_index is None:
        f = check_finite_scalar("validation_fraction", validation_fraction)
        if not 0 <= f < 1:
            raise ValueError(f"validation_fraction must be in [0, 1). Got {f}.")
        split = round(n * (1.0 - f))
    else:
        split = int(split_index)
        if split != split_index or not 0 < split <= n:
            raise ValueError(f"split_index must be an integer in (0, {n}]. Got {split_index!r}.")
    if split - int(warmup_samples) < 2:
        raise ValueError(
            f"too few samples to fit: {split} before the split and {warmup_samples} of warm-up."
        )
    return split
