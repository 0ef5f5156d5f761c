"""Population optimizers in JAX behind one interface (see :mod:`icgo.optim.base`).

:data:`OPTIMIZERS` (:mod:`icgo.optim.registry`): ``cgo`` (with the ICGO 4th-seed mutations),
``pso``, ``ga``, ``sma``, ``misma`` (magnetometer calibration); CGO's 4th-seed strategies by name:
:data:`MUTATIONS` (:mod:`icgo.optim.mutation`). Run one with :func:`run`, a batch of
repeats (and of S configs side by side, e.g. ``alg.axis_configs(config, strategies)``) with
:func:`run_batch`: ``run_batch(get("cgo"), fitness, bounds, keys, pop_size, n_iter)``.
"""

from icgo.optim.base import (
                             Algorithm,
                             Bound,
                             Context,
                             RunResult,
                             State,
                             best_at_evals,
                             bind,
                             compiled_runners,
                             evaluate,
                             iterations_for_budget,
                             run,
                             run_batch,
)
from icgo.optim.mutation import MUTATIONS, STRATEGIES, strategy_index
from icgo.optim.registry import OPTIMIZERS, get

__all__ = ["MUTATIONS", "OPTIMIZERS", "Algorithm", "Bound", "Context", "RunResult", "State", "STRATEGIES",
           "best_at_evals", "bind", "compiled_runners", "evaluate", "get", "iterations_for_budget", "run", "run_batch",
           "strategy_index"]
