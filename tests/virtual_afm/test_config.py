"""Configuration: presets, unknown keys, bad values, round trip."""

import math
from dataclasses import asdict, replace

import pytest

from piezocomp.virtual_afm import VirtualAFM, config_to_toml, list_presets, load_config
from piezocomp.virtual_afm.config import AFMConfig


def test_presets_exist_and_cpr5_is_the_default():
    """The default, ``cpr5``, drifts as an AFM in air does; ``cpr5-nodrift`` is its twin
    without drift, and a configuration that names no drift has none."""
    assert {"cpr5", "cpr5-nodrift", "cpr5-warmup", "gentle", "harsh"} <= set(list_presets())
    assert asdict(load_config("cpr5-nodrift").scanner) == asdict(AFMConfig().scanner)
    assert asdict(load_config("cpr5-nodrift").sample) == asdict(AFMConfig().sample)
    cpr5 = load_config("cpr5")
    assert cpr5.drifts and not load_config("cpr5-nodrift").drifts
    calm = replace(cpr5.scanner, drift_nm_per_s=0.0, drift_random_walk_nm_per_sqrt_s=0.0)
    assert asdict(calm) == asdict(AFMConfig().scanner)
    assert asdict(VirtualAFM().config.scanner) == asdict(cpr5.scanner)
    g, h = load_config("gentle").scanner, load_config("harsh").scanner
    assert (g.hysteresis, g.creep) == (0.02, 0.01)
    assert (h.hysteresis, h.creep) == (0.15, 0.20) and h.drift_nm_per_s > 0


def test_unknown_key_is_an_error_naming_it_and_the_section(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text("[scanner]\nhysterisis = 0.1\n")
    with pytest.raises(ValueError, match=r"unknown key 'hysterisis' in \[scanner\]"):
        load_config(f)
    with pytest.raises(ValueError, match="unknown key 'extra' at top level"):
        load_config({"extra": {}})


@pytest.mark.parametrize(
    ("section", "key", "value", "rule"),
    [
        ("scanner", "creep", -0.1, "in \\[0, 1\\)"),
        ("scanner", "range_nm", math.nan, "finite"),
        ("sample", "tip_radius_nm", -1.0, "> 0"),
        ("sample", "height_noise_nm", -0.5, ">= 0"),
    ],
)
def test_bad_values_name_the_key_the_rule_and_the_value(section, key, value, rule):
    with pytest.raises(ValueError, match=f"{section}.{key} must be {rule}"):
        load_config({section: {key: value}})


def test_round_trip_through_toml(tmp_path):
    cfg = load_config({"scanner": {"creep": 0.07}, "sample": {"particle_positions_nm": [[1, 2]]}})
    f = tmp_path / "c.toml"
    f.write_text(config_to_toml(cfg))
    assert load_config(f) == cfg
