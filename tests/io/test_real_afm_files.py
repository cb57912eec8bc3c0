"""Real Nanonis .sxm, JPK .jpk / .jpk-qi-image and high-speed AFM .asd files
(``tests/data/afm_files``, provenance and licences in its README.md), read through pySPM and
AFMReader, checked against the files' own layout and headers."""

import datetime as dt

import numpy as np
import pytest

from piezocomp.io import AfmFileError, read_scan
from piezocomp.io.afm_files import read_series
from sxm_files import DATA_DIR, REAL_SXM, crop_sxm, split_sxm, write_sxm

ASD = DATA_DIR / "hs_afm_movie_6frames.asd"
JPK = DATA_DIR / "jpk_glass_in_liquid.jpk"
JPK_QI = DATA_DIR / "jpk_qi.jpk-qi-image"


@pytest.fixture(autouse=True)
def _readers():
    pytest.importorskip("pySPM", reason="pySPM (pip install '.[files]') not installed")
    pytest.importorskip("AFMReader", reason="AFMReader (pip install '.[files]') not installed")


def test_sxm_reads_size_units_times_and_both_traces():
    scan = read_scan(REAL_SXM)
    assert scan.channel == "Z" and scan.shape == (256, 256)
    # header: SCAN_RANGE 4e-9 m square, SCAN_TIME 0.256 s each way, ACQ_TIME 131.3 s
    assert scan.size_nm == pytest.approx((4.0, 4.0))
    assert scan.pixel_nm == pytest.approx((4.0 / 256, 4.0 / 256))
    assert scan.line_time_s == pytest.approx(0.512)
    assert scan.acquisition_s == pytest.approx(131.3)
    assert scan.started_at == dt.datetime(2023, 3, 31, 14, 38, 44)
    assert scan.slow_direction == "down"
    # Z in m in the file: an Au(111) terrace, 9.29 nm of piezo, 0.2 nm of atomic corrugation
    assert np.mean(scan.forward_nm) == pytest.approx(9.2927, abs=1e-3)
    assert 0.1 < np.ptp(scan.forward_nm) < 0.3
    assert scan.metadata["scan_angle"] == "0.000E+0"


def test_sxm_is_upright_and_its_retrace_left_to_right():
    """Against the file's bytes read here: big-endian float32, lines as taken (a 'down' scan
    stores the top line first), the backward lines right to left."""
    _, data = split_sxm(REAL_SXM)
    scan = read_scan(REAL_SXM)
    np.testing.assert_allclose(scan.forward_nm, data[("Z", "forward")][::-1] * 1e9, rtol=1e-6)
    np.testing.assert_allclose(
        scan.backward_nm, data[("Z", "backward")][::-1, ::-1] * 1e9, rtol=1e-6
    )
    # the traces agree once the retrace is turned left to right, not before
    f = scan.forward_nm - scan.forward_nm.mean(axis=1, keepdims=True)
    b = scan.backward_nm - scan.backward_nm.mean(axis=1, keepdims=True)
    assert np.corrcoef(f.ravel(), b.ravel())[0, 1] > 0.9
    assert np.corrcoef(f.ravel(), b[:, ::-1].ravel())[0, 1] < 0.0


def test_sxm_up_and_down_give_the_same_upright_image(tmp_path):
    rows, cols = slice(10, 90), slice(30, 130)
    down = read_scan(crop_sxm(tmp_path / "d.sxm", REAL_SXM, rows=rows, cols=cols))
    up = read_scan(crop_sxm(tmp_path / "u.sxm", REAL_SXM, rows=rows, cols=cols, scan_dir="up"))
    assert (down.slow_direction, up.slow_direction) == ("down", "up")
    assert up.shape == (80, 100) and up.size_nm == pytest.approx((100 / 64, 80 / 64))
    np.testing.assert_array_equal(up.forward_nm, down.forward_nm)
    np.testing.assert_array_equal(up.backward_nm, down.backward_nm)
    np.testing.assert_allclose(up.forward_nm, read_scan(REAL_SXM).forward_nm[rows, cols])


def test_sxm_retrace_only_and_channels(tmp_path):
    only = crop_sxm(
        tmp_path / "r.sxm", REAL_SXM, rows=slice(0, 64), cols=slice(0, 64), direction="backward"
    )
    scan = read_scan(only)
    assert scan.forward_nm is None and scan.trace == "backward"
    np.testing.assert_allclose(scan.image_nm, read_scan(REAL_SXM).backward_nm[:64, :64])
    with pytest.raises(AfmFileError, match=r"STM_nanonis_generic_4_5\.sxm: channel 'Current' is"):
        read_scan(REAL_SXM, channel="Current")  # A, not a length
    with pytest.raises(AfmFileError, match=r"no channel 'Phase'; available: Z, Current"):
        read_scan(REAL_SXM, channel="Phase")


def test_bad_sxm_files_say_what_is_wrong(tmp_path):
    raw = REAL_SXM.read_bytes()
    cases = {
        "cut.sxm": (raw[:-1000], r"cut\.sxm: truncated: the header announces 4 images"),
        "head.sxm": (raw[:1500], r"head\.sxm: truncated: the header has no :SCANIT_END:"),
        "nomark.sxm": (raw[: raw.index(b"\x1a\x04")], r"nomark\.sxm: truncated: no data"),
        "junk.sxm": (b"GWYP" + raw[4:], r"junk\.sxm: not a Nanonis \.sxm file"),
    }
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(AfmFileError, match=message):
            read_scan(tmp_path / name)
    blocks, data = split_sxm(REAL_SXM)
    empty = {k: np.full_like(v, np.nan) for k, v in data.items()}
    write_sxm(tmp_path / "empty.sxm", blocks, empty)
    with pytest.raises(AfmFileError, match=r"empty\.sxm: channel 'Z' \(forward\) is empty"):
        read_scan(tmp_path / "empty.sxm")
    part = {k: v.copy() for k, v in data.items()}
    for v in part.values():
        v[200:] = np.nan  # a scan stopped after 200 of 256 lines
    write_sxm(tmp_path / "part.sxm", blocks, part)
    with pytest.raises(AfmFileError, match=r"part\.sxm: channel 'Z' \(forward\) has 56 of 256"):
        read_scan(tmp_path / "part.sxm")
    # a real file under a wrong suffix is read by that suffix's reader, and refused by it
    (tmp_path / "x.jpk").write_bytes(raw)
    with pytest.raises(AfmFileError, match=r"x\.jpk: not a JPK image"):
        read_scan(tmp_path / "x.jpk")


def test_asd_movie_frames_times_and_size():
    frames = read_series(ASD)
    assert len(frames) == 6
    first = frames[0]
    assert first.channel == "TP" and first.shape == (200, 200)
    assert first.size_nm == pytest.approx((100.0, 100.0))  # header: 100 x 100 nm, 200 px
    assert first.backward_nm is None and first.slow_direction is None
    # header: recorded 2017-11-21 13:12:39, one frame a second (frame_time 1000 ms)
    assert [f.started_at for f in frames] == [
        dt.datetime(2017, 11, 21, 13, 12, 39) + dt.timedelta(seconds=k) for k in range(6)
    ]
    assert first.acquisition_s == pytest.approx(1.0)
    assert first.line_time_s == pytest.approx(1.0 / 200)
    assert frames[3].source.endswith("hs_afm_movie_6frames.asd#3")
    # heights in nm: a protein lattice about a nanometre deep, not metres or volts
    assert 0.5 < np.ptp(first.forward_nm - np.median(first.forward_nm)) < 5.0
    with pytest.raises(AfmFileError, match=r"a movie of 6 frames; give the frame"):
        read_scan(ASD)
    np.testing.assert_array_equal(read_scan(ASD, frame=4).forward_nm, frames[4].forward_nm)
    with pytest.raises(AfmFileError, match=r"frame 6 does not exist \(the file has 6\)"):
        read_scan(ASD, frame=6)


def test_bad_asd_files(tmp_path):
    raw = ASD.read_bytes()
    (tmp_path / "cut.asd").write_bytes(raw[: len(raw) - 5000])
    with pytest.raises(AfmFileError, match=r"cut\.asd: truncated: the header announces 6 frames"):
        read_series(tmp_path / "cut.asd")
    (tmp_path / "x.asd").write_bytes(b"\x07\x00\x00\x00" + raw[4:400])
    with pytest.raises(AfmFileError, match=r"x\.asd: not an \.asd movie \(file version 7"):
        read_series(tmp_path / "x.asd")
    with pytest.raises(AfmFileError, match=r"hs_afm_movie_6frames\.asd: no channel 'PH'"):
        read_series(ASD, channel="PH")


def test_jpk_reads_size_units_times_and_both_traces():
    scan = read_scan(JPK)
    assert scan.channel == "height" and scan.shape == (256, 256)
    # tags: grid 3.269e-7 m square, 256 x 256; 4 Hz line rate; 16:00:32.334 to 16:01:36.264
    assert scan.size_nm == pytest.approx((326.9165, 326.9165), abs=1e-3)
    assert scan.line_time_s == pytest.approx(0.25)
    assert scan.started_at == dt.datetime(2017, 1, 16, 16, 0, 32, 334000)
    assert scan.acquisition_s == pytest.approx(63.93)
    assert scan.acquisition_s == pytest.approx(256 * scan.line_time_s, rel=0.01)
    assert scan.slow_direction == "up"  # bottomUp
    assert scan.metadata["grid_angle_deg"] == pytest.approx(90.0)
    # height in nm (the z piezo about 3.3 um out), tens of nm of relief on glass
    assert 3000 < np.median(scan.forward_nm) < 3500
    assert 10 < np.ptp(scan.forward_nm) < 200
    # the retrace is stored left to right: it matches the trace as it is
    f = scan.forward_nm - scan.forward_nm.mean(axis=1, keepdims=True)
    b = scan.backward_nm - scan.backward_nm.mean(axis=1, keepdims=True)
    assert np.corrcoef(f.ravel(), b.ravel())[0, 1] > 0.95
    with pytest.raises(AfmFileError, match=r"channel 'phase' is not a height in nm"):
        read_scan(JPK, channel="phase")


def test_jpk_qi_image_is_upright():
    """JPK's own thumbnail (page 0, drawn top row first) is the upright image upside down."""
    tifffile = pytest.importorskip("tifffile")
    from skimage.transform import resize

    scan = read_scan(JPK_QI)
    assert scan.channel == "height" and scan.shape == (100, 100)
    assert scan.size_nm == pytest.approx((500.0, 500.0))
    assert scan.backward_nm is None and scan.line_time_s is None
    with tifffile.TiffFile(JPK_QI) as tif:
        thumb = tif.pages[0].asarray().astype(float)
    small = resize(scan.forward_nm, thumb.shape, anti_aliasing=True)
    r_up = np.corrcoef(small[::-1].ravel(), thumb.ravel())[0, 1]
    r_as_is = np.corrcoef(small.ravel(), thumb.ravel())[0, 1]
    assert r_up > 0.85 > 0.2 > r_as_is


def test_series_from_folder_and_glob(tmp_path):
    a = crop_sxm(tmp_path / "f1.sxm", REAL_SXM, rows=slice(0, 50), cols=slice(0, 50))
    crop_sxm(tmp_path / "f2.sxm", REAL_SXM, rows=slice(5, 55), cols=slice(0, 50))
    (tmp_path / "notes.txt").write_text("not an image")
    by_folder = read_series(tmp_path)
    by_glob = read_series(str(tmp_path / "f*.sxm"))
    assert (
        [s.source for s in by_folder]
        == [s.source for s in by_glob]
        == [
            str(a),
            str(tmp_path / "f2.sxm"),
        ]
    )
    assert len(read_series([ASD, a])) == 7
    with pytest.raises(AfmFileError, match=r"the pattern matches no file"):
        read_series(str(tmp_path / "g*.sxm"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(AfmFileError, match=r"empty: a folder without AFM images"):
        read_series(tmp_path / "empty")
