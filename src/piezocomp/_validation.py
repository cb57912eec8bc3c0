"""Input checks shared by the package; each raises with the name, the rule and the value."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["MESSAGE_CHARS", "as_finite_1d", "as_finite_array", "check_finite_scalar",
           "check_int_at_least", "one_line", "readonly"]  # fmt: skip

MESSAGE_CHARS = 2000
"""Longest message :func:`one_line` keeps (a garbage file must not flood the terminal)."""


def one_line(text: str, limit: int = MESSAGE_CHARS) -> str:
    """``text`` as one printable line: whitespace runs made one space, other unprintable
    characters escaped (``\\x00``), cut to ``limit`` characters."""
    words = " ".join(str(text).split())
    clean = "".join(c if c.isprintable() else repr(c)[1:-1] for c in words)
    return clean if len(clean) <= limit else clean[: limit - 3] + "..."


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


def check_int_at_least(name: str, value: Any, lo: int) -> int:
    """Return ``value``; refuse anything but an integer ``>= lo`` (booleans included)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise ValueError(f"{name} must be an integer >= {lo}. Got {value!r}.")
    return value
