"""Real AFM image files: one structure for every vendor, read through the ecosystem's readers.

Supported (optional extras, ``pip install piezocomp[files]``):

========================  =========================  ====================================
Format                    Suffix                     Reader
========================  =========================  ====================================
Nanosurf                  ``.nid``                   NSFopen
Gwyddion                  ``.gwy``                   gwyfile (also :func:`write_gwy`)
Asylum Research / Igor    ``.ibw``                   igor2
Bruker Nanoscope          ``.spm``, ``.000``-``.999``  pySPM
========================  =========================  ====================================

Every reader returns an :class:`AfmScan`: forward and backward (retrace) images in nm, the
backward one stored left to right like the forward one, scan size and pixel size in nm and
the line time in s when the file records it.
"""

from __future__ import annotations

import importlib
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezocomp._atomic import atomic_open
from piezocomp._validation import as_finite_array

__all__ = ["AfmFileError", "AfmScan", "MissingReaderError", "read_scan", "write_gwy"]

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


def _to_nm(unit: str, *, what: str, source: str) -> float:
    key = unit.strip().lower()
    if key in _LENGTH_TO_NM:
        return _LENGTH_TO_NM[key]
    raise AfmFileError(f"{source}: {what} is in {unit!r}, not a length unit (expected m or nm)")


def _import_reader(module: str, package: str, source: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingReaderError(
            f"{source}: reading this format needs the optional package {package!r} "
            f"({exc}); install it with: pip install piezocomp[files]"
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


# ---------------------------------------------------------------------------------------------
# Dispatch
# ---------------------------------------------------------------------------------------------
def read_scan(path: str | os.PathLike[str], channel: str | None = None) -> AfmScan:
    """Read one channel (forward and backward) of an AFM image file.

    Parameters
    ----------
    path : path-like
        ``.nid`` (Nanosurf), ``.gwy`` (Gwyddion), ``.ibw`` (Asylum/Igor), ``.spm`` or a numbered
        suffix ``.000``... (Bruker Nanoscope).
    channel : str, optional
        Channel name as in the file (case-insensitive). Default: the topography channel
        (``Z-Axis``, ``Topography``, ``Height``... whichever the file has first).

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
    source = str(p)
    if not p.is_file():
        raise AfmFileError(f"{source}: no such file")
    suffix = p.suffix.lower()
    if suffix == ".nid":
        reader = _read_nid
    elif suffix == ".gwy":
        reader = _read_gwy
    elif suffix == ".ibw":
        reader = _read_ibw
    elif suffix == ".spm" or re.fullmatch(r"\.\d{3}", suffix):
        reader = _read_bruker
    else:
        raise AfmFileError(
            f"{source}: unsupported file type {suffix or '(no suffix)'!r}; "
            "supported: .nid, .gwy, .ibw, .spm, .000-.999"
        )
    try:
        return reader(p, channel)
    except AfmFileError:
        raise
    except Exception as exc:  # vendor readers fail in many ways on corrupt files
        raise AfmFileError(
            f"{source}: cannot read as {suffix} file (corrupt or truncated?): "
            f"{type(exc).__name__}: {exc}"
        ) from exc


def _pick_channel(available: list[str], channel: str | None, source: str) -> str:
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
    nsf = _import_reader("NSFopen.read", "NSFopen", source)
    nid = nsf.nid_read(source, dataframe=False, verbose=False)
    images = (nid.data or {}).get("Image", {})
    forward = images.get("Forward", {})
    backward = images.get("Backward", {})
    name = _pick_channel(list(forward), channel, source)
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
    z_scale = _to_nm(unit_z, what=f"channel {name!r}", source=source)
    fw = np.asarray(forward[name], dtype=float)
    if fw.shape != (lines, points):
        raise AfmFileError(
            f"{source}: channel {name!r} has shape {fw.shape}, header says {(lines, points)}"
        )
    bw = backward.get(name)
    bw_nm = None if bw is None else np.asarray(bw, dtype=float) * z_scale
    size = (
        rng[0] * _to_nm(unit_x, what="x range", source=source),
        rng[1] * _to_nm(unit_y, what="y range", source=source),
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
_DIRECTION = re.compile(
    r"^(?P<base>.*?)[\s_\-]*[\(\[]?(?P<dir>forward|backward|trace|retrace|fwd|bwd)[\)\]]?\s*$",
    re.IGNORECASE,
)


def _split_direction(title: str) -> tuple[str, str]:
    m = _DIRECTION.match(title.strip())
    if m is None:
        return title.strip(), "forward"
    d = m.group("dir").lower()
    direction = "backward" if d in ("backward", "retrace", "bwd") else "forward"
    return m.group("base").strip() or title.strip(), direction


def _read_gwy(path: Path, channel: str | None) -> AfmScan:
    source = str(path)
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"GWYP":
        raise AfmFileError(f"{source}: not a Gwyddion .gwy file (no GWYP magic)")
    gwyfile = _import_reader("gwyfile", "gwyfile", source)
    obj = gwyfile.load(source)
    fields = gwyfile.util.get_datafields(obj)
    groups: dict[str, dict[str, Any]] = {}
    for title, df in fields.items():
        base, direction = _split_direction(str(title))
        groups.setdefault(base, {}).setdefault(direction, (str(title), df))
    names = [b for b, g in groups.items() if "forward" in g]
    name = _pick_channel(names, channel, source)
    fw_title, fw_field = groups[name]["forward"]
    z_unit = _unitstr(fw_field.get("si_unit_z"))
    xy_unit = _unitstr(fw_field.get("si_unit_xy"))
    z_scale = _to_nm(z_unit or "m", what=f"channel {fw_title!r}", source=source)
    xy_scale = _to_nm(xy_unit or "m", what="lateral size", source=source)
    fw = np.asarray(fw_field.data, dtype=float) * z_scale
    bw = None
    if "backward" in groups[name]:
        bw = np.asarray(groups[name]["backward"][1].data, dtype=float) * z_scale
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
    ``"<channel> (backward)"``; data in metres as Gwyddion expects. :func:`read_scan` reads it
    back. The line time, if known, is stored in the forward channel's metadata.
    """
    gwyfile = _import_reader("gwyfile", "gwyfile", str(path))
    objects = gwyfile.objects
    container = objects.GwyContainer()
    images = [("forward", scan.forward_nm)]
    if scan.backward_nm is not None:
        images.append(("backward", scan.backward_nm))
    for i, (direction, img) in enumerate(images):
        df = objects.GwyDataField(
            np.ascontiguousarray(np.asarray(img, dtype=float) * 1e-9),
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
    igor = _import_reader("igor2.binarywave", "igor2", source)
    wave = igor.load(source)["wave"]
    data = np.asarray(wave["wData"], dtype=float)
    if data.ndim == 2:
        data = data[:, :, None]
    if data.ndim != 3:
        raise AfmFileError(f"{source}: wave of shape {data.shape} is not an image stack")
    labels_all = wave.get("labels") or []
    labels = []
    if len(labels_all) > 2 and labels_all[2]:
        labels = [_decode(lb) for lb in labels_all[2] if _decode(lb)]
    if len(labels) != data.shape[2]:
        labels = [f"layer{i}" for i in range(data.shape[2])]
    # Asylum labels: HeightTrace / HeightRetrace, ZSensorTrace / ZSensorRetrace, ...
    bases: dict[str, dict[str, int]] = {}
    for i, lb in enumerate(labels):
        m = re.match(r"^(?P<base>.+?)(?P<dir>Retrace|Trace)$", lb)
        base, direction = (m.group("base"), m.group("dir")) if m else (lb, "Trace")
        bases.setdefault(base, {})[direction] = i
    names = [b for b, d in bases.items() if "Trace" in d]
    name = _pick_channel(names, channel, source)
    note = _decode(wave.get("note", b""))
    notes = _parse_note(note)
    header = wave["wave_header"]
    z_units = _decode(wave.get("data_units", b"")) or _decode(header.get("dataUnits", b"")) or "m"
    z_scale = _to_nm(z_units, what=f"channel {name!r}", source=source)
    fw = data[:, :, bases[name]["Trace"]].T * z_scale
    bw = None
    if "Retrace" in bases[name]:
        bw = data[:, :, bases[name]["Retrace"]].T * z_scale
    sfa = header.get("sfA")
    dim_units = header.get("dimUnits")
    xy_unit = _decode(wave.get("dimension_units") or b"")
    if not xy_unit and dim_units is not None and len(dim_units):
        xy_unit = _decode(dim_units[0])
    xy_unit = xy_unit or "m"
    ny, nx = fw.shape
    if sfa is not None:
        size = (
            float(sfa[0]) * nx * _to_nm(xy_unit, what="x scale", source=source),
            float(sfa[1]) * ny * _to_nm(xy_unit, what="y scale", source=source),
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


def _decode(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("latin-1").strip("\x00").strip()
    if isinstance(value, np.ndarray):
        return "".join(_decode(v) for v in value.ravel().tolist())
    if isinstance(value, list | tuple):
        return "".join(_decode(v) for v in value)
    return str(value).strip()


def _parse_note(note: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for line in re.split(r"[\r\n]+", note):
        if ":" in line:
            k, v = line.split(":", 1)
            out[k.strip()] = v.strip()
    return out


# ---------------------------------------------------------------------------------------------
# Bruker Nanoscope (pySPM)
# ---------------------------------------------------------------------------------------------
def _read_bruker(path: Path, channel: str | None) -> AfmScan:
    source = str(path)
    with open(path, "rb") as fh:
        head = fh.read(64)
    if not head.lstrip(b"\\").startswith(b"*File list"):
        raise AfmFileError(f"{source}: not a Bruker Nanoscope file (no '*File list' header)")
    bruker_mod = _import_reader("pySPM.Bruker", "pySPM", source)
    bruker = bruker_mod.Bruker(source)
    names: list[str] = []
    for layer in bruker.layers:
        raw = layer.get(b"@2:Image Data")
        if not raw:
            continue
        m = re.match(r'([^ ]+) \[([^]]*)] "([^"]*)"', raw[0].decode("latin1"))
        if m and m.group(3) not in names:
            names.append(m.group(3))
    name = _pick_channel(names, channel, source)
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
    z_scale = _to_nm(str(fw_img.zscale), what=f"channel {name!r}", source=source)
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
    xy_scale = _to_nm(unit, what="scan size", source=source)

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
