import json

import pytest
from hypothesis import given

from piezocomp.io.model_files import load_model, model_from_json, model_to_json, save_model
from piezocomp.model import ScannerModel, ScannerModel2D
from strategies import coupled_models, models

ISSUE_EXAMPLE = """{"format": "piezocomp/scanner-model", "version": 1, "input_unit": "nm",
 "output_unit": "nm", "offset": 0.0, "gain": 0.62,
 "play": {"thresholds": [10.0, 20.0], "weights": [0.05, 0.03]},
 "creep": {"time_constants_s": [0.5, 20.0], "gains": [0.02, 0.04]}}"""


def test_hand_written_file_loads(tmp_path):
    path = tmp_path / "m.json"
    path.write_text(ISSUE_EXAMPLE)
    m = load_model(path)
    assert isinstance(m, ScannerModel)
    assert m.gain == 0.62 and m.weights.tolist() == [0.05, 0.03]
    assert m.creep_time_constants_s.tolist() == [0.5, 20.0]


@given(models(), models())
def test_round_trip_is_exact(mx, my):
    assert model_from_json(model_to_json(mx)) == mx
    two = model_from_json(model_to_json(ScannerModel2D(mx, my), metadata={"note": "x"}))
    assert isinstance(two, ScannerModel2D)
    assert two.x == mx and two.y == my


def test_save_is_atomic_and_keeps_old_file_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "m.json"
    m = ScannerModel(gain=0.5)
    save_model(path, m)
    before = path.read_text()

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("os.replace", boom)
    with pytest.raises(OSError, match="disk full"):
        save_model(path, ScannerModel(gain=0.7))
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]  # no temp file left


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda d: d.update(format="other"), "'format' must be 'piezocomp/scanner-model'"),
        (lambda d: d.update(version=4), r"'version' must be 1, 2 or 3 .*Got 4\."),
        (lambda d: d.update(version=True), "'version' must be 1, 2 or 3"),
        (lambda d: d["creep"].update(coupling=0.5), r"unknown key\(s\) \['coupling'\]"),
        (lambda d: d.update(extra=1), r"unknown key\(s\) \['extra'\]"),
        (lambda d: d["play"].update(thresholds=[20.0, 10.0]), "strictly increasing"),
        (lambda d: d["play"].update(weights=[0.05, -0.03]), "weights must be > 0"),
        (lambda d: d.update(gain=0), "gain must be > 0"),
        (lambda d: d["creep"].pop("gains"), r"missing key\(s\) \['gains'\]"),
        (lambda d: d.update(gain=True), "must be a number"),
        (lambda d: d.update(input_unit="V"), "'input_unit' must be 'nm'"),
    ],
)
def test_bad_files_are_refused_with_the_field(mutate, match, tmp_path):
    doc = json.loads(ISSUE_EXAMPLE)
    mutate(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=match):
        load_model(path)


def test_truncated_nan_and_empty_files(tmp_path):
    path = tmp_path / "t.json"
    path.write_text(ISSUE_EXAMPLE[:-40])
    with pytest.raises(ValueError, match=r"t\.json: not valid JSON \(the file looks truncated\)"):
        load_model(path)
    path.write_text(ISSUE_EXAMPLE.replace("0.62", "NaN"))
    with pytest.raises(ValueError, match="NaN is not a valid number"):
        load_model(path)
    path.write_text("")
    with pytest.raises(ValueError, match="empty"):
        load_model(path)
    path.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match="not a text"):
        load_model(path)


def test_2d_file_needs_both_axes(tmp_path):
    doc = json.loads(model_to_json(ScannerModel2D(ScannerModel(), ScannerModel())))
    del doc["y"]
    with pytest.raises(ValueError, match="needs both 'x' and 'y'"):
        model_from_json(json.dumps(doc))


def test_written_files_get_the_usual_permissions(tmp_path):
    import os

    path = tmp_path / "m.json"
    save_model(path, ScannerModel())
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask
    path.chmod(0o600)
    save_model(path, ScannerModel(gain=2.0))
    assert path.stat().st_mode & 0o777 == 0o600


V2_EXAMPLE = ISSUE_EXAMPLE.replace('"version": 1', '"version": 2').replace(
    '"gains": [0.02, 0.04]}', '"gains": [0.02, 0.04], "coupling": 0.55}'
)


def test_version_1_file_means_the_paper_model(tmp_path):
    """A version-1 text (before the coupling existed) reads as beta = 0 and is written back
    as version 2 with coupling 0, the same model."""
    m = model_from_json(ISSUE_EXAMPLE)
    assert isinstance(m, ScannerModel) and m.creep_coupling == 0.0
    doc = json.loads(model_to_json(m))
    assert doc["version"] == 2 and doc["creep"]["coupling"] == 0.0
    assert model_from_json(model_to_json(m)) == m


def test_version_2_file_carries_the_coupling():
    m = model_from_json(V2_EXAMPLE)
    assert isinstance(m, ScannerModel) and m.creep_coupling == 0.55
    doc = json.loads(V2_EXAMPLE)
    del doc["creep"]["coupling"]
    with pytest.raises(ValueError, match=r"creep is missing key\(s\) \['coupling'\]"):
        model_from_json(json.dumps(doc))
    doc["creep"]["coupling"] = -0.1
    with pytest.raises(ValueError, match="creep_coupling must be >= 0"):
        model_from_json(json.dumps(doc))


@given(coupled_models(), models())
def test_coupled_round_trip_is_exact(mx, my):
    assert model_from_json(model_to_json(mx)) == mx
    two = model_from_json(model_to_json(ScannerModel2D(mx, my)))
    assert isinstance(two, ScannerModel2D) and two.x == mx and two.y == my


def test_unknown_version_is_refused_in_one_line():
    with pytest.raises(ValueError) as info:
        model_from_json(ISSUE_EXAMPLE.replace('"version": 1', '"version": 7'))
    assert "\n" not in str(info.value) and "7" in str(info.value)
