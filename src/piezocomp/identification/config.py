"""The configuration of the sensorless identification: one nested, frozen object.

:class:`IdentifyConfig` holds one configuration per stage, each read by its own stage:

- ``acquisition`` (:class:`AcquisitionConfig`, with its ``waveform``,
  :class:`WaveformConfig`): the working area, the overview and the line, the settling, the
  record of Fig. 7a, the calibration cycles, the further lines, the peak finding;
- ``loop`` (:class:`LoopConfig`): the steady loop of Section IV (eqs 21-23);
- ``estimation`` (:class:`~piezocomp.identification.estimation_options.EstimationConfig`):
  the candidate orders, the RLS (eqs 16-20), the batch refinement, the held-out choice;
- ``rounds`` (:class:`RoundsConfig`): the rounds after it: over the further lines, with the
  sample's drift along the line, over the whole record;
- ``reference`` (:class:`ReferenceConfig`): the length reference (a calibration grating).

There is one set of defaults, those of ``piezocomp identify``, which the accuracy table of
``docs/identification.md`` was measured with; :meth:`IdentifyConfig.quick` is ``--quick``'s
reduced run, :meth:`IdentifyConfig.paper` the procedure as the paper prints it. A
configuration is written and read as TOML (:meth:`IdentifyConfig.to_toml`,
:meth:`IdentifyConfig.from_toml`); ``None`` is written ``"none"``. Lengths are nm of command,
times s.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp._atomic import atomic_write_text
from piezocomp._validation import check_finite_scalar
from piezocomp.identification.cross_drift import DITHER_NM
from piezocomp.identification.estimation_options import EstimationConfig
from piezocomp.identification.rls import GROUPS, RLSSettings

__all__ = [
    "AcquisitionConfig",
    "IdentifyConfig",
    "LoopConfig",
    "ReferenceConfig",
    "RoundsConfig",
    "WaveformConfig",
    "read_config",
    "write_config",
]

NONE = "none"
"""How ``None`` is written in a TOML configuration (TOML has no null)."""


def _int_at_least(name: str, value: Any, lo: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise ValueError(f"{name} must be an integer >= {lo}. Got {value!r}.")


@dataclass(frozen=True)
class WaveformConfig:
    """The identification waveform of Fig. 7a
    (:func:`~piezocomp.identification.waveforms.identification_waveform`).

    Parameters
    ----------
    n_steady, n_decaying, n_random : int
        Steady cycles of part A; decaying and random ramps of part B.
    max_dwell_s : float
        Longest dwell of part B's random ramps.
    speed_factors : tuple of float
        Part B's ramps run at the acquisition's ``speed_nm_per_s`` times these factors in
        turn (capped at the instrument's speed limit): 0.5 to 8 are 125 nm/s to 2 um/s at the
        default speed, the speeds the compensator is then used at; several speeds tell the
        fast creep modes from narrow play operators; ``(1.0,)`` is the paper's single speed.
    seed : int
        Randomness of the waveform.
    """

    n_steady: int = 4
    n_decaying: int = 12
    n_random: int = 30
    max_dwell_s: float = 4.0
    speed_factors: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0, 8.0)
    seed: int = 0

    def __post_init__(self) -> None:
        factors = tuple(
            check_finite_scalar("speed_factors", v) for v in np.atleast_1d(self.speed_factors)
        )
        if not factors or min(factors) <= 0:
            raise ValueError(
                f"speed_factors must hold at least one factor, all > 0. Got {self.speed_factors}."
            )
        object.__setattr__(self, "speed_factors", factors)

    @property
    def reduced(self) -> bool:
        """Whether the waveform holds fewer cycles or shorter dwells than the default's (as
        ``--quick``'s): a shorter record tells drift from creep less well."""
        default = WaveformConfig()
        return any(getattr(self, k) < getattr(default, k)
                   for k in ("n_steady", "n_decaying", "n_random", "max_dwell_s"))  # fmt: skip


@dataclass(frozen=True)
class AcquisitionConfig:
    """What the instrument is asked to do for one axis (Section V, steps 1-2), and how its
    records are read (the peak finding).

    Parameters
    ----------
    center_nm, span_nm, speed_nm_per_s
        Centre (x, y) and side of the working area; base ramp speed of the waveform. The
        default span, 2000 nm, reaches about +-800 true nm on the virtual ``cpr5``.
    waveform : WaveformConfig
        The identification waveform of Fig. 7a.
    min_prominence_nm : float
        Smallest particle prominence counted as a peak, wherever peaks are found.
    calibrate : "full-range", "span" or float
        Steady cycles over a wider span, where the nominal sensitivity was calibrated, give a
        second loop onto whose frame the models are mapped
        (:func:`~piezocomp.identification.frames.frame_map`): ``"full-range"``, the scanner's
        whole range; a number, that span (nm); ``"span"``: none, the paper's calibration
        condition on the working span.
    calibration_speed_nm_per_s : float, optional
        The calibration cycles' speed (``None``: the instrument's ``calibration_scan``).
    overview_pixels, overview_speed_nm_per_s
        Pixels per side of the overview image, and the speed of its fast axis (capped at
        the instrument's speed limit; ``None``: ``speed_nm_per_s``). The overview only
        chooses the line: at the waveform's 250 nm/s a 2 um, 128-line overview takes 34
        minutes, at an imaging speed a few, but the slow axis then creeps over the line for
        longer and the models came out worse on ``cpr5`` (``docs/identification.md``,
        *Instrument time*).
    line_settle_s, relocate_settle_s
        Time scanning the line's steady cycle before the record, so that the slow axis'
        creep has slowed; settling time when the tip left the line while settling.
    cross_dither_nm
        Step of the slow command on every other settling cycle, by which the line's slide
        across its particles is measured and then followed during the record
        (:mod:`~piezocomp.identification.cross_drift`); 0: the slow command is held.
    check_cycles, rerecord_unstable
        Steady cycles scanned right after the record to check the line's profile (0: no
        check); times the line is found again and recorded anew when it changed (0: report
        only).
    extra_lines, extra_line_offset_nm
        Further particle lines (overviews this far apart on the slow axis) whose records
        refine the same models with the first (0: the paper's single line).
    """

    center_nm: tuple[float, float] = (0.0, 0.0)
    span_nm: float = 2000.0
    speed_nm_per_s: float = 250.0
    waveform: WaveformConfig = field(default_factory=WaveformConfig)
    min_prominence_nm: float = 3.0
    calibrate: str | float = "full-range"
    calibration_speed_nm_per_s: float | None = None
    overview_pixels: int = 128
    overview_speed_nm_per_s: float | None = None
    line_settle_s: float = 600.0
    relocate_settle_s: float = 300.0
    cross_dither_nm: float = DITHER_NM
    check_cycles: int = 4
    rerecord_unstable: int = 1
    extra_lines: int = 1
    extra_line_offset_nm: float = 1000.0

    def __post_init__(self) -> None:
        if not isinstance(self.waveform, WaveformConfig):
            raise TypeError(f"waveform must be a WaveformConfig. Got {type(self.waveform)}.")
        centre = tuple(check_finite_scalar("center_nm", v) for v in self.center_nm)
        if len(centre) != 2:
            raise ValueError(f"center_nm must be (x, y). Got {self.center_nm!r}.")
        object.__setattr__(self, "center_nm", centre)
        for name in ("span_nm", "speed_nm_per_s", "extra_line_offset_nm", "min_prominence_nm"):
            if check_finite_scalar(name, getattr(self, name)) <= 0:
                raise ValueError(f"{name} must be > 0. Got {getattr(self, name)}.")
        for name in ("overview_speed_nm_per_s", "calibration_speed_nm_per_s"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not check_finite_scalar(name, v) > 0):
                raise ValueError(f"{name} must be None or > 0. Got {v!r}.")
        cal = self.calibrate
        if cal not in ("full-range", "span") and (
            isinstance(cal, (bool, str)) or not check_finite_scalar("calibrate", cal) > 0
        ):
            raise ValueError(
                f"calibrate must be 'full-range', 'span' or a span in nm > 0. Got {cal!r}."
            )
        for name, lo in (("extra_lines", 0), ("rerecord_unstable", 0), ("check_cycles", 0),
                         ("overview_pixels", 2)):  # fmt: skip
            _int_at_least(name, getattr(self, name), lo)
        for name in ("line_settle_s", "relocate_settle_s", "cross_dither_nm"):
            if check_finite_scalar(name, getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0. Got {getattr(self, name)}.")

    def calibration_span_nm(self, range_nm: float | None) -> float | None:
        """The calibration cycles' span for a scanner of ``range_nm`` (``None``: none)."""
        if self.calibrate == "span":
            return None
        if self.calibrate == "full-range":
            if range_nm is None or not float(range_nm) > 0:
                raise ValueError(
                    f"calibrate='full-range' needs the scanner's range_nm > 0. Got {range_nm}."
                )
            return float(range_nm)
        return float(self.calibrate)


@dataclass(frozen=True)
class LoopConfig:
    """The steady loop of Section IV.

    Parameters
    ----------
    degree : int
        Degree of the loop polynomial ``f_a`` of eq (23) (>= 5 in the paper).
    """

    degree: int = 5

    def __post_init__(self) -> None:
        _int_at_least("degree", self.degree, 1)


@dataclass(frozen=True)
class RoundsConfig:
    """The rounds after each candidate's estimation
    (:mod:`~piezocomp.identification.lines`, :mod:`~piezocomp.identification.drift_rounds`).

    Parameters
    ----------
    joint_rounds, rls_lines_passes : int
        With extra lines: rounds of the joint batch refinement over all lines, each line
        weighted by the inverse of its residual level; passes of the RLS on every line, kept
        if it predicts the lines' held-out heights better.
    drift_rounds : int
        Rounds of estimating the sample's drift along the line during each record with the
        batch model, then the models again with it taken out
        (:mod:`~piezocomp.identification.line_drift`); kept when it predicts the held-out
        heights better than the estimate without (0: no drift).
    final_rounds, rls_final_passes : int
        After the held-out part has chosen orders and rounds: batch rounds and RLS passes
        over the whole record of every line (0: none).
    """

    joint_rounds: int = 3
    rls_lines_passes: int = 10
    drift_rounds: int = 1
    final_rounds: int = 1
    rls_final_passes: int = 10

    def __post_init__(self) -> None:
        for name, lo in (("joint_rounds", 1), ("rls_lines_passes", 0), ("final_rounds", 0),
                         ("rls_final_passes", 0), ("drift_rounds", 0)):  # fmt: skip
            _int_at_least(name, getattr(self, name), lo)
        if self.drift_rounds > 10:
            raise ValueError(
                f"drift_rounds must be an integer in [0, 10]. Got {self.drift_rounds}."
            )

    @property
    def final_fit(self) -> bool:
        """Whether the models are fitted again over the whole record, held-out part
        included."""
        return self.final_rounds > 0 or self.rls_final_passes > 0


@dataclass(frozen=True)
class ReferenceConfig:
    """The length reference (:mod:`~piezocomp.identification.reference`,
    :mod:`~piezocomp.identification.scaling`).

    Parameters
    ----------
    grating : bool
        Whether a calibration grating of known pitch, scanned with the same scanner, scales
        the models (particles cannot give the scale).
    grating_pitch_nm : float, optional
        Its pitch (``None``: the virtual AFM's grating; a recorded grating needs it).
    """

    grating: bool = True
    grating_pitch_nm: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.grating, bool):
            raise TypeError(f"grating must be true or false. Got {self.grating!r}.")
        p = self.grating_pitch_nm
        if p is not None and (
            isinstance(p, bool) or not check_finite_scalar("grating_pitch_nm", p) > 0
        ):
            raise ValueError(f"grating_pitch_nm must be None or > 0. Got {p!r}.")


_STAGES: dict[str, type] = {
    "acquisition": AcquisitionConfig,
    "loop": LoopConfig,
    "estimation": EstimationConfig,
    "rounds": RoundsConfig,
    "reference": ReferenceConfig,
}


@dataclass(frozen=True)
class IdentifyConfig:
    """Every setting of the sensorless identification, one configuration per stage.

    The defaults are ``piezocomp identify``'s; the reasons for them are in
    ``docs/identification-design.md``.

    Parameters
    ----------
    acquisition : AcquisitionConfig
    loop : LoopConfig
    estimation : EstimationConfig
    rounds : RoundsConfig
    reference : ReferenceConfig

    Examples
    --------
    >>> cfg = IdentifyConfig.quick().updated(span_nm=1000.0, orders=((16, 22),))
    >>> cfg.acquisition.span_nm, cfg.estimation.orders
    (1000.0, ((16, 22),))
    >>> IdentifyConfig.from_toml(cfg.to_toml()) == cfg
    True
    """

    acquisition: AcquisitionConfig = field(default_factory=AcquisitionConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    estimation: EstimationConfig = field(default_factory=EstimationConfig)
    rounds: RoundsConfig = field(default_factory=RoundsConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)

    def __post_init__(self) -> None:
        for name, cls in _STAGES.items():
            if not isinstance(getattr(self, name), cls):
                raise TypeError(
                    f"{name} must be a {cls.__name__}. Got {type(getattr(self, name)).__name__}."
                )

    @classmethod
    def quick(cls) -> IdentifyConfig:
        """``--quick``'s reduced run, for tests and smoke runs: a shorter waveform, orders
        8 x 2, one round, no RLS continuation, no further line (its models are far from the
        default's)."""
        return cls().updated(
            n_steady=3, n_decaying=6, n_random=8, max_dwell_s=2.0, orders=((8, 2),),
            refine_max_nfev=8, reindex_rounds=1, overview_pixels=96, extra_lines=0,
            rls_continue=None, rls_reindex_rounds=1, rls_reindex_passes=2, rls_final_passes=2,
        )  # fmt: skip

    @classmethod
    def paper(cls) -> IdentifyConfig:
        """The procedure as the paper prints it (Secs. III.C-V): one ramp speed, one line,
        the calibration condition on the working span, orders 8 x 2 estimated by the RLS of
        eqs (16)-(20) with every group of eq (15) free, the gain of eq (20) and covariance
        resetting, ``h`` never re-indexed, no drift rounds, no grating."""
        paper_rls = RLSSettings(
            alpha="paper", free=GROUPS, k0=3000, passes=20,
            min_time_constant_s=EstimationConfig().creep_tau_range_s[0],
        )  # fmt: skip
        return cls().updated(
            speed_factors=(1.0,), extra_lines=0, calibrate="span", orders=((8, 2),),
            rls_settings=paper_rls, rls_start=None, rls_continue=None, rls_reindex_rounds=0,
            reindex_rounds=0, rls_lines_passes=0, rls_final_passes=0, drift_rounds=0,
            grating=False,
        )  # fmt: skip

    def updated(self, **changes: Any) -> IdentifyConfig:
        """A copy with settings changed by name (``span_nm=1000``, ``orders=((8, 2),)``): each
        name is a field of exactly one stage's configuration (the waveform's inside the
        acquisition's); an unknown name is refused."""
        where = setting_names()
        unknown = sorted(set(changes) - set(where))
        if unknown:
            raise ValueError(f"unknown setting(s) {unknown}: the settings are {sorted(where)}.")
        tree: dict[str, Any] = {}  # the changes by stage, each stage replaced once
        for name, value in changes.items():
            node = tree
            for part in where[name]:
                node = node.setdefault(part, {})
            node[name] = value
        return _replace_tree(self, tree)  # type: ignore[no-any-return]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready nested dictionary (``None`` as ``None``, tuples as lists)."""
        return _plain(self, none=None)  # type: ignore[no-any-return]

    def to_toml(self) -> str:
        """The configuration as TOML text, one table per stage (``None`` written
        ``"none"``)."""
        return _toml_tables(_plain(self, none=NONE), ())

    @classmethod
    def from_toml(cls, text: str, base: IdentifyConfig | None = None) -> IdentifyConfig:
        """The configuration of TOML ``text``: the settings it holds, the others from
        ``base`` (default: the defaults). Unknown tables and keys are refused."""
        try:
            table = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"not a TOML configuration: {exc}") from None
        return _merge(cls() if base is None else base, table, "")  # type: ignore[no-any-return]


def setting_names() -> dict[str, tuple[str, ...]]:
    """Every setting's name and the path of stages holding it (``{"n_steady":
    ("acquisition", "waveform"), ...}``); names are unique across stages."""
    out: dict[str, tuple[str, ...]] = {}

    def walk(obj: Any, path: tuple[str, ...]) -> None:
        for f in fields(obj):
            value = getattr(obj, f.name)
            if isinstance(value, (AcquisitionConfig, WaveformConfig)) or (
                not path and f.name in _STAGES
            ):
                walk(value, (*path, f.name))
            else:
                out[f.name] = path

    walk(IdentifyConfig(), ())
    return out


def read_config(path: str | Path, base: IdentifyConfig | None = None) -> IdentifyConfig:
    """The configuration in TOML file ``path`` (:meth:`IdentifyConfig.from_toml`); errors name
    the file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read the configuration {p}: {exc.strerror}") from None
    try:
        return IdentifyConfig.from_toml(text, base)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"configuration {p}: {exc}") from None


def write_config(path: str | Path, config: IdentifyConfig, header: str = "") -> None:
    """Write ``config`` to ``path`` as TOML, atomically, after ``header`` comment lines."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    text = ("\n".join(lines) + "\n\n" if lines else "") + config.to_toml()
    atomic_write_text(Path(path), text)


def _replace_tree(obj: Any, tree: Mapping[str, Any]) -> Any:
    """``obj`` with the fields of ``tree`` set, its dicts the changes of nested dataclasses
    (all of a dataclass' changes at once: its checks see them together)."""
    changes = {
        k: _replace_tree(getattr(obj, k), v) if isinstance(v, dict) else v for k, v in tree.items()
    }
    return replace(obj, **changes)


def _plain(obj: Any, none: Any) -> Any:
    """Dataclasses as dicts of their init fields, tuples as lists, ``None`` as ``none``."""
    if is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _plain(getattr(obj, f.name), none) for f in fields(obj) if f.init}
    if isinstance(obj, (tuple, list)):
        return [_plain(v, none) for v in obj]
    if obj is None:
        return none
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string: JSON's escapes are TOML's
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML.")


def _toml_tables(table: dict[str, Any], path: tuple[str, ...]) -> str:
    """``table``'s values, then its sub-tables ``[a.b]``, in field order."""
    keys = [f"{k} = {_toml_value(v)}" for k, v in table.items() if not isinstance(v, dict)]
    out = ""
    if path:
        out += f"[{'.'.join(path)}]\n"
    if keys:
        out += "\n".join(keys) + "\n"
    for k, v in table.items():
        if isinstance(v, dict):
            out += ("\n" if out else "") + _toml_tables(v, (*path, k))
    return out


def _merge(base: Any, table: Mapping[str, Any], where: str) -> Any:
    """``base`` (a dataclass) with the values of ``table``; sub-tables merged into the
    nested dataclasses, lists made tuples, ``"none"`` made ``None`` where a string is not
    the setting's type."""
    names = {f.name for f in fields(base) if f.init}
    unknown = sorted(set(table) - names)
    if unknown:
        at = f"[{where}] " if where else ""
        raise ValueError(f"{at}unknown setting(s) {unknown}; known: {sorted(names)}.")
    default = type(base)()
    changes: dict[str, Any] = {}
    for key, value in table.items():
        current, fallback = getattr(base, key), getattr(default, key)
        name = f"{where}.{key}" if where else key
        if isinstance(value, dict):
            inner = current if is_dataclass(current) else fallback
            if not is_dataclass(inner):
                raise ValueError(f"{name} is a value, not a table. Got {value!r}.")
            changes[key] = _merge(inner, value, name)
        elif value == NONE and not isinstance(fallback, str):
            changes[key] = None
        else:
            changes[key] = _tuples(value)
    return replace(base, **changes)


def _tuples(v: Any) -> Any:
    return tuple(_tuples(x) for x in v) if isinstance(v, list) else v
