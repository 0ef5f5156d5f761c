"""Studies behind one protocol and one registry (the optimizer pattern one level up).

A study is a :class:`Study`: a frozen config dataclass that validates itself
(``__post_init__``, one-line ``ValueError`` naming the field), a pure-ish
``run(data, config, key) -> result`` and the records the result writes::

    study = get_study("icgo_relm")
    cfg = study.config_cls(n_repeats=3)
    result = study.run(data, cfg, jax.random.PRNGKey(0))
    tables = study.records(result)      # {"metrics": DataFrame, ...}
    result.models                        # {"relm_compensation": FittedModel, ...}

``data`` is whatever the study consumes (a data-contract ``DataFrame`` + metadata
for ICGO-RELM; a data set or devices for MISMA); ``key`` is a JAX PRNG key from
which every random draw of the run is split, so ``run`` is deterministic given
``(data, config, key)``. Every result carries its fitted models (dict
name -> :class:`icgo.models.FittedModel`) and its records (dict name ->
``DataFrame``, column names from :mod:`icgo.records`).

Hydra never appears here: ``experiments/`` composes a config, builds the
dataclass (``config_from_mapping``) and calls ``run``.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any, Callable, NamedTuple


class SettingError(ValueError):
    """A bad value of one config field: ``str(err)`` is ``"<field> <problem>"``, one line.

    Attributes:
        field: the dataclass field name (entry points rename it to their own key,
            e.g. ``n_repeats`` -> ``split.n_repeats``).
        problem: the rest of the message (``"must be an integer >= 1, got 0"``).
    """

    def __init__(self, field: str, problem: str):
        super().__init__(f"{field} {problem}")
        self.field, self.problem = field, problem


def need(cond: bool, field: str, problem: str) -> None:
    """Raise :class:`SettingError` ``(field, problem)`` unless ``cond``."""
    if not cond:
        raise SettingError(field, problem)


def is_int(x) -> bool:
    """True for a Python/numpy integer that is not a bool."""
    import numpy as np

    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def is_real(x) -> bool:
    """True for a finite real number that is not a bool."""
    import math

    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


class Study(NamedTuple):
    """A registered study.

    Attributes:
        name: registry name.
        config_cls: frozen dataclass of the settings; ``config_cls()`` = the defaults
            (the one source every Hydra config is checked against).
        run: ``(data, config, key) -> result`` with ``result.models`` and ``result.records``.
        description: one line.
        example: ``() -> (data, config)``: a tiny but real instance of the study (seconds),
            used by the registry-wide tests and as a usage example.
        fits_models: False for a study that fits nothing to apply (the optimizer benchmark);
            every other study's result carries at least one fitted model.
    """

    name: str
    config_cls: type
    run: Callable[[Any, Any, Any], Any]
    description: str = ""
    example: Callable[[], tuple] | None = None
    fits_models: bool = True

    def records(self, result) -> dict:
        """Named tables the study writes (``result.records``)."""
        return dict(result.records)


STUDIES: dict[str, Study] = {}

#: Modules that register a study at import.
_STUDY_MODULES = ("icgo.studies.icgo_relm", "icgo.studies.misma", "icgo.studies.gyro",
                  "icgo.studies.optimizers", "icgo.studies.discrepancy", "icgo.studies.generalisation",
                  "icgo.studies.calibration")


def register_study(study: Study) -> Study:
    """Add ``study`` to :data:`STUDIES` (called by each study module at import)."""
    STUDIES[study.name] = study
    return study


def get_study(name: str) -> Study:
    """Look up a study by name; ValueError naming the choices if unknown."""
    for m in _STUDY_MODULES:
        importlib.import_module(m)
    if name not in STUDIES:
        raise ValueError(f"unknown study {name!r}; choose one of {sorted(STUDIES)}")
    return STUDIES[name]


def all_studies() -> dict[str, Study]:
    """Every registered study (imports the study modules)."""
    for m in _STUDY_MODULES:
        importlib.import_module(m)
    return dict(STUDIES)


def config_from_mapping(cls, values: dict, where: str = "config"):
    """Build a config dataclass from a plain mapping, refusing unknown keys in one line.

    Args:
        cls: the config dataclass.
        values: field name -> value (nested dataclass fields given as mappings are built recursively).
        where: the name of the mapping in error messages (e.g. ``"conf/misma.yaml"``).
    Raises:
        ValueError: an unknown key, or the dataclass's own validation.
    """
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ValueError(f"{where}: unknown setting(s) {unknown}; known: {sorted(names)}")
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
