"""``piezocomp fit`` through ``piezocomp.cli.main``."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from piezocomp.cli import main
from piezocomp.io.model_files import load_model
from piezocomp.model import ModelState, ScannerModel, simulate
from piezocomp.sensor.fit import place_thresholds, place_time_constants

T = 0.01
TRUTH = ScannerModel(
    offset_nm=-20.0,
    gain=0.6,
    thresholds_nm=[60.0, 150.0, 250.0],
    weights=[0.2, 0.1, 0.05],
    creep_time_constants_s=[1.0],
    creep_gains=[0.1],
)


def _record(n: int = 2000):
    t = np.arange(n) * T
    u = 300.0 + 400.0 * np.sin(2 * np.pi * 0.5 * t) * (
        0.3 + 0.7 * np.abs(np.sin(2 * np.pi * 0.05 * t))
    )
    y, _ = simulate(TRUTH, u, T, ModelState.at_rest(TRUTH, u[0]))
    y = y + np.random.default_rng(0).normal(0.0, 0.5, n)
    return t, u, y


def _write_csv(path, header, rows):
    lines = [",".join(header)] + [",".join(repr(float(v)) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def test_fit_writes_model_summary_and_figure(tmp_path, capsys):
    t, u, y = _record()
    data = tmp_path / "rec.csv"
    _write_csv(data, ["t_s", "u_nm", "y_nm"], np.column_stack((t, u, y)))
    out = tmp_path / "model.json"
    summary = tmp_path / "summary.json"
    code = main(
        [
            "fit",
            "--input", str(data),
            "--output", str(out),
            "--n-play", "4",
            "--n-creep", "1",
            "--figures", str(tmp_path),
            "--summary", str(summary),
        ]
    )  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    assert "refined val" in printed and "% of range" in printed
    assert "written to " + str(out) + ": the refined model, better on the held-out" in printed
    model = load_model(out)
    assert isinstance(model, ScannerModel)
    assert (model.n_play, model.n_creep) == (4, 1)
    doc = json.loads(out.read_text())
    meta = doc["metadata"]
    assert meta["data_file"] == str(data)
    assert meta["n_play"] == 4 and meta["orders_selected"] is False
    assert meta["figures"] == [str(tmp_path / "fit.png")]
    assert (tmp_path / "fit.png").stat().st_size > 10_000
    figs = json.loads(summary.read_text())
    assert figs["refined"]["validation"]["n_samples"] == 500
    assert figs["refined"]["validation"]["rms_nm"] < 2.0  # noise 0.5 nm


def test_fit_npz_named_columns_and_selected_orders(tmp_path, capsys):
    t, u, y = _record()
    data = tmp_path / "rec.npz"
    np.savez(data, time=t, volts_nm=u, sensor=y)
    out = tmp_path / "m.json"
    code = main(
        [
            "fit",
            "--input", str(data),
            "--output", str(out),
            "--time-column", "time",
            "--input-column", "volts_nm",
            "--output-column", "sensor",
            "--select-orders",
            "--no-refine",
        ]
    )  # fmt: skip
    assert code == 0
    assert "(selected)" in capsys.readouterr().out
    meta = json.loads(out.read_text())["metadata"]
    assert meta["orders_selected"] is True
    assert sum(row["chosen"] for row in meta["order_trials"]) == 1


def _bad_csv(tmp_path, kind):
    t, u, y = _record(50)
    header = ["t_s", "u_nm", "y_nm"]
    rows = np.column_stack((t, u, y))
    if kind == "missing":
        header, rows = ["t_s", "u_nm"], rows[:, :2]
    elif kind == "nan":
        rows[17, 2] = np.nan
    elif kind == "uneven":
        rows[30:, 0] += 0.004
    path = tmp_path / f"{kind}.csv"
    _write_csv(path, header, rows)
    return path


@pytest.mark.parametrize(
    ("kind", "words"),
    [
        ("missing", ["no column 'y_nm'"]),
        ("nan", ["line 19", "non-finite"]),
        ("uneven", ["uniformly", "line 32"]),
    ],
)
def test_bad_csv_exits_2_with_one_line(tmp_path, capsys, kind, words):
    path = _bad_csv(tmp_path, kind)
    out = tmp_path / "m.json"
    code = main(["fit", "--input", str(path), "--output", str(out)])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("piezocomp fit: error:")
    for w in words:
        assert w in err
    assert not out.exists()


def test_orders_and_selection_are_exclusive(tmp_path, capsys):
    t, u, y = _record(200)
    data = tmp_path / "rec.csv"
    _write_csv(data, ["t_s", "u_nm", "y_nm"], np.column_stack((t, u, y)))
    code = main(
        ["fit", "--input", str(data), "--output", str(tmp_path / "m.json"),
         "--n-play", "4", "--select-orders"]
    )  # fmt: skip
    assert code == 2
    assert "not both" in capsys.readouterr().err


def test_excitation_warning_is_printed_not_raised(tmp_path, capsys):
    t = np.arange(600) * T
    u = np.where(t > 1.0, 100.0, 0.0)  # one step: play outputs are affine in u
    y = 0.5 * u
    data = tmp_path / "rec.csv"
    _write_csv(data, ["t_s", "u_nm", "y_nm"], np.column_stack((t, u, y)))
    code = main(
        ["fit", "--input", str(data), "--output", str(tmp_path / "m.json"),
         "--n-play", "2", "--n-creep", "1", "--no-refine"]
    )  # fmt: skip
    assert code == 0
    err = capsys.readouterr().err
    assert "piezocomp fit: warning:" in err and "collinear" in err


def test_missing_file_and_unknown_type(tmp_path, capsys):
    assert main(["fit", "--input", str(tmp_path / "no.csv"), "--output", "m.json"]) == 2
    assert "no such file" in capsys.readouterr().err
    other = tmp_path / "rec.txt"
    other.write_text("t_s,u_nm,y_nm\n")
    assert main(["fit", "--input", str(other), "--output", "m.json"]) == 2
    assert "unsupported" in capsys.readouterr().err


def test_fit_says_when_it_keeps_the_linear_model(tmp_path, capsys, monkeypatch):
    """A refinement worse on the held-out part (its gain made 5 % off) is not written, and
    the command says so with both figures."""
    from dataclasses import replace

    from piezocomp.identification.estimation import batch

    real = batch.refine

    def worse(model, *args, **kwargs):
        res = real(model, *args, **kwargs)
        return replace(res, model=replace(res.model, gain=1.05 * res.model.gain))

    monkeypatch.setattr(batch, "refine", worse)
    t, u, y = _record()
    data = tmp_path / "rec.csv"
    _write_csv(data, ["t_s", "u_nm", "y_nm"], np.column_stack((t, u, y)))
    out = tmp_path / "model.json"
    args = ["fit", "--input", str(data), "--output", str(out), "--n-play", "4", "--no-reference"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "the NNLS model: the refinement predicted the held-out part worse" in printed
    meta = json.loads(out.read_text())["metadata"]
    assert meta["chosen"] == "linear"
    assert meta["refined"]["validation"]["rms_nm"] > meta["nnls"]["validation"]["rms_nm"]


def test_fit_creep_coupling_fit_and_its_refusals(tmp_path, capsys):
    """``--creep-coupling fit`` on a record of a model of the extended family (eq 2'): the
    coupling is found and written (mathematics only: the record comes from that family).
    A held coupling is kept by both stages; a negative one is refused in one line."""
    t, u, _ = _record()
    coupled = ScannerModel(  # the thresholds and time constant the fit places
        offset_nm=-20.0, gain=0.6, thresholds_nm=place_thresholds(u[:1500], 3),
        weights=[0.2, 0.1, 0.05], creep_time_constants_s=place_time_constants(1500, T, 1, 0.1),
        creep_gains=[0.1], creep_coupling=0.5,
    )  # fmt: skip
    y, _ = simulate(coupled, u, T, ModelState.at_rest(coupled, u[0]))
    data = tmp_path / "rec.csv"
    _write_csv(data, ["t_s", "u_nm", "y_nm"], np.column_stack((t, u, y)))
    out, summary = tmp_path / "m.json", tmp_path / "s.json"
    args = ["fit", "--input", str(data), "--output", str(out), "--n-play", "3", "--n-creep",
            "1", "--no-refine", "--summary", str(summary), "--initial-state", "rest",
            "--no-reference"]  # fmt: skip
    assert main([*args, "--creep-coupling", "fit"]) == 0
    printed = capsys.readouterr().out
    found = re.search(r"creep coupling: search found beta = ([0-9.]+)", printed)
    assert found and float(found.group(1)) == pytest.approx(0.5, rel=0.02)
    assert "the coupled family kept" in printed
    model = load_model(out)
    assert isinstance(model, ScannerModel)
    assert model.creep_coupling == pytest.approx(0.5, rel=0.02)
    figs = json.loads(summary.read_text())
    assert figs["coupling_search"]["family"] == "coupled"
    assert figs["creep_coupling"] == model.creep_coupling
    args.remove("--no-refine")
    assert main([*args, "--creep-coupling", "0.5"]) == 0  # held by both stages
    assert load_model(out).creep_coupling == 0.5
    capsys.readouterr()
    assert main([*args, "--creep-coupling", "-1"]) == 2
    assert "must be 'fit' or a number >= 0" in capsys.readouterr().err


def test_fit_keeps_the_reference_when_it_predicts_better_and_says_so(tmp_path, capsys):
    """Two plays and no creep cannot follow a record with creep: the reference (the same
    family by plain NNLS, 16 x 19) is written, and the command names it; the summary
    carries its figures and the initial state the held-out part chose."""
    t, u, y = _record()
    data = tmp_path / "rec.csv"
    _write_csv(data, ["t_s", "u_nm", "y_nm"], np.column_stack((t, u, y)))
    out, summary = tmp_path / "model.json", tmp_path / "summary.json"
    args = ["fit", "--input", str(data), "--output", str(out), "--n-play", "2", "--n-creep", "0"]
    assert main([*args, "--summary", str(summary)]) == 0
    printed = capsys.readouterr().out
    assert "written to" in printed and "the reference fit (N_H=16, N_c=19" in printed
    assert "initial state: " in printed and "chosen by the NNLS fits' held-out rms" in printed
    meta = json.loads(summary.read_text())
    assert meta["chosen"] == "reference" and meta["reference"]["n_creep"] == 19
    assert set(meta["state_scores"]) == {"rest", "zero", "estimate"}
    assert json.loads(out.read_text())["metadata"]["n_play"] == 16


def test_fit_without_a_held_out_part_says_its_state_was_judged_on_the_fitted_part(tmp_path, capsys):
    t, u, y = _record()
    data = tmp_path / "rec.csv"
    _write_csv(data, ["t_s", "u_nm", "y_nm"], np.column_stack((t, u, y)))
    out = tmp_path / "model.json"
    args = ["fit", "--input", str(data), "--output", str(out), "--validation-fraction", "0"]
    assert main(args) == 0
    assert "chosen by the NNLS fits' fitted part's rms" in capsys.readouterr().out
