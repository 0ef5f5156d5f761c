"""Optimizer interface and runner: registry-wide contract tests, then CGO specifics.

Every algorithm in :data:`icgo.optim.OPTIMIZERS` (misma included) gets the
contract tests (init/step/run shapes, dtypes and evaluation accounting), the
batch-equals-single-runs and compile-once checks, the NaN test and a shifted,
rotated ellipsoid whose optimum it must reach. All of them share ONE batched
program per algorithm (:func:`batch`) and one single-run program
(:func:`single`), so the whole registry costs two compilations per algorithm.
Traces are counted with a Python counter inside the fitness: JAX calls a
fitness only while tracing, so the counter moves exactly when a program is
(re)traced.
"""

import ast
import dataclasses
import functools
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.optim import OPTIMIZERS, STRATEGIES, best_at_evals, bind, evaluate, get, run, run_batch
from icgo.optim.cgo import CGO, VARIANT_FIELDS, VARIANT_SETTINGS, CGOConfig
from icgo.optim.ga import GAConfig

D, P, T = 3, 12, 200
BOUNDS = (-100.0 * np.ones(D), 100.0 * np.ones(D))
NAMES = sorted(OPTIMIZERS)
SHIFT = jnp.array([12.0, -30.0, 47.0])
_Q = jnp.asarray(np.linalg.qr(np.random.default_rng(0).standard_normal((D, D)))[0])  # a random rotation
_W = jnp.array([1.0, 3.0, 10.0])
KEYS = jax.random.split(jax.random.key(3), 5)
#: per repeat: optimum o_r (5, D) and NaN mode: 0 none (rows 0-2), 1 NaN where x_0 > o_0, 2 NaN everywhere
AUX = (jnp.asarray(np.random.default_rng(1).uniform(-80.0, 80.0, (5, D))), jnp.array([0, 0, 0, 1, 2]))
TRACES = {"target": 0}


def sphere(pop):
    return jnp.sum((pop - SHIFT) ** 2, axis=1)


def target(pop, aux):
    """Shifted, rotated ellipsoid sum_i w_i z_i^2, z = Q (x - o), w = (1, 3, 10): minimum 0 at x = o.

    ``aux = (o (D,), mode)``; mode 1 returns NaN where x_0 > o_0, mode 2 NaN everywhere. Counts its traces.
    """
    TRACES["target"] += 1
    o, mode = aux
    z = jnp.sum((pop - o)[:, None, :] * _Q, axis=-1)  # Q (x - o) per row, without a dot (same rounding batched)
    f = jnp.sum(_W * z * z, axis=1)
    f = jnp.where((mode == 1) & (pop[:, 0] > o[0]), jnp.nan, f)
    return jnp.where(mode == 2, jnp.nan, f)


def row(r):
    """aux of repeat r."""
    return jax.tree_util.tree_map(lambda a: a[r], AUX)


@functools.cache
def single(name):
    """Single runs of repeats 0 and 1 (KEYS[r], aux row r): one compiled program per algorithm."""
    return [run(get(name), target, BOUNDS, KEYS[r], P, T, aux=row(r)) for r in range(2)]


@functools.cache
def batch(name):
    """The 5 repeats in one run_batch call, and how many times it traced the fitness."""
    before = TRACES["target"]
    r = run_batch(get(name), target, BOUNDS, KEYS, P, T, aux=AUX)
    jax.block_until_ready(r.best_f)
    return r, TRACES["target"] - before


# --------------------------------------------------------------- registry-wide


def test_registry_lists_every_optimizer_with_a_usable_config():
    assert {"cgo", "pso", "ga", "sma", "misma"} <= set(NAMES)
    assert STRATEGIES == ("original", "chaos", "gaussian", "wavelet", "three_stage")
    for name in NAMES:
        alg = get(name)
        cfg = alg.make_config()
        assert isinstance(cfg, alg.config_cls) and cfg == alg.config_cls(), name
        assert alg.axis is None or alg.axis in {f.name for f in dataclasses.fields(cfg)}, name
        first, per = alg.evals(P, cfg)
        assert first == P and per in (P, 4 * P), name


@pytest.mark.parametrize("name", NAMES)
def test_init_step_contract(name):
    """Init (run eagerly): values, shapes, dtypes, evaluation count. Step: the same pytree structure,
    shapes and dtypes (a lax.scan carry), from jax.eval_shape (no compile)."""
    alg = get(name)
    first, _ = alg.evals(P, alg.config_cls())
    s0 = alg.init(jax.random.key(1), target, BOUNDS, P, aux=row(0))
    assert s0.pop.shape == (P, D) and s0.fit.shape == (P,) and s0.best_x.shape == (D,) and s0.best_f.shape == ()
    assert s0.pop.dtype == s0.fit.dtype == s0.best_x.dtype == s0.best_f.dtype == jnp.float64
    assert s0.n_evals.dtype == jnp.int32 and int(s0.n_evals) == first
    np.testing.assert_allclose(np.asarray(s0.fit), np.asarray(target(s0.pop, row(0))), rtol=1e-12)
    assert float(s0.best_f) == float(np.min(np.asarray(s0.fit)))
    assert np.all(np.abs(np.asarray(s0.pop)) <= 100.0)
    s1 = jax.eval_shape(lambda s, k: alg.step(s, k, 0, T, target), s0, jax.random.key(2))
    assert jax.tree_util.tree_structure(s1) == jax.tree_util.tree_structure(s0)
    for a, b in zip(jax.tree_util.tree_leaves(s0._replace(ctx=None)), jax.tree_util.tree_leaves(s1._replace(ctx=None))):
        assert a.shape == b.shape and a.dtype == b.dtype


@pytest.mark.parametrize("name", NAMES)
def test_run_contract(name):
    """Curves, evaluation accounting (= alg.evals), monotone best-so-far, best_f = fitness(best_x)."""
    alg = OPTIMIZERS[name]
    first, per = alg.evals(P, alg.config_cls())
    for r, res in enumerate(single(name)):
        assert res.curve.shape == (T,) and res.evals_curve.shape == (T,) and res.best_x.shape == (D,)
        assert res.best_f.dtype == jnp.float64 and res.n_evals.dtype == jnp.int32
        np.testing.assert_array_equal(np.asarray(res.evals_curve), first + per * np.arange(1, T + 1))
        assert int(res.n_evals) == first + per * T
        assert np.all(np.diff(np.asarray(res.curve)) <= 0)  # best-so-far never rises
        assert float(res.best_f) == float(res.curve[-1])
        np.testing.assert_allclose(float(target(res.best_x[None], row(r))[0]), float(res.best_f), rtol=1e-12,
                                   atol=1e-300)
        assert np.all(np.abs(np.asarray(res.best_x)) <= 100.0)
        init = alg.init(jax.random.split(KEYS[r])[0], target, BOUNDS, P, aux=row(r))
        assert float(res.best_f) < float(init.best_f)  # better than the random initial population


@pytest.mark.parametrize("name", NAMES)
def test_batch_compiles_once_and_equals_single_runs(name):
    """run_batch over 5 repeats traced once; new keys and data reuse the program; rows equal single runs.

    Equal to rounding: XLA may fuse the vmapped program differently, and the rounding differences travel
    through the run (bitwise equal here for cgo, ga, pso and sma; misma differs by <= 1e-14 absolute)."""
    r, traced = batch(name)
    assert traced >= 1
    before = TRACES["target"]
    new_aux = (AUX[0][::-1] * 0.9, AUX[1])
    r2 = run_batch(get(name), target, BOUNDS, jax.random.split(jax.random.key(99), 5), P, T, aux=new_aux)
    jax.block_until_ready(r2.best_f)
    assert TRACES["target"] == before  # no retrace for new keys and new aux
    assert not np.array_equal(np.asarray(r.curve[:3]), np.asarray(r2.curve[:3]))
    assert r.best_f.shape == (5,) and r.curve.shape == (5, T) and r.best_x.shape == (5, D)
    for k in range(2):
        alone = single(name)[k]
        np.testing.assert_allclose(np.asarray(r.curve[k]), np.asarray(alone.curve), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(np.asarray(r.best_x[k]), np.asarray(alone.best_x), rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(np.asarray(r.evals_curve[k]), np.asarray(alone.evals_curve))


@pytest.mark.parametrize("name", NAMES)
def test_reaches_the_optimum_of_a_shifted_rotated_ellipsoid(name):
    """P = 12, T = 200 iterations, box [-100, 100]^3, 3 random optima in [-80, 80]^3: every run ends with
    f <= 0.2 (random points score ~1e4-1e5) and within 0.5 of the optimum. Measured worst of 8 runs:
    GA 0.044, MISMA 5e-3, SMA 5e-4, PSO 1e-9, CGO 0."""
    r, _ = batch(name)
    assert np.all(np.asarray(r.best_f[:3]) <= 0.2), np.asarray(r.best_f)
    assert np.all(np.linalg.norm(np.asarray(r.best_x[:3]) - np.asarray(AUX[0][:3]), axis=1) <= 0.5)


@pytest.mark.parametrize("name", NAMES)
def test_nan_fitness_never_yields_nan(name):
    """NaN from the fitness is +inf to the optimizer: best_f, curve and best_x are never NaN."""
    r, _ = batch(name)
    f, curve = np.asarray(r.best_f), np.asarray(r.curve)
    assert not np.any(np.isnan(f)) and not np.any(np.isnan(curve)) and not np.any(np.isnan(np.asarray(r.best_x)))
    assert np.isfinite(f[3]) and float(r.best_x[3, 0]) <= float(AUX[0][3, 0])  # half NaN: a valid point found
    assert np.isinf(f[4]) and np.all(np.isinf(curve[4]))  # all NaN: +inf, never NaN
    assert np.all(np.abs(np.asarray(r.best_x)) <= 100.0)


def test_evaluate_maps_nan_to_inf():
    o = AUX[0][3]
    f = evaluate(target, jnp.stack([o + 1.0, o - 1.0]), (o, 1))
    assert np.isinf(float(f[0])) and np.isfinite(float(f[1]))


@pytest.mark.parametrize("name, field, values", [
    ("cgo", "variant", ["matlab", "mealpy"]), ("cgo", "selection", ["truncation"]),
    ("cgo", "bound_mode", ["midpoint", "random"]), ("cgo", "dims", ["all", "one"]),
    ("cgo", "original_uniform", [True]), ("cgo", "wavelet_bounded", [True]), ("cgo", "chaos_guard", [False]),
    ("cgo", "alpha", ["dimension", "mealpy"]), ("cgo", "seed_form", ["matlab"]), ("cgo", "fourth_seed", [False]),
    ("ga", "crossover", ["blend"]), ("ga", "survivors", ["generational"]), ("misma", "p_mode", ["sma"]),
])
def test_every_static_option_traces(name, field, values):
    """Each code path chosen by a static option traces through the runner for every strategy (no Python
    ``if`` on a traced value, consistent shapes); jax.eval_shape, so nothing is compiled."""
    alg = get(name)
    for v in values:
        cfg = getattr(CGOConfig, v)() if field == "variant" else alg.make_config(**{field: v})
        assert getattr(cfg, field) == v
        configs = alg.axis_configs(cfg, STRATEGIES) if alg.axis else None
        out = jax.eval_shape(lambda k: run_batch(get(name), target, BOUNDS, k, P, 3, config=None if configs else cfg,
                                                 configs=configs, aux=AUX), KEYS)
        assert out.best_f.shape == ((len(STRATEGIES), 5) if configs else (5,))


# --------------------------------------------------------------- runner details


def test_cgo_counts_four_evals_per_seed():
    assert int(single("cgo")[0].n_evals) == P + 4 * P * T


def test_bind_step_matches_runner():
    T_short = 12
    opt = bind(get("pso"), sphere, BOUNDS, P)
    k_init, k_run = jax.random.split(jax.random.key(3))
    s = opt.init(k_init)
    step = jax.jit(opt.step, static_argnums=3)
    for t, k in enumerate(jax.random.split(k_run, T_short)):
        s = step(s, k, t, T_short)
    r = run(get("pso"), sphere, BOUNDS, jax.random.key(3), P, T_short)
    np.testing.assert_allclose(np.asarray(s.best_x), np.asarray(r.best_x), rtol=1e-12)
    assert int(s.n_evals) == int(r.n_evals)


def test_same_key_identical():
    cfg = CGOConfig(strategy="three_stage")  # same static fields as the default: the program of single("cgo")
    a = run(get("cgo"), target, BOUNDS, jax.random.key(7), P, T, config=cfg, aux=row(0))
    b = run(get("cgo"), target, BOUNDS, jax.random.key(7), P, T, config=cfg, aux=row(0))
    np.testing.assert_array_equal(np.asarray(a.curve), np.asarray(b.curve))
    np.testing.assert_array_equal(np.asarray(a.best_x), np.asarray(b.best_x))
    c = run(get("cgo"), target, BOUNDS, jax.random.key(8), P, T, config=cfg, aux=row(0))
    assert not np.array_equal(np.asarray(a.curve), np.asarray(c.curve))


def test_config_is_vmappable_data():
    """Data fields (CGO strategy, sigma) vmapped: 5 configs x 5 repeats are ONE traced program.

    The fitness is traced a fixed number of times (init and the scan body; JAX may re-trace once on a
    first compile), the same for 2 configs as for 5, not once per config; new keys, data, strategy
    order and sigma values reuse the program; each slice equals the single run with that config (to
    rounding: the fitness's reductions may round differently in the twice-vmapped program).
    """
    def fresh():  # a new fitness object is a new static argument: a first compile, whatever ran before
        def f(pop, aux):
            return target(pop, aux)
        return f

    configs = CGO.axis_configs(None, STRATEGIES)
    counts = {}
    for n_cfg in (2, 5):
        f = fresh()
        before = TRACES["target"]
        r = run_batch(get("cgo"), f, BOUNDS, KEYS, P, T, configs=configs[:n_cfg], aux=AUX)
        jax.block_until_ready(r.best_f)
        counts[n_cfg] = TRACES["target"] - before
    # the traces do not grow with the number of configs (a Python loop over 5 configs would trace 5x)
    assert counts[5] == counts[2] and 2 <= counts[5] <= 4, counts
    before = TRACES["target"]
    other = [dataclasses.replace(c, sigma=x) for c, x in zip(CGO.axis_configs(None, STRATEGIES[::-1]),
                                                              (0.1, 0.5, 2.0, 5.0, 50.0))]
    r2 = run_batch(get("cgo"), f, BOUNDS, jax.random.split(jax.random.key(12), 5), P, T, configs=other,
                   aux=(AUX[0] * 0.9, AUX[1]))
    jax.block_until_ready(r2.best_f)
    assert TRACES["target"] - before == 0  # new keys, data, order and sigma values: the same program
    assert r.best_f.shape == (5, 5) and r.curve.shape == (5, 5, T)
    for s, k in [(0, 0), (4, 1), (3, 1)]:  # KEYS[k], row k with k < 2: the program of single("cgo")
        alone = run(get("cgo"), target, BOUNDS, KEYS[k], P, T, config=configs[s], aux=row(k))
        np.testing.assert_allclose(np.asarray(r.curve[s, k]), np.asarray(alone.curve), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(np.asarray(r.best_x[s, k]), np.asarray(alone.best_x), rtol=1e-9, atol=1e-12)
    # each repeat optimised its own data: the best point is closer to its own optimum than to the others
    o = np.asarray(AUX[0][:3])
    d = np.linalg.norm(np.asarray(r.best_x)[:, :3, None, :] - o[None, None], axis=-1)
    assert np.all(np.argmin(d, axis=-1) == np.arange(3)[None, :])
    # a data field changes the values, not the program; a static field would change the program
    before = TRACES["target"]
    sig = run_batch(get("cgo"), f, BOUNDS, KEYS, P, T, aux=AUX,
                    configs=[dataclasses.replace(configs[2], sigma=x) for x in (0.5, 5.0, 50.0, 1.0, 1.0)])
    assert TRACES["target"] - before == 0
    assert not np.array_equal(np.asarray(sig.curve[0]), np.asarray(sig.curve[2]))
    np.testing.assert_array_equal(np.asarray(sig.curve[3]), np.asarray(r.curve[2]))  # sigma 1 = the gaussian row
    tree = jax.tree_util.tree_structure
    assert tree(dataclasses.replace(configs[0], sigma=7.0)) == tree(configs[0])
    assert tree(dataclasses.replace(configs[0], bound_mode="random")) != tree(configs[0])


def test_budget_to_iterations_and_best_at_evals():
    r = run(get("pso"), sphere, BOUNDS, jax.random.key(0), P, max_evals=P + 5 * P + 3)
    assert r.curve.shape == (5,) and int(r.n_evals) == 6 * P
    at = best_at_evals(r, [P, 2 * P, 6 * P])
    assert np.isinf(float(at[0]))  # no iteration finished within the initial population alone
    assert float(at[1]) == float(r.curve[0]) and float(at[2]) == float(r.curve[-1])


def test_axis_helpers_are_generic():
    assert CGO.axis == "strategy" and all(get(n).axis is None for n in NAMES if n != CGO.name)
    assert CGO.labels(["original", "three_stage"]) == ["cgo-original", "cgo-three_stage"]
    assert get("pso").labels(["original"]) == ["pso"]
    cfgs = CGO.axis_configs(CGOConfig.mealpy(sigma=2.0), ["chaos", 3])
    assert [c.strategy for c in cfgs] == [1, 3]
    assert all(c.variant == "mealpy" and c.sigma == 2.0 for c in cfgs)
    with pytest.raises(ValueError, match="'pso' has no side-by-side axis"):
        get("pso").axis_configs(None, ["chaos"])
    with pytest.raises(ValueError, match="non-empty sequence"):
        CGO.axis_configs(None, "chaos")


def test_static_fields_select_code():
    """Options that select code are static pytree metadata, not traced leaves; configs that differ in one
    cannot share a batched call (the error names the field)."""
    def static(cfg):
        return {f.name for f in dataclasses.fields(cfg)} - {
            str(p[0].name) for p, _ in jax.tree_util.tree_flatten_with_path(cfg)[0]}

    assert {"variant", "selection", "bound_mode", "dims", "original_uniform", "wavelet_bounded",
            "chaos_guard", "alpha", "seed_form", "fourth_seed", "overrides"} <= static(CGOConfig())
    assert "strategy" not in static(CGOConfig()) and "sigma" not in static(CGOConfig())
    assert {"crossover", "survivors", "tournament", "n_elite"} <= static(GAConfig())
    with pytest.raises(ValueError, match=r"configs\[1\] differs from configs\[0\] in \['selection', 'overrides'\]"):
        run_batch(get("cgo"), sphere, BOUNDS, KEYS, P, 2, configs=[CGOConfig(), CGOConfig.paper(selection="truncation")])
    with pytest.raises(ValueError, match="not both"):
        run_batch(get("cgo"), sphere, BOUNDS, KEYS, P, 2, config=CGOConfig(), configs=[CGOConfig()])
    with pytest.raises(ValueError, match="must be CGOConfig instances"):
        run_batch(get("cgo"), sphere, BOUNDS, KEYS, P, 2, configs=[GAConfig()])


# --------------------------------------------------------------- CGO variants


def test_cgo_variant_factories_set_every_variant_field():
    for variant, want in VARIANT_SETTINGS.items():
        cfg = getattr(CGOConfig, variant)()
        assert cfg.variant == variant and cfg.overrides == ()
        assert {f: getattr(cfg, f) for f in VARIANT_FIELDS} == want
        assert CGOConfig.build(variant=variant) == cfg
    assert CGOConfig() == CGOConfig.paper()
    assert (CGOConfig.matlab().selection, CGOConfig.matlab().original_uniform) == ("truncation", True)
    assert (CGOConfig.mealpy().bg_low, CGOConfig.mealpy().mg_size) == (0, 3)
    # keywords win; the deliberate changes are recorded
    c = CGOConfig.mealpy(bg_low=1, mg_size=3, sigma=2.0)
    assert (c.bg_low, c.mg_size, c.sigma, c.overrides) == (1, 3, 2.0, ("bg_low",))
    assert CGOConfig.build(variant="matlab", selection="greedy").overrides == ("selection",)


def test_cgo_replace_variant_is_refused_not_silently_mixed():
    """The trap of issue 14: replace(paper, variant=...) must not give a half-MATLAB config."""
    with pytest.raises(ValueError, match=r"variant 'matlab' sets selection='truncation', original_uniform=True"):
        dataclasses.replace(CGOConfig.paper(), variant="matlab")
    with pytest.raises(ValueError, match=r"CGOConfig\.mealpy\(\.\.\.\)"):
        CGOConfig(variant="mealpy")
    with pytest.raises(ValueError, match="variant 'paper' sets bg_low=1"):
        dataclasses.replace(CGOConfig.mealpy(), variant="paper")
    with pytest.raises(ValueError, match="variant 'mealpy' sets bg_low=0"):
        dataclasses.replace(CGOConfig.mealpy(), bg_low=1)  # a deviation must be named (use the factory)
    # replace of any other field keeps the variant consistent; a recorded override survives replace
    assert dataclasses.replace(CGOConfig.matlab(), sigma=3.0) == CGOConfig.matlab(sigma=3.0)
    assert dataclasses.replace(CGOConfig.mealpy(bg_low=1), strategy="chaos").bg_low == 1


def test_cgo_selection_greedy_and_truncation():
    """greedy: each seed keeps the best of itself and its 4 offspring; truncation (MATLAB): best P of the pool."""
    from icgo.optim.cgo import select

    rng = np.random.default_rng(0)
    X, seeds = rng.normal(size=(6, 2)), rng.normal(size=(6, 4, 2))
    f, fs = rng.random(6), rng.random((6, 4))
    gx, gf = (np.asarray(a) for a in select(X, f, seeds, fs, "greedy"))
    cand_f = np.concatenate([f[:, None], fs], axis=1)
    np.testing.assert_array_equal(gf, cand_f.min(axis=1))
    np.testing.assert_array_equal(gx, np.concatenate([X[:, None], seeds], axis=1)[np.arange(6), cand_f.argmin(1)])
    tx, tf = (np.asarray(a) for a in select(X, f, seeds, fs, "truncation"))
    np.testing.assert_array_equal(tf, np.sort(cand_f.ravel())[:6])
    pool = {tuple(x): v for x, v in zip(np.concatenate([X, seeds.reshape(-1, 2)]), np.concatenate([f, fs.ravel()]))}
    assert all(pool[tuple(x)] == v for x, v in zip(tx, tf))  # each survivor keeps its own fitness
    assert [CGOConfig.matlab().selection, CGOConfig.paper().selection, CGOConfig.mealpy().selection] == [
        "truncation", "greedy", "greedy"]


def test_a_cgo_variant_is_only_its_preset_of_options():
    """The MATLAB variant's run equals the paper variant with every MATLAB setting asked for one by one (per-dimension
    alpha, its seeds 2-3, a uniform 4th seed, truncation): bitwise, so each difference is an option of its own."""
    alike = CGOConfig.paper(alpha="dimension", seed_form="matlab", original_uniform=True, selection="truncation")
    assert alike.overrides == ("alpha", "original_uniform", "seed_form", "selection")
    a = run(get("cgo"), target, BOUNDS, KEYS[0], P, 20, config=CGOConfig.matlab(), aux=row(0))
    b = run(get("cgo"), target, BOUNDS, KEYS[0], P, 20, config=alike, aux=row(0))
    np.testing.assert_array_equal(np.asarray(a.curve), np.asarray(b.curve))
    np.testing.assert_array_equal(np.asarray(a.best_x), np.asarray(b.best_x))


@pytest.mark.parametrize("selection", ["greedy", "truncation"])
def test_cgo_without_the_fourth_seed_and_the_seed_outcomes(selection):
    """fourth_seed=False: three seeds per member and iteration (3 P evaluations), the budget converts with it; each
    iteration's SeedOutcome agrees with the selection it describes (a chosen seed is in the next population, an
    improved one beat its parent)."""
    from icgo.optim.cgo import advance

    cfg = CGOConfig.paper(fourth_seed=False, selection=selection)
    r = run(get("cgo"), target, BOUNDS, KEYS[1], P, 15, config=cfg, aux=row(1))
    assert int(r.n_evals) == P + 3 * P * 15
    assert get("cgo").evals(P, cfg) == (P, 3 * P) and get("cgo").evals(P, CGOConfig()) == (P, 4 * P)
    assert int(run(get("cgo"), target, BOUNDS, KEYS[1], P, max_evals=P + 3 * P * 7, config=cfg, aux=row(1)).n_evals) \
        == P + 3 * P * 7
    opt = bind(get("cgo"), target, BOUNDS, P, cfg)
    s = opt.init(KEYS[2], row(1))
    for t, k in enumerate(jax.random.split(KEYS[3], 6)):
        nxt, out = advance(s, k, t, 6, target)
        assert out.improved.shape == out.chosen.shape == (P, 3)
        step = opt.step(s, k, t, 6)
        np.testing.assert_array_equal(np.asarray(nxt.pop), np.asarray(step.pop))  # advance is the step
        kept = {tuple(np.round(x, 12)) for x in np.asarray(nxt.pop)}
        parents = {tuple(np.round(x, 12)) for x in np.asarray(s.pop)}
        if selection == "greedy":  # a chosen seed replaced its parent, and only an improving one can be chosen
            assert not np.any(np.asarray(out.chosen) & ~np.asarray(out.improved))
            assert np.asarray(out.chosen).any(axis=1).sum() == sum(tuple(np.round(x, 12)) not in parents
                                                                  for x in np.asarray(nxt.pop))
        else:
            assert np.asarray(out.chosen).sum() == sum(x not in parents for x in kept)
        s = nxt


def test_cgo_bound_repair_modes():
    """clip = np.clip; midpoint = (parent + violated bound) / 2; random: violated coords redrawn in the box."""
    from icgo.optim.cgo import repair

    lb, ub = jnp.array([-1.0, -1.0, 0.0]), jnp.array([1.0, 2.0, 5.0])
    parent = jnp.array([[0.5, 1.0, 4.0]])
    S = jnp.array([[3.0, -4.0, 2.5], [-0.2, 2.5, -1.0]])
    np.testing.assert_array_equal(np.asarray(repair(jax.random.key(0), S, parent, lb, ub, "clip")),
                                  np.clip(np.asarray(S), np.asarray(lb), np.asarray(ub)))
    mid = np.asarray(repair(jax.random.key(0), S, parent, lb, ub, "midpoint"))
    np.testing.assert_allclose(mid, [[0.75, 0.0, 2.5], [-0.2, 1.5, 2.0]], rtol=1e-15)
    rnd = np.asarray(repair(jax.random.key(0), jnp.tile(S, (500, 1)), parent, lb, ub, "random")).reshape(500, 2, 3)
    bad = (np.asarray(S) < np.asarray(lb)) | (np.asarray(S) > np.asarray(ub))
    np.testing.assert_array_equal(rnd[:, ~bad], np.broadcast_to(np.asarray(S)[~bad], (500, int((~bad).sum()))))
    assert np.all(rnd >= np.asarray(lb)) and np.all(rnd <= np.asarray(ub))
    # redrawn coordinate of dimension 1 (bounds -1..2) is uniform: mean 0.5, spans the box
    assert abs(rnd[:, 0, 1].mean() - 0.5) < 0.15 and rnd[:, 0, 1].min() < -0.8 and rnd[:, 0, 1].max() > 1.8


@pytest.mark.parametrize("call, msg", [
    (lambda: run(get("cgo"), sphere, BOUNDS, jax.random.key(0), 3, 2), "pop_size must be an integer >= 4"),
    (lambda: run(get("cgo"), sphere, (np.zeros(3), np.array([1.0, 0.0, 1.0])), jax.random.key(0), 8, 2),
     "lower bound >= upper bound in dimension 1"),
    (lambda: CGOConfig(strategy="levy_flight"), "unknown strategy"),
    (lambda: CGO.axis_configs(None, ["chaos", "levy_flight"]), "unknown strategy"),
    (lambda: run(get("cgo"), sphere, BOUNDS, jax.random.key(0), 8, max_evals=8 + 31), "smaller than one iteration"),
    (lambda: run(get("nope"), sphere, BOUNDS, jax.random.key(0), 8, 2), "unknown optimizer"),
    (lambda: run(get("pso"), sphere, BOUNDS, jax.random.key(0), 8), "exactly one stop criterion"),
    (lambda: run_batch(get("cgo"), target, BOUNDS, jax.random.split(jax.random.key(0), 2), 8, 2, aux=AUX),
     "leading axis 2"),
    (lambda: run(get("pso"), lambda p: jnp.sum(p), BOUNDS, jax.random.key(0), 8, 2), r"fitness must return shape \(8,\)"),
    (lambda: CGOConfig.build(variant="python"), "unknown CGO variant"),
    (lambda: CGOConfig.paper(variant="matlab"), "take the variant from their name"),
    (lambda: CGOConfig(mu=2.0), r"mu must be in \[3.57, 4\]"),
    (lambda: CGOConfig(bound_mode="reflect"), "unknown CGO bound_mode"),
    (lambda: CGOConfig(selection=1), "unknown CGO selection 1"),
    (lambda: CGOConfig(wavelet_bounded=1), "wavelet_bounded must be True or False"),
    (lambda: CGOConfig.paper(mg_size=-1), "mg_size must be an integer >= 0"),
    (lambda: CGOConfig(overrides=("sigma",)), "overrides must be a tuple of names"),
    (lambda: GAConfig(crossover=1), "unknown GA crossover 1"),
])
def test_bad_configs_one_line(call, msg):
    with pytest.raises(ValueError, match=msg) as e:
        call()
    assert "\n" not in str(e.value)


def test_no_python_loop_over_population_in_optim():
    """No for/while statement inside any function of icgo/optim (loops are lax.scan / vectorised)."""
    root = pathlib.Path(icgo.__file__).parent / "optim"
    offenders = []
    for path in root.glob("*.py"):
        tree = ast.parse(path.read_text())
        for fn in ast.walk(tree):
            if isinstance(fn, ast.FunctionDef) and fn.name != "__post_init__":
                for node in ast.walk(fn):
                    if isinstance(node, (ast.For, ast.While)):
                        offenders.append(f"{path.name}:{node.lineno} in {fn.name}")
    # _batch_chunked, run_members: the host loop over a run's chunks of iterations (progress between jitted calls)
    # and over the inputs' pytrees when checking them
    allowed = {"base.py": {"check_bounds", "_tree_differences", "run_batch", "_batch_chunked"},
               "sharded.py": {"run_members"}}
    bad = [o for o in offenders if o.split(" in ")[1] not in allowed.get(o.split(":")[0], set())]
    assert not bad, bad


def test_no_optimizer_specific_code_in_the_runner():
    """base.py imports no algorithm module and no registry (the algorithms and the registry build on it) and
    names no algorithm's options (the axis is generic)."""
    src = (pathlib.Path(icgo.__file__).parent / "optim" / "base.py").read_text()
    tree = ast.parse(src)
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert {m for m in imported if m and m.startswith("icgo")} <= {"icgo.core.errors"}, imported
    code = "\n".join(line for line in src.splitlines() if not line.lstrip().startswith(("#", "*", "`")))
    assert '== "cgo"' not in code and "strategy_index" not in code


def test_dataclass_configs_replace():
    c = dataclasses.replace(CGOConfig(), strategy="wavelet")
    assert c.strategy == 3


@pytest.mark.parametrize("name", sorted(OPTIMIZERS))
def test_minus_inf_is_not_a_valid_fitness(name):
    """A fitness that returns -inf for some candidates: they are dropped like NaN, never the best."""
    def f(pop):
        v = jnp.sum(pop**2, axis=1)
        return jnp.where(pop[:, 0] > 0.5, -jnp.inf, v)

    alg = OPTIMIZERS[name]
    res = run(get(name), f, (-np.ones(3), np.ones(3)), jax.random.key(1), 8, 5, config=alg.config_cls())
    assert np.isfinite(float(res.best_f)) and float(res.best_f) >= 0.0
    assert float(res.best_x[0]) <= 0.5
