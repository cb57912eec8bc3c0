"""JPK (Bruker) images, ``.jpk`` and ``.jpk-qi-image``, through AFMReader.

A JPK image is a TIFF: page 0 a thumbnail with the scan's tags, then one page per channel
and direction (tag ``0x8050`` the channel's name, ``0x8051`` 0 for trace, 1 for retrace).
AFMReader (``AFMReader.jpk.load_jpk``) reads one page and applies the calibration of its
default slot; it converts ``height`` and ``measuredHeight`` from m to nm. It gives no channel
list, no size along the slow axis, no times and flips the rows by default (top row first,
for drawing): this module reads the page list and the scan's tags with tifffile (AFMReader's
own dependency), and asks AFMReader for the unflipped image, which is upright (row 0 at the
bottom: the thumbnail of a QI image, drawn top row first by JPK's software, is the stored
image upside down). A retrace page is stored left to right already (it matches the trace
unflipped, correlation 0.996 on the real test file). Tags read: grid lengths
``0x8042``/``0x8043`` (m), pixels ``0x8046``/``0x8047``, the grid's angle ``0x8044``, the
line rate ``0x8049`` (Hz; 256 lines at 4 Hz are the 64 s between the start and end times
of the real test file), start and end times ``0x8003``/``0x8006`` and the slow-axis direction
``0x804B`` (``bottomUp``/``topDown``).
"""

from __future__ import annotations

import datetime as dt
import gc
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp.io.afm_scan import AfmFileError, AfmScan, import_reader, pick_channel

__all__ = ["JPK_LENGTH_CHANNELS", "read_jpk"]

JPK_LENGTH_CHANNELS = ("height", "measuredHeight")
"""Channels AFMReader returns in nm (it also scales ``amplitude`` by 1e9, which is not a
height)."""

TAG_START, TAG_END = 32771, 32774
TAG_ULENGTH, TAG_VLENGTH, TAG_THETA = 32834, 32835, 32836
TAG_ILENGTH, TAG_JLENGTH = 32838, 32839
TAG_LINE_RATE, TAG_SLOW_DIRECTION = 32841, 32843
TAG_CHANNEL, TAG_RETRACE = 32848, 32849


def _tag(page: Any, code: int) -> Any:
    tag = page.tags.get(code)
    return None if tag is None else tag.value


def _when(text: Any) -> dt.datetime | None:
    """``2017-01-16 16:00:32.334 GMT`` as a datetime (the zone's name dropped)."""
    if not isinstance(text, str):
        return None
    parts = text.split()
    try:
        return dt.datetime.strptime(" ".join(parts[:2]), "%Y-%m-%d %H:%M:%S.%f")
    except ValueError:
        return None


def read_jpk(path: Path, channel: str | None) -> AfmScan:
    """Read one channel (trace and retrace) of a JPK ``.jpk`` or ``.jpk-qi-image`` file.

    Parameters
    ----------
    path : Path
        The file.
    channel : str or None
        ``height`` (the default when present) or ``measuredHeight`` (case-insensitive).

    Returns
    -------
    AfmScan
        Upright, in nm; ``line_time_s`` from the line rate, ``started_at`` and
        ``acquisition_s`` from the start and end times when the file has them.
    """
    source = str(path)
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic not in (b"II*\x00", b"MM\x00*"):
        raise AfmFileError(f"{source}: not a JPK image (not a TIFF file)")
    tifffile = import_reader("tifffile", "tifffile", source)
    jpk = import_reader("AFMReader.jpk", "AFMReader", source)
    with tifffile.TiffFile(path) as tif:
        pages = list(tif.pages)
        if len(pages) < 2:
            raise AfmFileError(f"{source}: a JPK image holds no channel (thumbnail only)")
        head = pages[0]
        found: dict[str, dict[str, int]] = {}
        for i, page in enumerate(pages[1:], start=1):
            name = _tag(page, TAG_CHANNEL)
            if name is None:
                raise AfmFileError(f"{source}: page {i} has no JPK channel name (tag 0x8050)")
            direction = "retrace" if _tag(page, TAG_RETRACE) == 1 else "trace"
            # AFMReader keeps the last page of a name (a QI file holds measuredHeight twice)
            found.setdefault(str(name), {})[direction] = i
        u, v = _tag(head, TAG_ULENGTH), _tag(head, TAG_VLENGTH)
        ni, nj = _tag(head, TAG_ILENGTH), _tag(head, TAG_JLENGTH)
        theta = _tag(head, TAG_THETA)
        rate = _tag(head, TAG_LINE_RATE)
        slow = _tag(head, TAG_SLOW_DIRECTION)
        start, end = _when(_tag(head, TAG_START)), _when(_tag(head, TAG_END))
        shape = pages[1].shape
    names = [n for n, d in found.items() if "trace" in d]
    name = pick_channel(names or list(found), channel, source)
    if name not in JPK_LENGTH_CHANNELS:
        raise AfmFileError(
            f"{source}: channel {name!r} is not a height in nm (the JPK channels read: "
            f"{', '.join(c for c in JPK_LENGTH_CHANNELS if c in found) or 'none in this file'})"
        )
    if None in (u, v, ni, nj):
        raise AfmFileError(f"{source}: the thumbnail page lacks the grid's lengths or pixels")
    ni, nj = int(ni), int(nj)
    if tuple(shape) != (nj, ni):
        raise AfmFileError(f"{source}: pages of shape {tuple(shape)}, the grid says {(nj, ni)}")

    def image(direction: str) -> np.ndarray[Any, Any] | None:
        if direction not in found[name]:
            return None
        with warnings.catch_warnings():
            # load_jpk leaves its TiffFile open (AFMReader 0.0.7): collected here, quietly
            warnings.simplefilter("ignore", ResourceWarning)
            img, _ = jpk.load_jpk(path, f"{name}_{direction}", flip_image=False)
            gc.collect()
        img = np.asarray(img, dtype=float)
        if not np.any(np.isfinite(img)):
            raise AfmFileError(f"{source}: channel {name!r} ({direction}) is empty")
        return img

    line_time = None
    if isinstance(rate, int | float) and math.isfinite(rate) and rate > 0:
        line_time = 1.0 / float(rate)
    acq = None
    if start is not None and end is not None and end > start:
        acq = (end - start).total_seconds()
    meta: dict[str, Any] = {
        "format": "JPK tiff",
        "channels": list(found),
        "grid_angle_deg": math.degrees(float(theta)) if theta is not None else None,
    }
    slow_direction = {"bottomUp": "up", "topDown": "down"}.get(str(slow)) if slow else None
    return AfmScan(
        forward_nm=image("trace"),
        backward_nm=image("retrace"),
        size_nm=(float(u) * 1e9, float(v) * 1e9),
        line_time_s=line_time,
        channel=name,
        source=source,
        metadata=meta,
        slow_direction=slow_direction,
        started_at=start,
        acquisition_s=acq,
    )
