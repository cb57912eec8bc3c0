"""Nanonis ``.sxm`` files for the tests: parse a real file's layout and write variants of it.

No library writes ``.sxm``; the tests derive files from the real one of ``tests/data/afm_files``
(a crop, a scan direction, one channel, a truncation) by editing its text header and writing
its data back in the layout the header announces: after ``:SCANIT_END:`` and the bytes
``\\x1a\\x04``, every channel's forward then backward image (as ``DATA_INFO``'s ``Direction``
says), big-endian float32, lines in the order acquired, the backward lines right to left.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

DATA_DIR = Path(__file__).resolve().parent / "data" / "afm_files"
REAL_SXM = DATA_DIR / "STM_nanonis_generic_4_5.sxm"


def split_sxm(path):
    """``(blocks, data)``: the header as ``[(tag, text), ...]`` in file order and the raw data
    as ``{(channel, "forward"|"backward"): array (lines as stored)}``."""
    raw = Path(path).read_bytes()
    start = raw.index(b"\x1a\x04")
    head = raw[:start].decode("latin-1")
    blocks = []
    for chunk in head.split("\n:")[0:]:
        chunk = chunk.lstrip(":")
        tag, _, text = chunk.partition(":\n")
        blocks.append((tag, text))
    info = dict(blocks)["DATA_INFO"].strip("\n").split("\n")
    nx, ny = (int(v) for v in dict(blocks)["SCAN_PIXELS"].split())
    values = np.frombuffer(raw[start + 2 :], dtype=">f4")
    data, k = {}, 0
    for row in info[1:]:
        cols = row.strip().split("\t")
        name, direction = cols[1], cols[3]
        for d in ("forward", "backward"):
            if direction in (d, "both"):
                data[(name, d)] = values[k : k + nx * ny].reshape(ny, nx).astype(float)
                k += nx * ny
    return blocks, data


def write_sxm(path, blocks, data, **fields):
    """Write ``blocks`` (header, as :func:`split_sxm` gives it, with ``fields`` replacing the
    text of those tags) and ``data`` (the images of ``DATA_INFO``'s channels, in its order)."""
    blocks = [(tag, fields.get(tag, text)) for tag, text in blocks]
    head = ":" + "\n:".join(f"{tag}:\n{text}" for tag, text in blocks)
    info = dict(blocks)["DATA_INFO"].strip("\n").split("\n")
    parts = []
    for row in info[1:]:
        cols = row.strip().split("\t")
        for d in ("forward", "backward"):
            if cols[3] in (d, "both"):
                parts.append(np.asarray(data[(cols[1], d)], dtype=">f4").tobytes())
    Path(path).write_bytes(head.encode("latin-1") + b"\x1a\x04" + b"".join(parts))
    return Path(path)


def data_info(rows):
    """``DATA_INFO`` text for ``rows`` of (channel, unit, direction)."""
    lines = ["\tChannel\tName\tUnit\tDirection\tCalibration\tOffset"]
    lines += [f"\t{k}\t{n}\t{u}\t{d}\t1.000E+0\t0.000E+0" for k, (n, u, d) in enumerate(rows)]
    return "\n".join(lines) + "\n"


def crop_sxm(
    path, source, *, rows, cols, rec_time=None, scan_dir=None, channels=("Z",), direction=None
):
    """Write the crop ``[rows, cols]`` (slices, in the upright image: row 0 at the bottom) of
    ``source``'s ``channels`` as an ``.sxm`` taken in ``scan_dir`` (default: the source's),
    with the header's pixels, range, acquisition time and optionally ``rec_time`` updated;
    ``direction`` (``"forward"`` or ``"backward"``) keeps that trace only."""
    blocks, data = split_sxm(source)
    head = dict(blocks)
    src_dir = head["SCAN_DIR"].strip()
    out_dir = scan_dir or src_dir
    nx, ny = (int(v) for v in head["SCAN_PIXELS"].split())
    rx, ry = (float(v) for v in head["SCAN_RANGE"].split())
    info = [r.strip().split("\t") for r in head["DATA_INFO"].strip("\n").split("\n")[1:]]
    keep = [(c[1], c[2], c[3]) for c in info if c[1] in channels]
    if direction is not None:
        keep = [(n, u, direction) for n, u, _ in keep]
    out = {}
    for name, _, direction in keep:
        for d in ("forward", "backward"):
            if direction not in (d, "both"):
                continue
            img = data[(name, d)]
            up = img if src_dir == "up" else img[::-1]  # upright: row 0 at the bottom
            if d == "backward":
                up = up[:, ::-1]  # left to right
            cut = up[rows, cols]
            stored = cut if out_dir == "up" else cut[::-1]
            out[(name, d)] = stored[:, ::-1] if d == "backward" else stored
    any_img = next(iter(out.values()))
    my, mx = any_img.shape
    line_s = sum(float(v) for v in head["SCAN_TIME"].split())
    fields = {
        "SCAN_PIXELS": f"       {mx}       {my}",
        "SCAN_RANGE": f"           {rx * mx / nx:.6E}           {ry * my / ny:.6E}",
        "SCAN_DIR": out_dir,
        "ACQ_TIME": f"       {line_s * my:.1f}",
        "DATA_INFO": data_info(keep),
    }
    if rec_time is not None:
        fields["REC_TIME"] = rec_time
    return write_sxm(path, blocks, out, **fields)
