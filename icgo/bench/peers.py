"""A JAX peer on the study's fitness: evosax's PSO and differential evolution beside icgo's PSO
(:func:`peer_comparison`), used by :mod:`icgo.bench.cpu`.

Every search runs on the study's fast RELM fitness (:func:`icgo.models.relm.train_fitness`,
Table 3's training rows, one repeat's rows per search), with the same population,
the same number of fitness evaluations (``pop_size * (iterations + 1)``: one
evaluated initial population, then one per iteration), jitted as one
``lax.scan`` over iterations and ``vmap`` over the repeats, compiled before the
clock starts. evosax runs with its own default hyperparameters (each library's
algorithm as its authors set it: PSO inertia 0.75, cognitive 1.5, social 2.0;
DE rand/1/bin with F 0.8, CR 0.9 and elitism); evosax does not keep a search in
its box, so its candidates are clipped to the box before they are evaluated,
as icgo's PSO clips its particles. Wall time is the best of ``reps`` runs.
"""

from __future__ import annotations

import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from icgo.models import relm
from icgo.optim import run_batch
from icgo.optim.registry import get


def _clock(f, *args, reps: int) -> tuple[float, object]:
    out = jax.block_until_ready(f(*args))
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        out = jax.block_until_ready(f(*args))
        best = min(best, time.perf_counter() - t)
    return best, out


def _evosax_search(algorithm_cls, fitness, lb, ub, pop_size: int, iterations: int):
    """``(keys (R,2), rows (TrainRows, leading axis R)) -> best fitness (R,)`` for an evosax algorithm."""
    D = lb.shape[0]
    algo = algorithm_cls(population_size=pop_size, solution=jnp.zeros(D))
    params = algo.default_params

    def one(key, rows):
        k0, k1, k_scan = jax.random.split(key, 3)
        x0 = jax.random.uniform(k0, (pop_size, D), lb.dtype, lb, ub)
        f0 = fitness(x0, rows)
        state = algo.init(k1, x0, f0, params)

        def step(state, key):
            k_ask, k_tell = jax.random.split(key)
            x, state = algo.ask(k_ask, state, params)
            x = jnp.clip(x, lb, ub)
            f = fitness(x, rows)
            state, _ = algo.tell(k_tell, x, f, state, params)
            return state, None

        state, _ = jax.lax.scan(step, state, jax.random.split(k_scan, iterations))
        return jnp.minimum(state.best_fitness, jnp.min(f0))

    return jax.jit(jax.vmap(one))


def peer_comparison(rows: relm.TrainRows, lam: float, hidden: int, pop_size: int = 30, iterations: int = 100,
                    reps: int = 3) -> list[dict]:
    """icgo PSO vs evosax PSO and DE on the same fitness at equal evaluations.

    Args:
        rows: the repeats' training rows (leading axis R: one search per repeat).
        lam, hidden: the RELM's ridge lambda and hidden width (the fitness).
        pop_size, iterations: the search budget (``pop_size * (iterations + 1)`` evaluations each).
        reps: timed runs (best kept) after one compiling run.
    Returns:
        One dict per search: name, evals, compile_s, wall_s, best_f_mean, best_f_median (training RMSE, deg).
    """
    from evosax.algorithms import PSO as EvoPSO
    from evosax.algorithms import DifferentialEvolution as EvoDE

    fitness = relm.make_train_fitness(lam, hidden)
    D = relm.n_params(hidden)
    lb, ub = -jnp.ones(D), jnp.ones(D)
    R = int(rows.T.shape[0])
    keys = jax.random.split(jax.random.PRNGKey(0), R)

    @partial(jax.jit)
    def icgo_pso(keys, rows):
        return run_batch(get("pso"), fitness, (lb, ub), keys, pop_size, iterations, aux=rows).best_f

    searches = {"icgo PSO": icgo_pso,
                "evosax PSO": _evosax_search(EvoPSO, fitness, lb, ub, pop_size, iterations),
                "evosax DE": _evosax_search(EvoDE, fitness, lb, ub, pop_size, iterations)}
    out = []
    for name, f in searches.items():
        t = time.perf_counter()
        compiled = f.lower(keys, rows).compile()
        compile_s = time.perf_counter() - t
        wall, best = _clock(compiled, keys, rows, reps=reps)
        best = np.asarray(best)
        out.append({"name": name, "evals": pop_size * (iterations + 1), "compile_s": compile_s, "wall_s": wall,
                    "best_f_mean": float(best.mean()), "best_f_median": float(np.median(best))})
    return out
