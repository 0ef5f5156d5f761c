"""Population optimizers in JAX behind one interface (see :mod:`icgo.optim.base`).

Registry :data:`OPTIMIZERS`: ``cgo`` (with the ICGO 4th-seed mutations),
``pso``, ``ga``, ``sma``, ``misma`` (magnetometer calibration). Run one with :func:`run`, a batch of repeats (and
of S configs side by side, e.g. ``alg.axis_configs(config, strategies)``) with :func:`run_batch`.
"""

from icgo.optim.base import (OPTIMIZERS, Algorithm, Bound, Context, RunResult, State, best_at_evals, bind, evaluate,
                             get, iterations_for_budget, register, run, run_batch)
from icgo.optim.mutation import STRATEGIES, strategy_index
from icgo.optim import cgo, ga, misma, pso, sma  # noqa: F401  (register themselves)

__all__ = ["OPTIMIZERS", "Algorithm", "Bound", "Context", "RunResult", "State", "STRATEGIES", "best_at_evals", "bind",
           "evaluate", "get", "iterations_for_budget", "register", "run", "run_batch", "strategy_index"]
