"""Particle swarm optimization (inertia-weight PSO, Shi & Eberhart 1998).

v <- w v + c1 r1 (pbest - x) + c2 r2 (gbest - x), |v| <= vmax_frac (ub - lb),
x <- clip(x + v); w falls linearly from ``w_max`` to ``w_min`` over the run.
One fitness evaluation per particle per iteration.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from icgo.optim.base import Algorithm, State, evaluate, first_state, uniform_population, update_best


@partial(jax.tree_util.register_dataclass,
         data_fields=["w_max", "w_min", "c1", "c2", "vmax_frac"], meta_fields=[])
@dataclasses.dataclass(frozen=True)
class PSOConfig:
    """PSO hyperparameters (all data, vmappable).

    Attributes:
        w_max, w_min: inertia weight at the first and the last iteration.
        c1, c2: cognitive and social acceleration coefficients.
        vmax_frac: velocity clamp as a fraction of (ub - lb).
    """

    w_max: Any = 0.9
    w_min: Any = 0.4
    c1: Any = 2.0
    c2: Any = 2.0
    vmax_frac: Any = 0.2


class PSOExtra(NamedTuple):
    """PSO-specific state: velocities (P, D), personal bests (P, D) and (P,)."""

    vel: jax.Array
    pbest_x: jax.Array
    pbest_f: jax.Array


def _init(key, fitness, lb, ub, pop_size, config, aux) -> State:
    k_x, k_v = jax.random.split(key)
    x = uniform_population(k_x, lb, ub, pop_size)
    vmax = config.vmax_frac * (ub - lb)
    v = jax.random.uniform(k_v, x.shape, x.dtype, -1.0, 1.0) * vmax
    s = first_state(fitness, lb, ub, x, config, aux, PSOExtra(v, x, jnp.zeros(pop_size, x.dtype)))
    return s._replace(extra=PSOExtra(v, x, s.fit))


def _step(state: State, key, t, T, fitness) -> State:
    cfg: PSOConfig = state.ctx.config
    lb, ub = state.ctx.lb, state.ctx.ub
    x, (v, pbx, pbf) = state.pop, state.extra
    k1, k2 = jax.random.split(key)
    w = cfg.w_max - (cfg.w_max - cfg.w_min) * t / jnp.maximum(T - 1, 1)
    r1 = jax.random.uniform(k1, x.shape, x.dtype)
    r2 = jax.random.uniform(k2, x.shape, x.dtype)
    vmax = cfg.vmax_frac * (ub - lb)
    v = jnp.clip(w * v + cfg.c1 * r1 * (pbx - x) + cfg.c2 * r2 * (state.best_x - x), -vmax, vmax)
    x = jnp.clip(x + v, lb, ub)
    f = evaluate(fitness, x, state.ctx.aux)
    better = f < pbf
    pbx = jnp.where(better[:, None], x, pbx)
    pbf = jnp.where(better, f, pbf)
    best_x, best_f = update_best(state.best_x, state.best_f, x, f)
    return State(x, f, best_x, best_f, state.n_evals + x.shape[0], PSOExtra(v, pbx, pbf), state.ctx)


def _evals(pop_size: int, config) -> tuple[int, int]:
    return pop_size, pop_size


PSO = Algorithm("pso", PSOConfig, _init, _step, _evals)
