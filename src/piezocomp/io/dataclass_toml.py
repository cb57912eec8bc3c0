"""Frozen dataclasses as TOML: a tree of settings written as tables and read back.

:func:`dataclass_toml` writes a dataclass (its ``init`` fields, nested dataclasses as
sub-tables ``[a.b]``, tuples as arrays, ``None`` as :data:`NONE`: TOML has no null);
:func:`merged_from_toml` reads TOML text over a base instance: the keys it holds replace
the base's, sub-tables merge into the nested dataclasses, arrays become tuples, and an
unknown table or key is refused by name. :func:`plain` gives the JSON-ready dictionary.
The dataclasses' own checks (``__post_init__``) judge the values.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import fields, is_dataclass, replace
from typing import Any

import numpy as np
import tomli_w

__all__ = ["NONE", "dataclass_toml", "merged_from_toml", "plain", "replaced"]

NONE = "none"
"""How ``None`` is written in TOML (which has no null)."""


def dataclass_toml(obj: Any) -> str:
    """``obj`` (a dataclass) as TOML text: its values, then each nested dataclass as a
    table, in field order."""
    return tomli_w.dumps(plain(obj, none=NONE))


def merged_from_toml(base: Any, text: str) -> Any:
    """``base`` (a dataclass) with the values of TOML ``text`` (ValueError naming the table
    and key of what is not a setting of ``base``, or text that is not TOML)."""
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"not a TOML configuration: {exc}") from None
    return _merge(base, table, "")


def replaced(obj: Any, tree: Mapping[str, Any]) -> Any:
    """``obj`` with the fields of ``tree`` set, its dicts the changes of nested dataclasses
    (all of a dataclass' changes at once: its checks see them together)."""
    changes = {k: replaced(getattr(obj, k), v) if isinstance(v, dict) else v
               for k, v in tree.items()}  # fmt: skip
    return replace(obj, **changes)


def plain(obj: Any, none: Any = None) -> Any:
    """Dataclasses as dicts of their init fields, tuples as lists, ``None`` as ``none``."""
    if is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: plain(getattr(obj, f.name), none) for f in fields(obj) if f.init}
    if isinstance(obj, (tuple, list)):
        return [plain(v, none) for v in obj]
    if obj is None:
        return none
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj


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
