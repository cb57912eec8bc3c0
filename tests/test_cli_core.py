"""``compensate``, ``simulate`` and ``bench`` on the command line: columns named by axis,
ranges, domains, states, clipping reports, time stamps, one-line errors."""

import json

import numpy as np
import pytest

from piezocomp.cli import main
from piezocomp.io.model_files import save_model
from piezocomp.model import ScannerModel, ScannerModel2D, simulate

T = 0.008


def _model(gain=0.62, **kw):
    return ScannerModel(
        offset_nm=2.0,
        gain=gain,
        thresholds_nm=[10.0, 40.0, 120.0],
        weights=[0.05, 0.04, 0.03],
        creep_time_constants_s=[0.5, 20.0],
        creep_gains=[0.02, 0.04],
        **kw,
    )


@pytest.fixture
def model_file(tmp_path):
    m = _model(range_nm=5000.0)
    path = tmp_path / "model.json"
    save_model(path, m)
    return path, m


@pytest.fixture
def model2d_file(tmp_path):
    m = ScannerModel2D(_model(range_nm=5000.0), _model(0.7, range_nm=5000.0))
    path = tmp_path / "model2d.json"
    save_model(path, m)
    return path, m


def _write_csv(path, columns):
    names = list(columns)
    rows = [",".join(names)]
    rows += [",".join(repr(float(v)) for v in r) for r in zip(*columns.values(), strict=True)]
    path.write_text("\n".join(rows) + "\n")


def _read(path):
    return np.genfromtxt(path, delimiter=",", names=True)


def _run(*args):
    return main([str(a) for a in args])


def test_compensate_then_simulate_reproduces_the_trajectory(tmp_path, model_file):
    path, m = model_file
    t = np.arange(2000) * T
    yd = 300 * np.sin(2 * np.pi * 0.4 * t) * np.exp(-t / 10)
    _write_csv(tmp_path / "yd.csv", {"t_s": t, "position_nm": yd})
    assert _run("compensate", "--model", path, "--input", tmp_path / "yd.csv",
                "--output", tmp_path / "u.csv") == 0  # fmt: skip
    data = _read(tmp_path / "u.csv")
    assert data.dtype.names == ("t_s", "u_nm")
    y, _ = simulate(m, data["u_nm"], T)
    np.testing.assert_allclose(y, yd, atol=1e-9)
    assert _run("simulate", "--model", path, "--input", tmp_path / "u.csv",
                "--output", tmp_path / "y.csv") == 0  # fmt: skip
    np.testing.assert_allclose(_read(tmp_path / "y.csv")["position_nm"], yd, atol=1e-9)


def test_columns_are_named_by_axis(tmp_path, model2d_file, capsys):
    path, m = model2d_file
    t = np.arange(500) * T
    xd, yd = 200 * np.sin(t), -150 * np.cos(2 * t)
    _write_csv(tmp_path / "d.csv", {"t_s": t, "x_nm": xd, "y_nm": yd})
    # --axis x compensates x_nm through the x model (never the y column)
    assert _run("compensate", "--model", path, "--input", tmp_path / "d.csv",
                "--output", tmp_path / "ux.csv", "--axis", "x") == 0  # fmt: skip
    ux = _read(tmp_path / "ux.csv")
    assert ux.dtype.names == ("t_s", "ux_nm")
    np.testing.assert_allclose(simulate(m.x, ux["ux_nm"], T)[0], xd, atol=1e-9)
    # no --axis: every axis the file holds, each through its own model
    assert _run("compensate", "--model", path, "--input", tmp_path / "d.csv",
                "--output", tmp_path / "u.csv") == 0  # fmt: skip
    u = _read(tmp_path / "u.csv")
    np.testing.assert_allclose(simulate(m.y, u["uy_nm"], T)[0], yd, atol=1e-9)
    assert _run("simulate", "--model", path, "--input", tmp_path / "u.csv",
                "--output", tmp_path / "p.csv") == 0  # fmt: skip
    p = _read(tmp_path / "p.csv")
    np.testing.assert_allclose(p["x_nm"], xd, atol=1e-9)
    np.testing.assert_allclose(p["y_nm"], yd, atol=1e-9)
    # a file with x_nm only is fine for x
    _write_csv(tmp_path / "x.csv", {"t_s": t, "x_nm": xd})
    assert _run("compensate", "--model", path, "--input", tmp_path / "x.csv",
                "--output", tmp_path / "ux2.csv", "--axis", "x") == 0  # fmt: skip
    assert _run("compensate", "--model", path, "--input", tmp_path / "x.csv",
                "--output", tmp_path / "uy.csv", "--axis", "y") == 2  # fmt: skip
    assert "--axis y needs a column 'y_nm'" in capsys.readouterr().err


def test_axis_with_a_1d_model_and_two_columns_for_one_axis_are_refused(
    tmp_path, model_file, capsys
):
    path, _ = model_file
    t = np.arange(10) * T
    _write_csv(tmp_path / "d.csv", {"t_s": t, "x_nm": t, "y_nm": t})
    assert _run("compensate", "--model", path, "--input", tmp_path / "d.csv",
                "--output", tmp_path / "u.csv") == 2  # fmt: skip
    assert "one position column" in capsys.readouterr().err
    _write_csv(tmp_path / "x.csv", {"t_s": t, "x_nm": t})
    assert _run("compensate", "--model", path, "--input", tmp_path / "x.csv",
                "--output", tmp_path / "u.csv", "--axis", "x") == 2  # fmt: skip
    assert "1-D" in capsys.readouterr().err
    assert not (tmp_path / "u.csv").exists()


def test_commands_outside_the_range_are_refused_and_compensate_needs_a_range(tmp_path, capsys):
    save_model(tmp_path / "norange.json", _model())
    t = np.arange(10) * T
    _write_csv(tmp_path / "big.csv", {"t_s": t, "u_nm": np.full(10, 1e6)})
    _write_csv(tmp_path / "yd.csv", {"t_s": t, "position_nm": np.linspace(0, 1e9, 10)})
    for cmd, inp in (("simulate", "big.csv"), ("compensate", "yd.csv")):
        args = [cmd, "--model", tmp_path / "norange.json", "--input", tmp_path / inp,
                "--output", tmp_path / "o.csv"]  # fmt: skip
        if cmd == "compensate":  # what is sent to a scanner must fit its travel
            assert _run(*args) == 2
            assert "states no range_nm: give --range-nm" in capsys.readouterr().err
        assert _run(*args, "--range-nm", 5000) == 2
        assert "outside the scanner range" in capsys.readouterr().err
        assert not (tmp_path / "o.csv").exists()
    # a prediction needs no range unless one is given
    args = ["simulate", "--model", tmp_path / "norange.json", "--input", tmp_path / "big.csv",
            "--output", tmp_path / "o.csv"]  # fmt: skip
    assert _run(*args) == 0
    assert _read(tmp_path / "o.csv")["position_nm"][-1] > 1e5


def test_limits_refuse_or_clip_with_a_report(tmp_path, model_file, capsys):
    path, _ = model_file
    t = np.arange(100) * T
    _write_csv(tmp_path / "yd.csv", {"t_s": t, "position_nm": np.linspace(0, 900, 100)})
    args = ["compensate", "--model", path, "--input", tmp_path / "yd.csv",
            "--output", tmp_path / "u.csv", "--range-nm", 2000]  # fmt: skip
    assert _run(*args) == 2
    err = capsys.readouterr().err
    assert "outside the scanner range" in err and "Pass --clip to clip" in err
    assert _run(*args, "--clip", "--clip-report", tmp_path / "clip.csv") == 0
    err = capsys.readouterr().err
    assert "warning: u_nm: clipped" in err and len(err.strip().splitlines()) == 1
    u = _read(tmp_path / "u.csv")["u_nm"]
    assert u.max() == 1000.0
    listed = np.genfromtxt(tmp_path / "clip.csv", delimiter=",", names=True, dtype=None)
    assert listed.size == int(np.sum(u == 1000.0))


def test_the_domain_is_enforced_unless_extrapolation_is_allowed(tmp_path, capsys):
    save_model(tmp_path / "m.json", _model(range_nm=5000.0, domain_nm=(-200.0, 200.0)))
    t = np.arange(200) * T
    _write_csv(tmp_path / "yd.csv", {"t_s": t, "position_nm": np.linspace(0, 400, 200)})
    args = ["compensate", "--model", tmp_path / "m.json", "--input", tmp_path / "yd.csv",
            "--output", tmp_path / "u.csv"]  # fmt: skip
    assert _run(*args) == 2
    assert "outside the model's domain" in capsys.readouterr().err
    assert _run(*args, "--allow-extrapolation") == 0
    assert _run("simulate", "--model", tmp_path / "m.json", "--input", tmp_path / "u.csv",
                "--output", tmp_path / "p.csv") == 0  # fmt: skip
    assert "the prediction extrapolates" in capsys.readouterr().err


def test_a_state_saved_continues_the_trajectory_exactly(tmp_path, model2d_file):
    path, _ = model2d_file
    t = np.arange(1000) * T
    xd = 250 * np.sin(2 * np.pi * 0.3 * t)
    _write_csv(tmp_path / "all.csv", {"t_s": t, "x_nm": xd})
    _write_csv(tmp_path / "a.csv", {"t_s": t[:400], "x_nm": xd[:400]})
    _write_csv(tmp_path / "b.csv", {"t_s": t[400:], "x_nm": xd[400:]})
    base = ["compensate", "--model", path, "--axis", "x"]
    assert _run(*base, "--input", tmp_path / "all.csv", "--output", tmp_path / "all_u.csv") == 0
    assert _run(*base, "--input", tmp_path / "a.csv", "--output", tmp_path / "a_u.csv",
                "--state-out", tmp_path / "s.json") == 0  # fmt: skip
    assert _run(*base, "--input", tmp_path / "b.csv", "--output", tmp_path / "b_u.csv",
                "--state-in", tmp_path / "s.json") == 0  # fmt: skip
    joined = np.concatenate([_read(tmp_path / "a_u.csv")["ux_nm"],
                             _read(tmp_path / "b_u.csv")["ux_nm"]])  # fmt: skip
    np.testing.assert_allclose(joined, _read(tmp_path / "all_u.csv")["ux_nm"], atol=1e-9)
    state = json.loads((tmp_path / "s.json").read_text())
    assert state["format"] == "piezocomp/model-state" and set(state) >= {"x"}


def test_printed_stamps_are_accepted_and_gaps_refused(tmp_path, model_file, capsys):
    path, _ = model_file
    n = 300
    t = np.round(np.arange(n) * 0.002 * (1 - 1e-5), 8)  # a recorder's rounded printout
    yd = 100 * np.sin(np.arange(n) / 30)
    _write_csv(tmp_path / "j.csv", {"t_s": t, "position_nm": yd})
    args = ["compensate", "--model", path, "--output", tmp_path / "u.csv"]
    assert _run(*args, "--input", tmp_path / "j.csv") == 0
    gap = np.delete(np.arange(n + 1) * 0.002, 150)
    _write_csv(tmp_path / "g.csv", {"t_s": gap, "position_nm": yd})
    assert _run(*args, "--input", tmp_path / "g.csv") == 2
    assert "not uniformly sampled" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("t_s,u_nm\n0,1\n0.008,2\n", "one position column"),
        ("t_s,position_nm\n0,1\n0.008,nan\n", "line 3 holds a non-finite value"),
        ("t_s,position_nm\n0,1\n0.008,2\n0.02,3\n", "not uniformly sampled"),
        ("t_s,position_nm\n0,1\n0.008\n", "truncated"),
        ("t_s,position_nm,position_nm\n0,1,1\n0.008,2,2\n", "names a column twice"),
        ("", "empty"),
    ],
)
def test_bad_input_is_one_line_error(tmp_path, model_file, capsys, content, match):
    path, _ = model_file
    (tmp_path / "in.csv").write_text(content)
    code = _run("compensate", "--model", path, "--input", tmp_path / "in.csv",
                "--output", tmp_path / "out.csv")  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert match in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.csv").exists()


def test_file_errors_name_the_users_file(tmp_path, model_file, capsys):
    path, _ = model_file
    assert _run("simulate", "--model", path, "--input", tmp_path / "nope.csv",
                "--output", tmp_path / "o.csv") == 2  # fmt: skip
    assert capsys.readouterr().err.strip().endswith(f"{tmp_path / 'nope.csv'}: no such file")
    (tmp_path / "in.csv").write_text("t_s,u_nm\n0,1\n0.008,2\n")
    (tmp_path / "adir").mkdir()
    assert _run("simulate", "--model", path, "--input", tmp_path / "in.csv",
                "--output", tmp_path / "adir") == 2  # fmt: skip
    err = capsys.readouterr().err
    assert f"{tmp_path / 'adir'}: is a directory" in err and ".tmp" not in err
    # missing output folders are created
    assert _run("simulate", "--model", path, "--input", tmp_path / "in.csv",
                "--output", tmp_path / "new" / "sub" / "o.csv") == 0  # fmt: skip


def test_bad_model_file_is_one_line_error(tmp_path, capsys):
    (tmp_path / "m.json").write_text(
        '{"format": "piezocomp/scanner-model", "version": 1, "gain": -'
    )
    (tmp_path / "in.csv").write_text("t_s,u_nm\n0,1\n0.008,2\n")
    code = _run("simulate", "--model", tmp_path / "m.json", "--input", tmp_path / "in.csv",
                "--output", tmp_path / "o.csv")  # fmt: skip
    assert code == 2
    assert "truncated" in capsys.readouterr().err


def test_usage_errors_are_one_line_exit_2(capsys):
    for argv in (["compensate", "--bogus"], ["nope"], ["bench", "--samples", "x"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "error:" in err and "usage" not in err


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


def test_bench_counts_what_it_ran_and_refuses_what_would_not_fit(capsys):
    assert main(["bench", "--json", "--samples", "1"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["reference_samples"] == 1 and figures["n_samples"] == 1
    assert main(["bench", "--samples", str(10**12)]) == 2
    assert "at most" in capsys.readouterr().err


def test_help_everywhere_without_markup(capsys):
    from piezocomp.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name in sub.choices:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
        out = capsys.readouterr().out
        assert "usage" in out
        for markup in ("``", ":func:", ":class:", ":mod:", ":meth:"):
            assert markup not in out, (name, markup)


def test_the_command_line_loads_only_its_own_command():
    """``--version``, ``--help`` and a mistyped command load no command's module (nor numba
    or scipy); a command loads its own and no other's."""
    import subprocess
    import sys

    probe = (
        "import sys, contextlib, io, json\n"
        "from piezocomp.cli import main\n"
        "quiet = io.StringIO()\n"
        "with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):\n"
        "    try:\n"
        "        main(sys.argv[1:])\n"
        "    except SystemExit:\n"
        "        pass\n"
        "watched = ('numba', 'scipy', 'piezocomp.commands.')\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith(watched))))\n"
    )
    for argv, allowed in (
        (["--version"], set()),
        (["--help"], set()),
        (["idenify"], set()),
        (["waveform", "--help"], {"piezocomp.commands.waveform"}),
    ):
        out = subprocess.run(
            [sys.executable, "-c", probe, *argv], capture_output=True, text=True, check=True
        ).stdout
        loaded = set(json.loads(out))
        commands = {m for m in loaded if m.startswith("piezocomp.commands.")}
        assert commands <= allowed | {"piezocomp.commands._common"}, (argv, commands)
        if not allowed:
            assert not {m for m in loaded if m.split(".")[0] in ("numba", "scipy")}, argv


def test_every_command_module_is_listed_with_the_help_it_registers():
    import pkgutil

    from piezocomp import commands
    from piezocomp.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    registering = {
        m.name
        for m in pkgutil.iter_modules(commands.__path__)
        if hasattr(__import__(f"piezocomp.commands.{m.name}", fromlist=["x"]), "register")
    }
    assert registering == {module for module, _ in commands.COMMANDS.values()}
    assert set(sub.choices) == set(commands.COMMANDS)
    helps = {a.dest: a.help for a in sub._choices_actions}
    assert helps == {name: h for name, (_, h) in commands.COMMANDS.items()}


def test_a_flag_the_command_does_not_take_points_at_its_own_help(capsys):
    assert main(["waveform", "--out", "w.csv", "--no-such-flag"]) == 2
    err = capsys.readouterr().err
    assert "unrecognized arguments: --no-such-flag" in err
    assert "(see piezocomp waveform --help)" in err
