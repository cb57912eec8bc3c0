"""The file a drift-tracking state is saved in: an ``.npz`` of arrays and one JSON header.

:meth:`piezocomp.drift.compensated.DriftCompensatedInstrument.save` and ``load`` use these:
the settings, the landmarks with their templates and the measured scanner error go to plain
JSON and arrays and come back as the same frozen objects; the file is written atomically.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezocomp._atomic import atomic_write_bytes
from piezocomp.drift.filter import DriftEstimate, DriftNoise, DriftSettings
from piezocomp.drift.landmark_set import LandmarkSet
from piezocomp.drift.landmarks import Landmark, LandmarkSettings
from piezocomp.drift.noise_learning import SightingSpread
from piezocomp.drift.scanner_error import ScannerError
from piezocomp.imaging.features import FoundParticles
from piezocomp.instrument import ScanImage

__all__ = [
    "STATE_FORMAT",
    "TrackingState",
    "landmarks_from",
    "landmarks_to",
    "load_tracking",
    "read_state",
    "save_tracking",
    "scanner_error_from",
    "scanner_error_to",
    "settings_from",
    "write_state",
]

STATE_FORMAT = "piezocomp/drift-tracking"
"""Format tag of a saved tracking state."""


@dataclass(frozen=True)
class TrackingState:
    """Everything a drift-compensated instrument needs to resume tracking.

    Attributes
    ----------
    settings, base_settings : DriftSettings
        The settings in force, and those before sizing from the scanner's error.
    scanner_error : ScannerError or None
    estimate : DriftEstimate
    landmarks : LandmarkSet
    t_start_s, measuring_s, last_measurement_s : float
        When tracking started, the time spent measuring since, the last measurement's time.
    sighting_spread : SightingSpread or None
        The landmarks' pooled spread the measurement noise is learnt from (``None``: none
        yet; a file written before it existed reads as ``None``).
    prior_noise : DriftNoise or None
        The drift model learning started from (``None``: a file written before it was
        saved; the noise in force then stands for it).
    """

    settings: DriftSettings
    base_settings: DriftSettings
    scanner_error: ScannerError | None
    estimate: DriftEstimate
    landmarks: LandmarkSet
    t_start_s: float
    measuring_s: float
    last_measurement_s: float
    sighting_spread: SightingSpread | None = None
    prior_noise: DriftNoise | None = None


def save_tracking(path: str | os.PathLike[str], state: TrackingState) -> None:
    """Write ``state`` atomically to ``path`` (``.npz``)."""
    ls = state.landmarks
    lms, arrays = landmarks_to(ls.landmarks)
    areas, area_arrays = landmarks_to(list(ls.areas.values()), prefix="area")
    arrays.update(area_arrays)
    meta = {
        "settings": state.settings,
        "base_settings": asdict(state.base_settings),
        "scanner_error": scanner_error_to(state.scanner_error),
        "t_start_s": state.t_start_s,
        "avoid_radius_nm": ls.avoid_radius_nm,
        "measuring_s": state.measuring_s,
        "last_measurement_s": state.last_measurement_s,
        "sighting_spread": None
        if state.sighting_spread is None
        else [state.sighting_spread.sum_sq_nm2, state.sighting_spread.dof],
        "estimate_t_s": state.estimate.t_s,
        "prior_noise": None if state.prior_noise is None else asdict(state.prior_noise),
        "landmarks": lms,
        "areas": {"names": list(ls.areas), "references": areas},
    }
    arrays.update({
        "mean": state.estimate.mean, "cov": state.estimate.cov, "avoid": ls.avoid_nm,
        "retired": np.asarray(ls.retired, dtype=float).reshape(-1, 2),
    })  # fmt: skip
    if ls.particles is not None:
        arrays["particles"] = ls.particles.positions_nm
        arrays["particle_heights"] = ls.particles.heights_nm
    write_state(path, meta, arrays)


def load_tracking(path: str | os.PathLike[str]) -> TrackingState:
    """The tracking state saved in ``path``.

    Raises
    ------
    ValueError
        If the file is not a readable drift-tracking state.
    """
    meta, data = read_state(path)
    settings = meta["settings"]
    base = meta.get("base_settings")
    landmarks = LandmarkSet(
        landmarks_from(meta["landmarks"], data),
        FoundParticles(data["particles"], data["particle_heights"])
        if "particles" in data else None,
        data["avoid"].reshape(-1, 2),
        float(meta.get("avoid_radius_nm", 100.0)),
        [np.asarray(r) for r in data.get("retired", np.zeros((0, 2)))],
        _areas_from(meta.get("areas"), data),
    )  # fmt: skip
    return TrackingState(
        settings, settings if base is None else settings_from(base),
        scanner_error_from(meta.get("scanner_error")),
        DriftEstimate(meta["estimate_t_s"], data["mean"], data["cov"]), landmarks,
        meta["t_start_s"], meta["measuring_s"], meta["last_measurement_s"],
        _spread_from(meta.get("sighting_spread")),
        None if meta.get("prior_noise") is None else DriftNoise(**meta["prior_noise"]),
    )  # fmt: skip


def settings_from(d: dict[str, Any]) -> DriftSettings:
    """:class:`DriftSettings` from ``asdict`` of one (as saved)."""
    return DriftSettings(
        **{k: v for k, v in d.items() if k not in ("noise", "landmarks")},
        noise=DriftNoise(**d["noise"]), landmarks=LandmarkSettings(**d["landmarks"]),
    )  # fmt: skip


def scanner_error_to(error: ScannerError | None) -> dict[str, Any] | None:
    """A scanner error as JSON."""
    if error is None:
        return None
    return {"sum_sq_nm2": error.sum_sq_nm2.tolist(), "dof": error.dof,
            "sightings": error.sightings}  # fmt: skip


def scanner_error_from(d: dict[str, Any] | None) -> ScannerError | None:
    """A scanner error from its JSON."""
    return None if d is None else ScannerError(np.asarray(d["sum_sq_nm2"]), d["dof"],
                                               d["sightings"])  # fmt: skip


def landmarks_to(
    landmarks: list[Landmark], prefix: str = "lm"
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Landmarks as JSON entries and arrays (their templates, named ``prefix`` and the
    landmark's index)."""
    meta, arrays = [], {}
    for i, lm in enumerate(landmarks):
        tpl = lm.template
        meta.append({
            "center_nm": lm.center_nm.tolist(), "t_s": lm.t_s,
            "offset_nm": lm.offset_nm.tolist(), "offset_var_nm2": lm.offset_var_nm2.tolist(),
            "line_time_s": tpl.line_time_s, "t_start_s": tpl.t_start_s,
            "fast_axis": tpl.fast_axis,
        })  # fmt: skip
        k = f"{prefix}{i}"
        arrays.update({f"{k}_forward": tpl.forward_nm, f"{k}_backward": tpl.backward_nm,
                       f"{k}_x": tpl.x_nm, f"{k}_y": tpl.y_nm})  # fmt: skip
    return meta, arrays


def landmarks_from(
    meta: list[dict[str, Any]], data: dict[str, Any], prefix: str = "lm"
) -> list[Landmark]:
    """Landmarks from their JSON entries and arrays (named as :func:`landmarks_to` names
    them)."""
    out = []
    for i, lm in enumerate(meta):
        k = f"{prefix}{i}"
        tpl = ScanImage(data[f"{k}_forward"], data[f"{k}_backward"], data[f"{k}_x"],
                        data[f"{k}_y"], lm["line_time_s"], lm["t_start_s"],
                        lm["fast_axis"])  # fmt: skip
        out.append(Landmark(np.array(lm["center_nm"]), tpl, lm["t_s"], np.array(lm["offset_nm"]),
                            np.array(lm["offset_var_nm2"])))  # fmt: skip
    return out


def write_state(path: str | os.PathLike[str], meta: dict[str, Any], arrays: dict[str, Any]) -> None:
    """Write a state (``meta``: JSON-ready, with ``settings`` a :class:`DriftSettings`)
    atomically to ``path``."""
    head = {"format": STATE_FORMAT, "version": 1, **meta, "settings": asdict(meta["settings"])}
    buf = io.BytesIO()
    np.savez(buf, meta=np.array(json.dumps(head)), **arrays)
    atomic_write_bytes(path, buf.getvalue())


def read_state(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The header (its ``settings`` a :class:`DriftSettings`) and arrays of a saved state.

    Raises
    ------
    ValueError
        If the file is not a readable drift-tracking state.
    """
    p = Path(path)
    try:
        with np.load(io.BytesIO(p.read_bytes()), allow_pickle=False) as npz:
            data = {k: np.asarray(npz[k]) for k in npz.files}
        meta = json.loads(str(data["meta"]))
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{p}: not a readable drift-tracking state ({exc}).") from None
    if meta.get("format") != STATE_FORMAT:
        raise ValueError(f"{p}: 'format' must be {STATE_FORMAT!r}.")
    meta["settings"] = settings_from(meta["settings"])
    return meta, data


def _areas_from(value: Any, data: dict[str, Any]) -> dict[str, Landmark]:
    """The areas' references saved under ``areas`` (none in a file written before they
    existed)."""
    if value is None:
        return {}
    refs = landmarks_from(value["references"], data, prefix="area")
    return dict(zip(value["names"], refs, strict=True))


def _spread_from(value: Any) -> SightingSpread | None:
    """The saved ``[sum of squares, dof]`` of the landmarks' spread, checked."""
    if value is None:
        return None
    try:
        ss, dof = float(value[0]), int(value[1])
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"sighting_spread must be [sum of squares, dof]. Got {value!r}.") from None
    if not (np.isfinite(ss) and ss > 0 and dof >= 1):
        raise ValueError(f"sighting_spread must be [sum > 0, dof >= 1]. Got {value!r}.")
    return SightingSpread(ss, dof)
