"""Configuration of the virtual AFM: TOML files, named presets, validation.

A configuration has two tables, ``[scanner]`` and ``[sample]`` (and an optional top-level
``description`` string). Every key is optional: a missing key takes its default, which is
the ``cpr5`` preset's value. An unknown key or table is an error naming it; a value that
breaks its rule is an error naming the key, the rule and the value.

Presets ship in ``piezocomp/virtual_afm/presets/*.toml``; :func:`list_presets` names them.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar

import tomli_w

__all__ = [
    "AFMConfig",
    "SampleConfig",
    "ScannerConfig",
    "config_to_toml",
    "list_presets",
    "load_config",
]

_Rule = tuple[Callable[[float], bool], str]
_GE0: _Rule = (lambda v: v >= 0, ">= 0")
_GT0: _Rule = (lambda v: v > 0, "> 0")


def _check(section: str, name: str, value: Any, rule: _Rule, kind: type = float) -> Any:
    key = f"{section}.{name}"
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"{key} must be an integer. Got {value!r}.")
        v: Any = int(value)
    else:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise TypeError(f"{key} must be a number. Got {value!r}.")
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"{key} must be finite. Got {v}.")
    ok, text = rule
    if not ok(v):
        raise ValueError(f"{key} must be {text}. Got {v}.")
    return v


@dataclass(frozen=True)
class ScannerConfig:
    """``[scanner]`` table (lengths nm, times s). Defaults are the ``cpr5`` values.

    Attributes
    ----------
    range_nm : float
        Full travel of each axis.
    hysteresis : float
        Max divergence of the ascending and descending branches on a full-range cycle, / range.
    hysteresis_small : float
        The same on a centred cycle of span ``hysteresis_small_span`` (divergence / span).
    hysteresis_small_span : float
        Peak-to-peak span, / range, of that small cycle.
    hysteresis_asymmetry : float
        Asymmetry ``s`` of the Preisach density in the relays' mean switching input.
    hysteresis_saturation : float
        ``-q``: relative loss of relay density towards the ends of the range.
    creep : float
        (extension 100 s after a step - extension 0.1 s after it) / the step.
    creep_tau_min_s, creep_tau_max_s : float
        Shortest and longest time constants of the creep spectrum.
    creep_modes_per_decade : int
        Density of the creep spectrum.
    creep_reference_time_s : float
        Time after a step at which the extension equals the nominal command change.
    drift_nm_per_s : float
        Thermal drift speed (constant part).
    drift_direction_deg : float
        Direction of the constant drift, degrees from +x.
    drift_random_walk_nm_per_sqrt_s : float
        Random-walk part of the drift, per axis.
    drift_warmup_nm_per_s : float
        Extra drift speed at the start of the session (warming up), in the drift's
        direction, decaying as ``exp(-t / drift_warmup_time_s)``.
    drift_warmup_time_s : float
        Time constant of the warm-up's decay.
    cross_coupling : float
        Fraction of x motion that appears in y.
    max_speed_nm_per_s : float
        Slew limit of each axis' command.
    position_noise_nm : float
        White lateral positioning noise of each axis, nm rms per sample.
    position_flicker_nm : float
        1/f lateral positioning noise of each axis, nm rms (2 mHz to 2 Hz).
    creep_domain_fraction : float
        Fraction of the creep that relaxes the domains the hysteresis switched (driven by
        the hysteresis operator's extension rather than the command), in [0, 1].
    creep_domain_tau_min_s : float
        0 (every preset): the domains relax through the same modes as the command's creep,
        their drive mixed into it (the form of the extended model family's coupled creep,
        eq 2'). A time constant > 0: they relax only through the modes at least this slow,
        a spectrum of their own (weights scaled so that the domains' share of the creep from
        0.1 s to 100 s stays ``creep_domain_fraction``), which no single creep coupling
        follows: a scanner outside that family.
    """

    range_nm: float = 5000.0
    hysteresis: float = 0.12
    hysteresis_small: float = 0.03
    hysteresis_small_span: float = 0.1
    hysteresis_asymmetry: float = 0.05
    hysteresis_saturation: float = 0.3
    creep: float = 0.21
    creep_tau_min_s: float = 0.001
    creep_tau_max_s: float = 1800.0
    creep_modes_per_decade: int = 6
    creep_reference_time_s: float = 1.0
    drift_nm_per_s: float = 0.0
    drift_direction_deg: float = 30.0
    drift_random_walk_nm_per_sqrt_s: float = 0.0
    drift_warmup_nm_per_s: float = 0.0
    drift_warmup_time_s: float = 900.0
    cross_coupling: float = 0.0
    max_speed_nm_per_s: float = 20000.0
    position_noise_nm: float = 0.03
    position_flicker_nm: float = 0.05
    creep_domain_fraction: float = 0.35
    creep_domain_tau_min_s: float = 0.0

    _RULES: ClassVar[dict[str, _Rule]] = {
        "range_nm": _GT0,
        "hysteresis": (lambda v: 0 <= v < 0.5, "in [0, 0.5)"),
        "hysteresis_small": _GE0,
        "hysteresis_small_span": (lambda v: 0 < v < 1, "in (0, 1)"),
        "hysteresis_asymmetry": (lambda v: abs(v) < 0.9, "in (-0.9, 0.9)"),
        "hysteresis_saturation": (lambda v: 0 <= v < 0.9, "in [0, 0.9)"),
        "creep": (lambda v: 0 <= v < 1, "in [0, 1)"),
        "creep_tau_min_s": _GT0,
        "creep_tau_max_s": _GT0,
        "creep_modes_per_decade": ((lambda v: 1 <= v <= 100), "in [1, 100]"),
        "creep_reference_time_s": _GE0,
        "drift_nm_per_s": _GE0,
        "drift_direction_deg": ((lambda v: True), "a number"),
        "drift_random_walk_nm_per_sqrt_s": _GE0,
        "drift_warmup_nm_per_s": _GE0,
        "drift_warmup_time_s": _GT0,
        "cross_coupling": (lambda v: abs(v) < 0.5, "in (-0.5, 0.5)"),
        "max_speed_nm_per_s": _GT0,
        "position_noise_nm": (lambda v: 0 <= v <= 10, "in [0, 10]"),
        "position_flicker_nm": (lambda v: 0 <= v <= 10, "in [0, 10]"),
        "creep_domain_fraction": (lambda v: 0 <= v <= 1, "in [0, 1]"),
        "creep_domain_tau_min_s": _GE0,
    }

    def __post_init__(self) -> None:
        for f in fields(self):
            kind = int if f.name == "creep_modes_per_decade" else float
            v = _check("scanner", f.name, getattr(self, f.name), self._RULES[f.name], kind)
            object.__setattr__(self, f.name, v)
        if self.creep_tau_min_s >= self.creep_tau_max_s:
            raise ValueError(
                "scanner.creep_tau_min_s must be < scanner.creep_tau_max_s. "
                f"Got {self.creep_tau_min_s} and {self.creep_tau_max_s}."
            )
        if self.hysteresis > 0 and not 0 < self.hysteresis_small < self.hysteresis:
            raise ValueError(
                "scanner.hysteresis_small must be > 0 and < scanner.hysteresis. "
                f"Got {self.hysteresis_small} (hysteresis {self.hysteresis})."
            )


@dataclass(frozen=True)
class SampleConfig:
    """``[sample]`` table (lengths nm). Defaults are the ``cpr5`` values.

    Attributes
    ----------
    particle_diameter_nm : float
        Mean particle diameter.
    particle_diameter_std_nm : float
        Standard deviation of the diameters.
    particles_per_um2 : float
        Density of random particles (ignored when ``particle_positions_nm`` is given).
    area_half_width_nm : float
        Random particles lie in the square ``+-area_half_width_nm`` of the sample frame.
    particle_positions_nm : tuple of (x, y) or (x, y, diameter)
        Explicit particles; empty means random ones.
    tip_radius_nm : float
        Tip apex radius.
    tip_half_angle_deg : float
        Tip cone half-angle (the middle of its draw).
    tip_half_angle_spread_deg : float
        The cone's half-angle is drawn per sample seed, uniformly within
        ``tip_half_angle_deg +- tip_half_angle_spread_deg``: the software does not know it
        (it takes the datasheet's value).
    tip_radius_spread : float
        The tip's apex radius is drawn per sample seed, uniformly within
        ``tip_radius_nm * (1 +- tip_radius_spread)``: the software does not know it.
    tip_blunting_nm_per_push : float
        Growth of the apex radius with every push (wear).
    height_noise_nm : float
        Tapping-mode height noise, rms.
    roughness_nm : float
        Substrate roughness, rms.
    push_height_nm : float
        Apex height above the substrate while pushing (Z feedback off), as set.
    push_height_spread_nm : float
        The apex height each particle actually meets is drawn per particle, uniformly within
        ``push_height_nm +- push_height_spread_nm`` and never below the substrate (the
        substrate's height under it against the plane the setting refers to: tilt,
        roughness, Z drift): the software does not know it.
    tip_friction : float
        Coulomb friction coefficient between tip and particle while pushing (the median
        over particles): a particle whose contact normal lies within ``atan(mu)`` of the
        tip's motion is carried along with the tip; beyond, it slides around the tip and
        off its path. 0: frictionless (every off-centre push slides off).
    tip_friction_spread : float
        Each particle's coefficient is ``tip_friction * exp(tip_friction_spread * N(0, 1))``,
        drawn per sample seed.
    push_stuck_rate : float
        Probability that a push leaves the particle where it is (held by the substrate; the
        tip rides over it).
    push_roll_rate : float
        Probability that the particle rolls off the tip, sideways off its path, within its
        first 50 nm of travel.
    push_pickup_rate : float
        Probability that the particle sticks to the tip and leaves the surface.
    push_drop_fraction : float
        Fraction of the picked-up particles dropped near the tip when the push ends (the
        others are lost).
    seed : int
        Seed of every random draw (particles, roughness, noise, drift).
    """

    particle_diameter_nm: float = 15.0
    particle_diameter_std_nm: float = 1.0
    particles_per_um2: float = 150.0
    area_half_width_nm: float = 2800.0
    particle_positions_nm: tuple[tuple[float, ...], ...] = field(default_factory=tuple)
    tip_radius_nm: float = 10.0
    tip_half_angle_deg: float = 20.0
    tip_half_angle_spread_deg: float = 8.0
    tip_radius_spread: float = 0.3
    tip_blunting_nm_per_push: float = 0.02
    height_noise_nm: float = 0.1
    roughness_nm: float = 0.15
    push_height_nm: float = 1.0
    push_height_spread_nm: float = 0.5
    tip_friction: float = 0.3
    tip_friction_spread: float = 0.5
    push_stuck_rate: float = 0.03
    push_roll_rate: float = 0.02
    push_pickup_rate: float = 0.01
    push_drop_fraction: float = 0.5
    seed: int = 1

    _RULES: ClassVar[dict[str, _Rule]] = {
        "particle_diameter_nm": _GT0,
        "particle_diameter_std_nm": _GE0,
        "particles_per_um2": (lambda v: 0 <= v <= 2000, "in [0, 2000]"),
        "area_half_width_nm": _GT0,
        "tip_radius_nm": _GT0,
        "tip_half_angle_deg": (lambda v: 0 < v < 90, "in (0, 90)"),
        "tip_half_angle_spread_deg": _GE0,
        "tip_radius_spread": (lambda v: 0 <= v < 0.9, "in [0, 0.9)"),
        "tip_blunting_nm_per_push": (lambda v: 0 <= v <= 10, "in [0, 10]"),
        "height_noise_nm": _GE0,
        "roughness_nm": _GE0,
        "push_height_nm": _GE0,
        "push_height_spread_nm": _GE0,
        "tip_friction": _GE0,
        "tip_friction_spread": (lambda v: 0 <= v <= 3, "in [0, 3]"),
        "push_stuck_rate": (lambda v: 0 <= v <= 1, "in [0, 1]"),
        "push_roll_rate": (lambda v: 0 <= v <= 1, "in [0, 1]"),
        "push_pickup_rate": (lambda v: 0 <= v <= 1, "in [0, 1]"),
        "push_drop_fraction": (lambda v: 0 <= v <= 1, "in [0, 1]"),
        "seed": _GE0,
    }

    def __post_init__(self) -> None:
        for name, rule in self._RULES.items():
            kind = int if name == "seed" else float
            object.__setattr__(self, name, _check("sample", name, getattr(self, name), rule, kind))
        rows = []
        for i, row in enumerate(self.particle_positions_nm):
            if not isinstance(row, list | tuple) or len(row) not in (2, 3):
                raise ValueError(
                    f"sample.particle_positions_nm[{i}] must be [x, y] or [x, y, diameter]. "
                    f"Got {row!r}."
                )
            vals = tuple(
                _check("sample", f"particle_positions_nm[{i}]", v, ((lambda v: True), "a number"))
                for v in row
            )
            if len(vals) == 3 and vals[2] <= 0:
                raise ValueError(
                    f"sample.particle_positions_nm[{i}] diameter must be > 0. Got {vals[2]}."
                )
            rows.append(vals)
        object.__setattr__(self, "particle_positions_nm", tuple(rows))
        rates = self.push_stuck_rate + self.push_roll_rate + self.push_pickup_rate
        if rates > 1:
            raise ValueError(
                "sample.push_stuck_rate + push_roll_rate + push_pickup_rate must be <= 1. "
                f"Got {rates:g}."
            )
        if self.push_height_nm >= self.particle_diameter_nm:
            raise ValueError(
                "sample.push_height_nm must be < sample.particle_diameter_nm. "
                f"Got {self.push_height_nm}."
            )
        a, da = self.tip_half_angle_deg, self.tip_half_angle_spread_deg
        if not (0 < a - da and a + da < 90):
            raise ValueError(
                "sample.tip_half_angle_deg +- tip_half_angle_spread_deg must lie in (0, 90). "
                f"Got {a:g} +- {da:g}: lower tip_half_angle_spread_deg."
            )
        z, dz = self.push_height_nm, self.push_height_spread_nm
        if z + dz >= self.particle_diameter_nm:
            raise ValueError(
                "sample.push_height_nm + push_height_spread_nm must be < "
                f"sample.particle_diameter_nm. Got {z:g} + {dz:g}."
            )


@dataclass(frozen=True)
class AFMConfig:
    """A whole configuration: scanner, sample, and a free description."""

    scanner: ScannerConfig = field(default_factory=ScannerConfig)
    sample: SampleConfig = field(default_factory=SampleConfig)
    description: str = ""

    @property
    def drifts(self) -> bool:
        """True when the scanner has thermal drift (steady, warm-up or random walk)."""
        c = self.scanner
        return (c.drift_nm_per_s + c.drift_warmup_nm_per_s + c.drift_random_walk_nm_per_sqrt_s) > 0

    def with_seed(self, seed: int) -> AFMConfig:
        """A copy with ``sample.seed`` replaced."""
        d = asdict(self.sample)
        d["seed"] = seed
        return AFMConfig(self.scanner, SampleConfig(**d), self.description)


def _public_fields(cls: type) -> list[str]:
    return [f.name for f in fields(cls)]


def _from_mapping(data: Mapping[str, Any], origin: str) -> AFMConfig:
    if not isinstance(data, Mapping):
        raise TypeError(f"{origin}: a configuration must be a table. Got {type(data).__name__}.")
    known = {"scanner", "sample", "description"}
    for key in data:
        if key not in known:
            raise ValueError(
                f"{origin}: unknown key '{key}' at top level (known: {', '.join(sorted(known))})."
            )
    parts: dict[str, Any] = {}
    for section, cls in (("scanner", ScannerConfig), ("sample", SampleConfig)):
        table = data.get(section, {})
        if not isinstance(table, Mapping):
            raise TypeError(f"{origin}: [{section}] must be a table. Got {table!r}.")
        names = _public_fields(cls)
        for key in table:
            if key not in names:
                raise ValueError(
                    f"{origin}: unknown key '{key}' in [{section}] (known: {', '.join(names)})."
                )
        kwargs = dict(table)
        if "particle_positions_nm" in kwargs:
            kwargs["particle_positions_nm"] = tuple(
                tuple(r) if isinstance(r, list | tuple) else r
                for r in kwargs["particle_positions_nm"]
            )
        try:
            parts[section] = cls(**kwargs)
        except (ValueError, TypeError) as exc:
            raise type(exc)(f"{origin}: {exc}") from None
    desc = data.get("description", "")
    if not isinstance(desc, str):
        raise TypeError(f"{origin}: description must be a string. Got {desc!r}.")
    return AFMConfig(parts["scanner"], parts["sample"], desc)


def list_presets() -> list[str]:
    """Names of the presets shipped with the package."""
    folder = resources.files("piezocomp.virtual_afm") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_config(source: str | os.PathLike[str] | Mapping[str, Any] | AFMConfig) -> AFMConfig:
    """Load a configuration from a preset name, a TOML file or a mapping.

    Parameters
    ----------
    source : str, path-like, mapping or AFMConfig
        A preset name (see :func:`list_presets`), the path of a TOML file, or the parsed
        tables.

    Returns
    -------
    AFMConfig
    """
    if isinstance(source, AFMConfig):
        return source
    if isinstance(source, Mapping):
        return _from_mapping(source, "configuration")
    text_source = os.fspath(source)
    if text_source in list_presets():
        res = resources.files("piezocomp.virtual_afm") / "presets" / f"{text_source}.toml"
        return _from_mapping(
            tomllib.loads(res.read_text(encoding="utf-8")), f"preset {text_source}"
        )
    path = Path(text_source)
    if not path.is_file():
        raise ValueError(
            f"'{text_source}' is neither a preset ({', '.join(list_presets())}) nor a TOML file."
        )
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    return _from_mapping(data, str(path))


def config_to_toml(config: AFMConfig) -> str:
    """The configuration as TOML text that :func:`load_config` reads back identically."""
    doc: dict[str, Any] = {"description": config.description} if config.description else {}
    for section in ("scanner", "sample"):
        obj = getattr(config, section)
        doc[section] = {name: getattr(obj, name) for name in _public_fields(type(obj))}
    return tomli_w.dumps(doc)
