"""High-speed AFM movies (``.asd``, RIBM/Kodera's format), through AFMReader.

AFMReader (``AFMReader.asd.load_asd``) decodes the header, the frames and the conversion of
the digitised heights to nm (analogue-digital range, Z piezo extension and gain). It returns
the frames and the header; this module makes an :class:`AfmScan` of each frame: the size
from the header's ``x_nm``/``y_nm``, the frame times from its record time and ``frame_time``
(frame ``k`` starts ``k`` frame times after the record time), the lines as AFMReader gives
them (the file does not say which way they were taken: ``slow_direction`` is None) and no
retrace (the format keeps one trace).
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp.io.afm_scan import AfmFileError, AfmScan, import_reader, pick_channel

__all__ = ["ASD_LENGTH_CHANNELS", "read_asd"]

ASD_LENGTH_CHANNELS = {"TP": "topography"}
"""The ``.asd`` channels in lengths (AFMReader converts them to nm); ``ER`` (error) and
``PH`` (phase) are not."""


def read_asd(path: Path, channel: str | None) -> list[AfmScan]:
    """Every frame of an ``.asd`` movie as an :class:`AfmScan` (nm, times from the file).

    Parameters
    ----------
    path : Path
        The ``.asd`` file.
    channel : str or None
        ``TP`` (topography, the default) or the file's second channel if it is one.

    Returns
    -------
    list of AfmScan
        One per frame, ``source`` ``"<path>#<k>"``, ``started_at`` the record time plus ``k``
        frame times, ``acquisition_s`` and ``line_time_s`` from the frame time.
    """
    source = str(path)
    size = path.stat().st_size
    if size < 64:
        raise AfmFileError(f"{source}: truncated: {size} bytes cannot hold an .asd header")
    with open(path, "rb") as fh:
        version = int.from_bytes(fh.read(4), "little", signed=True)
    if version not in (0, 1, 2):
        raise AfmFileError(f"{source}: not an .asd movie (file version {version}, expected 0-2)")
    asd = import_reader("AFMReader.asd", "AFMReader", source)
    # The header first, for the channel names (load_asd raises on an unknown one).
    with open(path, "rb") as fh:
        asd.read_file_version(fh)
        reader = {
            0: asd.read_header_file_version_0,
            1: asd.read_header_file_version_1,
            2: asd.read_header_file_version_2,
        }[version]
        header: dict[str, Any] = reader(fh)
    names = [str(c) for c in (header.get("channel1"), header.get("channel2")) if c]
    name = pick_channel(names, channel, source)
    if name not in ASD_LENGTH_CHANNELS:
        raise AfmFileError(
            f"{source}: channel {name!r} is not a length (the length channel of an .asd "
            f"movie is {', '.join(ASD_LENGTH_CHANNELS)})"
        )
    n, nx, ny = int(header["num_frames"]), int(header["x_pixels"]), int(header["y_pixels"])
    need = int(header["header_length"]) + n * len(names) * (
        int(header["frame_header_length"]) + 2 * nx * ny
    )
    if n < 1 or nx < 2 or ny < 1:
        raise AfmFileError(f"{source}: the header announces {n} frames of {nx} x {ny} pixels")
    if size < need:
        raise AfmFileError(
            f"{source}: truncated: the header announces {n} frames of {nx} x {ny} pixels "
            f"({need} bytes), the file holds {size}"
        )
    frames, _, meta = asd.load_asd(path, name)
    frames = np.asarray(frames, dtype=float)
    if frames.shape != (n, ny, nx):
        raise AfmFileError(
            f"{source}: AFMReader returned frames of shape {frames.shape}, the header says "
            f"{(n, ny, nx)}"
        )
    frame_s = float(meta["frame_time"]) / 1000.0  # ms in the file
    try:
        y, mo, d, h, mi, sec = (
            int(meta[k]) for k in ("year", "month", "day", "hour", "minute", "second")
        )
        start: dt.datetime | None = dt.datetime(y, mo, d, h, mi, sec)
    except (KeyError, ValueError, TypeError):
        start = None
    size_nm = (float(meta["x_nm"]), float(meta["y_nm"]))
    extras = {
        "format": "high-speed AFM asd",
        "file_version": version,
        "frames": n,
        "frame_time_s": frame_s,
        "channels": names,
        "scan_direction_field": meta.get("scan_direction"),
    }
    scans = []
    for k in range(n):
        img = frames[k]
        if not np.all(np.isfinite(img)):
            raise AfmFileError(f"{source}: frame {k} holds values that are not finite")
        scans.append(
            AfmScan(
                forward_nm=img,
                backward_nm=None,
                size_nm=size_nm,
                line_time_s=frame_s / ny if frame_s > 0 else None,
                channel=name,
                source=f"{source}#{k}",
                metadata={**extras, "frame": k},
                started_at=None if start is None else start + dt.timedelta(seconds=k * frame_s),
                acquisition_s=frame_s if frame_s > 0 else None,
            )
        )
    return scans
