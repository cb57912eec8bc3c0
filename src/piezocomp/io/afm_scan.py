"""An AFM image as read from a vendor's file, in nm, and what the readers share.

:class:`AfmScan` holds one channel's forward and backward traces with the scan geometry;
the readers of :mod:`piezocomp.io.afm_files` (and :mod:`piezocomp.io.bruker`) build it.
Errors are :class:`AfmFileError` (a file that cannot be read as claimed) and
:class:`MissingReaderError` (the optional reader library is not installed).
"""

from __future__ import annotations

import contextlib
import datetime as dt
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
    "SLOW_DIRECTIONS",
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
    "å": 0.1,
    "angstrom": 0.1,
}
"""Length units (lower case) to nm. ``A`` is not among them: Nanonis writes the ampere so."""


_HEIGHT_CHANNELS = (
    "z-axis",
    "topography",
    "height",
    "heighttrace",
    "height sensor",
    "zsensor",
    "z",
    "measuredheight",
    "tp",
)

SLOW_DIRECTIONS = ("up", "down")
"""How the lines of an image were taken: ``"up"`` from the bottom of the area to its top,
``"down"`` from the top to the bottom."""


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
    error naming the package to install.

    AFMReader's modules log every step through loguru to the terminal; they are silenced
    (``loguru.logger.disable("AFMReader")``) once imported."""
    try:
        mod = importlib.import_module(module)
        if module.split(".")[0] == "AFMReader":
            importlib.import_module("loguru").logger.disable("AFMReader")
        return mod
    except ImportError as exc:
        raise MissingReaderError(
            f"{source}: {doing} this format needs the optional package {package!r} "
            f"({exc}); install it with: pip install {package}, or the readers of every "
            "format from piezocomp's folder: pip install '.[files]'"
        ) from None


@dataclass(frozen=True)
class AfmScan:
    """One channel of an AFM image, forward and backward traces, in nm.

    Images are upright: row 0 is the bottom of the scanned area (its lowest y), column 0 its
    left edge (the start of a forward line), as the image is drawn with its origin at the
    lower left. A reader flips the rows of a file that stores the top row first (a Nanonis
    image taken downwards, Gwyddion's fields); ``slow_direction`` says in which order the
    lines were taken.

    Attributes
    ----------
    forward_nm : ndarray, shape (ny, nx) or None
        Forward (trace) image (nm); None if the file holds the retrace only.
    backward_nm : ndarray, shape (ny, nx) or None
        Backward (retrace) image (nm), stored left to right like ``forward_nm`` (column ``j`` is
        the same command as in ``forward_nm``); None if the file has no retrace.
    size_nm : tuple of float
        Scan size ``(x, y)`` (nm).
    pixel_nm : tuple of float
        Pixel size ``(x, y)`` (nm): ``size / (n - 1)`` is not used; ``size / n`` is, as vendors do.
    line_time_s : float or None
        Time for one scan line, trace and retrace, as recorded by the instrument (s); None if
        unknown.
    channel : str
        Channel name as in the file.
    source : str
        Path of the file read (with ``#frame`` for a frame of a movie).
    metadata : dict
        Vendor-specific extras (strings and numbers).
    slow_direction : {"up", "down"} or None
        The order in which the lines were taken (:data:`SLOW_DIRECTIONS`); None if the file
        does not say.
    started_at : datetime.datetime or None
        When the image started, in the instrument's clock as the file states it (no time
        zone); None if the file does not say.
    acquisition_s : float or None
        How long the image took (s), as the file states it; None if it does not.
    """

    forward_nm: NDArray[np.float64] | None
    backward_nm: NDArray[np.float64] | None
    size_nm: tuple[float, float]
    pixel_nm: tuple[float, float] = field(default=(math.nan, math.nan))
    line_time_s: float | None = None
    channel: str = "height"
    source: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)
    slow_direction: str | None = None
    started_at: dt.datetime | None = None
    acquisition_s: float | None = None

    def __post_init__(self) -> None:
        if self.forward_nm is None and self.backward_nm is None:
            raise ValueError("an AfmScan needs forward_nm or backward_nm (or both).")
        shape = None
        for name in ("forward_nm", "backward_nm"):
            value = getattr(self, name)
            if value is None:
                continue
            img = as_finite_array(name, value, ndim=2)
            if shape is None and (img.shape[0] < 1 or img.shape[1] < 2):
                raise ValueError(f"{name} must have at least 1 x 2 pixels. Got {img.shape}.")
            if shape is not None and img.shape != shape:
                raise ValueError(
                    f"backward_nm must have the shape of forward_nm {shape}. Got {img.shape}."
                )
            shape = img.shape
            img = img.copy()
            img.setflags(write=False)
            object.__setattr__(self, name, img)
        fw = self.image_nm
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
        if self.slow_direction is not None and self.slow_direction not in SLOW_DIRECTIONS:
            raise ValueError(
                f"slow_direction must be one of {SLOW_DIRECTIONS} or None. "
                f"Got {self.slow_direction!r}."
            )
        if self.started_at is not None and not isinstance(self.started_at, dt.datetime):
            raise ValueError(f"started_at must be a datetime or None. Got {self.started_at!r}.")
        if self.acquisition_s is not None:
            acq = float(self.acquisition_s)
            if not (math.isfinite(acq) and acq > 0):
                raise ValueError(
                    f"acquisition_s must be finite and > 0 or None. Got {self.acquisition_s!r}."
                )
            object.__setattr__(self, "acquisition_s", acq)

    @property
    def image_nm(self) -> NDArray[np.float64]:
        """The forward image, or the backward one for a file that holds the retrace only."""
        img = self.forward_nm if self.forward_nm is not None else self.backward_nm
        assert img is not None  # __post_init__ requires one of them
        return img

    @property
    def trace(self) -> str:
        """Which trace :attr:`image_nm` is: ``"forward"`` or ``"backward"``."""
        return "forward" if self.forward_nm is not None else "backward"

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: lines and pixels per line."""
        return (int(self.image_nm.shape[0]), int(self.image_nm.shape[1]))

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
