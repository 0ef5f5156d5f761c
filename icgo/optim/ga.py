"""Real-coded genetic algorithm.

Tournament selection, SBX (Deb & Agrawal 1995) or BLX-alpha blend crossover,
per-gene Gaussian mutation with a step that shrinks over the run, and elitism
(the ``n_elite`` best parents replace the worst offspring). One fitness
evaluation per offspring, P per iteration.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

from icgo.optim.base import Algorithm, State, evaluate, first_state, register, uniform_population, update_best

CROSSOVERS = ("sbx", "blend")


@partial(jax.tree_util.register_dataclass,
         data_fields=["crossover", "pc", "eta_c", "blend_alpha", "pm", "mut_sigma", "mut_decay"],
         meta_fields=["tournament", "n_elite"])
@dataclasses.dataclass(frozen=True)
class GAConfig:
    """GA hyperparameters.

    Attributes:
        tournament: tournament size (static).
        n_elite: parents kept unchanged each generation (static).
        crossover: ``sbx`` (0) or ``blend`` (1).
        pc: crossover probability per pair.
        eta_c: SBX distribution index.
        blend_alpha: BLX-alpha extension.
        pm: per-gene mutation probability; None -> 1/D.
        mut_sigma: Gaussian mutation std as a fraction of (ub - lb).
        mut_decay: the std is scaled by (1 - mut_decay t/T).
    """

    tournament: int = 3
    n_elite: int = 2
    crossover: Any = 0
    pc: Any = 0.9
    eta_c: Any = 15.0
    blend_alpha: Any = 0.5
    pm: Any = None
    mut_sigma: Any = 0.1
    mut_decay: Any = 0.9

    def __post_init__(self):
        if isinstance(self.crossover, str):
            if self.crossover not in CROSSOVERS:
                raise ValueError(f"unknown GA crossover {self.crossover!r}; choose one of {CROSSOVERS}")
            object.__setattr__(self, "crossover", CROSSOVERS.index(self.crossover))
        if self.pm is None:
            object.__setattr__(self, "pm", -1.0)
        if not isinstance(self.tournament, int) or self.tournament < 1:
            raise ValueError(f"GA tournament must be an integer >= 1, got {self.tournament!r}")
        if not isinstance(self.n_elite, int) or self.n_elite < 0:
            raise ValueError(f"GA n_elite must be an integer >= 0, got {self.n_elite!r}")


def _init(key, fitness, lb, ub, pop_size, config, aux) -> State:
    if config.n_elite >= pop_size:
        raise ValueError(f"GA n_elite ({config.n_elite}) must be smaller than pop_size ({pop_size})")
    return first_state(fitness, lb, ub, uniform_population(key, lb, ub, pop_size), config, aux, ())


def _tournament(key, fit, n, k):
    """Indices of n tournament winners (size k, minimisation)."""
    idx = jax.random.randint(key, (n, k), 0, fit.shape[0])
    return jnp.take_along_axis(idx, jnp.argmin(fit[idx], axis=1)[:, None], axis=1)[:, 0]


def _step(state: State, key, t, T, fitness) -> State:
    cfg: GAConfig = state.ctx.config
    lb, ub = state.ctx.lb, state.ctx.ub
    X, f = state.pop, state.fit
    P, D = X.shape
    n_pairs = (P + 1) // 2
    ks = jax.random.split(key, 8)
    p1 = X[_tournament(ks[0], f, n_pairs, cfg.tournament)]
    p2 = X[_tournament(ks[1], f, n_pairs, cfg.tournament)]

    u = jax.random.uniform(ks[2], p1.shape, X.dtype)
    e = 1.0 / (cfg.eta_c + 1.0)
    beta = jnp.where(u <= 0.5, (2 * u) ** e, (1.0 / (2 * (1 - u) + 1e-300)) ** e)
    sbx1 = 0.5 * ((1 + beta) * p1 + (1 - beta) * p2)
    sbx2 = 0.5 * ((1 - beta) * p1 + (1 + beta) * p2)
    g = jax.random.uniform(ks[3], (2,) + p1.shape, X.dtype, -cfg.blend_alpha, 1 + cfg.blend_alpha)
    blx1, blx2 = p1 + g[0] * (p2 - p1), p1 + g[1] * (p2 - p1)
    blend = cfg.crossover == 1
    c1, c2 = jnp.where(blend, blx1, sbx1), jnp.where(blend, blx2, sbx2)
    do = jax.random.uniform(ks[4], (n_pairs, 1), X.dtype) < cfg.pc
    c1, c2 = jnp.where(do, c1, p1), jnp.where(do, c2, p2)
    kids = jnp.concatenate([c1, c2])[:P]

    pm = jnp.where(cfg.pm < 0, 1.0 / D, cfg.pm)
    sigma = cfg.mut_sigma * (1 - cfg.mut_decay * t / T) * (ub - lb)
    hit = jax.random.uniform(ks[5], kids.shape, X.dtype) < pm
    kids = jnp.clip(jnp.where(hit, kids + sigma * jax.random.normal(ks[6], kids.shape, X.dtype), kids), lb, ub)
    kf = evaluate(fitness, kids, state.ctx.aux)

    E = cfg.n_elite
    if E:
        elite = jnp.argsort(f)[:E]
        keep = jnp.argsort(kf)[:P - E]
        new_X = jnp.concatenate([X[elite], kids[keep]])
        new_f = jnp.concatenate([f[elite], kf[keep]])
    else:
        new_X, new_f = kids, kf
    best_x, best_f = update_best(state.best_x, state.best_f, kids, kf)
    return State(new_X, new_f, best_x, best_f, state.n_evals + P, (), state.ctx)


def _evals(pop_size: int, config) -> tuple[int, int]:
    return pop_size, pop_size


GA = register(Algorithm("ga", GAConfig, _init, _step, _evals))
