"""A study's search grid (methods x cells) as one program sharded over the devices of its execution plan.

A *cell* is one (world, repeat) of a study: its PRNG key and its prepared training rows. Every method (a CGO
strategy side by side, or the one optimizer) runs on every cell; each (method, cell) pair is a member of
:func:`icgo.optim.sharded.run_members`, laid out method-major, so the result comes back as (S, C, ...) arrays
exactly as :func:`icgo.optim.base.run_batch` gives them for S configs x C keys.
"""

from __future__ import annotations

import jax
import numpy as np

from icgo.core.devices import available_cores
from icgo.core.execution import ExecutionPlan, execution_plan
from icgo.optim.base import RunResult, resolve_iterations, stack_configs
from icgo.optim.sharded import run_members


def plan(backend: str | None, members: int, devices: int | None, cores: int | None = None) -> ExecutionPlan:
    """:func:`icgo.core.execution.execution_plan` for this process's JAX runtime (``backend`` None: the default
    backend; its device count over every process of the job)."""
    if backend is None:
        backend = jax.default_backend()
    try:
        available = len(jax.devices(backend))
    except RuntimeError:  # a backend named for a plan on another machine (tests, --help): plan for one device
        available = 1
    cores = len(available_cores()) if cores is None else cores
    return execution_plan(backend, available, members, devices, jax.process_count(), cores)


def plan_devices(p: ExecutionPlan) -> list:
    """The first ``p.devices`` devices of the plan's backend (every process's, in JAX's global order)."""
    return jax.devices(p.backend)[: p.devices]


def run_grid(alg, fitness, bounds, keys, pop_size: int, n_iter: int | None, *, max_evals: int | None = None,
             config=None, configs=None, aux=None, devices=None, progress=None) -> RunResult:
    """Every method on every cell, as one sharded program.

    Args:
        alg, fitness, bounds, pop_size, n_iter, max_evals: as :func:`icgo.optim.base.run_batch`.
        keys: (C, 2) the cells' keys. aux: pytree whose leaves have leading axis C (the cells' data), or None.
        config: one config (then S = 1), or configs: a sequence of S configs with equal static fields
            (e.g. ``alg.axis_configs(config, strategies)``).
        devices: the JAX devices (:func:`plan_devices`; default every device). progress: see
            :func:`icgo.optim.sharded.run_members`.
    Returns:
        :class:`icgo.optim.base.RunResult` with leading axes (S, C), host-side numpy arrays.
    """
    keys = np.asarray(keys)
    C = keys.shape[0]
    S = 1 if configs is None else len(configs)
    method, cell = np.repeat(np.arange(S), C), np.tile(np.arange(C), S)
    per_member = None
    if configs is not None:
        if len({resolve_iterations(alg, pop_size, n_iter, max_evals, c) for c in configs}) != 1:
            raise ValueError("configs spend different evaluations per iteration: they cannot share one run length")
        stacked = stack_configs(alg, configs)
        per_member = jax.tree_util.tree_map(lambda x: np.asarray(x)[method], stacked)
    member_aux = jax.tree_util.tree_map(lambda x: np.asarray(x)[cell], aux)
    res = run_members(alg, fitness, bounds, keys[cell], pop_size, n_iter, max_evals=max_evals,
                      config=None if configs is not None else config, configs=per_member, aux=member_aux,
                      devices=devices, progress=progress)
    return RunResult(*(x.reshape((S, C) + x.shape[1:]) for x in res))
