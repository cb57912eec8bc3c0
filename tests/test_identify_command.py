"""``piezocomp identify`` through ``main([...])`` with the reduced configuration."""

from __future__ import annotations

import json

import numpy as np
import pytest

from piezocomp.cli import main
from piezocomp.inverse import compensate
from piezocomp.io.model_files import load_model
from piezocomp.model import ScannerModel


def test_identify_writes_model_figures_and_summary(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["identify", "--preset", "gentle", "--axis", "x", "--out", str(out), "--quick",
            "--budget-min", "30"]  # fmt: skip
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    # the budget shortened the protocol (the quick one's 96-line overview at 250 nm/s alone
    # takes 26 minutes) and the plan was kept: the stages it fixes took what it said
    assert summary["budget_min"] == 30  # the quick protocol has no extra line to leave out
    assert summary["budget_steps"] == ["64-line overviews", "overviews at 1 um/s"]
    assert summary["settings"]["acquisition"]["overview_speed_nm_per_s"] == 1000.0
    planned, took = summary["planned_instrument_s"]["x"], summary["axes"]["x"]["instrument_s"]
    assert planned["total"] <= 30 * 60
    for stage in ("overview", "settling", "record and check", "calibration cycles"):
        assert planned[stage] * 0.98 <= took[stage] <= planned[stage] * 1.5 + 10.0, stage
    for method in ("rls", "batch"):
        for key in ("validation_max_error_nm", "validation_rms_error_nm"):
            assert np.isfinite(summary["methods"][method][key])
    assert summary["orders"]["x"]["n_play"] == 8
    assert "timing_s" in summary
    settings = summary["settings"]  # every setting of the run, for reproducing it
    est, acq = settings["estimation"], settings["acquisition"]
    assert est["orders"] == [[8, 2]] and est["rls_continue"] is None  # --quick
    assert est["rls_settings"]["free"] == ["c", "a", "w", "y0"]
    # the defaults make the model the positioning needs: the working area and its speeds
    assert acq["waveform"]["speed_factors"] == [0.5, 1.0, 2.0, 4.0, 8.0]
    assert acq["span_nm"] == 2000.0
    assert est["creep_smoothing_nm"] == 300.0 and est["weight_smoothing_nm"] == 1000.0
    # the default length reference: a virtual grating scanned with the same scanner
    assert summary["reference"] == "grating"
    ref = summary["axes"]["x"]["reference"]["batch"]
    assert 0.9 < ref["alpha"] < 1.0 and ref["passes"] == 24  # 6 lines x 4 sweeps (minor loops)
    assert summary["axes"]["x"]["frame_map"]["alpha"] == ref["alpha"]
    # the RLS keeps its own frame (its h may be re-indexed by it), scaled by its own fit
    rls_ref = summary["axes"]["x"]["reference"]["rls"]
    assert summary["axes"]["x"]["rls_frame_map"]["alpha"] == rls_ref["alpha"]
    assert est["rls_reindex_rounds"] == 1 and est["rls_reindex_passes"] == 2
    assert isinstance(summary["axes"]["x"]["rls_profile_reindexed"], bool)
    # the held-out scores are from before the final fit over the whole record
    assert summary["axes"]["x"]["heldout_before_final_fit"] is True
    assert settings["rounds"]["final_rounds"] == 1
    assert settings["rounds"]["rls_final_passes"] == 2
    check = summary["axes"]["x"]["line_check"]  # the line checked after the record
    assert 0 < check["noise_rms_nm"] and 0 < check["height_change_rms_nm"]
    assert check["height_change_rms_nm"] <= check["height_change_max_nm"]
    without = summary["methods_without_reference"]["batch"]["validation_max_error_nm"]
    assert summary["methods"]["batch"]["validation_max_error_nm"] < without
    model = load_model(out / "model.json")
    assert isinstance(model, ScannerModel) and model.n_play == 8
    assert model.domain_nm == (-1000.0, 1000.0)
    u = compensate(model, np.linspace(-400, 400, 50), 0.008).command_nm
    assert np.all(np.isfinite(u))
    for name in ("loop", "profile", "rls_traces", "prediction_error", "heldout_residual",
                 "reference"):  # fmt: skip
        assert (out / f"{name}_x.png").stat().st_size > 1000
    printed = capsys.readouterr().out
    assert "scaled by a 278 nm grating" in printed
    assert "planned instrument time" in printed and "fails its own validation" in printed


def test_identify_refuses_half_fixed_orders(tmp_path, capsys):
    assert main(["identify", "--out", str(tmp_path), "--n-play", "8", "--quick"]) == 2
    assert "--n-play and --n-creep go together" in capsys.readouterr().err


def test_identify_takes_a_user_configured_scanner(tmp_path):
    from piezocomp.virtual_afm import config_to_toml, load_config

    toml = tmp_path / "mine.toml"
    toml.write_text(config_to_toml(load_config("gentle")))
    out = tmp_path / "run"
    args = ["identify", "--scanner", str(toml), "--out", str(out), "--quick", "--no-figures"]
    args += ["--reference", "none", "--calibrate", "span", "--speed-factors", "1"]
    assert main([*args, "--n-play", "6", "--n-creep", "1"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["acquisition"]["waveform"]["speed_factors"] == [1.0]
    assert summary["reference"] == "none" and "methods_without_reference" not in summary
    assert summary["source"] == str(toml) and summary["calibration"] == "span"
    assert summary["orders"]["x"]["n_play"] == 6 and summary["orders"]["x"]["n_creep"] == 1
    fm = summary["axes"]["x"]["frame_map"]  # the span condition on the model's own cycles
    assert fm["alpha"] == pytest.approx(1.0, abs=0.03) and abs(fm["beta_nm"]) < 20.0
    assert not (out / "loop_x.png").exists()


def test_the_drift_an_identification_measured_is_said_in_one_line():
    from piezocomp.commands.identify_outputs import drift_report

    axis = {
        "line": {"drift_nm_per_s": -0.049, "cross_drift": {"rate_nm_per_s": -0.037,
                                                           "followed": True}},
        "line_drift": {"kept": True, "rate_nm_per_s": 0.048, "extent_nm": 11.3,
                       "heldout_rms_without_nm": 1.81, "heldout_rms_with_nm": 0.27},
    }  # fmt: skip
    text = drift_report("x", axis)
    # one drift, two measurements, one sign: the path d of h(y + d) moves the particles by -d
    assert text is not None
    assert text.startswith("axis x: drift measured: the particles slid -0.048 nm/s along")
    assert "1.81 nm without it taken out, 0.27 nm with" in text
    assert "-0.049 nm/s while the tip settled" in text  # the two measurements told apart
    assert "slid -0.037 nm/s across the line" in text and "followed by the slow axis" in text
    # a slide not followed says why, with how far it would have moved the line
    small = {"rate_nm_per_s": 0.011, "followed": False, "particles": 6, "residual_nm": 0.1,
             "still_residual_nm": 0.5, "record_slide_nm": 0.7}  # fmt: skip
    text = drift_report("x", {"line": {"cross_drift": small}}) or ""
    assert "+0.7 nm over the record" in text and "not followed (1 nm or less over" in text
    flat = {**small, "record_slide_nm": 2.5, "residual_nm": 0.4}
    text = drift_report("x", {"line": {"cross_drift": flat}}) or ""
    assert "not followed (it does not explain how the heights changed)" in text
    calm = {"line": {"drift_nm_per_s": 0.001, "cross_drift": None}, "line_drift": None}
    assert "not estimated with the model" in (drift_report("y", calm) or "")
    assert drift_report("y", {"line": None}) is None


def test_write_config_writes_the_default_and_the_flags_over_it(tmp_path, capsys):
    from piezocomp.identification.config import IdentifyConfig, read_config

    assert main(["identify", "--write-config", str(tmp_path / "default.toml")]) == 0
    assert read_config(tmp_path / "default.toml") == IdentifyConfig()
    assert not (tmp_path / "run").exists()
    argv = ["identify", "--quick", "--span-nm", "1500", "--reference", "none"]
    assert main([*argv, "--write-config", str(tmp_path / "mine.toml")]) == 0
    mine = read_config(tmp_path / "mine.toml")
    assert mine == IdentifyConfig.quick().updated(span_nm=1500.0, grating=False)
    # flags override the file
    argv = ["identify", "--config", str(tmp_path / "mine.toml"), "--n-play", "6", "--n-creep", "1"]
    assert main([*argv, "--write-config", str(tmp_path / "again.toml")]) == 0
    assert read_config(tmp_path / "again.toml") == mine.updated(orders=((6, 1),))
    (tmp_path / "bad.toml").write_text("[acquisition]\nspan = 3\n")
    code = main(["identify", "--config", str(tmp_path / "bad.toml"), "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert code == 2 and "bad.toml" in err and "unknown setting(s) ['span']" in err
    assert not (tmp_path / "b").exists()
    assert main(["identify", "--quick"]) == 2
    assert "--out is required" in capsys.readouterr().err


def test_the_configuration_saved_beside_the_results_runs_the_same_identification(tmp_path):
    """config.toml holds the configuration the run used (the budget's steps included):
    ``--config`` on it, with the same source, gives the same models and figures."""
    first = tmp_path / "first"
    argv = ["identify", "--preset", "gentle", "--axis", "x", "--no-figures", "--quick"]
    argv += ["--reference", "none", "--speed-factors", "1", "--budget-min", "20"]
    assert main([*argv, "--out", str(first)]) == 0
    again = tmp_path / "again"
    argv = ["identify", "--preset", "gentle", "--axis", "x", "--no-figures"]
    assert main([*argv, "--config", str(first / "config.toml"), "--out", str(again)]) == 0
    a, b = (json.loads((d / "summary.json").read_text()) for d in (first, again))
    assert a["budget_steps"] and not b["budget_steps"]  # the steps are in the file
    assert a["settings"] == b["settings"]
    assert a["methods"] == b["methods"] and a["orders"] == b["orders"]
    assert (first / "model.json").read_text() == (again / "model.json").read_text()


def test_calibrate_takes_a_span_in_nm_or_refuses_in_one_line(tmp_path, capsys):
    from piezocomp.identification.config import read_config

    path = tmp_path / "c.toml"
    assert main(["identify", "--calibrate", "1500", "--write-config", str(path)]) == 0
    assert read_config(path).acquisition.calibrate == 1500.0
    capsys.readouterr()
    for bad in ("wide", "-3", "inf"):
        assert main(["identify", "--calibrate", bad, "--write-config", str(path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) <= 2 and "'full-range', 'span' or a span in nm > 0" in err[-1], err


def test_a_refused_model_names_the_quick_orders_as_the_likely_cause(capsys):
    from piezocomp.commands.identify_outputs import refused

    class Failing:
        def validation_failures(self) -> list[str]:
            return ["held-out heights predicted to 3.10 nm RMS (at most 2.5)"]

    class Passing:
        def validation_failures(self) -> list[str]:
            return []

    assert refused({"x": Passing()}) == 0 and capsys.readouterr().err == ""
    assert refused({"x": Failing()}, quick=True) == 1
    err = capsys.readouterr().err
    assert "axis x: held-out heights" in err and "run without --quick" in err
    assert refused({"x": Failing()}) == 1
    err = capsys.readouterr().err
    assert "record again, on another area" in err and "--quick" not in err


def test_a_failed_record_is_recorded_again_on_another_line(monkeypatch, capsys):
    """An axis whose record fails (an error, then a model failing its validation) is
    identified again 400 nm across on the slow axis, then 400 nm the other way; each attempt
    said and listed; every line failing with an error fails the run in one line."""
    from piezocomp.commands import identify as command
    from piezocomp.identification.config import IdentifyConfig
    from piezocomp.instrument import RunValueError

    class Clock:
        time_s = 0.0

    class Ident:
        def __init__(self, failures: list[str]) -> None:
            self.failures = failures

        def validation_failures(self) -> list[str]:
            return self.failures

    lines: list[tuple[float, float]] = []
    outcomes: list[object] = []

    def fake(afm, cfg, axis):
        lines.append(cfg.acquisition.center_nm)
        afm.time_s += 60.0
        out = outcomes.pop(0)
        if isinstance(out, Exception):
            raise out
        return out

    monkeypatch.setattr(command, "identify_virtual", fake)
    cfg = IdentifyConfig.quick()
    outcomes[:] = [ValueError("no grating period"), Ident(["poor heights"]), Ident([])]
    ident, attempts = command._on_a_line_that_works(Clock(), cfg, "y", True, quick=False)
    assert ident.failures == [] and [a["line"] for a in attempts] == [
        "the line at 0 nm on the slow axis", "the line at 400 nm on the slow axis",
        "the line at -400 nm on the slow axis"]  # fmt: skip
    assert [c[0] for c in lines] == [0.0, 400.0, -400.0]  # y's slow axis is x
    assert attempts[0]["error"] == "no grating period" and attempts[0]["instrument_s"] == 60.0
    assert [a.get("kept", False) for a in attempts] == [False, False, True]
    err = capsys.readouterr().err
    first = "(axis y): the line at 0 nm on the slow axis (1 min of instrument time): no grating"
    assert first in err
    assert "recording again on the line at 400 nm" in err and "poor heights" in err
    assert "recording again on the line at -400 nm" in err
    # about another centre: the lines are shifted from it; a model failing its validation
    # is kept for inspection when the last line fails with an error
    lines.clear()
    off = cfg.updated(center_nm=(100.0, -50.0))
    outcomes[:] = [ValueError("a"), Ident(["poor heights"]), ValueError("c")]
    ident, attempts = command._on_a_line_that_works(Clock(), off, "x", False, quick=False)
    assert [c[1] for c in lines] == [-50.0, 350.0, -450.0]  # x's slow axis is y
    assert ident.failures == ["poor heights"] and "error" in attempts[-1]
    assert [a.get("kept", False) for a in attempts] == [False, True, False]
    err = capsys.readouterr().err
    assert (
        "the line at -50 nm on the slow axis (1 min of instrument time): a; recording "
        "again on the line at 350 nm"
        in err
        and "recording again on the line at -450 nm" in err
    )
    # --quick: a model failing its validation is kept (its small orders usually fail)
    lines.clear()
    outcomes[:] = [Ident(["poor heights"])]
    ident, attempts = command._on_a_line_that_works(Clock(), cfg, "x", False, quick=True)
    assert ident.failures == ["poor heights"] and lines == [(0.0, 0.0)]
    outcomes[:] = [ValueError("a"), ValueError("b"), ValueError("c")]
    with pytest.raises(
        RunValueError, match=r"no line gave a model \(3 tried; the first: a; the la"
    ):
        command._on_a_line_that_works(Clock(), cfg, "x", False, quick=False)
