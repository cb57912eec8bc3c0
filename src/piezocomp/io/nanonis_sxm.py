"""Nanonis ``.sxm`` images, through pySPM (``pySPM.SXM``).

The file is a text header (``:TAG:`` lines) ended by ``:SCANIT_END:`` and the bytes
``\\x1a\\x04``, then every channel's images one after the other as ``DATA_INFO`` lists them
(forward then backward for a channel recorded in ``both`` directions), big-endian float32.
The lines are stored in the order taken and a backward line right to left (as Gwyddion's
``nanonis.c`` reads them: it flips an ``up`` image's rows and a backward image's columns to
draw them top row first). pySPM reads one channel and direction as stored; this module
checks the file before pySPM sees it (pySPM loops forever on a header without
``:SCANIT_END:`` or ``\\x1a\\x04``), turns the image upright (row 0 at the bottom: rows
flipped for a scan taken ``down``), the backward image left to right, the values into nm, and
takes the times from the header: ``REC_DATE``/``REC_TIME`` (when the image started),
``ACQ_TIME`` (how long it took) and ``SCAN_TIME`` (forward and backward line times).
"""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp.io.afm_scan import AfmFileError, AfmScan, import_reader, pick_channel, to_nm

__all__ = ["read_sxm", "sxm_header"]

MAGIC = b":NANONIS_VERSION:"
HEADER_END = b":SCANIT_END:"
DATA_START = b"\x1a\x04"


def sxm_header(path: Path) -> tuple[dict[str, str], int]:
    """The header's tags (text, stripped) and the offset of the data, checked.

    Raises
    ------
    AfmFileError
        Not an ``.sxm`` file, a header cut short, or no data marker.
    """
    source = str(path)
    raw = path.read_bytes()
    if not raw.startswith(MAGIC):
        raise AfmFileError(f"{source}: not a Nanonis .sxm file (no {MAGIC.decode()} header)")
    end = raw.find(HEADER_END)
    if end < 0:
        raise AfmFileError(f"{source}: truncated: the header has no {HEADER_END.decode()} line")
    start = raw.find(DATA_START, end)
    if start < 0:
        raise AfmFileError(f"{source}: truncated: no data after the header (no \\x1a\\x04 mark)")
    tags: dict[str, str] = {}
    key = None
    lines: list[str] = []
    for line in raw[:end].decode("latin-1").split("\n"):
        if line.startswith(":") and line.endswith(":") and len(line) > 1:
            if key is not None:
                tags[key] = "\n".join(lines).strip()
            key, lines = line[1:-1], []
        else:
            lines.append(line)
    if key is not None:
        tags[key] = "\n".join(lines).strip()
    return tags, start + len(DATA_START)


def _channels(tags: dict[str, str], source: str) -> list[tuple[str, str, str]]:
    """``DATA_INFO``: (name, unit, direction) of each channel, in the file's order."""
    rows = [r.split("\t") for r in tags.get("DATA_INFO", "").split("\n")]
    rows = [[c.strip() for c in r if c.strip()] for r in rows]
    if not rows or rows[0][:4] != ["Channel", "Name", "Unit", "Direction"]:
        raise AfmFileError(f"{source}: the header has no DATA_INFO table of channels")
    out = []
    for r in rows[1:]:
        if len(r) < 4 or r[3] not in ("both", "forward", "backward"):
            raise AfmFileError(f"{source}: DATA_INFO row {' '.join(r)!r} is not understood")
        out.append((r[1], r[2], r[3]))
    return out


def _numbers(tags: dict[str, str], key: str, count: int, source: str) -> list[float]:
    try:
        values = [float(v) for v in tags[key].split()]
    except KeyError:
        raise AfmFileError(f"{source}: the header has no {key}") from None
    except ValueError:
        raise AfmFileError(f"{source}: {key} {tags[key]!r} is not {count} numbers") from None
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise AfmFileError(f"{source}: {key} {tags[key]!r} is not {count} finite numbers")
    return values


def _started_at(tags: dict[str, str]) -> dt.datetime | None:
    try:
        return dt.datetime.strptime(
            f"{tags['REC_DATE'].strip()} {tags['REC_TIME'].strip()}", "%d.%m.%Y %H:%M:%S"
        )
    except (KeyError, ValueError):
        return None


def read_sxm(path: Path, channel: str | None) -> AfmScan:
    """Read one channel (forward and backward) of a Nanonis ``.sxm`` image, upright, in nm.

    Parameters
    ----------
    path : Path
        The ``.sxm`` file.
    channel : str or None
        Channel name as in ``DATA_INFO`` (case-insensitive); default ``Z``.

    Returns
    -------
    AfmScan
        With ``slow_direction`` (``SCAN_DIR``), ``started_at`` (``REC_DATE`` ``REC_TIME``),
        ``acquisition_s`` (``ACQ_TIME``), ``line_time_s`` (the two ``SCAN_TIME`` values
        added) and in ``metadata`` the scan angle and offset.
    """
    source = str(path)
    tags, data_at = sxm_header(path)
    channels = _channels(tags, source)
    nx_f, ny_f = _numbers(tags, "SCAN_PIXELS", 2, source)
    nx, ny = int(nx_f), int(ny_f)
    if nx < 2 or ny < 1:
        raise AfmFileError(f"{source}: SCAN_PIXELS {nx} x {ny} holds no image")
    kind = tags.get("SCANIT_TYPE", "").split()
    if kind != ["FLOAT", "MSBFIRST"]:
        raise AfmFileError(
            f"{source}: SCANIT_TYPE {' '.join(kind) or '(missing)'} is not supported "
            "(FLOAT MSBFIRST is what Nanonis writes)"
        )
    images = sum(2 if d == "both" else 1 for _, _, d in channels)
    need = images * nx * ny * 4
    have = path.stat().st_size - data_at
    if have < need:
        raise AfmFileError(
            f"{source}: truncated: the header announces {images} images of {nx} x {ny} "
            f"pixels ({need} bytes), the file holds {have}"
        )
    names = [n for n, _, _ in channels]
    name = pick_channel(names, channel, source)
    _, unit, direction = channels[names.index(name)]
    z_scale = to_nm(unit, what=f"channel {name!r}", source=source)
    scan_dir = tags.get("SCAN_DIR", "").strip().lower()
    if scan_dir not in ("up", "down"):
        raise AfmFileError(f"{source}: SCAN_DIR {scan_dir!r} is neither 'up' nor 'down'")
    sxm_mod = import_reader("pySPM.SXM", "pySPM", source)
    sxm = sxm_mod.SXM(source)

    def image(which: str) -> np.ndarray[Any, Any]:
        img = np.asarray(sxm.get_channel(name, direction=which).pixels, dtype=float)
        if img.shape != (ny, nx):
            raise AfmFileError(
                f"{source}: channel {name!r} has shape {img.shape}, header says {(ny, nx)}"
            )
        if scan_dir == "down":  # stored top line first: upright puts the bottom line first
            img = img[::-1]
        if which == "backward":  # stored right to left, as taken
            img = img[:, ::-1]
        bad = ~np.isfinite(img)
        if bad.all():
            raise AfmFileError(
                f"{source}: channel {name!r} ({which}) is empty (no finite value: the scan "
                "stopped before its first line?)"
            )
        if bad.any():
            lines = int(np.any(bad, axis=1).sum())
            raise AfmFileError(
                f"{source}: channel {name!r} ({which}) has {lines} of {ny} lines without data "
                "(a scan stopped early?); crop the image to its complete lines first"
            )
        return img * z_scale

    fw = image("forward") if direction in ("both", "forward") else None
    bw = image("backward") if direction in ("both", "backward") else None
    size_x, size_y = _numbers(tags, "SCAN_RANGE", 2, source)
    line_time = None
    if "SCAN_TIME" in tags:
        t_fwd, t_bwd = _numbers(tags, "SCAN_TIME", 2, source)
        line_time = t_fwd + t_bwd if t_fwd + t_bwd > 0 else None
    acq = None
    if "ACQ_TIME" in tags:
        (acq,) = _numbers(tags, "ACQ_TIME", 1, source)
        acq = acq if acq > 0 else None
    meta: dict[str, Any] = {"format": "Nanonis sxm", "z_unit": unit, "channels": names}
    for key in ("SCAN_ANGLE", "SCAN_OFFSET", "BIAS", "SCAN_FILE"):
        if key in tags:
            meta[key.lower()] = tags[key]
    return AfmScan(
        forward_nm=fw,
        backward_nm=bw,
        size_nm=(size_x * 1e9, size_y * 1e9),
        line_time_s=line_time,
        channel=name,
        source=source,
        metadata=meta,
        slow_direction=scan_dir,
        started_at=_started_at(tags),
        acquisition_s=acq,
    )
