"""An AFM image as read from a vendor's file, in nm, and what the readers share.

:class:`AfmScan` holds one channel's forward and backward traces with the scan geometry;
the readers of :mod:`piezocomp.io.afm_files` (and :mod:`piezocomp.io.bruker`) build it.
Errors are :class:`AfmFileError` (a file that cannot be read as claimed) and
:class:`MissingReaderError` (the optional reader library is not installed).
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp._validation import as_finite_array

__all__ = [
    "AfmFileError",
    "AfmScan",
    "MissingReaderError",
    "decode",
    "import_reader",
    "parse_note",
    "pick_channel",
    "split_direction",
    "to_nm",
    "vendor_log",
]

_LENGTH_TO_NM = {
    "m": 1e9,
    "mm": 1e6,
    "um": 1e3,
    "µm": 1e3,
    "μm": 1e3,
    "~m": 1e3,
    "nm": 1.0,
    "pm": 1e-3,
    "a": 0.1,
    "å": 0.1,
}


_HEIGHT_CHANNELS = ("z-axis", "topography", "height", "heighttrace", "height sensor", "zsensor")


class AfmFileError(ValueError):
    """A file that cannot be read as an AFM image (corrupt, truncated, unsupported, no data)."""


class MissingReaderError(AfmFileError):
    """The optional package that reads this format is not installed."""


class _Collect(logging.Handler):
    def __init__(self, records: list[str]) -> None:
        super().__init__(logging.DEBUG)
        self.records = records

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):
            self.records.append(record.getMessage())


@contextlib.contextmanager
def vendor_log() -> Iterator[list[str]]:
    """Collect what the vendor readers log during the block instead of printing it
    (igor2 logs the raw bytes of a truncated wave); yields the messages."""
    records: list[str] = []
    handler = _Collect(records)
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        yield records
    finally:
        root.removeHandler(handler)


def to_nm(unit: str, *, what: str, source: str) -> float:
    key = unit.strip().lower()
    if key in _LENGTH_TO_NM:
        return _LENGTH_TO_NM[key]
    raise AfmFileError(f"{source}: {what} is in {unit!r}, not a length unit (expected m or nm)")


def import_reader(module: str, package: str, source: str, doing: str = "reading") -> Any:
    """The module that reads (or, ``doing="writing"``, writes) a file format, or a clear
    error naming the package to install."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingReaderError(
            f"{source}: {doing} this format needs the optional package {package!r} "
            f"({exc}); install it with: pip install {package}, or the readers of every "
            "format from piezocomp's folder: pip install '.[files]'"
        ) from None


@dataclass(frozen=True)
class AfmScan:
    """One channel of an AFM image, forward and backward traces, in nm.

    Attributes
    ----------
    forward_nm : ndarray, shape (ny, nx)
        Forward (trace) image (nm); row ``i`` is scan line ``i``, column ``j`` the ``j``-th pixel
        along the fast axis in the forward direction.
    backward_nm : ndarray, shape (ny, nx) or None
        Backward (retrace) image (nm), stored left to right like ``forward_nm`` (column ``j`` is
        the same command as in ``forward_nm``); None if the file has no retrace.
    size_nm : tuple of float
        Scan size ``(x, y)`` (nm).
    pixel_nm : tuple of float
        Pixel size ``(x, y)`` (nm): ``size / (n - 1)`` is not used; ``size / n`` is, as vendors do.
    line_time_s : float or None
        Time for one scan line as recorded by the instrument (s); None if unknown.
    channel : str
        Channel name as in the file.
    source : str
        Path of the file read.
    metadata : dict
        Vendor-specific extras (strings and numbers).
    """

    forward_nm: NDArray[np.float64]
    backward_nm: NDArray[np.float64] | None
    size_nm: tuple[float, float]
    pixel_nm: tuple[float, float] = field(default=(math.nan, math.nan))
    line_time_s: float | None = None
    channel: str = "height"
    source: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        fw = as_finite_array("forward_nm", self.forward_nm, ndim=2)
        if fw.shape[0] < 1 or fw.shape[1] < 2:
            raise ValueError(f"forward_nm must have at least 1 x 2 pixels. Got {fw.shape}.")
        fw = fw.copy()
        fw.setflags(write=False)
        object.__setattr__(self, "forward_nm", fw)
        if self.backward_nm is not None:
            bw = as_finite_array("backward_nm", self.backward_nm, ndim=2)
            if bw.shape != fw.shape:
                raise ValueError(
                    f"backward_nm must have the shape of forward_nm {fw.shape}. Got {bw.shape}."
                )
            bw = bw.copy()
            bw.setflags(write=False)
            object.__setattr__(self, "backward_nm", bw)
        size = tuple(float(v) for v in self.size_nm)
        if len(size) != 2 or not all(math.isfinite(v) and v > 0 for v in size):
            raise ValueError(f"size_nm must be two finite lengths > 0. Got {self.size_nm!r}.")
        object.__setattr__(self, "size_nm", size)
        ny, nx = fw.shape
        pixel = tuple(float(v) for v in self.pixel_nm)
        if len(pixel) != 2:
            raise ValueError(f"pixel_nm must have two entries. Got {self.pixel_nm!r}.")
        if not all(math.isfinite(v) for v in pixel):
            pixel = (size[0] / nx, size[1] / ny)
        if not all(v > 0 for v in pixel):
            raise ValueError(f"pixel_nm must be > 0. Got {pixel!r}.")
        object.__setattr__(self, "pixel_nm", pixel)
        if self.line_time_s is not None:
            lt = float(self.line_time_s)
            if not (math.isfinite(lt) and lt > 0):
                lt_msg = f"line_time_s must be finite and > 0 or None. Got {self.line_time_s!r}."
                raise ValueError(lt_msg)
            object.__setattr__(self, "line_time_s", lt)
        object.__setattr__(self, "channel", str(self.channel))
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "metadata", dict(self.metadata))

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: lines and pixels per line."""
        return (int(self.forward_nm.shape[0]), int(self.forward_nm.shape[1]))

    @property
    def x_nm(self) -> NDArray[np.float64]:
        """Nominal fast-axis position of each column (nm), from 0."""
        return np.arange(self.shape[1], dtype=np.float64) * self.pixel_nm[0]


def pick_channel(available: list[str], channel: str | None, source: str) -> str:
    if not available:
        raise AfmFileError(f"{source}: the file holds no image channel")
    if channel is not None:
        for name in available:
            if name.lower() == channel.lower():
                return name
        raise AfmFileError(f"{source}: no channel {channel!r}; available: {', '.join(available)}")
    for wanted in _HEIGHT_CHANNELS:
        for name in available:
            if name.lower() == wanted:
                return name
    return available[0]


_DIRECTION = re.compile(
    r"^(?P<base>.*?)[\s_\-]*[\(\[]?(?P<dir>forward|backward|trace|retrace|fwd|bwd)[\)\]]?\s*$",
    re.IGNORECASE,
)


def split_direction(title: str) -> tuple[str, str]:
    m = _DIRECTION.match(title.strip())
    if m is None:
        return title.strip(), "forward"
    d = m.group("dir").lower()
    direction = "backward" if d in ("backward", "retrace", "bwd") else "forward"
    return m.group("base").strip() or title.strip(), direction


def decode(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("latin-1").strip("\x00").strip()
    if isinstance(value, np.ndarray):
        return "".join(decode(v) for v in value.ravel().tolist())
    if isinstance(value, list | tuple):
        return "".join(decode(v) for v in value)
    return str(value).strip()


def parse_note(note: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for line in re.split(r"[\r\n]+", note):
        if ":" in line:
            k, v = line.split(":", 1)
            out[k.strip()] = v.strip()
    return out
