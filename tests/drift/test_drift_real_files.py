"""``piezocomp drift --scans`` on real files: a pair of Nanonis images of one area and a
high-speed AFM movie, against an independent registration (scikit-image's phase
correlation of the plane-levelled images, Hann-windowed, written here)."""

import csv
import json

import numpy as np
import pytest
from skimage.filters import window
from skimage.registration import phase_cross_correlation

from piezocomp.cli import main
from piezocomp.io import read_scan
from sxm_files import DATA_DIR, REAL_SXM, crop_sxm

PAIR = [str(DATA_DIR / "sxm_pair_A.sxm"), str(DATA_DIR / "sxm_pair_B.sxm")]
ASD = str(DATA_DIR / "hs_afm_movie_6frames.asd")


@pytest.fixture(autouse=True)
def _readers():
    pytest.importorskip("pySPM", reason="pySPM (pip install '.[files]') not installed")
    pytest.importorskip("AFMReader", reason="AFMReader (pip install '.[files]') not installed")


def plane_levelled(z):
    y, x = np.mgrid[: z.shape[0], : z.shape[1]]
    a = np.c_[np.ones(z.size), x.ravel(), y.ravel()]
    coef, *_ = np.linalg.lstsq(a, z.ravel(), rcond=None)
    return z - (a @ coef).reshape(z.shape)


def reference_shift_nm(first, second, trace="forward"):
    """How far the content of ``second`` lies from ``first``'s (nm, x right, y up)."""
    a, b = (plane_levelled(getattr(s, f"{trace}_nm")) for s in (first, second))
    w = window("hann", a.shape)
    shift, _, _ = phase_cross_correlation(a * w, b * w, upsample_factor=100)
    return np.array([-shift[1] * first.pixel_nm[0], -shift[0] * first.pixel_nm[1]])


def drift_rows(folder):
    with open(folder / "drift.csv") as fh:
        return list(csv.DictReader(fh))


def run(tmp_path, name, *args):
    out = tmp_path / name
    assert main(["drift", "--scans", *map(str, args), "--out", str(out)]) == 0
    return out, json.loads((out / "summary.json").read_text())


def measured(out, k=-1):
    row = drift_rows(out)[k]
    return np.array([float(row["measured_x_nm"]), float(row["measured_y_nm"])])


def test_sxm_pair_without_interval_matches_an_independent_registration(tmp_path, capsys):
    out, s = run(tmp_path, "pair", *PAIR)
    ref = reference_shift_nm(read_scan(PAIR[0]), read_scan(PAIR[1]))
    # the pair was cut 20 pixels right and 12 lines up: content at (-20, -12) px of 1/64 nm
    assert ref == pytest.approx([-20 / 64, -12 / 64], abs=0.005)
    assert measured(out) == pytest.approx(ref, abs=0.1)
    assert s["frames_dated_by"] == "the files' start times"
    assert s["clock_at_t0"] == "2023-03-31T14:38:44"
    assert s["duration_s"] == pytest.approx(82.0)  # REC_TIME 14:38:44 and 14:40:06
    assert "wrote" in capsys.readouterr().out
    png = (out / "drift.png").read_bytes()
    assert png.startswith(b"\x89PNG")


def test_scan_direction_and_retrace_give_the_same_drift(tmp_path):
    """The same two crops stored as taken upwards, or holding only the retrace."""
    kw = [dict(rows=slice(0, 160), cols=slice(0, 160)), dict(rows=slice(12, 172),
          cols=slice(20, 180), rec_time="14:40:06")]  # fmt: skip
    ups = [crop_sxm(tmp_path / f"u{k}.sxm", REAL_SXM, scan_dir="up", **kw[k]) for k in (0, 1)]
    mixed = [PAIR[0], ups[1]]  # one down, one up
    backs = [
        crop_sxm(tmp_path / f"b{k}.sxm", REAL_SXM, direction="backward", **kw[k]) for k in (0, 1)
    ]
    down, _ = run(tmp_path, "down", *PAIR)
    for name, files in (("up", ups), ("mixed", mixed), ("retrace", backs)):
        out, _ = run(tmp_path, name, *files)
        assert measured(out) == pytest.approx(measured(down), abs=0.03), name
    ref_b = reference_shift_nm(read_scan(backs[0]), read_scan(backs[1]), trace="backward")
    assert measured(tmp_path / "retrace") == pytest.approx(ref_b, abs=0.1)
    # the sign: content moved left and down (x < 0, y < 0) in every case
    assert np.all(measured(down) < 0)


def test_interval_contradicting_the_files_is_reported(tmp_path, capsys):
    out = tmp_path / "i"
    code = main(["drift", "--scans", *PAIR, "--interval-s", "600", "--out", str(out)])
    assert code == 0
    err = capsys.readouterr().err
    assert "sxm_pair_B.sxm: the file says it started 82 s after" in err
    assert "--interval-s says 600 s" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["frames_dated_by"] == "--interval-s" and s["duration_s"] == pytest.approx(600.0)
    assert any("sxm_pair_B.sxm: the file says" in f for f in s["findings"])
    # an interval within the files' whole seconds is no contradiction
    assert main(["drift", "--scans", *PAIR, "--interval-s", "82.5", "--out",
                 str(tmp_path / "j")]) == 0  # fmt: skip
    assert "the file says" not in capsys.readouterr().err


def test_files_out_of_order_and_a_single_image_are_refused(tmp_path, capsys):
    assert main(["drift", "--scans", PAIR[1], PAIR[0], "--out", str(tmp_path / "o")]) == 2
    assert "sxm_pair_A.sxm: started at 2023-03-31 14:38:44, not after" in capsys.readouterr().err
    assert main(["drift", "--scans", PAIR[0], "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert "sxm_pair_A.sxm: a drift series needs at least 2 images" in err
    assert len(err.strip().splitlines()) == 1


def test_asd_movie_is_a_series_dated_by_its_frame_time(tmp_path):
    out, s = run(tmp_path, "movie", ASD)
    assert s["frames"] == 6 and s["frames_dated_by"] == "the files' start times"
    assert s["clock_at_t0"] == "2017-11-21T13:12:39"
    t = [float(r["t_s"]) for r in drift_rows(out)]
    assert np.diff(t) == pytest.approx([1.0] * (len(t) - 1))  # frame_time 1000 ms
    # Registration on this movie is poor: a protein lattice under noise (match errors near
    # 0.9), and independent registrations disagree by tenths of a nm; the command says so.
    assert any("matched poorly" in f for f in s["findings"])
