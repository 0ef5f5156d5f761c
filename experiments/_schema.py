"""The typed schema of a study door's YAML, made from the study's config dataclass and registered in Hydra's
ConfigStore, so that Hydra refuses an unknown key or a wrongly typed value when it composes.

``conf/calibrate.yaml`` names its schema first in its defaults list (``defaults: [calibrate_schema, _self_]``);
:func:`register` stores it, made from ``STUDIES[name].config_cls`` (:func:`schema_of`) plus the entry point's own
keys (untyped, their values given by the YAML only).

``conf/misma.yaml`` and ``conf/gyro.yaml`` name an untyped node instead (``defaults: [misma_defaults, _self_]``,
:func:`register_defaults`): the same defaults from the dataclass, as a plain mapping, because a free mapping inside
a typed node (MISMA's ``simulated.variants``, gyro's ``data.instrument``) can no longer be deleted or replaced from
the command line (``~simulated.variants +simulated.variants={...}``, ``data.instrument={...}``: OmegaConf refuses
both on a structured node), which their command lines use; :func:`icgo.core.settings.config_from_mapping` stays
their one check. Either way no door's YAML repeats a study default: it holds the door's own settings and Hydra's.
The library's dataclass stays the one source of the defaults
and the one full check (:func:`icgo.core.settings.config_from_mapping` and its ``__post_init__``): OmegaConf
cannot express every field's type, so the schema types only what it checks exactly as the library does:

- ``int`` (not ``bool``) and ``str`` fields are typed (a value of another type is refused at compose time);
- ``bool`` fields are ``Any``: OmegaConf reads ``2``, ``"yes"`` or ``"on"`` as true, the library refuses them;
- ``float`` fields are ``Any``: OmegaConf would turn ``30`` into ``30.0`` in the composed settings the run
  summaries record;
- tuples, mappings of free keys (MISMA's and gyro's ``variants``, gyro's ``data.instrument``) and unions
  (gyro's ``table.toolface``: ``mean`` or a number) are ``Any``; nested config dataclasses are nested schemas.

The door (``experiments/calibrate.py``) registers the schema when it is imported, before Hydra composes; this module
imports nothing of icgo at import.

A door's ``--help`` lists these defaults from the dataclass (:func:`experiments._help.door_help`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from omegaconf import MISSING

#: What each typed field annotation becomes in a schema (every other annotation: ``Any``).
TYPED = {"int": int, "str": str}


def _plain(value):
    """A default as OmegaConf takes it: tuples as lists, mappings and lists copied."""
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def schema_of(config_cls, entry_keys=(), door_cls=None) -> type:
    """A mutable dataclass with the fields and defaults of the frozen ``config_cls`` (nested dataclasses mirrored,
    types as the module docstring says), plus ``entry_keys``: the entry point's own settings (``Any``; no default
    here, the YAML gives them, unless ``door_cls``, a config dataclass of door settings, has the field)."""
    fields = _fields(config_cls) + (_fields(door_cls) if door_cls is not None else [])
    given = {name for name, *_ in fields}
    fields += [(name, Any, dataclasses.field(default=MISSING)) for name in entry_keys if name not in given]
    return dataclasses.make_dataclass(f"{config_cls.__name__}Schema", fields)


def _fields(config_cls) -> list:
    """The schema's fields (name, type, field) of the config dataclass ``config_cls``, defaults included."""
    default = config_cls()
    fields = []
    for f in dataclasses.fields(config_cls):
        value = getattr(default, f.name)
        if dataclasses.is_dataclass(value):
            sub = schema_of(type(value))
            fields.append((f.name, sub, dataclasses.field(default_factory=sub)))
            continue
        kind = TYPED.get(f.type if isinstance(f.type, str) else getattr(f.type, "__name__", ""), Any)
        if kind is not Any and (type(value) is not kind):
            kind = Any  # a default of another type than its annotation: the library decides
        fields.append((f.name, kind, dataclasses.field(default_factory=lambda v=value: _plain(v))))
    return fields


def register_defaults(config_name: str, config_cls, door_cls=None) -> str:
    """Store the defaults of ``config_cls`` and of ``door_cls``, the door's own settings that have a default
    (:func:`icgo.core.settings.defaults_of`: every field that has one, as a plain, untyped mapping) in Hydra's
    ConfigStore as ``<config_name>_defaults``, the node ``conf/<config_name>.yaml`` names first in its defaults
    list; returns that name (storing again replaces it)."""
    from hydra.core.config_store import ConfigStore
    from omegaconf import OmegaConf

    from icgo.core.settings import defaults_of

    node = {**defaults_of(config_cls), **(defaults_of(door_cls) if door_cls is not None else {})}
    ConfigStore.instance().store(name=f"{config_name}_defaults", node=OmegaConf.create(node))
    return f"{config_name}_defaults"


def register(config_name: str, config_cls, entry_keys=(), door_cls=None) -> str:
    """Store the schema of ``conf/<config_name>.yaml`` (:func:`schema_of` ``config_cls``, the study's config class,
    ``entry_keys`` and ``door_cls``) in Hydra's ConfigStore as ``<config_name>_schema``; returns that name (storing
    again replaces it)."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name=f"{config_name}_schema", node=schema_of(config_cls, entry_keys, door_cls))
    return f"{config_name}_schema"


def stored_nodes(config_name: str, conf_dir) -> None:
    """Import the door of ``conf_dir/<config_name>.yaml`` when that YAML names a ConfigStore node
    (``misma_defaults``, ``calibrate_schema``) that nothing has stored yet: the door stores it at import (a compose
    outside the door, e.g. the preflight's or a test's, finds it then)."""
    import importlib

    from hydra.core.config_store import ConfigStore
    from omegaconf import OmegaConf

    defaults = OmegaConf.load(conf_dir / f"{config_name}.yaml").get("defaults") or []
    nodes = {str(d) for d in defaults if str(d).startswith(f"{config_name}_")}
    if nodes and not all(f"{n}.yaml" in ConfigStore.instance().repo for n in nodes):
        importlib.import_module(f"experiments.{config_name}")
