"""icgo: JAX framework for inclinometer / MWD azimuth error compensation.

Importing the package turns on JAX float64 (``jax_enable_x64``): the RELM ridge solve and the
least-squares fits need it (float32 ridge solves fail on ill-conditioned sigmoid features).
float32 paths are still available by passing float32 arrays explicitly. The switch is made
without importing JAX when JAX is not loaded yet (``JAX_ENABLE_X64``, read when JAX starts),
so the ground floor (:mod:`icgo.core`) stays light for the entry points' early checks.

It also drops one log record: JAX probes for a TPU on every start and logs "Unable to initialize
backend 'tpu'" at INFO, which Hydra's logging prints on every command of a machine without one.
Only that record is dropped (a failing CUDA backend is still reported).
"""

import logging
import os
import sys


class _NoTPUProbe(logging.Filter):
    """Drops JAX's "Unable to initialize backend 'tpu'" record (see the module docstring)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("Unable to initialize backend 'tpu'")


logging.getLogger("jax._src.xla_bridge").addFilter(_NoTPUProbe())

if "jax" in sys.modules:
    sys.modules["jax"].config.update("jax_enable_x64", True)
else:
    os.environ["JAX_ENABLE_X64"] = "1"

__version__ = "0.1.0"
