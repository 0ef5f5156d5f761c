"""GA operators: SBX against its closed-form spread distribution, the per-variable
exchange, survivor rules, and the recombination defect the exchange fixes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.optim import bind, run_batch
from icgo.optim.ga import GAConfig, sbx
from icgo.optim.registry import get

N, D = 4000, 5


@pytest.fixture(scope="module")
def parents():
    k1, k2 = jax.random.split(jax.random.key(0))
    return jax.random.uniform(k1, (N, D), minval=-50, maxval=50), jax.random.uniform(k2, (N, D), minval=-50, maxval=50)


@pytest.mark.parametrize("eta", [2.0, 15.0])
def test_sbx_spread_follows_deb_distribution(parents, eta):
    """|c1 - c2| = beta |p1 - p2|; P(beta <= b) = b^(eta+1) / 2 for b <= 1 (Deb & Agrawal 1995)."""
    p1, p2 = parents
    c1, c2 = sbx(jax.random.key(1), jax.random.key(2), p1, p2, eta, 0.5)
    np.testing.assert_allclose(np.asarray(c1 + c2), np.asarray(p1 + p2), rtol=1e-12, atol=1e-9)  # mean kept
    beta = np.abs(np.asarray(c1 - c2)) / np.abs(np.asarray(p1 - p2))
    for b in (0.5, 0.9, 0.98):
        want = 0.5 * b ** (eta + 1)
        got = np.mean(beta <= b)
        assert abs(got - want) < 4 * np.sqrt(want * (1 - want) / beta.size) + 1e-4, (b, got, want)
    b = 1.05  # P(beta > b) = b^-(eta+1) / 2
    assert abs(np.mean(beta > b) - 0.5 * b ** -(eta + 1)) < 0.01


def test_sbx_exchange_recombines(parents):
    """Without the exchange child 1 stays near parent 1 in every variable; with 1/2 it takes half from each."""
    p1, p2 = parents
    far = np.abs(np.asarray(p1 - p2)) > 10.0
    for swap, want in [(0.0, 0.0), (0.5, 0.5), (1.0, 1.0)]:
        c1, _ = sbx(jax.random.key(3), jax.random.key(4), p1, p2, 15.0, swap)
        near_p2 = np.abs(np.asarray(c1 - p2)) < np.abs(np.asarray(c1 - p1))
        assert abs(np.mean(near_p2[far]) - want) < 0.02, (swap, np.mean(near_p2[far]))


def _sphere(pop):
    return jnp.sum((pop - 17.0) ** 2, axis=1)


@pytest.mark.parametrize("survivors", ["plus", "generational"])
def test_survivor_rules(survivors):
    P = 12
    opt = bind(get("ga"), _sphere, (-100.0 * np.ones(D), 100.0 * np.ones(D)), P, GAConfig(survivors=survivors))
    s0 = jax.jit(opt.init)(jax.random.key(5))
    s1 = jax.jit(opt.step, static_argnums=3)(s0, jax.random.key(6), 0, 10)
    f0, f1 = np.sort(np.asarray(s0.fit)), np.sort(np.asarray(s1.fit))
    np.testing.assert_allclose(np.asarray(_sphere(s1.pop)), np.asarray(s1.fit), rtol=1e-12)
    if survivors == "plus":  # k-th best never gets worse
        assert np.all(f1 <= f0)
    else:  # the two elites survive, the rest are offspring
        assert np.all(np.isin(f0[:2], np.asarray(s1.fit)))


def test_exchange_fixes_ga_on_shifted_sphere():
    """The defect: SBX without the exchange (the old code, generational survivors) loses by a wide margin."""
    keys = jax.random.split(jax.random.key(7), 8)
    bounds = (-100.0 * np.ones(30), 100.0 * np.ones(30))
    med = {}
    for swap in (0.0, 0.5):
        r = run_batch(get("ga"), _sphere, bounds, keys, 20, 60, config=GAConfig(survivors="generational", sbx_swap=swap))
        med[swap] = float(np.median(np.asarray(r.best_f)))
    print(med)
    assert med[0.5] < 0.2 * med[0.0], med


def test_bad_survivors():
    with pytest.raises(ValueError, match="unknown GA survivors"):
        GAConfig(survivors="steady")
