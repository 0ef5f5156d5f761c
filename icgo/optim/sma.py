"""Slime mould algorithm (Li, Chen, Wang, Heidari, Mirjalili 2020), as in its original code.

Per iteration (t = 1..T in the paper's counting): weights
W = 1 +/- r log10((bF - f_i)/(bF - wF) + 1) ("+" for the better half by rank,
eq. 2.5), a = atanh(1 - t/T), b = 1 - t/T (eq. 2.4), p = tanh|f_i - DF|
(eq. 2.2, DF the best ever); with probability z a member restarts uniformly
(eq. 2.7), else per dimension X_b + vb (W X_A - X_B) if r < p, else vc X
(eq. 2.1), vb ~ U(-a, a), vc ~ U(-b, b). New positions are clipped and replace
the old ones (no greedy selection). One evaluation per member per iteration.

Deviation: the original code updates members in place inside the loop, so X_A
and X_B may already be moved; here all members use the positions of the start
of the iteration (synchronous update, one batched evaluation).
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

from icgo.optim.base import Algorithm, State, evaluate, finite_fitness, first_state, uniform_population, update_best


@partial(jax.tree_util.register_dataclass, data_fields=["z"], meta_fields=[])
@dataclasses.dataclass(frozen=True)
class SMAConfig:
    """SMA hyperparameters.

    Attributes:
        z: probability of a uniform random restart (paper: 0.03).
    """

    z: Any = 0.03


def _init(key, fitness, lb, ub, pop_size, config, aux) -> State:
    return first_state(fitness, lb, ub, uniform_population(key, lb, ub, pop_size), config, aux, ())


def _step(state: State, key, t, T, fitness) -> State:
    cfg: SMAConfig = state.ctx.config
    lb, ub = state.ctx.lb, state.ctx.ub
    X = state.pop
    P, D = X.shape
    f = finite_fitness(state.fit)
    ks = jax.random.split(key, 8)

    rank = jnp.argsort(jnp.argsort(f))
    bF, wF = jnp.min(f), jnp.max(f)
    S = bF - wF - jnp.finfo(X.dtype).eps  # <= 0, as (bF - f_i) is
    lg = jnp.log10((bF - f) / S + 1.0)[:, None]
    r = jax.random.uniform(ks[0], (P, D), X.dtype)
    W = jnp.where((rank < (P + 1) // 2)[:, None], 1 + r * lg, 1 - r * lg)  # eq. 2.5

    it = t + 1
    a = jnp.arctanh(1.0 - it / T)  # eq. 2.4
    b = 1.0 - it / T
    DF = jnp.where(jnp.isfinite(state.best_f), state.best_f, bF)
    p = jnp.tanh(jnp.abs(f - DF))[:, None]  # eq. 2.2
    vb = jax.random.uniform(ks[1], (P, D), X.dtype, -1.0, 1.0) * a
    vc = jax.random.uniform(ks[2], (P, D), X.dtype, -1.0, 1.0) * b
    A = jax.random.randint(ks[3], (P, D), 0, P)
    B = jax.random.randint(ks[4], (P, D), 0, P)
    XA = jnp.take_along_axis(X, A, axis=0)
    XB = jnp.take_along_axis(X, B, axis=0)
    move = jnp.where(jax.random.uniform(ks[5], (P, D), X.dtype) < p,
                     state.best_x + vb * (W * XA - XB), vc * X)  # eq. 2.1
    restart = jax.random.uniform(ks[6], (P, 1), X.dtype) < cfg.z  # eq. 2.7
    new = jnp.where(restart, uniform_population(ks[7], lb, ub, P), move)
    new = jnp.clip(new, lb, ub)
    nf = evaluate(fitness, new, state.ctx.aux)
    best_x, best_f = update_best(state.best_x, state.best_f, new, nf)
    return State(new, nf, best_x, best_f, state.n_evals + P, (), state.ctx)


def _evals(pop_size: int, config) -> tuple[int, int]:
    return pop_size, pop_size


SMA = Algorithm("sma", SMAConfig, _init, _step, _evals)
