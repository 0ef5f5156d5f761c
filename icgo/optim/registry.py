"""Every optimizer by name: one literal mapping (evosax's style; nothing registers itself at import). A
researcher's own :class:`~icgo.optim.base.Algorithm` is added with :func:`register` (from their config's
``optimizer._target_``: docs/extending.md)."""

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


def register(alg: Algorithm) -> Algorithm:
    """Add ``alg`` to :data:`OPTIMIZERS` under ``alg.name``; the same object again is a no-op.

    Raises:
        ValueError: not an :class:`~icgo.optim.base.Algorithm`, or its name taken by another one.
    """
    if not isinstance(alg, Algorithm):
        raise ValueError(f"an optimizer must be an icgo.optim.Algorithm (name, config_cls, init_fn, step_fn, evals), "
                         f"got {type(alg).__name__}")
    if OPTIMIZERS.get(alg.name, alg) is not alg:
        raise ValueError(f"optimizer name {alg.name!r} is taken by another optimizer; choose another name")
    OPTIMIZERS[alg.name] = alg
    return alg
