"""Building blocks of experiments/optimizers.py: the independent numpy fitness given to mealpy,
the equal-budget evaluation count on the mealpy side, and the +/=/- rule."""

import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from experiments.optimizers import _numpy_fn, _sign, mealpy_runs
from icgo import benchmarks as bm


@pytest.mark.parametrize("name", bm.STUDY)
def test_numpy_fitness_matches_jax_benchmark(name):
    rng = np.random.default_rng(0)
    x = rng.uniform(-100, 100, (5, 10))
    f_np = np.array([_numpy_fn(name, 10)(xi) for xi in x])
    np.testing.assert_allclose(f_np, np.asarray(bm.make(name, 10).fn(x)), rtol=1e-9)


@pytest.mark.parametrize("algo, budget", [("cgo", 20 + 2 * 80), ("pso", 20 + 3 * 20)])
def test_mealpy_side_spends_the_budget(algo, budget):
    _, _, _, vals, evals = mealpy_runs("sphere", 10, algo, 2, 20, budget)
    assert vals.shape == (2,) and np.all(vals > 0)
    np.testing.assert_array_equal(evals, [budget, budget])


def test_sign_rule():
    a = np.arange(30.0)
    assert _sign(a, a) == ("=", 1.0)
    assert _sign(a, a + 100)[0] == "+" and _sign(a + 100, a)[0] == "-"
    s, p = _sign(a, a + 0.5)
    assert s == "=" and p > 0.05
