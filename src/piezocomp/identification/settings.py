"""The settings a user of the sensorless identification chooses.

:class:`IdentifySettings` is what a user of ``piezocomp identify`` holds in their head: the
working area, the speed, the orders, the length reference, quick or standard, the seed and
the threads. :meth:`IdentifySettings.config` turns it into a
:class:`~piezocomp.identification.config.SensorlessConfig`, the research-level object with
every setting of every stage (all of which go into ``summary.json``). Lengths are nm of
command, times s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from piezocomp.identification.config import SensorlessConfig

__all__ = [
    "QUICK",
    "IdentifySettings",
]

QUICK: dict[str, Any] = {
    "n_steady": 3,
    "n_decaying": 6,
    "n_random": 8,
    "max_dwell_s": 2.0,
    "orders": ((8, 2),),
    "refine_max_nfev": 8,
    "reindex_rounds": 1,
    "overview_pixels": 96,
    "extra_lines": 0,
    "rls_continue": None,
    "rls_reindex_rounds": 1,
    "rls_reindex_passes": 2,
    "rls_final_passes": 2,
}
"""The reduced configuration of ``quality="quick"`` (``--quick``: tests and smoke runs;
its models are far from the standard ones)."""


@dataclass(frozen=True)
class IdentifySettings:
    """The settings a user of the identification chooses.

    Parameters
    ----------
    span_nm : float
        Side of the working area (nm of command); the models hold over it. The default,
        2000 nm, reaches about +-800 true nm on the virtual ``cpr5``.
    speed_nm_per_s : float
        Ramp speed of the identification waveform.
    center_nm : (float, float)
        Centre of the working area.
    speed_factors : tuple of float, optional
        Part B's ramp speeds as multiples of ``speed_nm_per_s`` (default 0.5 to 8: 125 nm/s
        to 2 um/s; ``None``: :class:`SensorlessConfig`'s 0.5, 1 and 2); cover the speeds the
        compensator will be used at.
    orders : "auto" or (int, int)
        ``"auto"`` chooses ``(n_play, n_creep)`` by held-out heights; a pair fixes them.
    calibrate : {"full-range", "span"}
        ``"full-range"`` adds steady cycles over the scanner's whole range, where its
        nominal sensitivity holds, and maps the models onto that frame; ``"span"`` is the
        paper's calibration condition on the working span.
    reference : {"grating", "none"}
        Whether a calibration grating of known pitch scales the models (the length
        reference particles cannot give).
    extra_lines : int, optional
        Further particle lines refining the same models (``None``: 1, or 0 when quick).
    overview_speed_nm_per_s : float, optional
        Fast-axis speed of the overview images that choose the lines (``None``: the
        waveform's speed). The overviews are most of the identification's instrument time
        at the waveform's speed (34 minutes each for a 2 um, 128-line image at 250 nm/s).
    quality : {"standard", "quick"}
        ``"quick"`` runs a reduced waveform and orders (:data:`QUICK`): for smoke tests.
    seed : int
        Randomness of the waveform.
    workers : int, optional
        Threads of the estimation (``None``: up to 4); results do not depend on it.
    """

    span_nm: float = 2000.0
    speed_nm_per_s: float = 250.0
    center_nm: tuple[float, float] = (0.0, 0.0)
    speed_factors: tuple[float, ...] | None = (0.5, 1.0, 2.0, 4.0, 8.0)
    orders: str | tuple[int, int] = "auto"
    calibrate: str = "full-range"
    reference: str = "grating"
    extra_lines: int | None = None
    overview_speed_nm_per_s: float | None = None
    quality: str = "standard"
    seed: int = 0
    workers: int | None = None

    def __post_init__(self) -> None:
        for name, allowed in (
            ("calibrate", ("full-range", "span")),
            ("reference", ("grating", "none")),
            ("quality", ("standard", "quick")),
        ):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}. Got {getattr(self, name)!r}.")
        if self.orders != "auto":
            pair: tuple[Any, ...] = tuple(self.orders)
            if len(pair) != 2:
                raise ValueError(
                    f"orders must be 'auto' or (n_play, n_creep). Got {self.orders!r}."
                )
            object.__setattr__(self, "orders", (int(pair[0]), int(pair[1])))

    def config(self, range_nm: float | None = None, **advanced: Any) -> SensorlessConfig:
        """The full configuration for a scanner of ``range_nm`` (needed with
        ``calibrate="full-range"``); ``advanced`` overrides any :class:`SensorlessConfig`
        field (research use)."""
        kw: dict[str, Any] = dict(QUICK) if self.quality == "quick" else {}
        if self.calibrate == "full-range":
            if range_nm is None or not float(range_nm) > 0:
                raise ValueError(
                    f"calibrate='full-range' needs the scanner's range_nm > 0. Got {range_nm}."
                )
            kw["calibration_span_nm"] = float(range_nm)
        if self.extra_lines is not None:
            kw["extra_lines"] = self.extra_lines
        if self.overview_speed_nm_per_s is not None:
            kw["overview_speed_nm_per_s"] = self.overview_speed_nm_per_s
        if self.speed_factors is not None:
            kw["speed_factors"] = tuple(self.speed_factors)
        if self.orders != "auto":
            kw["orders"] = (self.orders,)
        kw.update(
            center_nm=tuple(self.center_nm), span_nm=self.span_nm,
            speed_nm_per_s=self.speed_nm_per_s, seed=self.seed, workers=self.workers,
        )  # fmt: skip
        kw.update(advanced)
        return SensorlessConfig(**kw)
