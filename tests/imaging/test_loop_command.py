"""``piezocomp loop`` on real Nanosurf scans shipped inside the NSFopen wheel.

MoS2.nid: ~500 small particles on MoS2 (open-loop scanner, forward/backward shift ~54 nm).
grid.nid: a 3 um calibration grating (shift ~35 nm). Target of issue 5: the trace/retrace
mismatch cut at least ten times on both.
"""

import importlib.resources
import json

import numpy as np
import pytest

from piezocomp.cli import main


def example(relative):
    pytest.importorskip("NSFopen", reason="NSFopen (pip install '.[files]') not installed")
    pytest.importorskip("gwyfile", reason="gwyfile (pip install '.[files]') not installed")
    path = importlib.resources.files("NSFopen") / "example" / relative
    if not path.is_file():
        pytest.skip(f"NSFopen does not ship {relative} in this version")
    return str(path)


# (file, range of the measured mismatch before (nm), largest mismatch after (nm))
CASES = [
    ("Plotting_Data/MoS2.nid", (50.0, 58.0), 2.0),  # measured 53.90 -> 0.87 (held out 0.95)
    ("Plane_Removal/grid.nid", (31.0, 38.0), 1.0),  # measured 34.92 -> 0.39 (held out 0.38)
]


@pytest.mark.parametrize(("relative", "before_range", "after_max"), CASES)
def test_loop_cuts_the_trace_retrace_mismatch_tenfold(
    tmp_path, capsys, relative, before_range, after_max
):
    out = tmp_path / "out"
    assert main(["loop", "--scan", example(relative), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    before, after = summary["mismatch_before_nm"], summary["mismatch_after_nm"]
    assert before_range[0] < before < before_range[1]
    assert after < after_max
    assert before / after >= 10.0
    # A loop fitted on the even lines only corrects the odd lines as well (hold-out).
    assert summary["mismatch_after_heldout_nm"] < after_max
    assert summary["mismatch_reduction"] == pytest.approx(before / after)
    assert summary["lines_measured_after"] == 256
    assert summary["pairs"] > 1000 and summary["lines_with_pairs"] > 200
    assert summary["loop"]["degree"] == 5 and len(summary["loop"]["coefficients"]) == 6
    assert summary["mismatch_after_iqr_nm"] < summary["mismatch_before_iqr_nm"] + 1.0
    # Outputs: corrected images in NPZ, PNG and .gwy; the figure.
    with np.load(out / "corrected.npz") as npz:
        assert npz["forward_nm"].shape == npz["backward_nm"].shape
        assert np.all(np.diff(npz["position_nm"]) > 0)
    for name in ("corrected.png", "loop.png", "corrected.gwy"):
        assert (out / name).stat().st_size > 1000
    from piezocomp.io import read_scan

    gwy = read_scan(out / "corrected.gwy")
    assert gwy.backward_nm is not None
    assert gwy.pixel_nm[0] == pytest.approx(summary["corrected_pixel_nm"])
    assert "mismatch" in capsys.readouterr().out


def test_loop_command_errors_are_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.nid"
    bad.write_bytes(b"[DataSet]\r\nVersion=2\r\n")
    assert main(["loop", "--scan", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("piezocomp loop: error: ") and "bad.nid" in err
    assert "\n" not in err
    assert not (tmp_path / "o").exists()
    assert main(["loop", "--scan", str(tmp_path / "none.gwy"), "--out", str(tmp_path)]) == 2
    assert "none.gwy: no such file" in capsys.readouterr().err


def test_loop_on_a_real_nanonis_sxm_and_a_movie_frame(tmp_path, capsys):
    """The real STM image of tests/data/afm_files: Z in m, both traces, taken downwards."""
    pytest.importorskip("pySPM", reason="pySPM (pip install '.[files]') not installed")
    pytest.importorskip("AFMReader", reason="AFMReader (pip install '.[files]') not installed")
    from pathlib import Path

    data = Path(__file__).resolve().parents[1] / "data" / "afm_files"
    out = tmp_path / "sxm"
    assert main(["loop", "--scan", str(data / "STM_nanonis_generic_4_5.sxm"), "--out",
                 str(out)]) == 0  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    assert summary["image_shape"] == [256, 256]
    assert summary["pixel_nm"] == pytest.approx([4 / 256, 4 / 256])
    assert summary["line_time_s"] == pytest.approx(0.512)
    assert summary["mismatch_before_nm"] < 0.5  # a closed-loop STM scanner: little to correct
    movie = str(data / "hs_afm_movie_6frames.asd")
    assert main(["loop", "--scan", movie, "--out", str(tmp_path / "m")]) == 2
    assert "a movie of 6 frames; give the frame" in capsys.readouterr().err
    assert main(["loop", "--scan", movie, "--frame", "2", "--out", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err
    assert "asd#2: channel 'TP' has no backward (retrace) image" in err
