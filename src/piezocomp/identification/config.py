"""The configuration of the sensorless identification: one nested, frozen object.

:class:`IdentifyConfig` holds the stages' configurations, each read by its own stage (two
for the estimation), with three read by two stages: the acquisition's peak prominence by the
loop fit too, the loop's ``degree`` by the acquisition's line choice (the line must cross
enough particles for a loop of that degree, eq 23), and the acquisition's calibration
cycles, ``calibrate``, which serve the reference stage's calibration frame:

- ``acquisition`` (:class:`AcquisitionConfig`, with its ``waveform``,
  :class:`WaveformConfig`): the working area, the overview and the line, the settling, the
  record of Fig. 7a, the calibration cycles, the further lines, the peak finding;
- ``loop`` (:class:`LoopConfig`): the steady loop of Section IV (eqs 21-23);
- ``estimation`` (:class:`~piezocomp.identification.estimation.config.EstimationConfig`):
  the candidate orders, the RLS (eqs 16-20), the batch refinement, the held-out choice;
- ``rounds`` (:class:`RoundsConfig`): the estimation stage's rounds after the candidates:
  over the further lines, with the sample's drift along the line, over the whole record;
- ``reference`` (:class:`ReferenceConfig`): the length reference (a calibration grating).

There is one set of defaults, those of ``piezocomp identify``, which the accuracy table of
``docs/identification.md`` was measured with; :meth:`IdentifyConfig.quick` is ``--quick``'s
reduced run, :meth:`IdentifyConfig.paper` the procedure as the paper prints it. A
configuration is written and read as TOML (:meth:`IdentifyConfig.to_toml`,
:meth:`IdentifyConfig.from_toml`, through :mod:`piezocomp.io.dataclass_toml`); ``None`` is
written ``"none"``. Lengths are nm of command,
times s.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from piezocomp._atomic import atomic_write_text
from piezocomp.identification.acquisition.config import AcquisitionConfig, WaveformConfig
from piezocomp.identification.estimation.config import EstimationConfig, RoundsConfig
from piezocomp.identification.estimation.rls import GROUPS, RLSSettings
from piezocomp.identification.loop.config import LoopConfig
from piezocomp.identification.reference.config import ReferenceConfig
from piezocomp.io.dataclass_toml import dataclass_toml, merged_from_toml, plain, replaced

__all__ = [
    "PAPER_CREEP_START_S",
    "AcquisitionConfig",
    "EstimationConfig",
    "IdentifyConfig",
    "LoopConfig",
    "ReferenceConfig",
    "RoundsConfig",
    "WaveformConfig",
    "read_config",
    "write_config",
]

PAPER_CREEP_START_S = (1.0, 100.0)
"""Where the ``paper`` method's two creep poles start, as time constants (s). The paper sets
"all initial conditions to zero" (Sec. V); a creep gain of zero is that, but a zero pole
(a time constant of 0) is no creep operator at all, and a pole whose gain is zero has no
sensitivity (eq 17), so the start of the poles is not given by the paper. Here they start
at the time scales of the record (1 s, about one ramp of the identification waveform;
100 s, about its length): the start from which the RLS finds the poles of data of its own
family (``tests/identification/test_rls.py``), and on ``cpr5`` as good as the best other
start tried (``benchmarks/paper_start.py``, seeds 1-8: median 29.2 nm against 29.8 nm from
0.1/10 s; 43.7 nm from 0.01/2000 s on seeds 1-3; docs/experiments.md)."""

_STAGES: dict[str, type] = {
    "acquisition": AcquisitionConfig,
    "loop": LoopConfig,
    "estimation": EstimationConfig,
    "rounds": RoundsConfig,
    "reference": ReferenceConfig,
}


@dataclass(frozen=True)
class IdentifyConfig:
    """Every setting of the sensorless identification, the stages' configurations nested.

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
        resetting, the creep poles started at :data:`PAPER_CREEP_START_S`, ``h`` never
        re-indexed, no drift rounds, no grating; the paper's family throughout (its batch
        refinement without the creep coupling of eq 2')."""
        paper_rls = RLSSettings(
            alpha="paper", free=GROUPS, k0=3000, passes=20,
            min_time_constant_s=EstimationConfig().creep_tau_range_s[0],
        )  # fmt: skip
        return cls().updated(
            speed_factors=(1.0,), extra_lines=0, calibrate="span", orders=((8, 2),),
            creep_tau_range_s=PAPER_CREEP_START_S,
            rls_settings=paper_rls, rls_start=None, rls_continue=None, rls_reindex_rounds=0,
            reindex_rounds=0, rls_lines_passes=0, rls_final_passes=0, drift_rounds=0,
            grating=False, refine_free=("c", "a", "w", "y0"),
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
        return replaced(self, tree)  # type: ignore[no-any-return]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready nested dictionary (``None`` as ``None``, tuples as lists)."""
        return plain(self)  # type: ignore[no-any-return]

    def to_toml(self) -> str:
        """The configuration as TOML text, one table per stage (``None`` written
        ``"none"``)."""
        return dataclass_toml(self)

    @classmethod
    def from_toml(cls, text: str, base: IdentifyConfig | None = None) -> IdentifyConfig:
        """The configuration of TOML ``text``: the settings it holds, the others from
        ``base`` (default: the defaults). Unknown tables and keys are refused."""
        return merged_from_toml(cls() if base is None else base, text)  # type: ignore[no-any-return]


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
