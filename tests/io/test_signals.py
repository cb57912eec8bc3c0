"""Recorded time series (CSV with header, NPZ): round trips and clear errors."""

import numpy as np
import pytest

from piezocomp.io import RecordedSignal, read_signal, write_signal


def line_scan(n=50):
    t = np.arange(n) * 0.008
    u = 500.0 * np.sin(2 * np.pi * t / 0.4) + 1e-7  # full precision survives
    return {"t_s": t, "u_nm": u, "height_nm": np.cos(u / 37.0) * 3.0}


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip_with_metadata(tmp_path, suffix):
    cols = line_scan()
    path = tmp_path / f"scan{suffix}"
    write_signal(path, cols, metadata={"instrument": "Nanosurf Flex", "line_time_s": "0.68"})
    sig = read_signal(path)
    assert list(sig) == ["t_s", "u_nm", "height_nm"]
    for name, values in cols.items():
        np.testing.assert_array_equal(sig[name], values)  # bit-exact
    assert sig.metadata == {"instrument": "Nanosurf Flex", "line_time_s": "0.68"}
    assert sig.n_samples == 50
    assert sig.sample_period_s == pytest.approx(0.008)
    assert sig.source == str(path)
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no temp files left


def test_two_axis_and_extra_columns(tmp_path):
    t = np.linspace(0.0, 1.0, 11)
    cols = {"t_s": t, "x_nm": t * 10, "y_nm": -t, "height_nm": t**2, "y_true_nm": t + 1}
    write_signal(tmp_path / "xy.csv", RecordedSignal(cols, metadata={"a": "b"}))
    sig = read_signal(tmp_path / "xy.csv")
    assert set(sig) == set(cols)
    assert sig.metadata == {"a": "b"}


def test_hand_written_csv(tmp_path):
    path = tmp_path / "hand.csv"
    path.write_text("# sample: Au particles on mica\nt_s,u_nm,height_nm\n0,0,1.5\n0.008,2.5,1.75\n")
    sig = read_signal(path)
    np.testing.assert_array_equal(sig["u_nm"], [0.0, 2.5])
    assert sig.metadata["sample"] == "Au particles on mica"


def test_errors_name_the_file_and_the_problem(tmp_path):
    p = tmp_path / "trunc.csv"
    p.write_text("t_s,u_nm,height_nm\n0,0,1\n0.1,1\n")
    with pytest.raises(ValueError, match=r"trunc\.csv: line 3 has 2 fields, the header has 3"):
        read_signal(p)
    p = tmp_path / "text.csv"
    p.write_text("t_s,u_nm,height_nm\n0,0,abc\n")
    with pytest.raises(ValueError, match=r"text\.csv: sample 0 holds a value that is not a number"):
        read_signal(p)
    p = tmp_path / "nou.csv"
    p.write_text("t_s,height_nm\n0,1\n1,2\n")
    with pytest.raises(ValueError, match=r"nou\.csv: a recorded signal needs the command"):
        read_signal(p)
    p = tmp_path / "back.csv"
    p.write_text("t_s,u_nm,height_nm\n0,0,1\n0,1,2\n")
    with pytest.raises(ValueError, match=r"back\.csv: t_s must be strictly increasing"):
        read_signal(p)
    p = tmp_path / "empty.csv"
    p.write_text("# only a comment\n")
    with pytest.raises(ValueError, match=r"empty\.csv: no header line"):
        read_signal(p)
    write_signal(tmp_path / "ok.npz", line_scan())
    raw = (tmp_path / "ok.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match=r"cut\.npz: not a readable NPZ signal file"):
        read_signal(tmp_path / "cut.npz")
    with pytest.raises(ValueError, match=r"x\.txt: unsupported signal file type"):
        read_signal(tmp_path / "x.txt")
    with pytest.raises(ValueError, match=r"none\.csv: no such file"):
        read_signal(tmp_path / "none.csv")


def test_invalid_signal_is_refused_before_anything_is_written(tmp_path):
    bad = line_scan()
    bad["height_nm"] = bad["height_nm"].copy()
    bad["height_nm"][3] = np.nan
    with pytest.raises(ValueError, match=r"column 'height_nm' must be finite. Got nan at sample 3"):
        write_signal(tmp_path / "bad.csv", bad)
    short = line_scan()
    short["u_nm"] = short["u_nm"][:-1]
    with pytest.raises(ValueError, match="same length"):
        write_signal(tmp_path / "bad.npz", short)
    assert list(tmp_path.iterdir()) == []


def test_signal_is_read_only():
    sig = RecordedSignal(line_scan())
    with pytest.raises(ValueError):
        sig["u_nm"][0] = 1.0
    with pytest.raises(TypeError):
        sig["u_nm"] = np.zeros(3)  # type: ignore[index]
