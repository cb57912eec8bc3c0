"""Real AFM files: Nanosurf .nid (NSFopen's shipped examples), Gwyddion .gwy, .ibw, Bruker."""

import importlib.resources
import struct
import sys

import numpy as np
import pytest

from piezocomp.io import AfmFileError, AfmScan, MissingReaderError, read_scan, write_gwy


def nsfopen_example(relative):
    """Path of a file shipped inside the NSFopen wheel (obtained through pip, not copied)."""
    pytest.importorskip("NSFopen", reason="NSFopen (pip install '.[files]') not installed")
    path = importlib.resources.files("NSFopen") / "example" / relative
    if not path.is_file():
        pytest.skip(f"NSFopen does not ship {relative} in this version")
    return path


def write_ibw5(path, data, *, labels, sfa, data_units="m", dim_units="m", note=""):
    """Write a minimal Igor binary wave, version 5 (Igor Technical Note 003), float32.

    igor2 reads but cannot write .ibw, so the test builds one by hand, laid out as Asylum
    Research software saves images: (nx, ny, layers), layers labelled HeightTrace etc.
    """
    data = np.asarray(data, dtype="<f4")
    shape = list(data.shape) + [0] * (4 - data.ndim)
    raw = data.tobytes(order="F")  # Igor arrays are column-major
    note_b = note.encode("latin-1")
    labels_b = [b""] * 4
    labels_b[2] = b"".join([b"\0" * 32] + [lb.encode().ljust(32, b"\0") for lb in labels])
    wave_header = b"".join(
        [
            struct.pack("<IIIi", 0, 0, 0, data.size),  # next, dates, npnts
            struct.pack("<hh", 2, 0) + b"\0" * 6 + struct.pack("<h", 1),  # NT_FP32
            b"wave0".ljust(32, b"\0") + struct.pack("<iI", 0, 0),
            struct.pack("<4i", *shape),
            struct.pack("<4d", *(list(sfa) + [1.0] * (4 - len(sfa)))),
            struct.pack("<4d", 0, 0, 0, 0),
            data_units.encode().ljust(4, b"\0"),
            b"".join(dim_units.encode().ljust(4, b"\0") for _ in range(4)),
            struct.pack("<hhdd", 0, 0, 0, 0),
            b"\0" * 40 + b"\0" * 64 + b"\0" * 8 + b"\0" * 20,  # pointers, unused, flags
        ]
    )
    assert len(wave_header) == 320
    sizes = [len(x) for x in labels_b]
    bin_header = struct.pack(
        "<hhiiii4i4iiii", 5, 0, 320 + len(raw), 0, len(note_b), 0, 0, 0, 0, 0, *sizes, 0, 0, 0
    )
    path.write_bytes(bin_header + wave_header + raw + note_b + b"".join(labels_b))


def write_nanoscope(path, layers, *, samps, lines, scan_size="400 400 nm", rate=2.0):
    """Write a minimal Bruker Nanoscope file as pySPM parses it (no real file ships with pip).

    ``layers``: (direction, channel, heights_nm of shape (lines, samps)); int32 data with a
    Z scale of 1e-9 V/LSB times a sensitivity of 10 nm/V.
    """

    def header(offsets):
        h = [r"\*File list", r"\Version: 0x09200000", r"\*Scanner list"]
        h.append(r"\@Sens. Zsens: V 10.0 nm/V")
        for (direction, name, _), off in zip(layers, offsets, strict=True):
            h += [
                r"\*Ciao image list",
                f"\\Data offset: {off}",
                f"\\Data length: {samps * lines * 4}",
                r"\Bytes/pixel: 4",
                f"\\Samps/line: {samps}",
                f"\\Number of lines: {lines}",
                f"\\Scan Size: {scan_size}",
                r"\Aspect Ratio: 1:1",
                f"\\Line Direction: {direction}",
                f"\\Scan Rate: {rate}",
                f'\\@2:Image Data: S [{name}] "{name}"',
                r"\@2:Z scale: V [Sens. Zsens] (0.000000001 V/LSB) 4.294967296 V",
                r"\@2:Z offset: V [Sens. Zsens] (0.000000001 V/LSB) 0 V",
            ]
        h.append(r"\*File list end")
        return ("\r\n".join(h) + "\r\n").encode("latin-1")

    head_len = len(header([10**6] * len(layers))) + 64
    offsets = [head_len + k * samps * lines * 4 for k in range(len(layers))]
    body = b"".join(np.round(np.asarray(v) / 1e-8).astype("<i4").tobytes() for *_, v in layers)
    path.write_bytes(header(offsets).ljust(head_len, b"\x1a") + body)


MOS2 = "Plotting_Data/MoS2.nid"
GRID = "Plane_Removal/grid.nid"


def test_reads_nanosurf_mos2():
    scan = read_scan(nsfopen_example(MOS2))
    assert scan.channel == "Z-Axis"
    assert scan.shape == (256, 512)
    assert scan.backward_nm is not None and scan.backward_nm.shape == (256, 512)
    # Header: 3.97339 um square, 0.6803 s per line; heights stored in metres.
    assert scan.size_nm == pytest.approx((3973.39, 3973.39))
    assert scan.pixel_nm == pytest.approx((3973.39 / 512, 3973.39 / 256))
    assert scan.line_time_s == pytest.approx(0.6803)
    # Topography in nm: the z piezo sits near -1.4 um, relief of tens of nm.
    assert -1500 < np.median(scan.forward_nm) < -1350
    assert 5 < np.ptp(scan.forward_nm[100]) < 200
    assert scan.source.endswith("MoS2.nid")
    assert scan.metadata["format"] == "Nanosurf nid"


def test_backward_is_stored_left_to_right():
    # Forward and backward lines look alike without flipping (a ~54 nm shift), and unlike
    # when the backward line is flipped.
    scan = read_scan(nsfopen_example(MOS2))
    f = scan.forward_nm - scan.forward_nm.mean(axis=1, keepdims=True)
    b = scan.backward_nm - scan.backward_nm.mean(axis=1, keepdims=True)
    r_same = np.corrcoef(f[:, 10:].ravel(), b[:, 3:-7].ravel())[0, 1]
    r_flip = np.corrcoef(f.ravel(), b[:, ::-1].ravel())[0, 1]
    assert r_same > 0.9 > 0.5 > r_flip


def test_reads_nanosurf_grid_and_channels():
    path = nsfopen_example(GRID)
    scan = read_scan(path)
    assert scan.shape == (256, 256)
    assert scan.size_nm == pytest.approx((3000.0, 3000.0))
    assert scan.line_time_s == pytest.approx(0.7803)
    assert read_scan(path, channel="z-axis").channel == "Z-Axis"  # case-insensitive
    with pytest.raises(AfmFileError, match=r"grid\.nid: no channel 'Deflection'; available: "):
        read_scan(path, channel="Deflection")
    with pytest.raises(AfmFileError, match=r"grid\.nid: channel 'Amplitude' is in 'V'"):
        read_scan(path, channel="Amplitude")


def test_reads_asylum_ibw(tmp_path):
    pytest.importorskip("igor2", reason="igor2 (pip install '.[files]') not installed")
    rng = np.random.default_rng(4)
    nx, ny = 16, 6
    layers = rng.normal(0.0, 5.0, (nx, ny, 4))  # nm
    path = tmp_path / "asylum.ibw"
    write_ibw5(
        path,
        layers * 1e-9,  # Asylum stores metres
        labels=["HeightTrace", "HeightRetrace", "ZSensorTrace", "ZSensorRetrace"],
        sfa=[2.5e-8, 5e-8],
        note="ScanRate: 2\rScanSize: 4e-07\r",
    )
    scan = read_scan(path)
    assert scan.channel == "Height" and scan.shape == (ny, nx)
    np.testing.assert_allclose(scan.forward_nm, layers[:, :, 0].T, atol=1e-5)  # float32
    np.testing.assert_allclose(scan.backward_nm, layers[:, :, 1].T, atol=1e-5)
    assert scan.size_nm == pytest.approx((400.0, 300.0))
    assert scan.pixel_nm == pytest.approx((25.0, 50.0))
    assert scan.line_time_s == pytest.approx(0.5)
    z = read_scan(path, channel="zsensor")
    np.testing.assert_allclose(z.forward_nm, layers[:, :, 2].T, atol=1e-5)
    with pytest.raises(AfmFileError, match=r"asylum\.ibw: no channel 'Phase'; available: Height"):
        read_scan(path, channel="Phase")
    cut = tmp_path / "cut.ibw"
    cut.write_bytes(path.read_bytes()[:500])
    with pytest.raises(AfmFileError, match=r"cut\.ibw: cannot read as \.ibw file"):
        read_scan(cut)
    volts = tmp_path / "volts.ibw"
    write_ibw5(volts, layers[:, :, :1], labels=["AmplitudeTrace"], sfa=[1e-8, 1e-8], data_units="V")
    with pytest.raises(AfmFileError, match=r"volts\.ibw: channel 'Amplitude' is in 'V'"):
        read_scan(volts)


def test_reads_bruker_nanoscope_through_pyspm(tmp_path):
    pytest.importorskip("pySPM", reason="pySPM (pip install '.[files]') not installed")
    rng = np.random.default_rng(5)
    lines, samps = 8, 16  # not square: pySPM alone would transpose the shape
    fw = rng.normal(0.0, 3.0, (lines, samps))
    bw = rng.normal(0.0, 3.0, (lines, samps))
    path = tmp_path / "scan.001"
    write_nanoscope(
        path, [("Trace", "Height", fw), ("Retrace", "Height", bw)], samps=samps, lines=lines
    )
    scan = read_scan(path)
    assert scan.channel == "Height" and scan.shape == (lines, samps)
    np.testing.assert_allclose(scan.forward_nm, fw, atol=1e-8)  # 1e-8 nm per LSB
    np.testing.assert_allclose(scan.backward_nm, bw, atol=1e-8)
    assert scan.size_nm == pytest.approx((400.0, 200.0))
    assert scan.line_time_s == pytest.approx(0.5)
    only = tmp_path / "trace.spm"
    write_nanoscope(only, [("Trace", "Height", fw)], samps=samps, lines=lines)
    assert read_scan(only).backward_nm is None
    cut = tmp_path / "cut.002"
    cut.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(AfmFileError, match=r"cut\.002: truncated: channel 'Height' needs"):
        read_scan(cut)


def test_gwy_round_trip(tmp_path):
    pytest.importorskip("gwyfile", reason="gwyfile (pip install '.[files]') not installed")
    rng = np.random.default_rng(0)
    fw = rng.normal(0, 3, (12, 20))
    scan = AfmScan(fw, fw[:, ::-1] + 1.0, (2000.0, 1200.0), line_time_s=0.25, channel="Height")
    path = tmp_path / "v.gwy"
    write_gwy(path, scan)
    back = read_scan(path)
    assert back.channel == "Height"
    np.testing.assert_allclose(back.forward_nm, scan.forward_nm, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(back.backward_nm, scan.backward_nm, rtol=1e-12, atol=1e-12)
    assert back.size_nm == pytest.approx(scan.size_nm, rel=1e-12)
    assert back.pixel_nm == pytest.approx((100.0, 100.0), rel=1e-12)
    assert back.line_time_s == pytest.approx(0.25)
    # Forward only.
    write_gwy(tmp_path / "f.gwy", AfmScan(fw, None, (2000.0, 1200.0)))
    only = read_scan(tmp_path / "f.gwy")
    assert only.backward_nm is None and only.line_time_s is None


def test_gwy_of_a_real_scan_round_trips(tmp_path):
    pytest.importorskip("gwyfile", reason="gwyfile not installed")
    scan = read_scan(nsfopen_example(GRID))
    write_gwy(tmp_path / "grid.gwy", scan)
    back = read_scan(tmp_path / "grid.gwy")
    np.testing.assert_allclose(back.forward_nm, scan.forward_nm, rtol=1e-12)
    np.testing.assert_allclose(back.backward_nm, scan.backward_nm, rtol=1e-12)
    assert back.line_time_s == pytest.approx(scan.line_time_s)


def test_truncated_and_corrupt_files_name_the_file(tmp_path):
    data = nsfopen_example(GRID).read_bytes()
    cut = tmp_path / "cut.nid"
    cut.write_bytes(data[: len(data) // 3])  # header intact, image data missing
    with pytest.raises(AfmFileError, match=r"cut\.nid: truncated: the header announces"):
        read_scan(cut)
    head_only = tmp_path / "head.nid"
    head_only.write_bytes(data[:200])
    with pytest.raises(AfmFileError, match=r"head\.nid: no image data after the \.nid header"):
        read_scan(head_only)
    junk = tmp_path / "junk.nid"
    junk.write_bytes(b"\x00\x01garbage" * 10)
    with pytest.raises(AfmFileError, match=r"junk\.nid: not a Nanosurf \.nid file"):
        read_scan(junk)


def test_corrupt_gwy_ibw_bruker_and_unsupported(tmp_path):
    pytest.importorskip("gwyfile", reason="gwyfile not installed")
    good = tmp_path / "g.gwy"
    write_gwy(good, AfmScan(np.ones((4, 5)), None, (10.0, 8.0)))
    cut = tmp_path / "cut.gwy"
    cut.write_bytes(good.read_bytes()[:60])
    with pytest.raises(AfmFileError, match=r"cut\.gwy: cannot read as \.gwy file"):
        read_scan(cut)
    (tmp_path / "x.gwy").write_bytes(b"NOTGWY")
    with pytest.raises(AfmFileError, match=r"x\.gwy: not a Gwyddion \.gwy file"):
        read_scan(tmp_path / "x.gwy")
    (tmp_path / "x.ibw").write_bytes(b"\x05\x00" + b"\xff" * 400)
    with pytest.raises(AfmFileError, match=r"x\.ibw: "):
        read_scan(tmp_path / "x.ibw")
    (tmp_path / "tiny.ibw").write_bytes(b"\x05\x00")
    with pytest.raises(AfmFileError, match=r"tiny\.ibw: truncated Igor binary wave"):
        read_scan(tmp_path / "tiny.ibw")
    (tmp_path / "x.001").write_bytes(b"hello world\n" * 10)
    with pytest.raises(AfmFileError, match=r"x\.001: not a Bruker Nanoscope file"):
        read_scan(tmp_path / "x.001")
    (tmp_path / "b.spm").write_bytes(b"\\*File list\r\n\\*File list end\r\n")
    with pytest.raises(AfmFileError, match=r"b\.spm: the file holds no image channel"):
        read_scan(tmp_path / "b.spm")
    (tmp_path / "x.tif").write_bytes(b"II*\x00")
    with pytest.raises(AfmFileError, match=r"x\.tif: unsupported file type '\.tif'"):
        read_scan(tmp_path / "x.tif")
    with pytest.raises(AfmFileError, match=r"nothere\.nid: no such file"):
        read_scan(tmp_path / "nothere.nid")
    assert issubclass(AfmFileError, ValueError)


def test_missing_reader_tells_how_to_install(tmp_path, monkeypatch):
    path = tmp_path / "a.gwy"
    path.write_bytes(b"GWYP" + b"\x00" * 32)
    monkeypatch.setitem(sys.modules, "gwyfile", None)  # import gwyfile -> ImportError
    with pytest.raises(MissingReaderError, match=r"a\.gwy: .*pip install '\.\[files\]'"):
        read_scan(path)


def test_afmscan_validates():
    with pytest.raises(ValueError, match="backward_nm must have the shape"):
        AfmScan(np.zeros((3, 4)), np.zeros((3, 5)), (1.0, 1.0))
    with pytest.raises(ValueError, match="size_nm"):
        AfmScan(np.zeros((3, 4)), None, (0.0, 1.0))
    with pytest.raises(ValueError, match="finite"):
        AfmScan(np.full((3, 4), np.nan), None, (1.0, 1.0))
    s = AfmScan(np.zeros((3, 4)), None, (8.0, 6.0))
    assert s.pixel_nm == (2.0, 2.0)
    with pytest.raises(ValueError):
        s.forward_nm[0, 0] = 1.0
