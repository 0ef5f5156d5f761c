"""The simulated data sets by name: :data:`DATASETS` (what ``python -m icgo.datasets NAME`` writes and what a
study's ``dataset`` setting names).
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
