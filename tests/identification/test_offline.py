"""Offline identification: a waveform file run on an instrument, recorded, identified."""

import json

import numpy as np
import pytest

from piezocomp.cli import main
from piezocomp.io import load_model, read_signal, write_signal
from piezocomp.virtual_afm import VirtualAFM

QUICK_WAVEFORM = ["--n-steady", "3", "--n-decaying", "6", "--n-random", "8", "--max-dwell-s", "2",
                  "--speed-factors", "0.5", "1", "2"]  # fmt: skip
"""A short waveform at 125-500 nm/s (the figures below were measured on it)."""


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Run the waveform on the gentle virtual AFM as a user would on a real one."""
    tmp = tmp_path_factory.mktemp("offline")
    assert main(["waveform", "--out", str(tmp / "wf.csv"), *QUICK_WAVEFORM]) == 0
    wf = read_signal_like(tmp / "wf.csv")
    x = np.linspace(-440.0, 440.0, 12)
    particles = np.column_stack([x, np.zeros_like(x)])  # one line through 12 particles
    afm = VirtualAFM.from_preset("gentle", seed=2, sample_period_s=0.008, particles=particles)
    afm.move_to(wf["u_nm"][0], 0.0, 250.0)
    rec = afm.run(np.column_stack([wf["u_nm"], np.zeros(wf["u_nm"].size)]))
    t = rec.t_s - rec.t_s[0]
    columns = {"t_s": t, "u_nm": rec.command_nm[:, 0], "height_nm": rec.height_nm}
    write_signal(tmp / "record.csv", columns, metadata=wf["meta"])
    return tmp


def read_signal_like(path):
    """The waveform file has no height column: read its metadata and command directly."""
    lines = path.read_text().splitlines()
    meta = dict(line[2:].split(": ", 1) for line in lines if line.startswith("# "))
    body = [line for line in lines if not line.startswith("#")]
    assert body[0] == "t_s,u_nm"
    u = np.array([float(line.split(",")[1]) for line in body[1:]])
    return {"u_nm": u, "meta": meta}


def test_identify_record_writes_models_and_summary(recorded, capsys):
    out = recorded / "ident"
    code = main(["identify", "--record", str(recorded / "record.csv"), "--out", str(out),
                 "--quick"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    model = load_model(out / "model.json")
    assert model.n_play == 8
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "record"
    # held-out heights are predicted to about the height noise and flank steepness allow
    # (measured 0.3-0.5 nm on this record); the starting loop model does worse
    rms = summary["heldout_height_rms_nm"]
    assert rms["batch"] < 1.0
    assert rms["batch"] <= rms["initial"]
    # the RLS's h re-indexed by its own estimate (--quick: one round), kept if it predicts
    # the held-out heights better than the loop's h
    assert summary["settings"]["estimation"]["rls_reindex_rounds"] == 1
    assert summary["rls_reindex_round"] in (0, 1)
    assert summary["batch_restart"] is None  # the batch model is not far worse here
    assert summary["heldout_before_final_fit"] is True
    # the same entries as an axis of a virtual or an instrument run (AxisIdentification.summary)
    assert summary["line"]["slow_nm"] is None and summary["line"]["loop_pairs"] > 10
    assert summary["orders"]["n_play"] == 8 and summary["rls_orders"]["n_play"] == 8
    assert summary["instrument_s"] == {"total": 0.0}  # a recorded run: no instrument time here


def test_the_record_figures_are_the_virtual_runs(recorded, capsys):
    out = recorded / "figs"
    assert main(["identify", "--record", str(recorded / "record.csv"), "--out", str(out),
                 "--quick"]) == 0  # fmt: skip
    names = {p.name for p in out.glob("*.png")}
    assert names == {f"{n}_x.png" for n in ("waveform", "loop", "profile", "rls_traces",
                                            "prediction_error", "heldout_residual")}  # fmt: skip
    assert json.loads((out / "summary.json").read_text())["figures"] == sorted(names, key=[
        "waveform_x.png", "loop_x.png", "profile_x.png", "rls_traces_x.png",
        "prediction_error_x.png", "heldout_residual_x.png"].index)  # fmt: skip


def test_a_record_taken_before_the_line_settled_is_flagged(recorded, tmp_path, capsys):
    """The tip jumped 300 nm along the slow axis onto the line and the record started at
    once: the slow axis' creep moved the line under the tip during the record, and the
    held-out heights are predicted to several nm only. It must not pass quietly: the command
    says why, keeps the files for inspection and exits 1."""
    wf = read_signal_like(recorded / "wf.csv")
    x = np.linspace(-440.0, 440.0, 12)
    afm = VirtualAFM.from_preset(
        "cpr5-nodrift", seed=2, particles=np.column_stack([x, np.zeros(12)])
    )
    afm.move_to(wf["u_nm"][0], -300.0, 5000.0)
    afm.move_to(wf["u_nm"][0], 0.0, 5000.0)
    rec = afm.run(np.column_stack([wf["u_nm"], np.zeros(wf["u_nm"].size)]))
    cols = {"t_s": rec.t_s - rec.t_s[0], "u_nm": rec.command_nm[:, 0], "height_nm": rec.height_nm}
    write_signal(tmp_path / "unsettled.csv", cols, metadata=wf["meta"])
    out = tmp_path / "o"
    assert main(["identify", "--record", str(tmp_path / "unsettled.csv"), "--out", str(out),
                 "--quick", "--no-figures"]) == 1  # fmt: skip
    err = capsys.readouterr().err
    assert "warning" in err and "held-out heights" in err and "Record again" in err
    assert (
        err.strip()
        .splitlines()[-1]
        .startswith(
            "piezocomp identify: error: the model fails its own validation (axis x: held-out"
        )
    )
    summary = json.loads((out / "summary.json").read_text())
    assert any("Record again" in f for f in summary["findings"])
    assert summary["validation_failures"] and (out / "model.json").exists()


def test_record_without_waveform_metadata_is_refused(recorded, capsys):
    sig = read_signal(recorded / "record.csv")
    write_signal(recorded / "nometa.csv", dict(sig), metadata={})
    code = main(["identify", "--record", str(recorded / "nometa.csv"), "--out",
                 str(recorded / "o1")])  # fmt: skip
    assert code == 2
    assert "no 'piezocomp_waveform' metadata" in capsys.readouterr().err


def test_record_of_another_waveform_is_refused(recorded, capsys):
    sig = read_signal(recorded / "record.csv")
    cols = dict(sig)
    cols["u_nm"] = cols["u_nm"] + 5.0
    write_signal(recorded / "shifted.csv", cols, metadata=dict(sig.metadata))
    code = main(["identify", "--record", str(recorded / "shifted.csv"), "--out",
                 str(recorded / "o2")])  # fmt: skip
    assert code == 2
    assert "not a record of this waveform" in capsys.readouterr().err


def test_a_rounding_recorder_needs_its_tolerance_and_lengths_are_named(recorded, capsys):
    """A recorder that prints the command to 0.01 nm is refused with the reason named, and
    accepted with --command-tolerance-nm; a record one sample too long says so."""
    sig = read_signal(recorded / "record.csv")
    cols = dict(sig)
    cols["u_nm"] = np.round(cols["u_nm"], 2)
    write_signal(recorded / "rounded.csv", cols, metadata=dict(sig.metadata))
    base = ["identify", "--record", str(recorded / "rounded.csv"), "--quick", "--no-figures"]
    assert main([*base, "--out", str(recorded / "r1")]) == 2
    assert "--command-tolerance-nm" in capsys.readouterr().err
    assert main([*base, "--command-tolerance-nm", "0.006", "--out", str(recorded / "r2")]) == 0
    longer = {k: np.append(v, v[-1] + (v[-1] - v[-2])) for k, v in dict(sig).items()}
    write_signal(recorded / "long.csv", longer, metadata=dict(sig.metadata))
    assert main(["identify", "--record", str(recorded / "long.csv"), "--out",
                 str(recorded / "r3")]) == 2  # fmt: skip
    assert "more than the waveform's" in capsys.readouterr().err


def test_virtual_options_are_refused_offline_and_a_missing_scale_is_said(recorded, capsys):
    rec = str(recorded / "record.csv")
    for opt in (["--span-nm", "2000"], ["--reference", "none"], ["--seed", "3"]):
        assert main(["identify", "--record", rec, *opt, "--out", str(recorded / "v")]) == 2
        err = capsys.readouterr().err
        assert opt[0] in err and "virtual AFM option" in err
    assert main(["identify", "--record", rec, "--quick", "--no-figures",
                 "--out", str(recorded / "v2")]) == 0  # fmt: skip
    out = capsys.readouterr()
    assert "no length reference" in out.out and "no length reference" in out.err
    summary = json.loads((recorded / "v2" / "summary.json").read_text())
    # the waveform file fixes the acquisition: only its peak finding is a setting offline
    assert summary["settings"]["acquisition"] == {"min_prominence_nm": 3.0}
    assert summary["grating"] is None
    assert summary["waveform"]["span_nm"] == 1000.0


def test_a_recorded_grating_scales_the_offline_models(recorded, capsys):
    """Steady cycles over a grating, recorded on two lines as a user would, scale the
    models: the batch model's gain and weights are those of the run without it times the
    grating's ``alpha`` over the span condition's (the frame map the run without it used)."""
    from piezocomp.virtual_afm import Grating

    wf_args = ["--n-steady", "4", "--n-decaying", "0", "--n-random", "0"]
    assert main(["waveform", "--out", str(recorded / "gwf.csv"), *wf_args]) == 0
    wf = read_signal_like(recorded / "gwf.csv")
    lab = VirtualAFM.from_preset("gentle", seed=2, sample_period_s=0.008, grating=Grating())
    files = []
    for i, slow in enumerate((-50.0, 50.0)):
        lab.move_to(wf["u_nm"][0], slow, 250.0)
        rec = lab.run(np.column_stack([wf["u_nm"], np.full(wf["u_nm"].size, slow)]))
        cols = {
            "t_s": rec.t_s - rec.t_s[0],
            "u_nm": rec.command_nm[:, 0],
            "height_nm": rec.height_nm,
        }
        write_signal(recorded / f"grating{i}.csv", cols, metadata=wf["meta"])
        files.append(str(recorded / f"grating{i}.csv"))
    base = ["identify", "--record", str(recorded / "record.csv"), "--quick"]
    assert main([*base, "--out", str(recorded / "plain")]) == 0
    code = main([*base, "--out", str(recorded / "ref"), "--grating-record", *files,
                 "--grating-pitch-nm", "278"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    summary = json.loads((recorded / "ref" / "summary.json").read_text())
    ref = summary["reference"]["batch"]
    assert len(ref["line_alphas"]) == 2 and ref["passes"] == 8  # 2 lines x 2 cycles x 2
    assert 0.9 < ref["alpha"] < 1.0  # the gentle scanner's +-500 nm cycle is narrower
    plain, scaled = (load_model(recorded / d / "model.json") for d in ("plain", "ref"))
    span_alpha = json.loads((recorded / "plain" / "summary.json").read_text())["frame_map"]
    span_alpha = span_alpha["alpha"]
    assert 0.9 < span_alpha < 1.1  # the loop's span, on the model's own steady cycles
    assert summary["frame_map"]["alpha"] == ref["alpha"]
    factor = ref["alpha"] / span_alpha
    assert scaled.gain == pytest.approx(factor * plain.gain, rel=1e-12)
    np.testing.assert_allclose(scaled.weights, factor * plain.weights, rtol=1e-12)
    # the pitch is the user's to state; a waveform with a part B is not a grating record
    code = main([*base, "--out", str(recorded / "o3"), "--grating-record", *files])
    assert code == 2 and "needs --grating-pitch-nm" in capsys.readouterr().err
    code = main([*base, "--out", str(recorded / "o4"), "--grating-pitch-nm", "278",
                 "--grating-record", str(recorded / "record.csv")])  # fmt: skip
    assert code == 2 and "steady cycles only" in capsys.readouterr().err


def test_minor_loop_grating_lines_recorded_offline_give_the_driven_record(tmp_path, capsys):
    """``piezocomp waveform --grating-line I`` writes line I of the minor-loop grating path;
    the lines recorded by the instrument's own software read back as the record the driven
    path makes on the same instrument (the same commands, the same passes: the sweeps, two
    each way per line), so the offline scale is the driven one's."""
    from piezocomp.identification.offline import grating_record_from_signals
    from piezocomp.identification.reference.grating import measure_grating
    from piezocomp.virtual_afm import Grating

    slows = (-1000.0, 0.0, 100.0, 1000.0)
    files = []
    for i in range(len(slows)):
        out = tmp_path / f"gl{i}.csv"
        assert main(["waveform", "--out", str(out), "--grating-line", str(i), "--span-nm",
                     "2000"]) == 0  # fmt: skip
        files.append(out)
    assert "sweeps over 70% of the span" in capsys.readouterr().out
    lab = VirtualAFM.from_preset("gentle", seed=2, sample_period_s=0.008, grating=Grating())
    signals = []
    for f, slow in zip(files, slows, strict=True):
        wf = read_signal_like(f)
        lab.move_to(wf["u_nm"][0], slow, 250.0)
        rec = lab.run(np.column_stack([wf["u_nm"], np.full(wf["u_nm"].size, slow)]))
        cols = {"t_s": rec.t_s - rec.t_s[0], "x_nm": rec.command_nm[:, 0],
                "y_nm": rec.command_nm[:, 1], "height_nm": rec.height_nm}  # fmt: skip
        write_signal(f.with_suffix(".rec.csv"), cols, metadata=wf["meta"])
        signals.append(read_signal(f.with_suffix(".rec.csv")))
    offline = grating_record_from_signals(signals, 278.0)
    driven = measure_grating(
        VirtualAFM.from_preset("gentle", seed=2, sample_period_s=0.008, grating=Grating()),
        278.0, span_nm=2000.0, n_lines=3, line_spacing_nm=1000.0, path="minor_loops",
    )  # fmt: skip
    assert offline.pass_lines == driven.pass_lines and len(offline.passes) == 16
    for (a, b), (c, d) in zip(offline.passes, driven.passes, strict=True):
        assert b - a == d - c
        np.testing.assert_array_equal(offline.u_nm[a:b], driven.u_nm[c:d])
    assert offline.line_slow_nm == pytest.approx(slows)
    # conflicting options are refused, naming them
    code = main(["waveform", "--out", str(tmp_path / "x.csv"), "--grating-line", "0",
                 "--n-steady", "4"])  # fmt: skip
    assert code == 2 and "--n-steady cannot go with it" in capsys.readouterr().err
    code = main(["waveform", "--out", str(tmp_path / "x.csv"), "--n-sweeps", "4"])
    assert code == 2 and "give --grating-line I with it" in capsys.readouterr().err
    # one kind of line at a time
    steady = tmp_path / "steady.csv"
    assert main(["waveform", "--out", str(steady), "--n-decaying", "0", "--n-random", "0"]) == 0
    with pytest.raises(ValueError, match="give the lines of one kind"):
        grating_record_from_signals([signals[0], read_signal_like_signal(steady)], 278.0)


def read_signal_like_signal(path):
    """A waveform file as a recorded signal with zero heights (its command and metadata)."""
    from piezocomp.io.signals import RecordedSignal

    wf = read_signal_like(path)
    n = wf["u_nm"].size
    return RecordedSignal(
        {"t_s": np.arange(n) * 0.008, "u_nm": wf["u_nm"], "height_nm": np.zeros(n)},
        metadata=wf["meta"], source=str(path),
    )  # fmt: skip


def test_waveform_files_carry_their_speed_factors_and_older_files_still_read(tmp_path):
    from piezocomp.identification.acquisition.waveforms import identification_waveform
    from piezocomp.identification.offline import WAVEFORM_KEY, waveform_from_metadata

    out = tmp_path / "wf.csv"
    assert main(["waveform", "--out", str(out), *QUICK_WAVEFORM, "--speed-factors", "1", "3"]) == 0
    meta = read_signal_like(out)["meta"]
    params = json.loads(meta[WAVEFORM_KEY])
    assert params["speed_factors"] == [1.0, 3.0]
    wf, _ = waveform_from_metadata(meta)
    np.testing.assert_array_equal(wf.u_nm, read_signal_like(out)["u_nm"])
    # a file written before the factors existed ran part B at one speed
    del params["speed_factors"]
    old, back = waveform_from_metadata({WAVEFORM_KEY: json.dumps(params)})
    assert back["speed_factors"] == [1.0]
    one = identification_waveform(0.0, 1000.0, 250.0, 0.008, n_steady=3, n_decaying=6,
                                  n_random=8, max_dwell_s=2.0, rng=0)  # fmt: skip
    np.testing.assert_array_equal(old.u_nm, one.u_nm)
    with pytest.raises(ValueError, match="exactly the keys"):
        waveform_from_metadata({WAVEFORM_KEY: json.dumps({**params, "speed": 1})})
