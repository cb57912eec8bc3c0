"""Recorded time series (line scans, identification runs) as CSV or NPZ files.

A recorded signal is a set of equally long columns sampled at times ``t_s``:

* ``t_s`` (s), strictly increasing;
* the command, either ``u_nm`` (one axis) or ``x_nm`` and ``y_nm`` (two axes), nominal nm;
* ``height_nm``, the measured topography ``z_m`` (nm), the only sensor the method uses;
* any further columns (e.g. ``y_true_nm`` from a simulation), kept as they are.

CSV: optional ``# key: value`` metadata lines, one header line of column names, then one row
per sample. NPZ: one array per column, metadata as a JSON string under ``__metadata__``.
Writers are atomic (a crash never leaves half a file).
"""

from __future__ import annotations

import csv
import io
import json
import os
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezocomp._atomic import atomic_open
from piezocomp._validation import readonly

__all__ = ["STAMP_TOLERANCE", "RecordedSignal", "read_signal", "uniform_period", "write_signal"]

_META_KEY = "__metadata__"

STAMP_TOLERANCE = 0.01
"""Largest distance of a time stamp from the uniform grid, as a fraction of the sample
period. Recorders print their clock rounded (steps of 0.00199998 s for 0.002 s); a missing
sample is a whole period off."""


def uniform_period(
    t_s: ArrayLike, where: str = "", first_line: int = 0, unit: str = "row"
) -> float:
    """The sample period of uniformly sampled time stamps, s.

    The period is the slope of a least-squares line through the stamps, which printing
    rounds but does not bias; every stamp must lie within :data:`STAMP_TOLERANCE` of a period
    of that line. ``first_line`` is the file line (``unit="line"``) or array row of the first
    stamp, to name the bad one.

    Raises
    ------
    ValueError
        Fewer than 2 stamps, stamps that do not increase, or a stamp off the grid (a gap, a
        repeated or a missing sample).
    """
    t = np.asarray(t_s, dtype=float)
    pre = f"{where}: " if where else ""
    if t.size < 2:
        raise ValueError(f"{pre}needs at least 2 samples. Got {t.size}.")
    k = np.arange(t.size, dtype=float)
    T, t0 = np.polyfit(k, t, 1)
    if not T > 0:
        raise ValueError(f"{pre}the time stamps must increase.")
    off = t - (t0 + T * k)
    i = int(np.argmax(np.abs(off)))
    if abs(off[i]) > STAMP_TOLERANCE * T:
        steps = np.diff(t)
        j = int(np.argmax(np.abs(steps - T)))
        raise ValueError(
            f"{pre}the time stamps are not uniformly sampled: the step into {unit} "
            f"{j + 1 + first_line} is {steps[j]:.9g} s against a period of {T:.9g} s (a gap or "
            f"a repeated sample; stamp jitter up to {STAMP_TOLERANCE:.0%} of a period is "
            "accepted)."
        )
    return float(T)


@dataclass(frozen=True)
class RecordedSignal(Mapping[str, NDArray[np.float64]]):
    """Columns of a recorded time series; a read-only mapping ``name -> array``.

    Parameters
    ----------
    columns : mapping of str to array_like
        Equally long 1-D columns; must hold ``t_s`` (strictly increasing), ``height_nm`` and
        ``u_nm`` or both ``x_nm`` and ``y_nm``. Values must be finite.
    metadata : mapping of str to str, optional
        Free-form text (instrument, sample, line time...).
    source : str, optional
        File the signal was read from.
    """

    columns: Mapping[str, ArrayLike]
    metadata: Mapping[str, str] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        where = f"{self.source}: " if self.source else ""
        cols: dict[str, NDArray[np.float64]] = {}
        for name, values in self.columns.items():
            if not isinstance(name, str) or not name.isidentifier():
                raise ValueError(f"{where}column names must be identifiers. Got {name!r}.")
            try:
                a = np.asarray(values, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"{where}column {name!r} must hold numbers.") from None
            if a.ndim != 1:
                raise ValueError(f"{where}column {name!r} must be 1-D. Got shape {a.shape}.")
            bad = ~np.isfinite(a)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"{where}column {name!r} must be finite. Got {a[i]} at sample {i}."
                )
            cols[name] = readonly(a)
        for required in ("t_s", "height_nm"):
            if required not in cols:
                raise ValueError(
                    f"{where}a recorded signal needs a {required!r} column. "
                    f"Got columns {sorted(cols)}."
                )
        if "u_nm" not in cols and not ("x_nm" in cols and "y_nm" in cols):
            raise ValueError(
                f"{where}a recorded signal needs the command: 'u_nm', or 'x_nm' and 'y_nm'. "
                f"Got columns {sorted(cols)}."
            )
        lengths = {k: v.size for k, v in cols.items()}
        if len(set(lengths.values())) != 1:
            raise ValueError(f"{where}all columns must have the same length. Got {lengths}.")
        t = cols["t_s"]
        if t.size < 2 or np.any(np.diff(t) <= 0):
            raise ValueError(f"{where}t_s must be strictly increasing with at least 2 samples.")
        meta = {str(k): str(v) for k, v in self.metadata.items()}
        object.__setattr__(self, "columns", cols)
        object.__setattr__(self, "metadata", meta)
        object.__setattr__(self, "source", str(self.source))

    def __getitem__(self, key: str) -> NDArray[np.float64]:
        return self.columns[key]  # type: ignore[return-value]

    def __iter__(self) -> Iterator[str]:
        return iter(self.columns)

    def __len__(self) -> int:
        return len(self.columns)

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.columns["t_s"].size)  # type: ignore[union-attr]

    @property
    def sample_period_s(self) -> float:
        """Sampling period (s) of the uniform time stamps (:func:`uniform_period`)."""
        return uniform_period(self.columns["t_s"], self.source or "signal")


def _format_of(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in (".csv", ".npz"):
        return suffix[1:]
    raise ValueError(f"{path}: unsupported signal file type {suffix!r}; use .csv or .npz")


def read_signal(path: str | os.PathLike[str]) -> RecordedSignal:
    """Read a recorded signal from ``.csv`` or ``.npz``.

    Raises
    ------
    ValueError
        Missing, corrupt, truncated or incomplete file; the message names the file.
    """
    p = Path(path)
    fmt = _format_of(p)
    if not p.is_file():
        raise ValueError(f"{p}: no such file")
    if fmt == "csv":
        return _read_csv(p)
    return _read_npz(p)


def _read_csv(p: Path) -> RecordedSignal:
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p}: not a UTF-8 text CSV file ({exc})") from None
    meta: dict[str, str] = {}
    lines = text.splitlines()
    body: list[str] = []
    for line in lines:
        if line.startswith("#"):
            key, sep, value = line[1:].partition(":")
            if sep:
                meta[key.strip()] = value.strip()
        elif line.strip():
            body.append(line)
    if not body:
        raise ValueError(f"{p}: no header line of column names")
    try:
        rows = list(csv.reader(body))
    except csv.Error as exc:  # a field longer than the csv module takes, a NUL...
        raise ValueError(f"{p}: not a CSV of numbers: {exc}") from None
    header = [h.strip() for h in rows[0]]
    data = rows[1:]
    if not data:
        raise ValueError(f"{p}: header but no samples")
    values = np.empty((len(data), len(header)))
    for i, row in enumerate(data):
        if len(row) != len(header):
            raise ValueError(
                f"{p}: line {i + 2 + sum(1 for x in lines if x.startswith('#'))} has "
                f"{len(row)} fields, the header has {len(header)} (truncated?)"
            )
        try:
            values[i] = [float(v) for v in row]
        except ValueError:
            raise ValueError(f"{p}: sample {i} holds a value that is not a number: {row}") from None
    return RecordedSignal(
        {name: values[:, j] for j, name in enumerate(header)}, metadata=meta, source=str(p)
    )


def _read_npz(p: Path) -> RecordedSignal:
    try:
        with np.load(io.BytesIO(p.read_bytes()), allow_pickle=False) as npz:
            cols = {k: np.asarray(npz[k]) for k in npz.files if k != _META_KEY}
            meta: dict[str, Any] = {}
            if _META_KEY in npz.files:
                meta = json.loads(str(npz[_META_KEY]))
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, json.JSONDecodeError) as exc:
        raise ValueError(
            f"{p}: not a readable NPZ signal file (corrupt or truncated?): {exc}"
        ) from None
    if not isinstance(meta, dict):
        raise ValueError(f"{p}: {_META_KEY} must be a JSON object")
    return RecordedSignal(cols, metadata=meta, source=str(p))


def write_signal(
    path: str | os.PathLike[str],
    signal: RecordedSignal | Mapping[str, ArrayLike],
    metadata: Mapping[str, str] | None = None,
) -> None:
    """Write a recorded signal to ``.csv`` or ``.npz``, atomically.

    Parameters
    ----------
    path : path-like
        Destination; the suffix chooses the format.
    signal : RecordedSignal or mapping of columns
        The columns (validated as in :class:`RecordedSignal`).
    metadata : mapping, optional
        Metadata; default that of ``signal`` (if it is a :class:`RecordedSignal`).
    """
    p = Path(path)
    fmt = _format_of(p)
    if not isinstance(signal, RecordedSignal):
        signal = RecordedSignal(signal, metadata=metadata or {})
    meta = dict(signal.metadata if metadata is None else metadata)
    if fmt == "csv":
        for k, v in meta.items():
            if "\n" in k or "\n" in str(v) or ":" in k:
                raise ValueError(f"metadata key {k!r} or its value cannot go in a CSV comment")
        names = list(signal)
        with atomic_open(p, "w", newline="") as fh:
            for k, v in meta.items():
                fh.write(f"# {k}: {v}\n")
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(names)
            cols = [signal[n] for n in names]
            for i in range(signal.n_samples):
                writer.writerow([repr(float(c[i])) for c in cols])
        return
    buf = io.BytesIO()
    arrays: dict[str, Any] = {n: np.asarray(signal[n]) for n in signal}
    arrays[_META_KEY] = np.array(json.dumps(meta))
    np.savez(buf, **arrays)  # type: ignore[arg-type]
    with atomic_open(p, "wb") as fh:
        fh.write(buf.getvalue())
