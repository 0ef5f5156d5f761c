"""A batch of independent optimizer runs as one program sharded over devices (``jax.sharding``).

Each *member* of the batch is one whole run (:func:`icgo.optim.base.run_one`) with its own key, its own data
(``aux`` sliced on the leading axis) and its own config (``configs`` sliced likewise, or one ``config`` shared by
all). The members are laid out along one mesh axis (:data:`MEMBER_AXIS`) over the devices given: a CPU's host
devices (:func:`icgo.core.devices.use_host_devices`), the GPUs of a node, or the devices of every process of a
``jax.distributed`` job. ``shard_map`` hands each device its block of members, which it runs vmapped, as
:func:`icgo.optim.base.run_batch` runs a whole batch; nothing crosses devices during the run. A batch that does
not divide into the devices is padded with copies of its first member, whose results are dropped.
:func:`run_grid` lays a study's search grid out as members: every method (a config) on every cell (a key and its
data), the result back as (methods, cells, ...) arrays.

Result of member m == the same member run alone, bitwise, whenever its fitness is (the CPU kernel
:func:`icgo.models.relm.train_fitness` runs batch members one after another, so its result does not depend on
which members share its device: tested on 1 and 2 host devices, ``tests/test_parallel.py``).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from icgo.optim.base import (Algorithm, RunResult, check_bounds, check_pop_size, chunk_length, init_one,
                             resolve_iterations, run_one, stack_configs, steps_one)

#: The mesh axis the members are laid out along.
MEMBER_AXIS = "members"


def balanced_devices(members: int, devices: int) -> int:
    """How many of ``devices`` a batch of ``members`` uses: the fewest that keep the most members on one device
    as small as with all of them (50 members on 16 devices: 4 each, so 13 devices, 2 padded slots)."""
    members, devices = max(1, int(members)), max(1, int(devices))
    per = -(-members // devices)
    return -(-members // per)


def member_mesh(devices) -> Mesh:
    """A one-axis mesh (:data:`MEMBER_AXIS`) over ``devices`` (a sequence of JAX devices)."""
    return Mesh(np.asarray(list(devices), dtype=object), (MEMBER_AXIS,))


def _global(host, mesh: Mesh, spec: P):
    """A global array of ``host`` (numpy) laid out by ``spec`` over ``mesh``; in a multi-process job each process
    supplies its own devices' slices (every process holds the same host array)."""
    host = np.asarray(host)
    return jax.make_array_from_callback(host.shape, NamedSharding(mesh, spec), lambda idx: host[idx])


def to_host(x) -> np.ndarray:
    """A (possibly multi-process) global array as one numpy array in every process."""
    if jax.process_count() > 1 and not x.is_fully_addressable:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(x)


def _padded(tree, members: int, slots: int, mesh: Mesh, spec: P):
    """Every leaf (leading axis ``members``) padded to ``slots`` with copies of member 0, as global arrays."""
    index = np.concatenate([np.arange(members), np.zeros(slots - members, int)])
    return jax.tree_util.tree_map(lambda x: _global(np.asarray(x)[index], mesh, spec), tree)


def _replicated(tree, mesh: Mesh):
    return jax.tree_util.tree_map(lambda x: _global(np.asarray(x), mesh, P()), tree)


#: Every (whole run, first state, chunk) triple :func:`_programs` has built, for :func:`compiled_programs`.
_BUILT: list = []


@functools.lru_cache(maxsize=None)
def _programs(alg: Algorithm, fitness, pop_size: int, n_iter: int, by_config: bool, mesh: Mesh, step: int):
    """(whole run, first state, ``step`` iterations from a start): jitted ``shard_map`` programs over ``mesh``'s
    members."""
    m, r = P(MEMBER_AXIS), P()
    cfg_axis = 0 if by_config else None
    kw = dict(mesh=mesh, out_specs=m, check_vma=False)

    def whole(keys, lb, ub, config, aux):
        one = functools.partial(run_one, alg, fitness, pop_size, n_iter)
        return jax.vmap(one, in_axes=(0, None, None, cfg_axis, 0))(keys, lb, ub, config, aux)

    def first(keys, lb, ub, config, aux):
        one = functools.partial(init_one, alg, fitness, pop_size, n_iter)
        return jax.vmap(one, in_axes=(0, None, None, cfg_axis, 0))(keys, lb, ub, config, aux)

    def chunk(state, start, keys):  # iterations start .. start + step - 1; keys (members, n_iter, 2)
        ts = start + jnp.arange(step)
        keys = jax.lax.dynamic_slice_in_dim(keys, start, step, axis=1)
        return jax.vmap(functools.partial(steps_one, alg, fitness, n_iter), in_axes=(0, None, 0))(state, ts, keys)

    spec = (m, r, r, m if by_config else r, m)
    built = (jax.jit(jax.shard_map(whole, in_specs=spec, **kw)), jax.jit(jax.shard_map(first, in_specs=spec, **kw)),
             jax.jit(jax.shard_map(chunk, in_specs=(m, r, m), **kw)))
    _BUILT.append(built)
    return built


def compiled_programs() -> int:
    """How many programs the sharded runners have compiled in this process (one per algorithm, fitness, mesh and
    input shapes; a new ridge lambda, key or data of the same shapes compiles nothing)."""
    return sum(f._cache_size() for built in _BUILT for f in built)


def run_members(alg: Algorithm, fitness, bounds, keys, pop_size: int, n_iter: int | None = None, *,
                max_evals: int | None = None, config=None, configs=None, aux: Any = None, devices=None,
                progress=None) -> RunResult:
    """Run M independent members of ``alg`` as one program sharded over ``devices``.

    Args:
        alg: the algorithm. fitness: batched fitness ``f(pop, aux_m) -> (P,)`` (static).
        bounds: ``(lb, ub)`` or (D, 2). keys: (M, 2) PRNG keys, one per member.
        pop_size, n_iter, max_evals: as :func:`icgo.optim.base.run`.
        config: one config shared by every member (defaults if None), or
        configs: a config pytree whose data leaves have leading axis M (member m's config: every leaf at m;
            e.g. ``tree_map(lambda x: x[strategy_of_member], stack_configs(alg, per_strategy))``).
        aux: pytree of per-member data, every leaf with leading axis M, or None.
        devices: the JAX devices to shard over (default: every device of the default backend, all processes').
        progress: None, or ``progress(done, total)`` called on the host after each chunk of iterations
            (:func:`icgo.optim.base.chunk_length`), the members' state staying on their devices in between.

    Returns:
        :class:`icgo.optim.base.RunResult` with leading axis M, as host-side numpy arrays in every process.
    """
    lb, ub = check_bounds(bounds)
    check_pop_size(pop_size)
    keys = np.asarray(jax.random.key_data(keys) if jnp.issubdtype(jnp.asarray(keys).dtype, jax.dtypes.prng_key)
                      else keys)
    M = keys.shape[0]
    by_config = configs is not None
    if by_config and config is not None:
        raise ValueError("give config (shared by every member) or configs (one per member), not both")
    config = configs if by_config else (alg.config_cls() if config is None else config)
    first_config = jax.tree_util.tree_map(lambda x: x[0], config) if by_config else config
    n_iter = resolve_iterations(alg, pop_size, n_iter, max_evals, first_config)
    for name, tree in (("aux", aux), ("configs", configs if by_config else None)):
        for leaf in jax.tree_util.tree_leaves(tree):
            if jnp.ndim(leaf) < 1 or jnp.shape(leaf)[0] != M:
                raise ValueError(f"{name} leaves need leading axis {M} (one slice per member), got {jnp.shape(leaf)}")
    devices = list(jax.devices() if devices is None else devices)
    mesh = member_mesh(devices)
    slots = -(-M // len(devices)) * len(devices)
    step = chunk_length(n_iter)
    whole, first, chunk = _programs(alg, fitness, int(pop_size), n_iter, by_config, mesh, step if progress else 0)
    m = P(MEMBER_AXIS)
    args = (_padded(keys, M, slots, mesh, m), *_replicated((lb, ub), mesh),
            _padded(config, M, slots, mesh, m) if by_config else _replicated(config, mesh),
            _padded(aux, M, slots, mesh, m))
    if progress is None:
        res = whole(*args)
    else:
        state, step_keys = first(*args)
        curves, evals = [], []
        for a in range(0, n_iter, step):
            state, (c, e) = chunk(state, _global(np.asarray(a, np.int32), mesh, P()), step_keys)
            curves.append(to_host(c)[:M])
            evals.append(to_host(e)[:M])
            progress(a + step, n_iter)
        return RunResult(to_host(state.best_x)[:M], to_host(state.best_f)[:M], np.concatenate(curves, -1),
                         np.concatenate(evals, -1), to_host(state.n_evals)[:M])
    return RunResult(*(to_host(x)[:M] for x in res))


def run_grid(alg, fitness, bounds, keys, pop_size: int, n_iter: int | None, *, max_evals: int | None = None,
             config=None, configs=None, aux=None, devices=None, progress=None) -> RunResult:
    """Every method on every cell, as one sharded program.

    Args:
        alg, fitness, bounds, pop_size, n_iter, max_evals: as :func:`icgo.optim.base.run_batch`.
        keys: (C, 2) the cells' keys. aux: pytree whose leaves have leading axis C (the cells' data), or None.
        config: one config (then S = 1), or configs: a sequence of S configs with equal static fields
            (e.g. ``alg.axis_configs(config, strategies)``).
        devices: the JAX devices (default every device). progress: see
            :func:`run_members`.
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
