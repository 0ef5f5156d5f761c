"""Config dataclass helpers shared by every layer: checks that raise one-line settings errors,
and the mapping <-> dataclass conversions every entry point uses."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from icgo.core.errors import SettingError, SettingsError


def need(cond: bool, field: str, problem: str) -> None:
    """Raise :class:`~icgo.core.errors.SettingError` ``(field, problem)`` unless ``cond``."""
    if not cond:
        raise SettingError(field, problem)


def is_int(x) -> bool:
    """True for a Python/numpy integer that is not a bool."""
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def is_real(x) -> bool:
    """True for a finite real number that is not a bool."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def config_from_mapping(cls, values: dict, where: str = "config"):
    """Build a config dataclass from a plain mapping, refusing unknown keys in one line.

    Args:
        cls: the config dataclass.
        values: field name -> value (nested dataclass fields given as mappings are built recursively).
        where: the name of the mapping in error messages (e.g. ``"conf/misma.yaml"``).
    Raises:
        SettingError: an unknown key, or the dataclass's own validation.
    """
    if not isinstance(values, dict):
        raise SettingError(f"{where}: expected a mapping of settings, got {type(values).__name__}")
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise SettingError(f"{where}: unknown setting(s) {unknown}; known: {sorted(names)}")
    kwargs = {}
    for k, v in values.items():
        default = names[k].default
        if dataclasses.is_dataclass(default) and isinstance(v, dict):
            v = config_from_mapping(type(default), v, f"{where}.{k}")
        kwargs[k] = v
    return cls(**kwargs)


def config_to_mapping(config) -> dict:
    """The inverse of :func:`config_from_mapping`: a nested plain dict of the fields (tuples as lists)."""
    def plain(v):
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(config)


__all__ = ["need", "is_int", "is_real", "config_from_mapping", "config_to_mapping", "SettingError", "SettingsError"]
