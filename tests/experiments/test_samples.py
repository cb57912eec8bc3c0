"""Figures over samples, and identifications that recover on another line or fail loudly."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from piezocomp.cli import main
from piezocomp.experiments import methods as M
from piezocomp.experiments.samples import over_samples, parse_seeds
from piezocomp.identification.result import AxisIdentification
from piezocomp.virtual_afm import load_config


def test_seeds_are_parsed_and_bad_lists_refused():
    assert parse_seeds("1-3,7,2") == (1, 2, 3, 7)
    assert parse_seeds("5") == (5,)
    for bad, rule in [("a-b", "whole numbers"), ("3-1", "from low to high"), ("0-5000", "at most")]:
        with pytest.raises(ValueError, match=rule):
            parse_seeds(bad)


def _results(unc: float, comp: float, f9: float, success: float, failures=()):
    def row(d, u, c):
        cell = lambda v: {"max_error_nm": {"mean": v}, "true_max_error_nm": {"mean": v}}  # noqa: E731
        return {"d_nm": d, "speed_nm_per_s": 1000.0,
                "methods": {"uncompensated": cell(u), "compensated": cell(c)}}  # fmt: skip

    return {
        "paper": {"speed_nm_per_s": 1000.0},
        "table1": [row(645, unc, comp), row(951, unc + 1, comp + 0.1)],
        "fig9": {"methods": {"compensated": {"error_nm": f9, "true_error_nm": f9}}},
        "fig10": {"methods": {"compensated": {"true_success_rate": success}}},
        "failures": list(failures),
    }


def test_median_and_worst_over_samples():
    runs = [
        (1, _results(6.0, 0.2, 0.1, 1.0)),
        (2, _results(8.0, 0.4, 0.5, 0.5)),
        (3, _results(7.0, 0.3, 0.2, 1.0, failures=[{"x": 1}])),
        (4, "ValueError: broke"),
    ]
    s = over_samples(runs)
    comp = s["statistics"]["compensated"]
    assert comp["table1_true_nm"] == {"median": pytest.approx(0.4), "worst": 0.5, "n": 3}
    assert comp["fig9_true_nm"]["worst"] == 0.5 and comp["fig9_true_nm"]["median"] == 0.2
    assert comp["fig10_true_success"] == {"median": 1.0, "worst": 0.5, "n": 3}
    assert s["statistics"]["uncompensated"]["table1_true_nm"]["worst"] == 9.0
    assert s["statistics"]["uncompensated"]["fig9_true_nm"]["n"] == 0  # none given
    assert s["failed_seeds"] == {"4": "ValueError: broke"}
    assert s["runs_with_failures"] == ["3"]
    json.dumps(s, allow_nan=False)


def test_the_default_model_is_checked_on_its_own_validation():
    def failures(held):
        return AxisIdentification.validation_failures(SimpleNamespace(heldout_rms_nm=held))  # type: ignore[arg-type]

    assert failures({"batch": 0.3, "rls": 0.5}) == []
    assert "1.70 nm RMS" in failures({"batch": 1.7, "rls": 1.5})[0]
    assert any("far worse than the RLS" in f for f in failures({"batch": 1.5, "rls": 0.3}))
    assert failures({"batch": float("nan"), "rls": 0.2})  # no figure: not usable


class _Ident:
    def __init__(self, held):
        self.heldout_rms_nm = held
        self.batch_model = self.rls_model = "model"
        self.orders = SimpleNamespace(n_play=16, n_creep=22)
        self.findings = ()
        self.line_drift = None
        self.cross_drift = None
        self.instrument_s = {"record and check": 60.0}

    def validation_failures(self):
        return AxisIdentification.validation_failures(self)  # type: ignore[arg-type]


def test_a_failed_record_is_made_again_on_another_line(monkeypatch):
    """The first line raises, the second gives a model that fails its validation, the third
    is used; every attempt is reported, and the lines lie across the axis."""
    seen = []
    first = ValueError("the line crosses too few particles")
    outcomes = iter([first, _Ident({"batch": 2.0, "rls": 2.1}), _Ident({"batch": 0.2, "rls": 0.3})])

    def fake_identify(afm, cfg, axis):
        seen.append(cfg.acquisition.center_nm)
        out = next(outcomes)
        if isinstance(out, Exception):
            raise out
        return out

    monkeypatch.setattr(M, "identify_virtual", fake_identify)
    monkeypatch.setattr(M, "score_on_truth", lambda *a, **k: {n: {} for n in a[2]})
    settings = M.IdentificationSettings()
    job = M.identification_job("sensorless", "x", load_config("cpr5-nodrift"), 1, settings)
    assert seen == [(0.0, 0.0), (0.0, 400.0), (0.0, -400.0)]
    assert set(job["models"]) == {"compensated", "rls"}
    attempts = job["summary"]["attempts"]
    assert "too few particles" in attempts[0]["error"]
    assert "2.00 nm RMS" in attempts[1]["validation_failures"][0]
    assert attempts[2]["validation_failures"] == []


def test_a_method_with_no_usable_model_is_reported_failed_and_not_run(monkeypatch, tmp_path):
    """Every line fails for the comparison method ``pi_no_creep``: the run goes on with the
    others, says so in results.json and on stderr, and exits 0 (it is the default method's
    failure that makes the run fail)."""

    def fake_identify(afm, cfg, axis):
        raise ValueError("the grating gives the model a scale of 0.395")

    real = M.identification_job

    def job(kind, axis, config, seed, settings):
        if kind == "no_creep":
            monkeypatch.setattr(M, "identify_virtual", fake_identify)
        return real(kind, axis, config, seed, settings)

    import piezocomp.experiments.reproduce as R

    monkeypatch.setattr(R, "identification_job", job)
    monkeypatch.setattr(R, "METHODS", ("uncompensated", "pi_no_creep"))
    from piezocomp.experiments.reproduce import ReproduceSettings, reproduce

    s = ReproduceSettings(config=load_config("cpr5-nodrift"),
                          methods=("uncompensated", "pi_no_creep"),
                          distances_nm=(645.0,), table1_experiments=1,
                          speeds_nm_per_s=(1000.0,), fig10_trials=1, workers=1)  # fmt: skip
    rep = reproduce(s, progress=False)
    fails = rep.results["failures"]
    assert [f["method"] for f in fails] == ["pi_no_creep"]
    assert fails[0]["experiment"] == "identification" and "3 lines" in fails[0]["error"]
    assert all(t.method == "uncompensated" for t, _ in rep.outcomes)


def test_only_the_default_methods_failures_fail_the_run():
    from piezocomp.commands.reproduce import fatal_failures

    def fail(method, experiment="table1"):
        return {"experiment": experiment, "method": method, "settings": "", "error": "x"}

    comparison = [fail("rls", "fig8"), fail("pi_no_creep", "identification"), fail("none")]
    assert fatal_failures(comparison) == []
    assert fatal_failures([*comparison, fail("both")]) == [fail("both")]
    assert fatal_failures([fail("compensated", "identification")]) != []


def test_seeds_run_and_summarise(tmp_path, capsys, monkeypatch):
    """``--seeds`` runs each sample into its folder and writes the statistics."""
    import piezocomp.experiments.reproduce as R

    def fake(settings, progress=True, models=None):
        res = _results(5.0 + settings.seed, 0.1 * settings.seed, 0.05, 1.0)
        res.update({"preset": "cpr5-nodrift", "seed": settings.seed, "fig8": {"methods": {}}})
        return SimpleNamespace(results=res)

    monkeypatch.setattr(R, "reproduce", fake)
    import piezocomp.commands.reproduce as C

    monkeypatch.setattr(C, "_one", lambda args, out, seed, config, source: _write(out, seed))
    assert main(["reproduce", "--quick", "--seeds", "1-3", "--out", str(tmp_path)]) == 0
    s = json.loads((tmp_path / "samples.json").read_text())
    assert s["seeds"] == [1, 2, 3]
    assert s["statistics"]["compensated"]["table1_true_nm"]["worst"] == pytest.approx(0.4)
    assert "--seeds 1-3" in s["command"]
    assert "over 3 sample seeds" in capsys.readouterr().out


def _write(out, seed):
    return 0, _results(5.0 + seed, 0.1 * seed, 0.05, 1.0)


@pytest.mark.parametrize("compensated_key", ["compensated", "creep_hysteresis"])
def test_the_default_on_a_drifting_scanner_and_its_session_are_headline_figures(
    compensated_key,
):
    """``both`` (inside the drift compensator) reads Fig. 10 from the drift run and the
    session's figures map to the methods they belong to: by the methods' own names, and by
    the session's older keys (a ``results.json`` of the previous release)."""
    res = _results(6.0, 2.0, 1.5, 0.0)
    for row, v in zip(res["table1"], (0.6, 0.8), strict=True):
        row["methods"]["both"] = {"max_error_nm": {"mean": v}, "true_max_error_nm": {"mean": v}}
    res["fig9"]["methods"]["both"] = {"error_nm": 0.7, "true_error_nm": 0.9}
    res["fig10_drift"] = {"methods": {"both": {"true_success_rate": 1.0}}}
    res["drift_session"] = {"methods": {
        "both": {"true_max_error_nm": 1.2, "true_final_error_nm": 0.8,
                 "measurement_overhead_fraction": 0.1},
        compensated_key: {"true_max_error_nm": 20.0, "true_final_error_nm": 19.0,
                             "measurement_overhead_fraction": None},
    }}  # fmt: skip
    s = over_samples([(1, res), (2, _results(6.0, 2.0, 1.5, 0.0))])["statistics"]
    both = s["both"]
    assert both["table1_true_nm"] == {"median": 0.8, "worst": 0.8, "n": 1}
    assert both["fig9_true_nm"]["worst"] == 0.9 and both["fig10_true_success"]["worst"] == 1.0
    assert both["session_true_worst_nm"]["worst"] == 1.2
    assert both["session_measuring"]["worst"] == pytest.approx(0.1)
    assert s["compensated"]["session_true_final_nm"]["worst"] == 19.0
    assert s["compensated"]["fig10_true_success"]["worst"] == 0.0  # not the drift run's
    assert s["uncompensated"]["session_true_worst_nm"]["n"] == 0
