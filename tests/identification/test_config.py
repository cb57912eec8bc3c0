"""The identification's nested configuration: one set of defaults, TOML both ways, every
setting used, none too big a class."""

import re
from dataclasses import fields, is_dataclass
from pathlib import Path

import pytest

import piezocomp
from piezocomp.identification.config import (
    AcquisitionConfig,
    IdentifyConfig,
    read_config,
    setting_names,
    write_config,
)
from piezocomp.identification.estimation.rls import RLSSettings


def _classes(obj, seen=None):
    """Every dataclass type in the configuration tree."""
    seen = set() if seen is None else seen
    seen.add(type(obj))
    for f in fields(obj):
        v = getattr(obj, f.name)
        if is_dataclass(v) and type(v) not in seen:
            _classes(v, seen)
    return seen


def test_no_configuration_class_has_more_than_20_fields():
    classes = _classes(IdentifyConfig())
    assert RLSSettings in classes and AcquisitionConfig in classes
    sizes = {c.__name__: len([f for f in fields(c) if f.init]) for c in classes}
    assert max(sizes.values()) <= 20, sizes


@pytest.mark.parametrize("make", [IdentifyConfig, IdentifyConfig.quick, IdentifyConfig.paper])
def test_a_configuration_reads_back_from_its_toml_as_it_was(make, tmp_path):
    cfg = make()
    assert IdentifyConfig.from_toml(cfg.to_toml()) == cfg
    write_config(tmp_path / "c.toml", cfg, "a header\nof two lines")
    assert read_config(tmp_path / "c.toml") == cfg
    assert (tmp_path / "c.toml").read_text().startswith("# a header\n# of two lines\n")


def test_a_partial_file_changes_only_what_it_holds():
    text = "[acquisition]\nspan_nm = 1500.0\n\n[acquisition.waveform]\nspeed_factors = [1.0]\n"
    text += '\n[estimation]\nrls_continue = "none"\norders = [[16, 22]]\n'
    cfg = IdentifyConfig.from_toml(text)
    assert cfg == IdentifyConfig().updated(
        span_nm=1500.0, speed_factors=(1.0,), rls_continue=None, orders=((16, 22),)
    )
    # a file over the quick base keeps the quick settings it does not hold
    quick = IdentifyConfig.from_toml("[loop]\ndegree = 7\n", IdentifyConfig.quick())
    assert quick == IdentifyConfig.quick().updated(degree=7)
    wider = IdentifyConfig.from_toml("[acquisition]\ncalibrate = 8000.0\n")
    assert wider.acquisition.calibration_span_nm(10000.0) == 8000.0


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[acquisition]\nspan = 1000.0\n", r"\[acquisition\] unknown setting\(s\) \['span'\]"),
        ("[optics]\nzoom = 2\n", r"unknown setting\(s\) \['optics'\]"),
        ("[acquisition]\nspan_nm = -5.0\n", r"span_nm must be > 0\. Got -5\.0"),
        ('[acquisition]\ncalibrate = "whole"\n', "calibrate must be 'full-range', 'span'"),
        ("[estimation]\norders = [[0, 2]]\n", r"n_play >= 1"),
        ("[loop]\ndegree = 2.5\n", r"degree must be an integer >= 1\. Got 2\.5"),
        ("[rounds\n", "not a TOML configuration"),
        ("[loop]\ndegree = { a = 1 }\n", "degree is a value, not a table"),
    ],
)
def test_a_bad_file_is_refused_naming_the_setting(tmp_path, text, message):
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises((ValueError, TypeError), match=message) as exc:
        read_config(tmp_path / "bad.toml")
    assert "\n" not in str(exc.value)
    with pytest.raises(ValueError, match="cannot read the configuration"):
        read_config(tmp_path / "absent.toml")


def test_settings_are_changed_by_name_and_unknown_names_refused():
    cfg = IdentifyConfig().updated(n_steady=5, degree=7, drift_rounds=0, grating=False)
    assert cfg.acquisition.waveform.n_steady == 5 and cfg.loop.degree == 7
    assert cfg.rounds.drift_rounds == 0 and cfg.reference.grating is False
    with pytest.raises(ValueError, match=r"unknown setting\(s\) \['span'\]"):
        IdentifyConfig().updated(span=1000.0)


def test_setting_names_are_unique_across_the_stages():
    names = setting_names()
    leaves = []

    def walk(obj, path):
        for f in fields(obj):
            v = getattr(obj, f.name)
            if path == () or isinstance(v, AcquisitionConfig) or f.name == "waveform":
                if is_dataclass(v) and not isinstance(v, RLSSettings):
                    walk(v, (*path, f.name))
                    continue
            leaves.append(f.name)

    walk(IdentifyConfig(), ())
    assert len(leaves) == len(set(leaves)) == len(names)


def test_every_setting_is_read_by_the_package():
    """A knob no path reads is no knob: each setting is read as an attribute somewhere in
    the package outside the configuration's own module."""
    root = Path(piezocomp.__file__).parent
    text = "\n".join(
        p.read_text(encoding="utf-8")
        for p in root.rglob("*.py")
        if p.name != "config.py" or p.parent.name != "identification"
    )
    unread = [n for n in setting_names() if not re.search(rf"\.{n}\b", text)]
    assert unread == []


def test_one_set_of_defaults_the_commands_share():
    """The ``waveform`` command writes the default configuration's waveform."""
    from piezocomp.identification.config import WaveformConfig

    assert IdentifyConfig().acquisition.waveform == WaveformConfig()
    assert IdentifyConfig().acquisition.span_nm == 2000.0
    assert IdentifyConfig().acquisition.calibrate == "full-range"
    assert IdentifyConfig.quick().estimation.orders == ((8, 2),)
    paper = IdentifyConfig.paper()
    assert paper.acquisition.waveform.speed_factors == (1.0,) and paper.rounds.drift_rounds == 0
