"""Every optimizer by name: one literal mapping (evosax's style; nothing registers itself at import)."""

from __future__ import annotations

from icgo.core.errors import SettingError
from icgo.optim.base import Algorithm
from icgo.optim.cgo import CGO
from icgo.optim.ga import GA
from icgo.optim.misma import MISMA
from icgo.optim.pso import PSO
from icgo.optim.sma import SMA

OPTIMIZERS: dict[str, Algorithm] = {
    "cgo": CGO,
    "pso": PSO,
    "ga": GA,
    "sma": SMA,
    "misma": MISMA,
}


def get(name: str) -> Algorithm:
    """The optimizer called ``name``; a one-line :class:`~icgo.core.errors.SettingError` naming the choices if unknown."""
    if not isinstance(name, str) or name not in OPTIMIZERS:
        raise SettingError(f"unknown optimizer {name!r}; choose one of {sorted(OPTIMIZERS)}")
    return OPTIMIZERS[name]
