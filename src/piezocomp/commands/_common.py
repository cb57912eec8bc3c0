"""Helpers shared by the CLI subcommands: reading and writing uniform time series."""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from piezocomp._atomic import atomic_open, check_output, make_folder
from piezocomp.io.model_files import load_model
from piezocomp.io.signals import uniform_period
from piezocomp.model import ScannerModel, ScannerModel2D

__all__ = [
    "POSITION_COLUMNS",
    "AxisJob",
    "axis_jobs",
    "load_axis_model",
    "output_folder",
    "read_columns",
    "read_metadata",
    "read_uniform_series",
    "record_range",
    "uniform_sample_period",
    "write_series",
]


@contextlib.contextmanager
def output_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """The output folder ``path``, created with its missing parents; if the command then
    fails, the folders it created are removed again while they are empty (a failed run
    leaves no empty folder behind; inside an :func:`~piezocomp._atomic.output_group`, once
    the group has removed its temporary files)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{p}: exists and is not a folder")
    check_output(p / "summary.json")  # a folder that can be written into
    created = make_folder(p)
    try:
        yield p
    except BaseException:
        for d in created:  # deepest first
            with contextlib.suppress(OSError):
                d.rmdir()  # only if empty
        raise


def read_columns(
    path: str | os.PathLike[str], time_column: str = "t_s"
) -> tuple[NDArray[np.float64], dict[str, NDArray[np.float64]], float]:
    """Every column of a CSV with a header (``#`` lines skipped); refuse missing or
    non-numeric fields, NaN and non-uniform time stamps.

    Returns the time stamps, the other columns by name and the sample period, s.
    """
    p = Path(path)
    with p.open(newline="", encoding="utf-8") as fh:
        reader = csv.reader(row for row in fh if not row.lstrip().startswith("#"))
        try:
            header = [h.strip() for h in next(reader)]
            rows = list(reader)
        except StopIteration:
            raise ValueError(f"{p}: the file is empty.") from None
        except csv.Error as exc:  # a field longer than the csv module takes, a NUL...
            raise ValueError(
                f"{p}: not a CSV of numbers: {exc} (row {reader.line_num}, # lines not counted)"
            ) from None
    if time_column not in header:
        raise ValueError(f"{p}: no column {time_column!r}; the header has {header}.")
    if len(set(header)) != len(header):
        raise ValueError(f"{p}: the header names a column twice: {header}.")
    data = np.empty((len(rows), len(header)))
    for k, row in enumerate(rows):
        line = k + 2
        if len(row) != len(header):
            raise ValueError(
                f"{p}: line {line} has {len(row)} fields, the header has {len(header)} "
                "(truncated file?)."
            )
        try:
            data[k] = [float(v) for v in row]
        except ValueError:
            raise ValueError(f"{p}: line {line} is not numeric: {row}.") from None
        if not np.all(np.isfinite(data[k])):
            raise ValueError(f"{p}: line {line} holds a non-finite value: {row}.")
    cols = {name: data[:, i] for i, name in enumerate(header)}
    t = cols.pop(time_column)
    return t, cols, uniform_sample_period(p, t, time_column, first_line=2, unit="line")


def read_metadata(path: str | os.PathLike[str]) -> dict[str, str]:
    """The ``# key: value`` lines that open a CSV, or the ``__metadata__`` JSON object of an
    NPZ (:mod:`piezocomp.io.signals`); an empty dict if there are none."""
    p = Path(path)
    meta: dict[str, str] = {}
    if p.suffix.lower() == ".npz":
        try:
            with np.load(p, allow_pickle=False) as data:
                if "__metadata__" not in data.files:
                    return meta
                doc = json.loads(str(data["__metadata__"]))
        except (ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise ValueError(f"{p}: unreadable __metadata__ ({exc}).") from None
        if not isinstance(doc, dict):
            raise ValueError(f"{p}: __metadata__ must be a JSON object.")
        return {str(k): str(v) for k, v in doc.items()}
    with p.open(encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if not line.startswith("#"):
                break
            key, sep, value = line[1:].partition(":")
            if sep:
                meta[key.strip()] = value.strip()
    return meta


def record_range(path: str | os.PathLike[str]) -> tuple[float | None, str]:
    """The scanner range a record states, nm, and where it was found: its ``range_nm``
    metadata, else the ``range_nm`` of the waveform it ran (``piezocomp waveform``);
    ``(None, "")`` if it states none."""
    from piezocomp.identification.offline import WAVEFORM_KEY

    meta = read_metadata(path)
    value: object = None
    where = ""
    if "range_nm" in meta:
        value, where = meta["range_nm"], f"{path}'s range_nm metadata"
    elif WAVEFORM_KEY in meta:
        try:
            params = json.loads(meta[WAVEFORM_KEY])
        except json.JSONDecodeError:
            params = None
        if isinstance(params, dict) and params.get("range_nm") is not None:
            value, where = params["range_nm"], f"the waveform in {path}"
    if value is None:
        return None, ""
    try:
        r = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        r = math.nan
    if not (math.isfinite(r) and r > 0):
        raise ValueError(f"{where}: range_nm must be a finite number > 0. Got {value!r}.")
    return r, where


def read_uniform_series(
    path: str | os.PathLike[str], time_column: str, value_column: str
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Read ``(t, value)`` from a CSV with a header (:func:`read_columns`).

    Returns the time stamps, the values and the sample period, s.
    """
    t, cols, T = read_columns(path, time_column)
    if value_column not in cols:
        header = [time_column, *cols]
        raise ValueError(f"{path}: no column {value_column!r}; the header has {header}.")
    return t, cols[value_column], T


def uniform_sample_period(
    path: str | os.PathLike[str],
    t: NDArray[np.float64],
    time_column: str,
    first_line: int = 0,
    unit: str = "row",
) -> float:
    """Sample period of uniformly spaced time stamps (:func:`piezocomp.io.signals.uniform_period`:
    printing jitter accepted, gaps refused); ``first_line`` is the file line
    (``unit="line"``) or array row of ``t[0]``, to name the bad step in the error."""
    return uniform_period(t, f"{path}: {time_column}", first_line=first_line, unit=unit)


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


@dataclass(frozen=True)
class AxisJob:
    """One axis a trajectory command works on: its model, the columns it reads and writes,
    its key in a state file and its command range (None: not known, not checked)."""

    key: str
    model: ScannerModel
    in_column: str
    out_column: str
    range_nm: float | None


POSITION_COLUMNS = ("x_nm", "y_nm", "position_nm")
"""The position column of a 1-D model's trajectory (named by its axis, or not)."""


def axis_jobs(
    model: ScannerModel | ScannerModel2D,
    axis: str | None,
    columns: dict[str, NDArray[np.float64]],
    source: str,
    *,
    commands_in: bool,
    range_nm: float | None,
    need_range: bool = True,
) -> list[AxisJob]:
    """Which columns a command reads and writes, by axis.

    Positions are named by axis (``x_nm``, ``y_nm``; ``position_nm`` for a 1-D model of an
    unnamed axis), commands by axis too (``ux_nm``, ``uy_nm``; ``u_nm`` for a 1-D model).
    ``commands_in`` reads commands and writes positions (``simulate``), else the other way
    (``compensate``). With a 2-D model every axis the file holds is done, or only ``axis``;
    ``axis`` with a 1-D model is refused. The range is ``range_nm`` or the model's; with
    neither, it is refused if ``need_range``, else None.
    """
    names = sorted(columns)
    if isinstance(model, ScannerModel2D):
        want = [axis] if axis is not None else ["x", "y"]
        jobs = []
        for a in want:
            pos, cmd = f"{a}_nm", f"u{a}_nm"
            src, dst = (cmd, pos) if commands_in else (pos, cmd)
            if src in columns:
                rng = _range(model[a], range_nm, a, need_range)
                jobs.append(AxisJob(a, model[a], src, dst, rng))
            elif axis is not None:
                raise ValueError(f"{source}: --axis {a} needs a column {src!r}; it has {names}.")
        if not jobs:
            need = "ux_nm and/or uy_nm" if commands_in else "x_nm and/or y_nm"
            raise ValueError(f"{source}: a 2-D model needs the columns {need}; it has {names}.")
        return jobs
    if axis is not None:
        raise ValueError(
            f"--axis {axis} selects an axis of a 2-D model; {source}'s model is 1-D (one axis): "
            "leave --axis out."
        )
    if commands_in:
        if "u_nm" not in columns:
            raise ValueError(
                f"{source}: a 1-D model needs the command column 'u_nm'; it has {names}."
            )
        rng = _range(model, range_nm, None, need_range)
        return [AxisJob("axis", model, "u_nm", "position_nm", rng)]
    found = [c for c in POSITION_COLUMNS if c in columns]
    if len(found) != 1:
        raise ValueError(
            f"{source}: a 1-D model compensates one position column, one of "
            f"{list(POSITION_COLUMNS)}; the file has {names} (for both axes use a 2-D model)."
        )
    return [AxisJob("axis", model, found[0], "u_nm", _range(model, range_nm, None, need_range))]


def _range(
    model: ScannerModel, range_nm: float | None, axis: str | None, need: bool
) -> float | None:
    """The scanner's full travel: ``--range-nm`` or the model file's ``range_nm``."""
    r = range_nm if range_nm is not None else model.range_nm
    if r is None and not need:
        return None
    if r is None:
        where = f" for axis {axis}" if axis else ""
        raise ValueError(
            f"the model file states no range_nm{where}: give --range-nm (the scanner's full "
            "travel; commands outside +-range/2 are refused)."
        )
    if not (np.isfinite(r) and r > 0):
        raise ValueError(f"--range-nm must be a finite number > 0. Got {r}.")
    return float(r)


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
