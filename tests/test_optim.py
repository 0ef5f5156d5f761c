"""Optimizer interface, runner, determinism, compile-once, aux data, bad configs.

Small shapes (D=3, P=8) keep compilation cheap; every algorithm in the registry
gets the same API tests.
"""

import ast
import dataclasses
import logging
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.optim import OPTIMIZERS, STRATEGIES, base, best_at_evals, bind, evaluate, run, run_batch
from icgo.optim.cgo import CGOConfig

D, P, T = 3, 8, 12
SHIFT = jnp.array([12.0, -30.0, 47.0])
BOUNDS = (-100.0 * np.ones(D), 100.0 * np.ones(D))


def sphere(pop):
    return jnp.sum((pop - SHIFT) ** 2, axis=1)


def shifted(pop, aux):
    return jnp.sum((pop - aux) ** 2, axis=1)


NAMES = ("cgo", "pso", "ga", "sma")


@pytest.fixture(scope="module")
def results():
    return {n: run(n, sphere, BOUNDS, jax.random.key(3), P, T) for n in NAMES}


def test_registry_has_the_four():
    assert set(NAMES) <= set(OPTIMIZERS)
    assert STRATEGIES == ("original", "chaos", "gaussian", "wavelet", "three_stage")


@pytest.mark.parametrize("name", NAMES)
def test_run_contract(results, name):
    r = results[name]
    alg = OPTIMIZERS[name]
    first, per = alg.evals(P, alg.config_cls())
    assert r.curve.shape == (T,) and r.evals_curve.shape == (T,)
    np.testing.assert_array_equal(np.asarray(r.evals_curve), first + per * np.arange(1, T + 1))
    assert int(r.n_evals) == first + per * T
    assert np.all(np.diff(np.asarray(r.curve)) <= 0)  # best-so-far never rises
    assert float(r.best_f) == float(r.curve[-1])
    np.testing.assert_allclose(float(sphere(r.best_x[None])[0]), float(r.best_f), rtol=1e-12)
    assert np.all(np.abs(np.asarray(r.best_x)) <= 100.0)
    # better than the best of the initial population (random box samples)
    init = alg.init(jax.random.split(jax.random.key(3))[0], sphere, BOUNDS, P)
    assert float(r.best_f) < float(init.best_f)


def test_cgo_counts_four_evals_per_seed(results):
    assert int(results["cgo"].n_evals) == P + 4 * P * T


def test_bind_step_matches_runner():
    opt = bind("pso", sphere, BOUNDS, P)
    k_init, k_run = jax.random.split(jax.random.key(3))
    s = opt.init(k_init)
    step = jax.jit(opt.step, static_argnums=3)
    for t, k in enumerate(jax.random.split(k_run, T)):
        s = step(s, k, t, T)
    r = run("pso", sphere, BOUNDS, jax.random.key(3), P, T)
    np.testing.assert_allclose(np.asarray(s.best_x), np.asarray(r.best_x), rtol=1e-12)
    assert int(s.n_evals) == int(r.n_evals)


def test_same_key_identical():
    a = run("cgo", sphere, BOUNDS, jax.random.key(7), P, T, strategy="three_stage")
    b = run("cgo", sphere, BOUNDS, jax.random.key(7), P, T, strategy="three_stage")
    np.testing.assert_array_equal(np.asarray(a.curve), np.asarray(b.curve))
    np.testing.assert_array_equal(np.asarray(a.best_x), np.asarray(b.best_x))
    c = run("cgo", sphere, BOUNDS, jax.random.key(8), P, T, strategy="three_stage")
    assert not np.array_equal(np.asarray(a.curve), np.asarray(c.curve))


def _compiles_of_batch(records):
    return sum(1 for m in records if m.startswith("Compiling jit(_batch_jit)"))


class _Collect(logging.Handler):
    def __init__(self):
        super().__init__()
        self.msgs = []

    def emit(self, record):
        self.msgs.append(record.getMessage())


def test_five_strategies_vmapped_compile_once_and_match_single_runs():
    """5 strategies x 3 repeats with per-repeat aux: one compile; slice == single run."""
    keys = jax.random.split(jax.random.key(11), 3)
    aux = jnp.stack([SHIFT, -SHIFT, 0.5 * SHIFT])
    h = _Collect()
    logging.getLogger("jax").addHandler(h)
    try:
        with jax.log_compiles():
            r = run_batch("cgo", shifted, BOUNDS, keys, P, T, strategies=STRATEGIES, aux=aux)
            jax.block_until_ready(r.best_f)
            # different keys, data and strategy order: same program
            r2 = run_batch("cgo", shifted, BOUNDS, jax.random.split(jax.random.key(12), 3), P, T,
                           strategies=STRATEGIES[::-1], aux=aux * 0.9)
            jax.block_until_ready(r2.best_f)
    finally:
        logging.getLogger("jax").removeHandler(h)
    assert _compiles_of_batch(h.msgs) == 1, h.msgs
    assert r.best_f.shape == (5, 3) and r.curve.shape == (5, 3, T)
    for s, k in [(0, 0), (4, 2), (3, 1)]:
        alone = run("cgo", shifted, BOUNDS, keys[k], P, T, strategy=STRATEGIES[s], aux=aux[k])
        np.testing.assert_array_equal(np.asarray(r.curve[s, k]), np.asarray(alone.curve))
        np.testing.assert_array_equal(np.asarray(r.best_x[s, k]), np.asarray(alone.best_x))
    # each repeat optimised its own data: the best point is closer to its own shift than to the others
    d = np.linalg.norm(np.asarray(r.best_x)[:, :, None, :] - np.asarray(aux)[None, None], axis=-1)
    assert np.all(np.argmin(d, axis=-1) == np.arange(3)[None, :])


def test_batch_without_strategies_matches_single_run():
    keys = jax.random.split(jax.random.key(5), 2)
    r = run_batch("sma", sphere, BOUNDS, keys, P, T)
    alone = run("sma", sphere, BOUNDS, keys[1], P, T)
    np.testing.assert_array_equal(np.asarray(r.curve[1]), np.asarray(alone.curve))


def test_budget_to_iterations_and_best_at_evals():
    r = run("pso", sphere, BOUNDS, jax.random.key(0), P, max_evals=P + 5 * P + 3)
    assert r.curve.shape == (5,) and int(r.n_evals) == 6 * P
    at = best_at_evals(r, [P, 2 * P, 6 * P])
    assert np.isinf(float(at[0]))  # no iteration finished within the initial population alone
    assert float(at[1]) == float(r.curve[0]) and float(at[2]) == float(r.curve[-1])


def test_nan_fitness_is_dropped():
    def half_nan(pop):
        return jnp.where(pop[:, 0] > 0, jnp.nan, jnp.sum((pop + 20.0) ** 2, axis=1))

    f = evaluate(half_nan, jnp.array([[1.0, 0, 0], [-1.0, 0, 0]]), None)
    assert np.isinf(float(f[0])) and np.isfinite(float(f[1]))
    for name in ("cgo", "sma"):  # the two with fitness-weighted formulas
        r = run(name, half_nan, BOUNDS, jax.random.key(1), P, T)
        assert np.isfinite(float(r.best_f)) and float(r.best_x[0]) <= 0, name
        assert not np.any(np.isnan(np.asarray(r.curve)))


def test_cgo_matlab_truncation_and_paper_greedy():
    configs = [(CGOConfig.matlab(), "sorted"), (CGOConfig(), "greedy"), (CGOConfig(variant="mealpy"), "greedy")]
    for cfg, check in configs:
        opt = bind("cgo", sphere, BOUNDS, P, cfg)
        s0 = jax.jit(opt.init)(jax.random.key(2))
        s1 = jax.jit(opt.step, static_argnums=3)(s0, jax.random.key(4), 0, T)
        f0, f1 = np.asarray(s0.fit), np.asarray(s1.fit)
        np.testing.assert_allclose(np.asarray(sphere(s1.pop)), f1, rtol=1e-12)
        if check == "sorted":  # best N of the (N + 4N) pool, ascending
            assert np.all(np.diff(f1) >= 0) and f1[-1] <= np.sort(f0)[-1]
        else:  # each seed keeps the best of itself and its four offspring
            assert np.all(f1 <= f0)


def test_cgo_bound_repair_modes():
    """clip = np.clip; midpoint = (parent + violated bound) / 2; random: violated coords redrawn in the box."""
    from icgo.optim.cgo import repair

    lb, ub = jnp.array([-1.0, -1.0, 0.0]), jnp.array([1.0, 2.0, 5.0])
    parent = jnp.array([[0.5, 1.0, 4.0]])
    S = jnp.array([[3.0, -4.0, 2.5], [-0.2, 2.5, -1.0]])
    np.testing.assert_array_equal(np.asarray(repair(jax.random.key(0), S, parent, lb, ub, 0)),
                                  np.clip(np.asarray(S), np.asarray(lb), np.asarray(ub)))
    mid = np.asarray(repair(jax.random.key(0), S, parent, lb, ub, 1))
    np.testing.assert_allclose(mid, [[0.75, 0.0, 2.5], [-0.2, 1.5, 2.0]], rtol=1e-15)
    rnd = np.asarray(repair(jax.random.key(0), jnp.tile(S, (500, 1)), parent, lb, ub, 2)).reshape(500, 2, 3)
    bad = (np.asarray(S) < np.asarray(lb)) | (np.asarray(S) > np.asarray(ub))
    np.testing.assert_array_equal(rnd[:, ~bad], np.broadcast_to(np.asarray(S)[~bad], (500, int((~bad).sum()))))
    assert np.all(rnd >= np.asarray(lb)) and np.all(rnd <= np.asarray(ub))
    # redrawn coordinate of dimension 1 (bounds -1..2) is uniform: mean 0.5, spans the box
    assert abs(rnd[:, 0, 1].mean() - 0.5) < 0.15 and rnd[:, 0, 1].min() < -0.8 and rnd[:, 0, 1].max() > 1.8
    r = run("cgo", sphere, BOUNDS, jax.random.key(3), P, T, config=CGOConfig(bound_mode="random"))
    assert np.all(np.abs(np.asarray(r.best_x)) <= 100.0) and np.isfinite(float(r.best_f))


def test_config_is_vmappable_data():
    """A hyperparameter (CGO sigma) vmapped as data: one traced program for several values."""
    cfg = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(jnp.asarray(x), (2,) + jnp.shape(x)), CGOConfig(strategy=2))
    cfg = dataclasses.replace(cfg, sigma=jnp.array([0.5, 5.0]))
    one = jax.vmap(lambda c: base._run_one(OPTIMIZERS["cgo"], sphere, P, 4, jax.random.key(0),
                                           jnp.asarray(BOUNDS[0]), jnp.asarray(BOUNDS[1]), c, None).best_f)
    out = one(cfg)
    assert out.shape == (2,) and np.all(np.isfinite(np.asarray(out)))


@pytest.mark.parametrize("call, msg", [
    (lambda: run("cgo", sphere, BOUNDS, jax.random.key(0), 3, 2), "pop_size must be an integer >= 4"),
    (lambda: run("cgo", sphere, (np.zeros(3), np.array([1.0, 0.0, 1.0])), jax.random.key(0), 8, 2),
     "lower bound >= upper bound in dimension 1"),
    (lambda: run("cgo", sphere, BOUNDS, jax.random.key(0), 8, 2, strategy="levy_flight"), "unknown strategy"),
    (lambda: run("cgo", sphere, BOUNDS, jax.random.key(0), 8, max_evals=8 + 31), "smaller than one iteration"),
    (lambda: run("nope", sphere, BOUNDS, jax.random.key(0), 8, 2), "unknown optimizer"),
    (lambda: run("pso", sphere, BOUNDS, jax.random.key(0), 8, 2, strategy="chaos"), "has no 'strategy'"),
    (lambda: run("pso", sphere, BOUNDS, jax.random.key(0), 8), "exactly one stop criterion"),
    (lambda: run_batch("cgo", shifted, BOUNDS, jax.random.split(jax.random.key(0), 2), 8, 2, aux=jnp.zeros((3, 3))),
     "leading axis 2"),
    (lambda: run("pso", lambda p: jnp.sum(p), BOUNDS, jax.random.key(0), 8, 2), r"fitness must return shape \(8,\)"),
    (lambda: CGOConfig(variant="python"), "unknown CGO variant"),
    (lambda: CGOConfig(mu=2.0), r"mu must be in \[3.57, 4\]"),
    (lambda: CGOConfig(bound_mode="reflect"), "unknown CGO bound_mode"),
    (lambda: CGOConfig(mg_size=-1), "mg_size must be an integer >= 0"),
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
    allowed = {"base.py": {"check_bounds", "_with_strategy", "run_batch"}}
    bad = [o for o in offenders if o.split(" in ")[1] not in allowed.get(o.split(":")[0], set())]
    assert not bad, bad


def test_cgo_variant_defaults():
    paper, matlab, mp = CGOConfig(), CGOConfig.matlab(), CGOConfig(variant="mealpy")
    assert (paper.bg_low, paper.mg_size, paper.selection) == (1, 0, 0)
    assert (matlab.bg_low, matlab.mg_size, matlab.selection) == (1, 0, 1)
    assert (mp.bg_low, mp.mg_size, mp.selection, mp.original_uniform) == (0, 3, 0, False)
    assert CGOConfig(variant="mealpy", bg_low=1, mg_size=0).bg_low == 1  # explicit values win


def test_dataclass_configs_replace():
    c = dataclasses.replace(CGOConfig(), strategy="wavelet")
    assert c.strategy == 3
