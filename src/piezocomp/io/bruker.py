"""Bruker (Digital Instruments) Nanoscope files (``.spm``, ``.000``...), through pySPM."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp.io.afm_scan import (
    AfmFileError,
    AfmScan,
    import_reader,
    pick_channel,
    to_nm,
)

__all__ = ["read_bruker"]


HEADER_MAX_BYTES = 4 << 20
"""Longest text header read from a Nanoscope file (real ones hold tens of kB)."""


def read_bruker(path: Path, channel: str | None) -> AfmScan:
    source = str(path)
    with open(path, "rb") as fh:
        head = fh.read(HEADER_MAX_BYTES)
    if not head.lstrip(b"\\").startswith(b"*File list"):
        raise AfmFileError(f"{source}: not a Bruker Nanoscope file (no '*File list' header)")
    # pySPM reads lines until this one, past the end of the file if it is missing
    if not any(_is_header_end(line) for line in head.split(b"\n")):
        raise AfmFileError(
            f"{source}: no '*File list end' line in its first {len(head)} "
            "bytes (truncated, or not a Nanoscope file)"
        )
    bruker_mod = import_reader("pySPM.Bruker", "pySPM", source)
    bruker = bruker_mod.Bruker(source)
    names: list[str] = []
    for layer in bruker.layers:
        raw = layer.get(b"@2:Image Data")
        if not raw:
            continue
        m = re.match(r'([^ ]+) \[([^]]*)] "([^"]*)"', raw[0].decode("latin1"))
        if m and m.group(3) not in names:
            names.append(m.group(3))
    name = pick_channel(names, channel, source)
    size = path.stat().st_size
    directions = set()
    for lay in bruker.layers:
        raw = lay.get(b"@2:Image Data")
        if not raw or f'"{name}"' not in raw[0].decode("latin1"):
            continue
        directions.add((lay.get(b"Line Direction") or [b"Trace"])[0].decode("latin1"))
        try:
            end = int(lay[b"Data offset"][0]) + int(lay[b"Data length"][0])
        except (KeyError, ValueError, IndexError):
            raise AfmFileError(f"{source}: channel {name!r} lacks its data offset/length") from None
        if end > size:
            raise AfmFileError(
                f"{source}: truncated: channel {name!r} needs {end} bytes, the file has {size}"
            )
    fw_img = bruker.get_channel(name, backward=False, lazy=False)
    has_retrace = "Retrace" in directions
    bw_img = bruker.get_channel(name, backward=True, lazy=False) if has_retrace else None
    z_scale = to_nm(str(fw_img.zscale), what=f"channel {name!r}", source=source)
    layer = next(
        lay
        for lay in bruker.layers
        if lay.get(b"@2:Image Data") and f'"{name}"' in lay[b"@2:Image Data"][0].decode("latin1")
    )
    lines = int(layer[b"Number of lines"][0])
    samps = int(layer[b"Samps/line"][0])
    size_field = layer[b"Scan Size"][0].split()
    unit = size_field[2].decode("latin1") if len(size_field) > 2 else "nm"
    unit = "um" if unit.startswith("~") else unit
    xy_scale = to_nm(unit, what="scan size", source=source)

    def image(img: Any) -> NDArray[np.float64]:
        # pySPM reshapes (samples, lines); the file stores one line after the other.
        flat = np.asarray(img.pixels, dtype=float).ravel()
        if flat.size != lines * samps:
            raise AfmFileError(
                f"{source}: channel {name!r} holds {flat.size} values, header says "
                f"{lines} lines x {samps} samples"
            )
        return flat.reshape(lines, samps) * z_scale

    fw = image(fw_img)
    bw = None if bw_img is None else image(bw_img)
    size_x = float(size_field[0]) * xy_scale
    # Square pixels unless the header's slow-axis size says otherwise.
    size_y = float(size_field[1]) * xy_scale * lines / samps if len(size_field) > 2 else size_x
    line_time = None
    for layer in bruker.layers:
        rate = layer.get(b"Scan Rate")
        if rate:
            try:
                hz = float(rate[0].split()[0])
                line_time = 1.0 / hz if hz > 0 else None
            except (ValueError, IndexError):
                line_time = None
            break
    return AfmScan(
        forward_nm=fw,
        backward_nm=bw,
        size_nm=(size_x, size_y),
        line_time_s=line_time,
        channel=name,
        source=source,
        metadata={"format": "Bruker Nanoscope", "channels": names},
    )


def _is_header_end(line: bytes) -> bool:
    """The line that ends a Nanoscope header, as pySPM recognises it."""
    return line.rstrip().replace(b"\\", b"") == b"*File list end"
