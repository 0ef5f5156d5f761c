"""Real-coded genetic algorithm.

Tournament selection, SBX (Deb & Agrawal 1995) or BLX-alpha blend crossover,
per-gene Gaussian mutation with a step that shrinks over the run, and elitism.
Two survivor rules (``survivors`` option): ``plus`` (default, (mu + lambda):
the best P of parents and offspring survive, so no good point is ever lost)
and ``generational`` (offspring replace the parents; the ``n_elite`` best
parents replace the worst offspring). One fitness evaluation per offspring, P
per iteration.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

from icgo.optim.base import Algorithm, State, evaluate, first_state, uniform_population, update_best

CROSSOVERS = ("sbx", "blend")
SURVIVORS = ("plus", "generational")


@partial(jax.tree_util.register_dataclass,
         data_fields=["pc", "eta_c", "sbx_swap", "blend_alpha", "pm", "mut_sigma", "mut_decay"],
         meta_fields=["tournament", "n_elite", "crossover", "survivors"])
@dataclasses.dataclass(frozen=True)
class GAConfig:
    """GA hyperparameters (numeric fields are data; the static ones select code).

    Attributes:
        tournament: tournament size (static).
        n_elite: parents kept unchanged each generation (static).
        crossover: ``sbx`` or ``blend`` (static).
        survivors: ``plus`` (best P of parents + offspring) or
            ``generational`` (offspring + ``n_elite`` elite parents) (static).
        pc: crossover probability per pair.
        eta_c: SBX distribution index.
        sbx_swap: per-variable probability of exchanging the two SBX
            children's values (0.5 as in Deb's reference code; 0 = no exchange).
        blend_alpha: BLX-alpha extension.
        pm: per-gene mutation probability; None -> 1/D.
        mut_sigma: Gaussian mutation std as a fraction of (ub - lb).
        mut_decay: the std is scaled by (1 - mut_decay t/T).
    """

    tournament: int = 3
    n_elite: int = 2
    crossover: str = "sbx"
    survivors: str = "plus"
    pc: Any = 0.9
    eta_c: Any = 15.0
    sbx_swap: Any = 0.5
    blend_alpha: Any = 0.5
    pm: Any = None
    mut_sigma: Any = 0.1
    mut_decay: Any = 0.9

    def __post_init__(self):
        if not isinstance(self.crossover, str) or self.crossover not in CROSSOVERS:
            raise ValueError(f"unknown GA crossover {self.crossover!r}; choose one of {CROSSOVERS} (static option)")
        if not isinstance(self.survivors, str) or self.survivors not in SURVIVORS:
            raise ValueError(f"unknown GA survivors {self.survivors!r}; choose one of {SURVIVORS} (static option)")
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


def sbx(k_beta, k_swap, p1, p2, eta, swap_prob):
    """Simulated binary crossover (Deb & Agrawal 1995), as in Deb's reference code.

    Per variable: u ~ U(0,1), beta = (2u)^(1/(eta+1)) if u <= 1/2 else
    (1/(2(1-u)))^(1/(eta+1)); c1,2 = ((1 +- beta) p1 + (1 -+ beta) p2) / 2
    (so c1 + c2 = p1 + p2), then the two children's values are exchanged with
    probability ``swap_prob``. Deb's code exchanges with probability 1/2:
    without the exchange (eta 15 gives beta ~ 1) child k is a near-copy of
    parent k in every variable and nothing is recombined.

    Args:
        k_beta: PRNG key of the spread factors u.
        k_swap: PRNG key of the exchanges.
        p1, p2: parents, shape (n, D).
        eta: distribution index (larger: children closer to the parents).
        swap_prob: per-variable exchange probability.

    Returns:
        Children ``(c1, c2)``, each (n, D), unclipped.
    """
    u = jax.random.uniform(k_beta, p1.shape, p1.dtype)
    e = 1.0 / (eta + 1.0)
    beta = jnp.where(u <= 0.5, (2 * u) ** e, (1.0 / (2 * (1 - u) + 1e-300)) ** e)
    c1 = 0.5 * ((1 + beta) * p1 + (1 - beta) * p2)
    c2 = 0.5 * ((1 - beta) * p1 + (1 + beta) * p2)
    swap = jax.random.uniform(k_swap, p1.shape, p1.dtype) < swap_prob
    return jnp.where(swap, c2, c1), jnp.where(swap, c1, c2)


def _step(state: State, key, t, T, fitness) -> State:
    cfg: GAConfig = state.ctx.config
    lb, ub = state.ctx.lb, state.ctx.ub
    X, f = state.pop, state.fit
    P, D = X.shape
    n_pairs = (P + 1) // 2
    ks = jax.random.split(key, 8)
    p1 = X[_tournament(ks[0], f, n_pairs, cfg.tournament)]
    p2 = X[_tournament(ks[1], f, n_pairs, cfg.tournament)]

    if cfg.crossover == "sbx":
        c1, c2 = sbx(ks[2], ks[7], p1, p2, cfg.eta_c, cfg.sbx_swap)
    else:  # BLX-alpha
        g = jax.random.uniform(ks[3], (2,) + p1.shape, X.dtype, -cfg.blend_alpha, 1 + cfg.blend_alpha)
        c1, c2 = p1 + g[0] * (p2 - p1), p1 + g[1] * (p2 - p1)
    do = jax.random.uniform(ks[4], (n_pairs, 1), X.dtype) < cfg.pc
    c1, c2 = jnp.where(do, c1, p1), jnp.where(do, c2, p2)
    kids = jnp.concatenate([c1, c2])[:P]

    pm = jnp.where(cfg.pm < 0, 1.0 / D, cfg.pm)
    sigma = cfg.mut_sigma * (1 - cfg.mut_decay * t / T) * (ub - lb)
    hit = jax.random.uniform(ks[5], kids.shape, X.dtype) < pm
    kids = jnp.clip(jnp.where(hit, kids + sigma * jax.random.normal(ks[6], kids.shape, X.dtype), kids), lb, ub)
    kf = evaluate(fitness, kids, state.ctx.aux)

    E = cfg.n_elite
    if cfg.survivors == "plus":  # (mu + lambda): best P of the 2P pool (stable sort keeps parents first on ties)
        pool_X, pool_f = jnp.concatenate([X, kids]), jnp.concatenate([f, kf])
        best = jnp.argsort(pool_f, stable=True)[:P]
        new_X, new_f = pool_X[best], pool_f[best]
    elif E:  # generational with elitism
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


GA = Algorithm("ga", GAConfig, _init, _step, _evals)
