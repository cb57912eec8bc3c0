"""Input checks shared by the package; each raises with the name, the rule and the value."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["as_finite_1d", "as_finite_array", "check_finite_scalar", "readonly"]


def readonly(a: NDArray[Any]) -> NDArray[Any]:
    """Return a read-only copy of ``a`` (so frozen objects stay frozen)."""
    out = np.array(a, dtype=float, copy=True)
    out.setflags(write=False)
    return out


def check_finite_scalar(name: str, value: Any) -> float:
    """Return ``value`` as float; refuse non-numbers, NaN and infinities."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a real number. Got {value!r}.") from None
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite. Got {v}.")
    return v


def as_finite_array(name: str, values: ArrayLike, ndim: int | None = None) -> NDArray[np.float64]:
    """Return ``values`` as a float64 array; refuse NaN/inf (naming the first bad index)."""
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an array of real numbers.") from None
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-D. Got shape {a.shape}.")
    bad = ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        where = idx[0] if len(idx) == 1 else idx
        raise ValueError(
            f"{name} must contain only finite samples. Got {a[idx]} at index {where} "
            f"({int(bad.sum())} non-finite samples in all)."
        )
    return a


def as_finite_1d(name: str, values: ArrayLike) -> NDArray[np.float64]:
    """Return a contiguous finite 1-D float64 array."""
    return np.ascontiguousarray(as_finite_array(name, values, ndim=1))
