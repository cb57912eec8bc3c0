"""Outputs that are not plain files, failed runs that would change outputs, inputs that
crashed or hung, and models that carry the range they were made for (issue 33)."""

from __future__ import annotations

import importlib.util
import json
import os
import stat
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from piezocomp.cli import main
from piezocomp.io.model_files import load_model, save_model
from piezocomp.model import ModelState, ScannerModel, simulate

T = 0.01
MODEL = ScannerModel(offset_nm=1.0, gain=0.6, thresholds_nm=[15.0, 60.0], weights=[0.05, 0.04],
                     creep_time_constants_s=[0.5], creep_gains=[0.02])  # fmt: skip


def run(capsys, *args) -> tuple[int, str]:
    capsys.readouterr()
    code = main([str(a) for a in args])
    err = capsys.readouterr().err
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in err, err
        assert lines[0].isprintable(), lines[0]
    return code, err


def commands_csv(path, n=50):
    t = np.arange(n) * T
    u = 100.0 * np.sin(t)
    path.write_text(
        "t_s,u_nm\n" + "\n".join(f"{a:.17g},{b:.17g}" for a, b in zip(t, u, strict=True))
    )


def record_csv(path, header="", n=1200):
    t = np.arange(n) * T
    u = 200.0 * np.sin(2 * np.pi * 0.5 * t) * (0.3 + 0.7 * np.abs(np.sin(0.3 * t)))
    y, _ = simulate(MODEL, u, T, ModelState.at_rest(MODEL, u[0]))
    rows = "\n".join(",".join(repr(float(v)) for v in r) for r in zip(t, u, y, strict=True))
    path.write_text(header + "t_s,u_nm,y_nm\n" + rows + "\n")


# --- outputs that are not plain files -------------------------------------------------------
def test_a_symlinked_output_is_written_through(tmp_path, capsys):
    save_model(tmp_path / "m.json", MODEL)
    commands_csv(tmp_path / "u.csv")
    (tmp_path / "real.csv").write_text("old")
    (tmp_path / "link.csv").symlink_to("real.csv")
    code, _ = run(capsys, "simulate", "--model", tmp_path / "m.json", "--input",
                  tmp_path / "u.csv", "--output", tmp_path / "link.csv")  # fmt: skip
    assert code == 0
    assert (tmp_path / "link.csv").is_symlink()
    assert (tmp_path / "real.csv").read_text().startswith("t_s,position_nm")


def test_a_pipe_as_output_is_written_into_not_replaced(tmp_path, capsys):
    """A device or a pipe (``--output /dev/null``) stays what it is."""
    save_model(tmp_path / "m.json", MODEL)
    commands_csv(tmp_path / "u.csv")
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    code, _ = run(capsys, "simulate", "--model", tmp_path / "m.json", "--input",
                  tmp_path / "u.csv", "--output", fifo)  # fmt: skip
    reader.join(10)
    assert code == 0
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert got and got[0].startswith(b"t_s,position_nm")


# --- failed runs change nothing -------------------------------------------------------------
def test_fit_checks_every_output_before_writing_any(tmp_path, capsys):
    record_csv(tmp_path / "rec.csv")
    (tmp_path / "model.json").write_text("the earlier model")
    (tmp_path / "summary").mkdir()
    (tmp_path / "afile").write_text("")
    base = ["fit", "--input", tmp_path / "rec.csv", "--output", tmp_path / "model.json",
            "--n-play", "2", "--n-creep", "1"]  # fmt: skip
    t0 = time.perf_counter()
    code, err = run(capsys, *base, "--summary", tmp_path / "summary")
    assert code == 2 and f"{tmp_path / 'summary'}: is a directory" in err
    code, err = run(capsys, *base, "--figures", tmp_path / "afile")
    assert code == 2 and "afile" in err
    code, err = run(capsys, *base, "--summary", tmp_path / "model.json")
    assert code == 2 and "same file" in err
    assert time.perf_counter() - t0 < 5  # refused before fitting
    assert (tmp_path / "model.json").read_text() == "the earlier model"
    # a missing figures folder is created, with the figure in it
    code, _ = run(capsys, *base, "--figures", tmp_path / "new" / "figs", "--range-nm", "1000")
    assert code == 0 and (tmp_path / "new" / "figs" / "fit.png").stat().st_size > 1000


def test_a_run_failing_midway_leaves_earlier_outputs(tmp_path, capsys, monkeypatch):
    """A command that fails after writing some of its files changes none of them."""
    from piezocomp.commands import fit

    record_csv(tmp_path / "rec.csv")
    (tmp_path / "model.json").write_text("the earlier model")

    def broken(*args, **kwargs):
        raise ValueError("the summary failed")

    monkeypatch.setattr(fit, "atomic_write_text", lambda *a: broken())
    code, err = run(capsys, "fit", "--input", tmp_path / "rec.csv", "--output",
                    tmp_path / "model.json", "--n-play", "2", "--n-creep", "1", "--summary",
                    tmp_path / "s.json", "--range-nm", "1000")  # fmt: skip
    assert code == 2 and "the summary failed" in err
    assert (tmp_path / "model.json").read_text() == "the earlier model"  # written, not put
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json", "rec.csv"]


# --- inputs that crashed or hung ------------------------------------------------------------
def test_csv_fields_beyond_the_csv_limit_are_one_line_errors(tmp_path, capsys):
    save_model(tmp_path / "m.json", MODEL)
    (tmp_path / "head.csv").write_text("t_s," + "x" * 200_000 + "\n0,1\n")
    (tmp_path / "field.csv").write_text("t_s,position_nm\n0," + "1" * 200_000 + "\n")
    for name in ("head.csv", "field.csv"):
        code, err = run(capsys, "compensate", "--model", tmp_path / "m.json", "--input",
                        tmp_path / name, "--output", tmp_path / "c.csv",
                        "--range-nm", "5000")  # fmt: skip
        assert code == 2 and "field larger than field limit" in err and len(err) < 400


def test_deeply_nested_model_metadata_is_a_one_line_error(tmp_path, capsys):
    save_model(tmp_path / "ok.json", MODEL)
    text = (tmp_path / "ok.json").read_text().rstrip()[:-1]
    text += ', "metadata": ' + "[" * 100_000 + "]" * 100_000 + "}"
    (tmp_path / "deep.json").write_text(text)
    commands_csv(tmp_path / "u.csv")
    code, err = run(capsys, "simulate", "--model", tmp_path / "deep.json", "--input",
                    tmp_path / "u.csv", "--output", tmp_path / "p.csv")  # fmt: skip
    assert code == 2 and "nested too deeply" in err


def test_a_garbage_spm_fails_fast(tmp_path, capsys):
    pytest.importorskip("pySPM", reason="pySPM (pip install '.[files]') not installed")
    rng = np.random.default_rng(0)
    (tmp_path / "g.spm").write_bytes(b"\\*File list\r\n" + rng.bytes(300_000))
    t0 = time.perf_counter()
    code, err = run(capsys, "loop", "--scan", tmp_path / "g.spm", "--out", tmp_path / "o")
    assert code == 2 and "File list end" in err
    assert time.perf_counter() - t0 < 10
    assert not (tmp_path / "o").exists()


def test_a_truncated_ibw_says_one_printable_line(tmp_path, capsys):
    pytest.importorskip("igor2", reason="igor2 (pip install '.[files]') not installed")
    spec = importlib.util.spec_from_file_location(
        "afm_files_tests", Path(__file__).parent / "io" / "test_afm_files.py"
    )
    assert spec is not None and spec.loader is not None
    helpers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(helpers)
    write_ibw5 = helpers.write_ibw5

    layers = np.random.default_rng(1).normal(size=(32, 16, 2)) * 1e-9
    whole = tmp_path / "whole.ibw"
    write_ibw5(whole, layers, labels=["HeightTrace", "HeightRetrace"], sfa=[1e-8, 1e-8])
    raw = whole.read_bytes()
    for n in (400, len(raw) // 2, len(raw) - 10):
        (tmp_path / "cut.ibw").write_bytes(raw[:n])
        code, err = run(capsys, "loop", "--scan", tmp_path / "cut.ibw", "--out", tmp_path / "o")
        assert code == 2 and "cut.ibw: cannot read" in err and "\\x" not in err


# --- models carry their range ---------------------------------------------------------------
def test_fit_takes_the_range_from_the_record_and_says_so(tmp_path, capsys):
    record_csv(tmp_path / "rec.csv", header="# range_nm: 4000\n")
    wave = json.dumps({"range_nm": 3000.0})
    record_csv(tmp_path / "wave.csv", header=f"# piezocomp_waveform: {wave}\n")
    for name, expected in (("rec.csv", 4000.0), ("wave.csv", 3000.0)):
        out = tmp_path / f"{name}.json"
        code, _ = run(capsys, "fit", "--input", tmp_path / name, "--output", out, "--n-play",
                      "2", "--n-creep", "1", "--no-refine")  # fmt: skip
        assert code == 0
        assert load_model(out).range_nm == expected
        assert name in json.loads(out.read_text())["metadata"]["range_nm_from"]
    # so compensate needs no --range-nm
    t = np.arange(50) * T
    (tmp_path / "want.csv").write_text(
        "t_s,position_nm\n" + "\n".join(f"{a:.17g},{50 * np.sin(a):.17g}" for a in t)
    )
    code, _ = run(capsys, "compensate", "--model", tmp_path / "rec.csv.json", "--input",
                  tmp_path / "want.csv", "--output", tmp_path / "u.csv")  # fmt: skip
    assert code == 0


def test_the_waveform_carries_its_range_into_the_record(tmp_path, capsys):
    code, _ = run(capsys, "waveform", "--out", tmp_path / "w.csv", "--range-nm", "6000",
                  "--n-decaying", "0", "--n-random", "0", "--n-steady", "2")  # fmt: skip
    assert code == 0
    from piezocomp.commands._common import record_range

    assert record_range(tmp_path / "w.csv")[0] == 6000.0
