"""Helpers shared by the CLI subcommands: reading and writing uniform time series."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from piezocomp._atomic import atomic_open
from piezocomp.io.model_files import load_model
from piezocomp.model import ScannerModel, ScannerModel2D

__all__ = ["load_axis_model", "read_uniform_series", "uniform_sample_period", "write_series"]


def read_uniform_series(
    path: str | os.PathLike[str], time_column: str, value_column: str
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Read ``(t, value)`` from a CSV with a header; refuse gaps, NaN and uneven steps.

    Returns the time stamps, the values and the sample period (mean step), s.
    """
    p = Path(path)
    with p.open(newline="", encoding="utf-8") as fh:
        reader = csv.reader(row for row in fh if not row.lstrip().startswith("#"))
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise ValueError(f"{p}: the file is empty.") from None
        rows = list(reader)
    for col in (time_column, value_column):
        if col not in header:
            raise ValueError(f"{p}: no column {col!r}; the header has {header}.")
    it, iv = header.index(time_column), header.index(value_column)
    t = np.empty(len(rows))
    v = np.empty(len(rows))
    for k, row in enumerate(rows):
        line = k + 2
        if len(row) != len(header):
            raise ValueError(
                f"{p}: line {line} has {len(row)} fields, the header has {len(header)} "
                "(truncated file?)."
            )
        try:
            t[k], v[k] = float(row[it]), float(row[iv])
        except ValueError:
            raise ValueError(f"{p}: line {line} is not numeric: {row}.") from None
        if not (np.isfinite(t[k]) and np.isfinite(v[k])):
            raise ValueError(f"{p}: line {line} holds a non-finite value: {row}.")
    return t, v, uniform_sample_period(p, t, time_column, first_line=2, unit="line")


def uniform_sample_period(
    path: str | os.PathLike[str],
    t: NDArray[np.float64],
    time_column: str,
    first_line: int = 0,
    unit: str = "row",
) -> float:
    """Sample period of uniformly spaced time stamps; refuse fewer than 2 or uneven steps.

    ``first_line`` is the file line (``unit="line"``) or array row of ``t[0]``, to name the
    bad step in the error.
    """
    if t.size < 2:
        raise ValueError(f"{path}: needs at least 2 samples. Got {t.size}.")
    dt = np.diff(t)
    T = float(np.mean(dt))
    if T <= 0 or np.max(np.abs(dt - T)) > 1e-6 * T + 1e-12:
        k = int(np.argmax(np.abs(dt - T)))
        raise ValueError(
            f"{path}: {time_column} must be uniformly increasing; the step into {unit} "
            f"{k + 1 + first_line} is {dt[k]:.9g} s against a mean of {T:.9g} s."
        )
    return T


def write_series(
    path: str | os.PathLike[str],
    columns: dict[str, NDArray[np.float64]],
    metadata: dict[str, str] | None = None,
) -> None:
    """Write equal-length columns as CSV with a header, atomically, full precision.

    ``metadata`` goes first as ``# key: value`` lines (read back by
    :func:`piezocomp.io.signals.read_signal`).
    """
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], float) for n in names])
    with atomic_open(path, "w", newline="") as fh:
        for key, value in (metadata or {}).items():
            fh.write(f"# {key}: {value}\n")
        writer = csv.writer(fh)
        writer.writerow(names)
        writer.writerows([[repr(float(x)) for x in row] for row in data])


def load_axis_model(path: str | os.PathLike[str], axis: str | None) -> ScannerModel:
    """One axis of a model file: the file's model, or its ``axis`` of a 2-D file."""
    model = load_model(path)
    if isinstance(model, ScannerModel2D):
        if axis is None:
            raise ValueError(f"{path} holds a 2-D model: choose an axis with --axis x or --axis y.")
        return model[axis]
    if axis is not None and axis not in ("x", "y"):
        raise ValueError(f"--axis must be x or y. Got {axis!r}.")
    return model
