import json

import numpy as np
import pytest

from piezocomp.cli import main
from piezocomp.io.model_files import save_model
from piezocomp.model import ScannerModel, simulate

T = 0.008


@pytest.fixture
def model_file(tmp_path):
    m = ScannerModel(
        offset_nm=2.0,
        gain=0.62,
        thresholds_nm=[10.0, 40.0, 120.0],
        weights=[0.05, 0.04, 0.03],
        creep_time_constants_s=[0.5, 20.0],
        creep_gains=[0.02, 0.04],
    )
    path = tmp_path / "model.json"
    save_model(path, m)
    return path, m


def _write_csv(path, header, t, v):
    lines = [",".join(header)] + [f"{float(a)!r},{float(b)!r}" for a, b in zip(t, v, strict=True)]
    path.write_text("\n".join(lines) + "\n")


def test_compensate_then_simulate_reproduces_the_trajectory(tmp_path, model_file):
    path, m = model_file
    t = np.arange(2000) * T
    yd = 300 * np.sin(2 * np.pi * 0.4 * t) * np.exp(-t / 10)
    _write_csv(tmp_path / "yd.csv", ["t_s", "y_nm"], t, yd)
    assert (
        main(
            [
                "compensate",
                "--model",
                str(path),
                "--input",
                str(tmp_path / "yd.csv"),
                "--output",
                str(tmp_path / "u.csv"),
            ]
        )
        == 0
    )
    data = np.genfromtxt(tmp_path / "u.csv", delimiter=",", names=True)
    assert data.dtype.names == ("t_s", "u_nm")
    y, _ = simulate(m, data["u_nm"], T)
    np.testing.assert_allclose(y, yd, atol=1e-9)
    assert (
        main(
            [
                "simulate",
                "--model",
                str(path),
                "--input",
                str(tmp_path / "u.csv"),
                "--output",
                str(tmp_path / "y.csv"),
            ]
        )
        == 0
    )
    back = np.genfromtxt(tmp_path / "y.csv", delimiter=",", names=True)
    np.testing.assert_allclose(back["y_nm"], yd, atol=1e-9)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("t_s,x_nm\n0,1\n0.008,2\n", "no column 'y_nm'"),
        ("t_s,y_nm\n0,1\n0.008,nan\n", "line 3 holds a non-finite value"),
        ("t_s,y_nm\n0,1\n0.008,2\n0.02,3\n", "uniformly increasing"),
        ("t_s,y_nm\n0,1\n0.008\n", "truncated"),
        ("", "empty"),
    ],
)
def test_bad_input_is_one_line_error(tmp_path, model_file, capsys, content, match):
    path, _ = model_file
    (tmp_path / "in.csv").write_text(content)
    code = main(
        [
            "compensate",
            "--model",
            str(path),
            "--input",
            str(tmp_path / "in.csv"),
            "--output",
            str(tmp_path / "out.csv"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert match in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.csv").exists()


def test_limits_refuse_or_clip(tmp_path, model_file, capsys):
    path, _ = model_file
    t = np.arange(100) * T
    _write_csv(tmp_path / "yd.csv", ["t_s", "y_nm"], t, np.linspace(0, 900, 100))
    args = [
        "compensate",
        "--model",
        str(path),
        "--input",
        str(tmp_path / "yd.csv"),
        "--output",
        str(tmp_path / "u.csv"),
        "--range-nm",
        "2000",
    ]
    assert main(args) == 2
    assert "outside the scanner range" in capsys.readouterr().err
    assert main([*args, "--clip"]) == 0
    assert "clipped" in capsys.readouterr().err
    u = np.genfromtxt(tmp_path / "u.csv", delimiter=",", names=True)["u_nm"]
    assert u.max() == 1000.0


def test_bad_model_file_is_one_line_error(tmp_path, capsys):
    (tmp_path / "m.json").write_text(
        '{"format": "piezocomp/scanner-model", "version": 1, "gain": -'
    )
    (tmp_path / "in.csv").write_text("t_s,y_nm\n0,1\n0.008,2\n")
    code = main(
        [
            "simulate",
            "--model",
            str(tmp_path / "m.json"),
            "--input",
            str(tmp_path / "in.csv"),
            "--output",
            str(tmp_path / "o.csv"),
        ]
    )
    assert code == 2
    assert "truncated" in capsys.readouterr().err


def test_bench_json(capsys):
    assert main(["bench", "--json", "--samples", "20000"]) == 0
    figures = json.loads(capsys.readouterr().out)
    for key in (
        "forward_samples_per_s",
        "inverse_samples_per_s",
        "reference_inverse_samples_per_s",
        "stream_step_us",
    ):
        assert figures[key] > 0


def test_help_everywhere(capsys):
    for cmd in (["--help"], ["compensate", "--help"], ["simulate", "--help"], ["bench", "--help"]):
        with pytest.raises(SystemExit) as exc:
            main(cmd)
        assert exc.value.code == 0
    assert "usage" in capsys.readouterr().out
