"""Real AFM image files: one structure for every vendor, read through the ecosystem's readers.

Supported (optional extras, ``pip install '.[files]'`` in piezocomp's folder):

========================  ==================================  ==================================
Format                    Suffix                              Reader
========================  ==================================  ==================================
Nanosurf                  ``.nid``                            NSFopen
Gwyddion                  ``.gwy``                            gwyfile (also :func:`write_gwy`)
Asylum Research / Igor    ``.ibw``                            igor2
Bruker Nanoscope          ``.spm``, ``.000``-``.999``         pySPM
Nanonis                   ``.sxm``                            pySPM (:mod:`.nanonis_sxm`)
JPK                       ``.jpk``, ``.jpk-qi-image``         AFMReader (:mod:`.jpk`)
High-speed AFM movie      ``.asd``                            AFMReader (:mod:`.hs_afm`)
========================  ==================================  ==================================

Every reader returns an :class:`AfmScan`: forward and backward (retrace) images in nm, the
backward one stored left to right like the forward one, upright (row 0 at the bottom of the
area), scan size and pixel size in nm and the line time in s when the file records it, and
when the image started and how long it took when the file says. :func:`read_series` reads a
series of images of one area: files, folders, glob patterns and movies (every frame of an
``.asd``).
"""

from __future__ import annotations

import glob
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp._atomic import atomic_open
from piezocomp._validation import one_line
from piezocomp.io.afm_scan import (
    AfmFileError,
    AfmScan,
    decode,
    import_reader,
    parse_note,
    pick_channel,
    split_direction,
    to_nm,
    vendor_log,
)
from piezocomp.io.bruker import read_bruker
from piezocomp.io.hs_afm import read_asd
from piezocomp.io.jpk import read_jpk
from piezocomp.io.nanonis_sxm import read_sxm

__all__ = ["SUFFIXES", "read_scan", "read_series", "write_gwy"]

SUFFIXES = (".nid", ".gwy", ".ibw", ".spm", ".000-.999", ".sxm", ".jpk", ".jpk-qi-image", ".asd")
"""The file types read (``.000-.999``: Bruker's numbered files)."""

MOVIE_SUFFIXES = (".asd",)
"""File types that hold a movie (many frames of one area)."""


def _suffix(p: Path) -> str:
    name = p.name.lower()
    return ".jpk-qi-image" if name.endswith(".jpk-qi-image") else p.suffix.lower()


def _supported(p: Path) -> bool:
    suffix = _suffix(p)
    return suffix in SUFFIXES or re.fullmatch(r"\.\d{3}", suffix) is not None


def _read(p: Path, channel: str | None) -> list[AfmScan]:
    """Every image of the file (one, or a movie's frames), errors as one line."""
    source = str(p)
    if not p.is_file():
        raise AfmFileError(f"{source}: no such file")
    suffix = _suffix(p)
    if suffix == ".nid":
        reader = _read_nid
    elif suffix == ".gwy":
        reader = _read_gwy
    elif suffix == ".ibw":
        reader = _read_ibw
    elif suffix == ".spm" or re.fullmatch(r"\.\d{3}", suffix):
        reader = read_bruker
    elif suffix == ".sxm":
        reader = read_sxm
    elif suffix in (".jpk", ".jpk-qi-image"):
        reader = read_jpk
    elif suffix == ".asd":
        reader = None
    else:
        raise AfmFileError(
            f"{source}: unsupported file type {suffix or '(no suffix)'!r}; "
            f"supported: {', '.join(SUFFIXES)}"
        )
    try:
        with vendor_log():  # what they log on a corrupt file is not for the terminal
            if reader is None:
                return read_asd(p, channel)
            return [reader(p, channel)]
    except AfmFileError:
        raise
    except Exception as exc:  # vendor readers fail in many ways on corrupt files
        raise AfmFileError(
            f"{source}: cannot read as {suffix} file (corrupt or truncated?): "
            + one_line(f"{type(exc).__name__}: {exc}", 300)
        ) from exc


# ---------------------------------------------------------------------------------------------
# Dispatch
# ---------------------------------------------------------------------------------------------
def read_scan(
    path: str | os.PathLike[str], channel: str | None = None, *, frame: int | None = None
) -> AfmScan:
    """Read one channel (forward and backward) of an AFM image file.

    Parameters
    ----------
    path : path-like
        ``.nid`` (Nanosurf), ``.gwy`` (Gwyddion), ``.ibw`` (Asylum/Igor), ``.spm`` or a numbered
        suffix ``.000``... (Bruker Nanoscope), ``.sxm`` (Nanonis), ``.jpk`` or
        ``.jpk-qi-image`` (JPK), ``.asd`` (high-speed AFM movie: give ``frame``).
    channel : str, optional
        Channel name as in the file (case-insensitive). Default: the topography channel
        (``Z-Axis``, ``Topography``, ``Height``, ``Z``... whichever the file has first).
    frame : int, optional
        The frame of a movie (from 0); required for a movie; a single image is frame 0.

    Returns
    -------
    AfmScan

    Raises
    ------
    AfmFileError (a ValueError)
        Missing, corrupt, truncated or unsupported file, or no such channel; the message names
        the file and what was wrong. :class:`MissingReaderError` when the optional reader is
        not installed.
    """
    p = Path(path)
    scans = _read(p, channel)
    if frame is None:
        if len(scans) > 1:
            raise AfmFileError(
                f"{p}: a movie of {len(scans)} frames; give the frame to read (from 0: "
                "frame=, or loop's --frame), or read them all (read_series, drift --scans)"
            )
        return scans[0]
    if isinstance(frame, bool) or not isinstance(frame, int) or not 0 <= frame < len(scans):
        raise AfmFileError(f"{p}: frame {frame!r} does not exist (the file has {len(scans)})")
    return scans[frame]


def read_series(
    paths: str | os.PathLike[str] | list[str | os.PathLike[str]], channel: str | None = None
) -> list[AfmScan]:
    """A series of images of one area, in the order taken.

    Parameters
    ----------
    paths : path-like or list of them
        Each entry is a file (a movie gives all its frames), a folder (its files of the
        supported types, sorted by name) or a glob pattern (``frames/*.sxm``, matches sorted
        by name). The series keeps the order of the entries.
    channel : str, optional
        As in :func:`read_scan`.

    Raises
    ------
    AfmFileError
        An entry that matches nothing, a folder without images, or a file that cannot be read.
    """
    entries = [paths] if isinstance(paths, str | os.PathLike) else list(paths)
    files: list[Path] = []
    for entry in entries:
        p = Path(entry)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and _supported(f))
            if not found:
                raise AfmFileError(
                    f"{p}: a folder without AFM images (supported: {', '.join(SUFFIXES)})"
                )
            files += found
        elif not p.exists() and glob.has_magic(str(entry)):
            found = sorted(Path(f) for f in glob.glob(str(entry)) if Path(f).is_file())
            if not found:
                raise AfmFileError(f"{entry}: the pattern matches no file")
            files += found
        else:
            files.append(p)
    scans: list[AfmScan] = []
    for f in files:
        scans += _read(f, channel)
    return scans


# ---------------------------------------------------------------------------------------------
# Nanosurf .nid (NSFopen)
# ---------------------------------------------------------------------------------------------
def _read_nid(path: Path, channel: str | None) -> AfmScan:
    source = str(path)
    with open(path, "rb") as fh:
        head = fh.read(64)
    if not head.startswith(b"[DataSet]"):
        raise AfmFileError(f"{source}: not a Nanosurf .nid file (no [DataSet] header)")
    _check_nid_size(path)
    nsf = import_reader("NSFopen.read", "NSFopen", source)
    nid = nsf.nid_read(source, dataframe=False, verbose=False)
    images = (nid.data or {}).get("Image", {})
    forward = images.get("Forward", {})
    backward = images.get("Backward", {})
    name = pick_channel(list(forward), channel, source)
    header = nid.param["HeaderDump"]
    # The dataset section of this channel, for its units.
    unit_z, unit_x, unit_y = "m", "m", "m"
    for key, sect in header.items():
        if sect.get("Frame") == "Scan forward" and sect.get("Dim2Name") == name:
            unit_z = sect.get("Dim2Unit", "m")
            unit_x = sect.get("Dim0Unit", "m")
            unit_y = sect.get("Dim1Unit", "m")
            rng = (float(sect["Dim0Range"]), float(sect["Dim1Range"]))
            points, lines = int(sect["Points"]), int(sect["Lines"])
            section = key
            break
    else:
        raise AfmFileError(f"{source}: no 'Scan forward' dataset header for channel {name!r}")
    z_scale = to_nm(unit_z, what=f"channel {name!r}", source=source)
    fw = np.asarray(forward[name], dtype=float)
    if fw.shape != (lines, points):
        raise AfmFileError(
            f"{source}: channel {name!r} has shape {fw.shape}, header says {(lines, points)}"
        )
    bw = backward.get(name)
    bw_nm = None if bw is None else np.asarray(bw, dtype=float) * z_scale
    size = (
        rng[0] * to_nm(unit_x, what="x range", source=source),
        rng[1] * to_nm(unit_y, what="y range", source=source),
    )
    line_time = None
    scan = nid.param.get("Scan", {})
    try:
        t = float(scan["time/line"]["Value"][0])
        line_time = t if t > 0 else None
    except (KeyError, IndexError, TypeError, ValueError):
        line_time = None
    meta: dict[str, Any] = {"format": "Nanosurf nid", "dataset": section, "z_unit": unit_z}
    for key in ("offset", "rotation"):
        try:
            meta[f"scan_{key}"] = list(scan[key]["Value"])
            meta[f"scan_{key}_unit"] = list(scan[key]["Unit"])
        except (KeyError, TypeError):
            pass
    return AfmScan(
        forward_nm=fw * z_scale,
        backward_nm=bw_nm,
        size_nm=size,
        line_time_s=line_time,
        channel=name,
        source=source,
        metadata=meta,
    )


def _check_nid_size(path: Path) -> None:
    """Refuse a .nid whose binary part is shorter than its header announces.

    (NSFopen leaves the file open when it fails on a truncated file.)
    """
    raw = path.read_bytes()
    marker = raw.find(b"#!")
    if marker < 0:
        raise AfmFileError(f"{path}: no image data after the .nid header (truncated?)")
    sections: dict[str, dict[str, str]] = {}
    current: dict[str, str] = {}
    for line in raw[:marker].decode("latin-1").splitlines():
        line = line.strip()
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
        elif "=" in line:
            key, value = line.split("=", 1)
            current[key.strip()] = value.strip()
    datasets = [
        v for k, v in sections.get("DataSet", {}).items() if re.fullmatch(r"Gr\d+-Ch\d+", k)
    ]
    need = 0
    for name in datasets:
        sect = sections.get(name)
        if sect is None:
            raise AfmFileError(f"{path}: header lists dataset {name!r} but has no section for it")
        try:
            need += int(sect["Points"]) * int(sect["Lines"]) * int(sect["SaveBits"]) // 8
        except (KeyError, ValueError) as exc:
            raise AfmFileError(f"{path}: dataset {name!r} header lacks sizes ({exc})") from None
    have = len(raw) - marker - 2
    if have < need:
        raise AfmFileError(
            f"{path}: truncated: the header announces {need} bytes of image data, "
            f"the file holds {have}"
        )


# ---------------------------------------------------------------------------------------------
# Gwyddion .gwy (gwyfile)
# ---------------------------------------------------------------------------------------------


def _read_gwy(path: Path, channel: str | None) -> AfmScan:
    source = str(path)
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"GWYP":
        raise AfmFileError(f"{source}: not a Gwyddion .gwy file (no GWYP magic)")
    gwyfile = import_reader("gwyfile", "gwyfile", source)
    obj = gwyfile.load(source)
    fields = gwyfile.util.get_datafields(obj)
    groups: dict[str, dict[str, Any]] = {}
    for title, df in fields.items():
        base, direction = split_direction(str(title))
        groups.setdefault(base, {}).setdefault(direction, (str(title), df))
    names = [b for b, g in groups.items() if "forward" in g]
    name = pick_channel(names, channel, source)
    fw_title, fw_field = groups[name]["forward"]
    z_unit = _unitstr(fw_field.get("si_unit_z"))
    xy_unit = _unitstr(fw_field.get("si_unit_xy"))
    z_scale = to_nm(z_unit or "m", what=f"channel {fw_title!r}", source=source)
    xy_scale = to_nm(xy_unit or "m", what="lateral size", source=source)
    # Gwyddion's fields hold the top row first: upright puts the bottom row first
    fw = np.asarray(fw_field.data, dtype=float)[::-1] * z_scale
    bw = None
    if "backward" in groups[name]:
        bw = np.asarray(groups[name]["backward"][1].data, dtype=float)[::-1] * z_scale
    size = (float(fw_field["xreal"]) * xy_scale, float(fw_field["yreal"]) * xy_scale)
    meta: dict[str, Any] = {"format": "Gwyddion gwy", "title": fw_title}
    line_time = None
    for key, value in obj.items():
        if key.endswith("/meta") and isinstance(value, dict):
            for mk, mv in value.items():
                if isinstance(mv, str | int | float) and mk not in ("__name__",):
                    meta[f"meta:{mk}"] = mv
            lt = value.get("Line time (s)")
            if lt is not None:
                try:
                    line_time = float(lt)
                except ValueError:
                    line_time = None
    return AfmScan(
        forward_nm=fw,
        backward_nm=bw,
        size_nm=size,
        line_time_s=line_time,
        channel=name,
        source=source,
        metadata=meta,
    )


def _unitstr(unit: Any) -> str:
    if unit is None:
        return ""
    if isinstance(unit, dict):
        return str(unit.get("unitstr", ""))
    return str(getattr(unit, "unitstr", unit))


def write_gwy(path: str | os.PathLike[str], scan: AfmScan) -> None:
    """Write an :class:`AfmScan` as a Gwyddion ``.gwy`` file (atomically).

    The forward image becomes channel ``"<channel> (forward)"``, the backward one
    ``"<channel> (backward)"``; data in metres and top row first as Gwyddion expects.
    :func:`read_scan` reads it back. The line time, if known, is stored in the forward
    channel's metadata.
    """
    gwyfile = import_reader("gwyfile", "gwyfile", str(path), doing="writing")
    objects = gwyfile.objects
    container = objects.GwyContainer()
    images = [("forward", scan.forward_nm), ("backward", scan.backward_nm)]
    kept = [(direction, img) for direction, img in images if img is not None]
    for i, (direction, img) in enumerate(kept):
        df = objects.GwyDataField(
            np.ascontiguousarray(np.asarray(img, dtype=float)[::-1] * 1e-9),
            xreal=scan.size_nm[0] * 1e-9,
            yreal=scan.size_nm[1] * 1e-9,
            si_unit_xy=objects.GwySIUnit(unitstr="m"),
            si_unit_z=objects.GwySIUnit(unitstr="m"),
        )
        container[f"/{i}/data"] = df
        container[f"/{i}/data/title"] = f"{scan.channel} ({direction})"
        meta = objects.GwyContainer()
        meta["Source"] = scan.source or "piezocomp"
        if scan.line_time_s is not None:
            meta["Line time (s)"] = repr(float(scan.line_time_s))
        container[f"/{i}/meta"] = meta
    with atomic_open(path, "wb") as fh:
        container.tofile(fh)


# ---------------------------------------------------------------------------------------------
# Asylum .ibw (igor2)
# ---------------------------------------------------------------------------------------------
def _read_ibw(path: Path, channel: str | None) -> AfmScan:
    source = str(path)
    if path.stat().st_size < 64:
        raise AfmFileError(f"{source}: truncated Igor binary wave ({path.stat().st_size} bytes)")
    igor = import_reader("igor2.binarywave", "igor2", source)
    wave = igor.load(source)["wave"]
    data = np.asarray(wave["wData"], dtype=float)
    if data.ndim == 2:
        data = data[:, :, None]
    if data.ndim != 3:
        raise AfmFileError(f"{source}: wave of shape {data.shape} is not an image stack")
    labels_all = wave.get("labels") or []
    labels = []
    if len(labels_all) > 2 and labels_all[2]:
        labels = [decode(lb) for lb in labels_all[2] if decode(lb)]
    if len(labels) != data.shape[2]:
        labels = [f"layer{i}" for i in range(data.shape[2])]
    # Asylum labels: HeightTrace / HeightRetrace, ZSensorTrace / ZSensorRetrace, ...
    bases: dict[str, dict[str, int]] = {}
    for i, lb in enumerate(labels):
        m = re.match(r"^(?P<base>.+?)(?P<dir>Retrace|Trace)$", lb)
        base, direction = (m.group("base"), m.group("dir")) if m else (lb, "Trace")
        bases.setdefault(base, {})[direction] = i
    names = [b for b, d in bases.items() if "Trace" in d]
    name = pick_channel(names, channel, source)
    note = decode(wave.get("note", b""))
    notes = parse_note(note)
    header = wave["wave_header"]
    z_units = decode(wave.get("data_units", b"")) or decode(header.get("dataUnits", b"")) or "m"
    z_scale = to_nm(z_units, what=f"channel {name!r}", source=source)
    fw = data[:, :, bases[name]["Trace"]].T * z_scale
    bw = None
    if "Retrace" in bases[name]:
        bw = data[:, :, bases[name]["Retrace"]].T * z_scale
    sfa = header.get("sfA")
    dim_units = header.get("dimUnits")
    xy_unit = decode(wave.get("dimension_units") or b"")
    if not xy_unit and dim_units is not None and len(dim_units):
        xy_unit = decode(dim_units[0])
    xy_unit = xy_unit or "m"
    ny, nx = fw.shape
    if sfa is not None:
        size = (
            float(sfa[0]) * nx * to_nm(xy_unit, what="x scale", source=source),
            float(sfa[1]) * ny * to_nm(xy_unit, what="y scale", source=source),
        )
    elif "ScanSize" in notes:
        s = float(notes["ScanSize"]) * 1e9
        size = (s, s * ny / nx)
    else:
        raise AfmFileError(f"{source}: no scan size (neither wave scaling nor ScanSize note)")
    line_time = None
    if "ScanRate" in notes:
        try:
            rate = float(notes["ScanRate"])
            line_time = 1.0 / rate if rate > 0 else None
        except ValueError:
            line_time = None
    return AfmScan(
        forward_nm=fw,
        backward_nm=bw,
        size_nm=size,
        line_time_s=line_time,
        channel=name,
        source=source,
        metadata={"format": "Igor ibw", "labels": labels},
    )


# ---------------------------------------------------------------------------------------------
# Bruker Nanoscope (pySPM)
# ---------------------------------------------------------------------------------------------
