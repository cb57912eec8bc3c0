"""Scanner-model files: versioned, human-readable JSON, written atomically.

One axis (version 2)::

    {"format": "piezocomp/scanner-model", "version": 2, "input_unit": "nm",
     "output_unit": "nm", "offset": 0.0, "gain": 0.62,
     "play": {"thresholds": [10.0, 20.0], "weights": [0.05, 0.03]},
     "creep": {"time_constants_s": [0.5, 20.0], "gains": [0.02, 0.04], "coupling": 0.0}}

``creep.coupling`` is the creep coupling ``beta`` of eq (2') (``0``: the paper's model).
Version 1 files, written before the coupling existed, have no ``coupling`` key and are read
as what they meant: the paper's model, ``beta = 0``. Version 3 adds, per axis, the optional
``"asymmetry": {"dead_zones": [...], "gains": [...]}``: the one-sided dead zones of Kuhnen's
asymmetry map, eq (8') (thresholds in nm of the hysteresis output). A file is written at the
lowest version that holds its model: 3 when an axis has dead zones, else 2, so a symmetric
model stays readable by the releases before version 3. Any other version is refused.

Optional per-axis keys: ``"domain_nm": [lo, hi]``, the command interval the model was
identified over (the compensated instrument refuses commands outside it unless told to
extrapolate), and ``"range_nm"``, the scanner's full travel (commands in ``+-range_nm/2``).
A 2-D scanner holds ``"x"`` and ``"y"`` objects with the per-axis keys (``offset``, ``gain``,
``play``, ``creep``, ...) instead. An optional ``"metadata"`` object (free-form: how the model was
identified) is kept but not interpreted. Anything else is refused, naming the key.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from piezocomp._atomic import atomic_write_text
from piezocomp.model import OPTIONAL_KEYS, ModelState, ScannerModel, ScannerModel2D

__all__ = [
    "FORMAT",
    "READABLE_VERSIONS",
    "STATE_FORMAT",
    "STATE_VERSION",
    "VERSION",
    "load_model",
    "load_state",
    "model_from_json",
    "model_to_json",
    "save_model",
    "save_state",
]

STATE_FORMAT = "piezocomp/model-state"
"""Format tag of a state file: the predicted plant state of each axis between two runs."""

STATE_VERSION = 1
"""Version of the state files (the model state is the same in both model versions)."""

FORMAT = "piezocomp/scanner-model"
VERSION = 3
"""The newest version of the model files: 2 added ``creep.coupling`` (eq 2'), 3 the dead
zones of eq (8') (``asymmetry``). Symmetric models are written as version 2."""
READABLE_VERSIONS = (1, 2, 3)
"""Model file versions read; 1 means ``creep_coupling = 0``, 1 and 2 mean no dead zones."""
_HEADER = {"format", "version", "input_unit", "output_unit", "metadata"}
_AXIS = {"offset", "gain", "play", "creep", "asymmetry"} | OPTIONAL_KEYS


def model_to_json(
    model: ScannerModel | ScannerModel2D, metadata: dict[str, Any] | None = None
) -> str:
    """The file text for a model (floats written with full precision: exact round trip)."""
    doc: dict[str, Any] = {"format": FORMAT}
    if isinstance(model, ScannerModel2D):
        doc["version"] = max(model.x.file_version, model.y.file_version)
    elif isinstance(model, ScannerModel):
        doc["version"] = model.file_version
    doc.update({"input_unit": "nm", "output_unit": "nm"})
    if isinstance(model, ScannerModel2D):
        doc["x"] = model.x.to_dict()
        doc["y"] = model.y.to_dict()
    elif isinstance(model, ScannerModel):
        doc.update(model.to_dict())
    else:
        raise TypeError(
            f"model must be a ScannerModel or ScannerModel2D. Got {type(model).__name__}."
        )
    if metadata:
        doc["metadata"] = metadata
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def save_model(
    path: str | os.PathLike[str],
    model: ScannerModel | ScannerModel2D,
    metadata: dict[str, Any] | None = None,
) -> None:
    """Write a model file atomically (temporary file + rename)."""
    atomic_write_text(path, model_to_json(model, metadata))


_TOO_DEEP = "JSON nested too deeply to read (not a model file?)"


def _reject_constant(value: str) -> float:
    raise ValueError(f"{value} is not a valid number in a model file")


def model_from_json(text: str, source: str = "model file") -> ScannerModel | ScannerModel2D:
    """Parse and validate a model file's text; errors name ``source`` and the field."""
    try:
        doc = json.loads(text, parse_constant=_reject_constant)
    except RecursionError:
        raise ValueError(f"{source}: {_TOO_DEEP}") from None
    except json.JSONDecodeError as exc:
        stripped = text.rstrip()
        truncated = exc.pos >= len(stripped) or not stripped.endswith("}")
        hint = " (the file looks truncated)" if truncated else ""
        raise ValueError(
            f"{source}: not valid JSON{hint}: {exc.msg} at line {exc.lineno}"
        ) from None
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{source}: the top level must be a JSON object.")
    if doc.get("format") != FORMAT:
        raise ValueError(f"{source}: 'format' must be {FORMAT!r}. Got {doc.get('format')!r}.")
    version = doc.get("version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise ValueError(
            f"{source}: 'version' must be 1, 2 or 3 (the versions this piezocomp reads). "
            f"Got {version!r}."
        )
    for key in ("input_unit", "output_unit"):
        if doc.get(key, "nm") != "nm":
            raise ValueError(f"{source}: {key!r} must be 'nm'. Got {doc[key]!r}.")
    try:
        _check_numbers(doc, source)
    except RecursionError:
        raise ValueError(f"{source}: {_TOO_DEEP}") from None
    if "x" in doc or "y" in doc:
        unknown = sorted(set(doc) - _HEADER - {"x", "y"})
        if unknown:
            raise ValueError(f"{source}: unknown key(s) {unknown} in a 2-D model file.")
        for axis in ("x", "y"):
            if axis not in doc:
                raise ValueError(f"{source}: a 2-D model file needs both 'x' and 'y'.")
        return ScannerModel2D(
            ScannerModel.from_dict(doc["x"], f"{source}: x", int(version)),
            ScannerModel.from_dict(doc["y"], f"{source}: y", int(version)),
        )
    unknown = sorted(set(doc) - _HEADER - _AXIS)
    if unknown:
        raise ValueError(f"{source}: unknown key(s) {unknown}; expected {sorted(_AXIS)}.")
    body = {k: doc[k] for k in _AXIS if k in doc}
    return ScannerModel.from_dict(body, source, int(version))


def _check_numbers(node: Any, where: str) -> None:
    """Refuse booleans and non-finite numbers anywhere outside metadata."""
    if isinstance(node, dict):
        for k, v in node.items():
            if k != "metadata":
                _check_numbers(v, f"{where}: {k}")
    elif isinstance(node, list):
        for i, v in enumerate(node):
            _check_numbers(v, f"{where}[{i}]")
    elif isinstance(node, bool):
        if not where.endswith(("format", "version")):
            raise ValueError(f"{where} must be a number. Got {node!r}.")
    elif isinstance(node, float) and not math.isfinite(node):
        raise ValueError(f"{where} must be finite. Got {node}.")


def load_model(path: str | os.PathLike[str]) -> ScannerModel | ScannerModel2D:
    """Read and validate a model file (1-D or 2-D)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not a text (UTF-8 JSON) model file.") from None
    if not text.strip():
        raise ValueError(f"{p}: the file is empty.")
    return model_from_json(text, str(p))


def save_state(path: str | os.PathLike[str], states: dict[str, ModelState]) -> None:
    """Write the model state of each axis (``{"x": state, "y": state}``, or ``{"axis": state}``
    for a 1-D model) atomically, so that a trajectory can continue where the last ended::

        {"format": "piezocomp/model-state", "version": 1,
         "x": {"play_nm": [...], "creep_nm": [...], "u_prev_nm": 12.5}}
    """
    doc: dict[str, Any] = {"format": STATE_FORMAT, "version": STATE_VERSION}
    for axis, st in states.items():
        doc[axis] = {
            "play_nm": st.play_nm.tolist(),
            "creep_nm": st.creep_nm.tolist(),
            "u_prev_nm": st.u_prev_nm,
        }
    atomic_write_text(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")


def load_state(path: str | os.PathLike[str]) -> dict[str, ModelState]:
    """Read a state file written by :func:`save_state` (each axis' state; check it against
    the model with :meth:`ModelState.check_for`)."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"), parse_constant=_reject_constant)
    except RecursionError:
        raise ValueError(f"{p}: {_TOO_DEEP.replace('model', 'state')}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not a text (UTF-8 JSON) state file.") from None
    except ValueError as exc:
        raise ValueError(f"{p}: not a valid state file ({exc}).") from None
    if not isinstance(doc, dict) or doc.get("format") != STATE_FORMAT:
        raise ValueError(f"{p}: 'format' must be {STATE_FORMAT!r}.")
    if doc.get("version") != STATE_VERSION:
        raise ValueError(f"{p}: 'version' must be {STATE_VERSION}. Got {doc.get('version')!r}.")
    out = {}
    for axis, body in doc.items():
        if axis in ("format", "version"):
            continue
        if not isinstance(body, dict) or set(body) != {"play_nm", "creep_nm", "u_prev_nm"}:
            raise ValueError(f"{p}: {axis} must hold play_nm, creep_nm and u_prev_nm.")
        try:
            out[axis] = ModelState(body["play_nm"], body["creep_nm"], body["u_prev_nm"])
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{p}: {axis}: {exc}") from None
    if not out:
        raise ValueError(f"{p}: the state file holds no axis.")
    return out
