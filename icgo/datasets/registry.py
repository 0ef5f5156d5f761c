"""The simulated data sets by name: :data:`DATASETS`, the one registry of data sets (what ``python -m icgo.datasets
NAME`` writes and what a study's ``dataset`` setting names). A researcher's own simulator is added with
:func:`register` (from their config's ``dataset._target_``: docs/extending.md).
"""

from __future__ import annotations

from icgo.datasets.casing_stations import lab_casing, well_conditions
from icgo.datasets.drill_string import rotating_drill
from icgo.datasets.gyro_turntable import turntable, turntable_between, turntable_random

#: name -> simulator ``fn(seed, **kwargs) -> Dataset``.
DATASETS = {
    "lab_casing": lab_casing,
    "well_conditions": well_conditions,
    "turntable": turntable,
    "turntable_random": turntable_random,
    "turntable_between": turntable_between,
    "rotating_drill": rotating_drill,
}


def register(name: str, fn) -> None:
    """Add the simulator ``fn(seed, **kwargs) -> icgo.datasets.dataset.Dataset`` under ``name``; the same function
    again is a no-op.

    Raises:
        ValueError: ``fn`` not callable, or ``name`` taken by another simulator.
    """
    if not callable(fn):
        raise ValueError(f"data set {name!r}: the simulator must be a function fn(seed, **kwargs) -> Dataset")
    if DATASETS.get(name, fn) is not fn:
        raise ValueError(f"data set name {name!r} is taken by another simulator; choose another name")
    DATASETS[name] = fn
