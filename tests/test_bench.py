"""Building blocks of experiments/bench.py at tiny sizes (no timing is tested)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from experiments import bench
from icgo import relm


def _data(n=60, hidden=5, seed=0, scale=1.0):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, 6))
    T = np.sin(X[:, 0]) + 0.3 * X[:, 1] * X[:, 2] + 0.01 * rng.standard_normal(n)
    mask = (rng.random(n) < 0.7).astype(float)
    pop = scale * rng.uniform(-1, 1, (8, relm.n_params(hidden)))
    fit = relm.FitData(jnp.asarray(X), jnp.asarray(T), jnp.asarray(mask)[None], jnp.asarray(mask)[None])
    return X, T, mask, jnp.asarray(pop), fit


def test_flop_count_matches_hand_count():
    # n=10, L=2, d=6: 2ndL 240 + nL 20 + sigmoid 3nL 60 + Gram 2nL^2 80 + H^T T 40
    # + Cholesky L^3/3 -> 2 + solves 2L^2 8 + H beta 40 + residual 3n 30 + ridge L 2
    assert bench.flops_per_eval(10, hidden=2, d=6) == 522
    # the Gram term dominates at the paper's scale
    assert 2 * 407 * 30**2 / bench.flops_per_eval(407) > 0.7


def test_numpy_fitness_equals_jax_fitness():
    X, T, mask, pop, fit = _data()
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    idx = mask > 0
    got = np.array([bench.numpy_fitness(np.asarray(th), X[idx], T[idx], 1e-3, 5) for th in pop])
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=0)


def test_compact_keeps_exactly_the_training_rows():
    X, T, mask, pop, fit = _data()
    c = bench.compact(fit, int(mask.sum()))
    np.testing.assert_array_equal(np.asarray(c.Xa[:, :6]), X[mask > 0])
    np.testing.assert_array_equal(np.asarray(c.Xa[:, 6]), 1.0)
    np.testing.assert_array_equal(np.asarray(c.T), T[mask > 0])
    # batched (leading repeat axis) gives the same rows
    cb = bench.compact(jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), fit), int(mask.sum()))
    np.testing.assert_array_equal(np.asarray(cb.T[1]), np.asarray(c.T))


@pytest.mark.parametrize("scale", [1.0, 0.05])  # 0.05: near-linear sigmoids, ill-conditioned Gram
def test_mixed_precision_fitness_matches_float64(scale):
    X, T, mask, pop, fit = _data(scale=scale)
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    c = bench.compact(fit, int(mask.sum()))
    got = np.asarray(bench.fast_fitness(pop, c, 1e-3, 5, chunk=3, refine=2))
    np.testing.assert_allclose(got, ref, rtol=1e-9)
    # float64 Gram without refinement: the same numbers
    f64 = np.asarray(bench.fast_fitness(pop, c, 1e-3, 5, chunk=3, refine=0, gram_dtype="float64"))
    np.testing.assert_allclose(f64, ref, rtol=1e-10)


def test_refinement_is_what_recovers_float64():
    # without refinement the float32 Gram is visibly off on ill-conditioned features;
    # the refinement steps bring it back (so the check above can fail)
    X, T, mask, pop, fit = _data(scale=0.05, seed=1)
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    c = bench.compact(fit, int(mask.sum()))
    err = [np.max(np.abs(np.asarray(bench.fast_fitness(pop, c, 1e-3, 5, 3, k)) / ref - 1)) for k in (0, 2)]
    assert err[1] < 1e-9 < err[0]


def test_nonfinite_fitness_is_inf():
    X, T, mask, pop, fit = _data()
    c = bench.compact(fit, int(mask.sum()))
    bad = pop.at[0, 0].set(jnp.nan)
    f = np.asarray(bench.fast_fitness(bad, c, 1e-3, 5, chunk=3))
    assert f[0] == np.inf and np.isfinite(f[1:]).all()
