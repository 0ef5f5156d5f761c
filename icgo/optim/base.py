"""Shared interface of the population optimizers and the lax.scan runner.

Every optimizer in :mod:`icgo.optim` is an :class:`Algorithm` (a NamedTuple of
pure functions), listed under a short name (``cgo``, ``pso``, ``ga``, ``sma``,
``misma``) in the literal mapping :data:`icgo.optim.registry.OPTIMIZERS`. An
algorithm is a pair of pure functions over a :class:`State` NamedTuple::

    state = alg.init(key, fitness, bounds, pop_size, config, aux=None)
    state = alg.step(state, key, t, T, fitness)

or, with the fitness closed over::

    opt = bind(PSO, fitness, bounds, pop_size, config)
    state = opt.init(key, aux)            # aux: per-repeat data or None
    state = opt.step(state, key, t, T)    # t = 0 .. T-1 (int), T static int

and the runners::

    run(alg, fitness, bounds, key, pop_size, n_iter=None, *, max_evals=None, config=None, aux=None)
    run_batch(alg, fitness, bounds, keys, pop_size, n_iter=None, *, max_evals=None,
              config=None, configs=None, aux=None)       # axes (R,) or, with configs, (S, R)

Design choices (read before building on this):

* **Fitness** is a batched, jax-traceable function ``fitness(pop) -> (P,)`` or, when the run is given ``aux`` (any
  pytree, e.g. a per-repeat data split), ``fitness(pop, aux) -> (P,)``. The rule is simple: ``aux is None`` ->
  ``fitness(pop)``, otherwise ``fitness(pop, aux)``. Minimisation. A fitness may return ``+inf`` for bad candidates;
  NaN is mapped to ``+inf`` by :func:`evaluate`, so selection drops such candidates and nothing NaN escapes. The
  fitness is a *static* argument of the jitted runner: pass the same function object to reuse the compiled program (a
  fresh lambda recompiles).
* **Config** (hyperparameters) is one frozen dataclass per algorithm, registered as a JAX pytree: numeric fields are
  *data* (traced, vmappable), fields listed as ``meta`` are static and select code with a Python ``if`` (e.g. CGO
  ``variant``, ``selection``, ``bound_mode``; GA ``crossover``), so one compiled program serves every value of the
  data fields and a change of a static field compiles another. ``alg.config_cls()`` gives the defaults,
  ``alg.make_config(**params)`` builds one from a config file's parameters.
* **Side-by-side axis**: ``run_batch(configs=[c_1, ..., c_S])`` stacks S
  configs with equal static fields along a leading axis and vmaps over them,
  so S settings x R repeats is one jitted call. ``alg.axis`` names the data
  field a study runs side by side (CGO: ``"strategy"``, the 4th-seed mutation;
  others None); ``alg.axis_configs(config, values)`` gives the S configs and
  ``alg.labels(values)`` their method names, so a study needs no
  algorithm-specific code::

      configs = alg.axis_configs(config, values) if alg.axis else None
      labels = alg.labels(values)        # ["cgo-original", ...] or ["pso"]

* **Context**: bounds, config and aux travel inside the state (``state.ctx``), so ``step`` needs no other data and a
  whole repeat is described by ``(key, aux, config)``: exactly what ``run_batch`` vmaps.
* **Evaluation counting**: ``state.n_evals`` counts fitness evaluations (initial population included). CGO spends 4
  per seed per iteration, PSO, SMA and MISMA 1 per member, GA 1 per offspring. ``alg.evals(pop_size, config)`` returns
  ``(initial, per_iteration)``; a budget ``max_evals`` is converted to the static iteration count
  ``(max_evals - initial) // per_iteration``.
* **Keys**: the runner splits its key into an init key and one key per iteration; algorithms split the step key
  further and never reuse one.

Adding an optimizer: write ``init_fn(key, fitness, lb, ub, pop_size, config,
aux) -> State`` and ``step_fn(state, key, t, T, fitness) -> State`` using the
helpers here (:func:`evaluate`, :func:`uniform_population`,
:func:`update_best`), define ``NAME = Algorithm(...)`` in its module, and add one
line to :data:`icgo.optim.registry.OPTIMIZERS`. The registry-wide tests in
``tests/test_optim.py`` then run on it.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

Array = jax.Array
Fitness = Callable[..., Array]


class Context(NamedTuple):
    """Constant per-run data carried in the state.

    Attributes:
        lb: lower bounds, shape (D,).
        ub: upper bounds, shape (D,).
        config: the algorithm's config pytree (hyperparameters).
        aux: per-run data handed to the fitness (any pytree) or None.
    """

    lb: Array
    ub: Array
    config: Any
    aux: Any


class State(NamedTuple):
    """Optimizer state shared by every algorithm.

    Attributes:
        pop: population, shape (P, D).
        fit: fitness of ``pop``, shape (P,); +inf marks invalid candidates.
        best_x: best point found so far, shape (D,).
        best_f: its fitness, shape ().
        n_evals: fitness evaluations spent so far (int32, shape ()).
        extra: algorithm-specific pytree (PSO velocities, CGO chaos state, ...).
        ctx: :class:`Context` (bounds, config, aux).
    """

    pop: Array
    fit: Array
    best_x: Array
    best_f: Array
    n_evals: Array
    extra: Any
    ctx: Context


class RunResult(NamedTuple):
    """Result of :func:`run` (leading batch axes added by :func:`run_batch`).

    Attributes:
        best_x: best point, shape (..., D).
        best_f: best fitness, shape (...).
        curve: best-so-far fitness after each iteration, shape (..., n_iter).
        evals_curve: cumulative evaluations after each iteration, (..., n_iter).
        n_evals: total evaluations, shape (...).
    """

    best_x: Array
    best_f: Array
    curve: Array
    evals_curve: Array
    n_evals: Array


class Algorithm(NamedTuple):
    """A registered optimizer.

    Attributes:
        name: registry name.
        config_cls: config dataclass (pytree); ``config_cls()`` = defaults.
        init_fn: ``(key, fitness, lb, ub, pop_size, config, aux) -> State``.
        step_fn: ``(state, key, t, T, fitness) -> State``.
        evals: ``(pop_size, config) -> (initial, per_iteration)`` evaluations.
        axis: the config data field a study runs side by side (one method per
            value), or None.
        config_factory: ``(**params) -> config`` for config files, or None for
            ``config_cls``.
    """

    name: str
    config_cls: type
    init_fn: Callable
    step_fn: Callable
    evals: Callable[[int, Any], tuple[int, int]]
    axis: str | None = None
    config_factory: Callable | None = None

    def init(self, key, fitness, bounds, pop_size, config=None, aux=None) -> State:
        """Initial state (eq. 11: uniform population), validated inputs.

        Args:
            key: PRNG key.
            fitness: batched fitness, see module docstring.
            bounds: ``(lb, ub)`` pair of (D,) arrays, or a (D, 2) array.
            pop_size: population size P (>= 4).
            config: config pytree or None for the defaults.
            aux: per-run data for the fitness, or None.

        Returns:
            State with the evaluated initial population.
        """
        lb, ub = check_bounds(bounds)
        check_pop_size(pop_size)
        config = self.config_cls() if config is None else config
        return self.init_fn(key, fitness, lb, ub, int(pop_size), config, aux)

    def step(self, state: State, key, t, T, fitness) -> State:
        """One iteration ``t`` (0-based) of ``T``; pure, jit/vmap friendly."""
        return self.step_fn(state, key, t, T, fitness)

    def make_config(self, **params):
        """Config from keyword parameters (e.g. a config file's ``optimizer.params``)."""
        return (self.config_factory or self.config_cls)(**params)

    def axis_configs(self, config, values: Sequence) -> list:
        """One config per value of :attr:`axis`: ``dataclasses.replace(config, **{axis: v})``.

        Args:
            config: base config, or None for the defaults.
            values: non-empty sequence of axis values (e.g. CGO strategy names).

        Returns:
            List of S configs with equal static fields, for ``run_batch(configs=...)``.

        Raises:
            ValueError: the algorithm has no axis, or ``values`` is empty or a string.
        """
        if self.axis is None:
            raise ValueError(f"optimizer {self.name!r} has no side-by-side axis (no 'strategy' or similar option)")
        if isinstance(values, (str, bytes)) or len(values) < 1:
            raise ValueError(f"{self.name} {self.axis} values must be a non-empty sequence, got {values!r}")
        config = self.config_cls() if config is None else config
        return [dataclasses.replace(config, **{self.axis: v}) for v in values]

    def labels(self, values: Sequence = ()) -> list[str]:
        """Method names: ``[f"{name}-{v}" for v in values]`` with an axis, else ``[name]``."""
        return [f"{self.name}-{v}" for v in values] if self.axis else [self.name]


class Bound(NamedTuple):
    """An algorithm with fitness, bounds, population size and config closed over.

    Attributes:
        init: ``(key, aux=None) -> State``.
        step: ``(state, key, t, T) -> State``.
        algorithm: the underlying :class:`Algorithm`.
    """

    init: Callable
    step: Callable
    algorithm: Algorithm


def bind(alg: Algorithm, fitness: Fitness, bounds, pop_size: int, config=None) -> Bound:
    """Close an optimizer over its fitness, bounds, population size and config.

    Returns:
        :class:`Bound` with ``init(key, aux=None)`` and ``step(state, key, t, T)``.
    """
    lb, ub = check_bounds(bounds)
    check_pop_size(pop_size)
    config = alg.config_cls() if config is None else config

    def init(key, aux=None):
        return alg.init_fn(key, fitness, lb, ub, int(pop_size), config, aux)

    def step(state, key, t, T):
        return alg.step_fn(state, key, t, T, fitness)

    return Bound(init, step, alg)


# ----------------------------------------------------------------------------
# helpers for algorithm implementations
# ----------------------------------------------------------------------------


def evaluate(fitness: Fitness, pop: Array, aux: Any) -> Array:
    """Evaluate a population; NaN and -inf -> +inf; shape checked at trace time.

    -inf is not a valid fitness: a minimised RMSE or error that reaches -inf is a
    broken evaluation, not an optimum, so it is dropped like NaN.

    Args:
        fitness: ``fitness(pop)`` (aux None) or ``fitness(pop, aux)``.
        pop: candidates, shape (P, D).
        aux: per-run data or None.

    Returns:
        Fitness values, shape (P,), same float dtype as ``pop``.
    """
    f = fitness(pop) if aux is None else fitness(pop, aux)
    f = jnp.asarray(f)
    if f.shape != (pop.shape[0],):
        raise ValueError(
            f"fitness must return shape ({pop.shape[0]},) for a population of shape "
            f"{tuple(pop.shape)}, got {tuple(f.shape)}"
        )
    f = f.astype(pop.dtype)
    return jnp.where(jnp.isnan(f) | jnp.isneginf(f), jnp.inf, f)


def uniform_population(key, lb: Array, ub: Array, pop_size: int) -> Array:
    """Uniform random population in the box (ICGO paper eq. 11), shape (P, D)."""
    u = jax.random.uniform(key, (pop_size, lb.shape[0]), dtype=lb.dtype)
    return lb + u * (ub - lb)


def update_best(best_x: Array, best_f: Array, pop: Array, fit: Array):
    """Return the better of the incumbent and the best member of ``pop``."""
    i = jnp.argmin(fit)
    better = fit[i] < best_f
    return jnp.where(better, pop[i], best_x), jnp.where(better, fit[i], best_f)


def finite_fitness(fit: Array) -> Array:
    """Replace +inf by (largest finite value + 1) for rank/weight formulas."""
    finite = jnp.isfinite(fit)
    worst = jnp.max(jnp.where(finite, fit, -jnp.inf))
    worst = jnp.where(jnp.isfinite(worst), worst, 0.0)
    return jnp.where(finite, fit, worst + 1.0 + jnp.abs(worst))


def first_state(fitness, lb, ub, pop, config, aux, extra, n_evals=None) -> State:
    """Evaluate ``pop`` and build a :class:`State` (helper for ``init_fn``)."""
    fit = evaluate(fitness, pop, aux)
    i = jnp.argmin(fit)
    n = pop.shape[0] if n_evals is None else n_evals
    return State(pop, fit, pop[i], fit[i], jnp.asarray(n, jnp.int32), extra,
                 Context(lb, ub, config, aux))


# ----------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------


def check_bounds(bounds) -> tuple[Array, Array]:
    """Validate bounds; return float ``(lb, ub)`` arrays of shape (D,).

    Args:
        bounds: ``(lb, ub)`` with 1-D array-likes of equal length, or a (D, 2)
            array of ``[lower, upper]`` rows.

    Raises:
        ValueError: wrong shape, non-finite values or lb >= ub anywhere.
    """
    try:
        if isinstance(bounds, (tuple, list)) and len(bounds) == 2:
            lb, ub = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
        else:
            b = np.asarray(bounds, float)
            if b.ndim != 2 or b.shape[1] != 2:
                raise ValueError
            lb, ub = b[:, 0], b[:, 1]
    except (TypeError, ValueError):
        raise ValueError("bounds must be (lb, ub) with 1-D arrays of length D, or a (D, 2) array") from None
    if lb.ndim != 1 or lb.shape != ub.shape or lb.shape[0] < 1:
        raise ValueError(f"bounds: lb and ub must be 1-D of equal length >= 1, got shapes {lb.shape} and {ub.shape}")
    if not (np.all(np.isfinite(lb)) and np.all(np.isfinite(ub))):
        raise ValueError("bounds must be finite")
    bad = np.flatnonzero(lb >= ub)
    if bad.size:
        j = int(bad[0])
        raise ValueError(f"bounds: lower bound >= upper bound in dimension {j} ({lb[j]} >= {ub[j]})")
    return jnp.asarray(lb), jnp.asarray(ub)


#: The smallest population every algorithm accepts (CGO's seeds 2-3 need distinct members besides the best); the
#: studies' configs refuse a smaller one by this same bound.
MIN_POP_SIZE = 4


def check_pop_size(pop_size) -> None:
    """Raise ValueError unless ``pop_size`` is an int >= :data:`MIN_POP_SIZE`."""
    if isinstance(pop_size, bool) or not isinstance(pop_size, (int, np.integer)) or pop_size < MIN_POP_SIZE:
        raise ValueError(f"pop_size must be an integer >= {MIN_POP_SIZE}, got {pop_size!r}")


def iterations_for_budget(alg: Algorithm, pop_size: int, max_evals: int, config=None) -> int:
    """Static iteration count that spends at most ``max_evals`` evaluations.

    Raises:
        ValueError: if the budget does not cover the initial population plus
            one iteration.
    """
    config = alg.config_cls() if config is None else config
    first, per = alg.evals(int(pop_size), config)
    n = (int(max_evals) - first) // per
    if n < 1:
        raise ValueError(
            f"evaluation budget {max_evals} is smaller than one iteration of {alg.name} "
            f"with pop_size {pop_size} (needs {first} + {per})"
        )
    return n


def resolve_iterations(alg, pop_size, n_iter, max_evals, config) -> int:
    """The static iteration count of a run: ``n_iter`` checked, or the iterations ``max_evals`` buys."""
    if (n_iter is None) == (max_evals is None):
        raise ValueError("give exactly one stop criterion: n_iter or max_evals")
    if max_evals is not None:
        return iterations_for_budget(alg, pop_size, max_evals, config)
    if isinstance(n_iter, bool) or not isinstance(n_iter, (int, np.integer)) or n_iter < 1:
        raise ValueError(f"n_iter must be an integer >= 1, got {n_iter!r}")
    return int(n_iter)


def stack_configs(alg: Algorithm, configs: Sequence):
    """Stack S configs of ``alg`` along a new leading axis (for vmap).

    Args:
        alg: the algorithm.
        configs: non-empty sequence of ``alg.config_cls`` instances whose static
            fields (and leaf shapes) agree.

    Returns:
        One config pytree whose data leaves have shape (S, ...).

    Raises:
        ValueError: empty, wrong class, or static fields that differ.
    """
    if isinstance(configs, (str, bytes)) or not isinstance(configs, Sequence) or len(configs) < 1:
        raise ValueError("configs must be a non-empty sequence of configs")
    bad = [type(c).__name__ for c in configs if not isinstance(c, alg.config_cls)]
    if bad:
        raise ValueError(f"configs for {alg.name} must be {alg.config_cls.__name__} instances, got {bad}")
    trees = [jax.tree_util.tree_structure(c) for c in configs]
    odd = [i for i, t in enumerate(trees) if t != trees[0]]
    if odd:
        i = odd[0]
        raise ValueError(f"configs[{i}] differs from configs[0] in {_tree_differences(configs[0], configs[i])}; "
                         "one batched call needs equal static fields and leaf shapes")
    return jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *configs)


def _tree_differences(a, b) -> list[str]:
    """Names of the dataclass fields of ``a`` and ``b`` whose static value or pytree structure differ."""
    data = {str(getattr(path[0], "name", path[0])) for path, _ in jax.tree_util.tree_flatten_with_path(a)[0]}
    out = []
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name in data:
            differs = jax.tree_util.tree_structure(x) != jax.tree_util.tree_structure(y)
        else:
            try:
                differs = bool(x != y)
            except Exception:  # noqa: BLE001  (values without a truth value)
                differs = True
        if differs:
            out.append(f.name)
    return out


# ----------------------------------------------------------------------------
# runner
# ----------------------------------------------------------------------------


def init_one(alg: Algorithm, fitness, pop_size: int, n_iter: int, key, lb, ub, config, aux):
    """The first state and the ``n_iter`` step keys of one run."""
    k_init, k_run = jax.random.split(key)
    return alg.init_fn(k_init, fitness, lb, ub, pop_size, config, aux), jax.random.split(k_run, n_iter)


def steps_one(alg: Algorithm, fitness, n_iter: int, state, ts, keys):
    """Iterations ``ts`` (of ``n_iter``) of one run from ``state``: (state, (best_f, n_evals) per iteration)."""

    def body(s, xs):
        t, k = xs
        s = alg.step_fn(s, k, t, n_iter, fitness)
        return s, (s.best_f, s.n_evals)

    return lax.scan(body, state, (ts, keys))


def run_one(alg: Algorithm, fitness, pop_size: int, n_iter: int, key, lb, ub, config, aux) -> RunResult:
    """One whole run (:func:`init_one`, then every iteration by :func:`steps_one`): what the runners vmap."""
    state, keys = init_one(alg, fitness, pop_size, n_iter, key, lb, ub, config, aux)
    state, (curve, evals) = steps_one(alg, fitness, n_iter, state, jnp.arange(n_iter), keys)
    return RunResult(state.best_x, state.best_f, curve, evals, state.n_evals)


@partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _run_jit(alg, fitness, pop_size, n_iter, key, lb, ub, config, aux):
    return run_one(alg, fitness, pop_size, n_iter, key, lb, ub, config, aux)


@partial(jax.jit, static_argnums=(0, 1, 2, 3, 4))
def _batch_jit(alg, fitness, pop_size, n_iter, by_config, keys, lb, ub, config, aux):
    one = partial(run_one, alg, fitness, pop_size, n_iter)
    over_repeats = jax.vmap(one, in_axes=(0, None, None, None, 0))
    if not by_config:
        return over_repeats(keys, lb, ub, config, aux)
    return jax.vmap(over_repeats, in_axes=(None, None, None, 0, None))(keys, lb, ub, config, aux)


@partial(jax.jit, static_argnums=(0, 1, 2, 3, 4))
def _batch_init_jit(alg, fitness, pop_size, n_iter, by_config, keys, lb, ub, config, aux):
    one = jax.vmap(partial(init_one, alg, fitness, pop_size, n_iter), in_axes=(0, None, None, None, 0))
    return jax.vmap(one, in_axes=(None, None, None, 0, None))(keys, lb, ub, config, aux) if by_config else \
        one(keys, lb, ub, config, aux)


@partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _batch_steps_jit(alg, fitness, n_iter, by_config, state, ts, keys):
    one = jax.vmap(partial(steps_one, alg, fitness, n_iter), in_axes=(0, None, 0))
    return jax.vmap(one, in_axes=(0, None, 0))(state, ts, keys) if by_config else one(state, ts, keys)


def chunk_length(n_iter: int, chunks: int = 10) -> int:
    """Iterations per chunk of a run with progress: the largest divisor of ``n_iter`` up to ``n_iter / chunks``
    (one compiled chunk program, at most a few host round trips per run)."""
    return max(d for d in range(1, max(1, n_iter // chunks) + 1) if n_iter % d == 0)


def _batch_chunked(alg, fitness, pop_size, n_iter, by_config, keys, lb, ub, config, aux, progress) -> RunResult:
    """:func:`_batch_jit` in chunks of :func:`chunk_length` iterations, calling ``progress(done, n_iter)`` after
    each: no host callback inside the compiled programs, so they stay in the persistent compilation cache."""
    state, step_keys = _batch_init_jit(alg, fitness, pop_size, n_iter, by_config, keys, lb, ub, config, aux)
    step = chunk_length(n_iter)
    curves, evals = [], []
    for a in range(0, n_iter, step):
        state, (c, e) = _batch_steps_jit(alg, fitness, n_iter, by_config, state, jnp.arange(a, a + step),
                                         step_keys[..., a:a + step, :])
        jax.block_until_ready(c)
        curves.append(c)
        evals.append(e)
        progress(a + step, n_iter)
    return RunResult(state.best_x, state.best_f, jnp.concatenate(curves, -1), jnp.concatenate(evals, -1),
                     state.n_evals)


def run(alg: Algorithm, fitness: Fitness, bounds, key, pop_size: int, n_iter: int | None = None, *,
        max_evals: int | None = None, config=None, aux=None) -> RunResult:
    """Run one optimizer for ``n_iter`` iterations (or an evaluation budget).

    Args:
        alg: the :class:`Algorithm` (``icgo.optim.get("cgo")``, or its module constant ``CGO``).
        fitness: batched fitness (see module docstring); static for jit.
        bounds: ``(lb, ub)`` or (D, 2) array.
        key: PRNG key.
        pop_size: population size P (>= 4).
        n_iter: iterations; exactly one of ``n_iter`` / ``max_evals``.
        max_evals: evaluation budget, converted to a static iteration count.
        config: config pytree (defaults if None).
        aux: data passed to ``fitness(pop, aux)``, or None.

    Returns:
        :class:`RunResult` (curves of length n_iter).
    """
    lb, ub = check_bounds(bounds)
    check_pop_size(pop_size)
    config = alg.config_cls() if config is None else config
    n_iter = resolve_iterations(alg, pop_size, n_iter, max_evals, config)
    return _run_jit(alg, fitness, int(pop_size), n_iter, key, lb, ub, config, aux)


def run_batch(alg: Algorithm, fitness: Fitness, bounds, keys, pop_size: int, n_iter: int | None = None, *,
              max_evals: int | None = None, config=None, configs: Sequence | None = None,
              aux=None, progress=None) -> RunResult:
    """Run R repeats (of S configs) in one jitted, vmapped call.

    Repeat r of config s uses ``keys[r]``, ``aux`` sliced at index r on every
    leaf and ``configs[s]``, and equals ``run(..., key=keys[r],
    config=configs[s], aux=aux_r)`` exactly.

    Args:
        keys: PRNG keys, shape (R, 2) (or (R,) typed keys).
        config: one config (defaults if None); result axes (R,).
        configs: sequence of S configs with equal static fields, stacked and
            vmapped (e.g. ``alg.axis_configs(config, strategies)``); result
            axes (S, R). Give ``config`` or ``configs``, not both.
        aux: pytree whose leaves have leading axis R, or None.
        progress: None, or ``progress(done, total)`` called on the host after each chunk of iterations
            (:func:`chunk_length`); the run is then a few jitted calls of one chunk program each, with no
            callback inside, so the compilation cache keeps it; results equal the unchunked run.
        (other arguments as in :func:`run`)

    Returns:
        :class:`RunResult` with leading axes (R,) or (S, R).
    """
    lb, ub = check_bounds(bounds)
    check_pop_size(pop_size)
    if configs is not None:
        if config is not None:
            raise ValueError("give config (one setting) or configs (S settings side by side), not both")
        stacked = stack_configs(alg, configs)
        n_iters = {resolve_iterations(alg, pop_size, n_iter, max_evals, c) for c in configs}
        if len(n_iters) != 1:
            raise ValueError(f"configs spend different evaluations per iteration ({sorted(n_iters)} iterations)")
        n_iter, config = n_iters.pop(), stacked
    else:
        config = alg.config_cls() if config is None else config
        n_iter = resolve_iterations(alg, pop_size, n_iter, max_evals, config)
    keys = jnp.asarray(keys) if not isinstance(keys, jax.Array) else keys
    n_rep = keys.shape[0]
    if aux is not None:
        for leaf in jax.tree_util.tree_leaves(aux):
            if jnp.ndim(leaf) < 1 or jnp.shape(leaf)[0] != n_rep:
                raise ValueError(f"aux leaves need leading axis {n_rep} (one slice per key), got shape {jnp.shape(leaf)}")
    if progress is not None:
        return _batch_chunked(alg, fitness, int(pop_size), n_iter, configs is not None, keys, lb, ub, config, aux,
                              progress)
    return _batch_jit(alg, fitness, int(pop_size), n_iter, configs is not None, keys, lb, ub, config, aux)


def compiled_runners() -> int:
    """How many programs the batched runner has compiled in this process (one per static signature)."""
    return _batch_jit._cache_size()


def best_at_evals(result: RunResult, budgets) -> Array:
    """Best-so-far fitness at given evaluation counts (equal-budget comparison).

    Args:
        result: a :class:`RunResult` (any leading batch axes).
        budgets: evaluation counts, shape (K,).

    Returns:
        Shape (..., K): best fitness after the last iteration whose cumulative
        evaluation count is <= budget (+inf if even the first exceeds it).
    """
    budgets = jnp.asarray(budgets)
    ok = result.evals_curve[..., None, :] <= budgets[:, None]
    vals = jnp.where(ok, result.curve[..., None, :], jnp.inf)
    return jnp.min(vals, axis=-1)
